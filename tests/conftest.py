import torch

torch.set_num_threads(1)


import pytest  # noqa: E402


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory):
    """A collected tiny data set (``tests/dataset_helpers.TINY``), built once per session."""
    from v2xbench.collectors.dataset.collect import collect

    from tests.dataset_helpers import TINY

    root = tmp_path_factory.mktemp("v2x_data")
    collect(TINY, root, workers=1, progress=False)
    return root
