"""A tiny collected data set shared by the dataset and Chat-V2XBench tests."""

from __future__ import annotations

from pathlib import Path

from v2xbench.collectors.dataset.collect import CollectConfig

#: two training routes kept apart from the shipped suites (a suite rebuild does not change what
#: the tests collect): ControlLoss on Town02, SignalizedJunctionRightTurn on Town03
TINY_SUITE = str(Path(__file__).parent / "fixtures" / "tiny_suite.json")
#: 2 train routes x 40 ticks, small cameras and LiDARs (about 5 s to collect)
TINY = CollectConfig(suite=TINY_SUITE, max_routes=2, max_ticks=40, camera_size=(32, 16), lidar_scale=0.5,
                     val_fraction=0.5)


#: one-step training calls of the AURORA stage tests (``train_stage`` / ``train_late_stage``)
ONE_STEP = dict(max_steps=1, stride=8, progress=False)


def branches_run(tiny_dataset: Path, tmp_path: Path) -> tuple[Path, Path]:
    """``(data, run)``: a copy of the tiny data set with its QA items and a tiny AURORA run with
    stages 1-2 trained one step each (the start of the late-stage tests)."""
    import shutil

    import torch
    from v2xbench.agents.aurora.cli import train_stage
    from v2xbench.collectors.chat.export import build as build_qa

    torch.set_num_threads(1)
    data, run = tmp_path / "data", tmp_path / "run"
    shutil.copytree(tiny_dataset, data)
    build_qa(data)
    for s in (1, 2):
        train_stage(data, run, s, scale="tiny", **ONE_STEP)
    return data, run
