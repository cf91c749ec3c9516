"""``v2xbench profile`` (``benchmarks/tick_profile.py``): the report's accounting, and that every
patched stage and kernel is put back. No timing is asserted."""

from __future__ import annotations

import json

import pytest
from v2xbench.benchmarks import tick_profile as tp
from v2xbench.envs.v2x_intersection.api import batch, gym_env
from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT
from v2xbench.envs.v2x_intersection.sim import world
from v2xbench.envs.v2x_intersection.traffic import jit_vehicles as jit_traffic
from v2xbench.envs.v2x_intersection.traffic import vehicles as traffic

from v2xbench.cli import main as cli_main


def _originals() -> dict:
    return {"stages": tuple(world.TICK_STAGES), "batch_stages": tuple(batch.TICK_STAGES),
            "perceive": world.World.perceive, "observation": gym_env.ego_observation,
            "kernel": world.traffic_tick_kernel, "inner": jit_traffic.followers_kernel,
            "followers": traffic.followers_tick_kernel}


def _nrt_stats_on() -> bool | None:
    if not HAVE_JIT:
        return None
    from numba.core.runtime import _nrt_python

    return _nrt_python.memsys_stats_enabled()


def _check(report: dict, mode: str, worlds: int = 1) -> None:
    assert report["mode"] == mode and report["steps"] > 0 and report["us_per_tick"] > 0
    stages = report["stages"]
    # the batch moves the traffic of all its worlds in one call (jit_batch) when numba is there
    one_call = mode == "batched" and HAVE_JIT and worlds > 1
    for name in ("check_events", "after_step"):  # once a tick
        assert stages[name]["calls"] == pytest.approx(1.0), name
    assert stages["move_traffic"]["calls"] == pytest.approx(1.0 / worlds if one_call else 1.0)
    assert stages["observation"]["calls"] >= 1.0  # once a tick, and once more for each reset
    # perception too, or once a tick for all the worlds of a batch (jit_batch), plus the resets'
    assert stages["perceive"]["calls"] >= (1.0 / worlds if one_call else 1.0)
    assert stages["update_signals"]["inside"] == "move_traffic"  # nested stages are named so
    assert stages["move_traffic"]["inside"] is None and stages["perceive"]["inside"] is None
    # the split adds up: kernels and Python make the tick; the stages and "other" too
    assert report["kernel_us"] + report["python_us"] == pytest.approx(report["us_per_tick"])
    assert report["other_us"] < report["us_per_tick"]
    if HAVE_JIT:
        kernels = report["kernels"]
        # the traffic's kernel is called inside jit_batch's, for the worlds of a batch or the one world
        name, calls = ("traffic_batch_kernel", 1.0 / worlds) if one_call else ("traffic_one_kernel", 1.0)
        assert kernels[name]["calls"] == pytest.approx(calls)
        assert "traffic_tick_kernel" not in kernels
        for inner in ("followers_tick_kernel", "followers_kernel"):  # called inside a kernel: counted in it
            assert inner not in kernels
        assert 0 < report["kernel_us"] < report["us_per_tick"]
        perception = "perceive_batch_kernel" if one_call else "perceive_one_kernel"
        assert kernels[perception]["us"] <= stages["perceive"]["us"]
        # numba's allocations: counted per kernel (the perception kernel makes arrays every call),
        # and no kernel's count exceeds the run's
        assert kernels[perception]["allocs"] >= 1.0 / worlds
        assert all(0 <= v["allocs"] <= report["allocs_per_tick"] + 1e-9 for v in kernels.values())
    else:
        assert report["kernels"] == {} and report["kernel_us"] == 0 and report["allocs_per_tick"] is None


def test_objects_profile_restores_what_it_patched():
    before = _originals()
    stats_on = _nrt_stats_on()
    report = tp.profile("objects", ticks=30)
    _check(report, "objects")
    assert _originals() == before
    assert _nrt_stats_on() == stats_on  # numba's allocation statistics are switched back
    md = tp.table(report)
    assert "| update_signals (inside move_traffic) |" in md and "| move_traffic |" in md
    assert "| other |" in md and "us per tick" in md
    if HAVE_JIT:
        assert "arrays allocated per tick" in md and "numba allocated" in md


def test_batched_profile(tmp_path):
    before = _originals()
    assert cli_main(["profile", "--mode", "batched", "--ticks", "4", "--worlds", "2", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "profile_batched.json").read_text())
    _check(report, "batched", worlds=2)
    assert report["config"] == {"num_worlds": 2} and report["steps"] == 8
    assert "world-step" in (tmp_path / "profile_batched.md").read_text()
    assert _originals() == before


def test_test50_profile_times_each_scenario_type(tmp_path):
    before = _originals()
    assert cli_main(["profile", "--mode", "test50", "--ticks", "30", "--routes", "3", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "profile_test50.json").read_text())
    _check(report, "test50")
    assert report["config"] == {"suite": "test50", "routes": 3, "ticks_per_route": 10} and report["steps"] == 30
    scen = report["scenarios"]
    # every scenario of test50 routes 0-2 is live from reset (its actors spawn then): each timed
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

    assert set(scen) == {s.type for r in load_suite_cached("test50")[:3] for s in r.scenarios}
    for v in scen.values():
        assert v["ticks"] >= 10 and v["us_live"] > 0
        assert v["us"] == pytest.approx(v["us_live"] * v["ticks"] / report["steps"])
    # the hooks run inside the stages run_scenarios and check_events
    hooks = sum(v["us"] for v in scen.values())
    assert hooks <= report["stages"]["run_scenarios"]["us"] + report["stages"]["check_events"]["us"]
    assert "| scenario type (hooks) |" in (tmp_path / "profile_test50.md").read_text()
    assert _originals() == before


def test_bad_arguments():
    with pytest.raises(ValueError, match="unknown mode"):
        tp.profile("sensors")
    with pytest.raises(ValueError, match="ticks=0"):
        tp.profile("objects", ticks=0)
    with pytest.raises(ValueError, match="routes=51"):
        tp.profile("test50", routes=51)
