"""``v2xbench floor`` (``benchmarks/kernel_floor.py``): the report's accounting, that every kernel of
an objects tick is captured, and that the kernels are put back. No timing is asserted."""

from __future__ import annotations

import json

import pytest
from v2xbench.benchmarks import kernel_floor as kf
from v2xbench.envs.v2x_intersection.api import observations
from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT
from v2xbench.envs.v2x_intersection.evaluation import infractions
from v2xbench.envs.v2x_intersection.sim import jit_batch, world
from v2xbench.envs.v2x_intersection.v2x import channel

from v2xbench.cli import main as cli_main

needs_jit = pytest.mark.skipif(not HAVE_JIT, reason="the floor times numba kernels")


def _kernels() -> dict:
    mods = {"sim.world": world, "sim.jit_batch": jit_batch, "evaluation.infractions": infractions,
            "v2x.channel": channel, "api.observations": observations}
    return {name: getattr(mods[m], name) for m, name in kf.KERNELS}


@needs_jit
def test_floor_report_adds_up_and_restores_the_kernels(tmp_path):
    before = _kernels()
    assert cli_main(["floor", "--episodes", "2", "--max-ticks", "15", "--out", str(tmp_path)]) == 0
    assert _kernels() == before  # the wrappers are gone
    r = json.loads((tmp_path / "floor_objects.json").read_text())
    assert r["episodes"] == 2 and 2 <= r["ticks"] <= 30
    # every per-tick kernel of the objects row was captured on its first step
    assert r["kernels_not_called"] == [] and list(r["kernels_alone_us"]) == [n for _, n in kf.KERNELS]
    assert all(v > 0 for v in r["kernels_alone_us"].values())
    assert r["kernels_alone_sum_us"] == pytest.approx(sum(r["kernels_alone_us"].values()))
    assert r["python_us"] == pytest.approx(r["env_step_us"] - r["kernels_back_to_back_us"])
    assert r["interleave_us"] == pytest.approx(r["kernels_back_to_back_us"] - r["kernels_alone_sum_us"])
    assert "| env.step |" in (tmp_path / "floor_objects.md").read_text()


@needs_jit
def test_capture_puts_the_kernels_back_on_error():
    before = _kernels()
    calls: dict = {}
    with pytest.raises(RuntimeError), kf._capturing(calls):
        assert _kernels() != before
        raise RuntimeError("boom")
    assert _kernels() == before and calls == {}


def test_floor_rejects_bad_sizes():
    with pytest.raises(ValueError, match="episodes"):
        kf.measure(episodes=0)
    with pytest.raises(ValueError, match="max_ticks"):
        kf.measure(max_ticks=0)
