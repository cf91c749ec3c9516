"""Smoke test of examples/ppo_torchrl.py: its ``--tiny`` mode runs end to end (seconds).

The learning claim (route completion rising far above a standing car's) is measured by a real
run and written in the example's docstring and the README, not asserted here.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "ppo_torchrl.py"


def test_ppo_example_tiny(tmp_path):
    out, png = tmp_path / "ppo.json", tmp_path / "curve.png"
    cmd = [sys.executable, str(EXAMPLE), "--tiny", "--out", str(out), "--plot", str(png)]
    # ~5 s with the numba kernels cached (as after any earlier test); a cold cache compiles first
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads(out.read_text())
    assert res["frames"] == 256 and res["num_worlds"] == 2
    assert res["env_config"]["action_mode"] == "accel_steer"
    assert [f for f, _ in res["curve"]] == [0, 256]  # before training and after it
    for m in (res["standing"], res["uniform_random"], res["start"], res["end"]):
        assert 0.0 <= m["route_completion"] <= 100.0 and math.isfinite(m["collision_pct"])
    assert res["standing"]["route_completion"] < 10.0  # a standing car does not get far
    assert png.stat().st_size > 1000 and png.read_bytes()[:4] == b"\x89PNG"
    assert "route completion" in proc.stdout
