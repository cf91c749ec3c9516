"""``v2xbench ab``: the revision's package is imported from its own tree, not the editable install."""

import subprocess
import sys
from pathlib import Path

import pytest
from v2xbench.benchmarks import ab

REPO = Path(__file__).resolve().parents[1]


def test_package_dir_imports_from_the_given_tree(tmp_path):
    pkg = ab._package_dir(REPO, tmp_path / "pkg")
    probe = ab.CHILD.split("import numpy as np")[0] + (
        "import v2xbench.envs.v2x_intersection.sim.world as w, v2xbench.benchmarks.ab as b; print(w.__file__, b.__file__)")
    out = subprocess.run([sys.executable, "-c", probe, "objects", "1", str(pkg)], capture_output=True, text=True,
                         check=True).stdout
    world_file, ab_file = out.split()
    assert world_file.startswith(str(pkg)) and ab_file.startswith(str(pkg))


@pytest.mark.parametrize("mode, ticks", [("objects", 20), ("test50", 50), ("perception", 20), ("expert", 20)])
def test_child_measures_this_checkout(mode, ticks):
    us = ab._measure(mode, ticks, None)
    assert 0.0 < us < 1e6


@pytest.mark.slow
def test_ab_against_head():
    res = ab.ab("HEAD", pairs=1, ticks=50)
    assert res["mode"] == "objects" and len(res["revision_us"]) == len(res["this_us"]) == 1
    assert res["median_ratio"] > 0.0
