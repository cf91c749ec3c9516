"""The benchmark suite's report plumbing (table, plot, README update) on a synthetic report.

No timing is asserted here: ``.ci/run`` runs ``v2xbench bench --quick`` as a smoke test.
"""

from __future__ import annotations

import pytest
from v2xbench.benchmarks import suite


def _report() -> dict:
    parts = {k: {"wall_ms": 1.0} for k in ("full_rig", "scene", "ego_cameras_batched", "lidar", "bev")}
    return {
        "date": "2026-01-01 00:00 UTC", "machine": "test machine", "quick": False,
        "results": {
            "objects": {"results": {
                "v2xbench_objects": {"steps_per_s": 5000.0, "actors": 56, "scenarios": ["ParkingExit"]},
                "intersection-v0": {"steps_per_s": 6.0, "frames_per_step": 15, "ratio_v2xbench_to_this": 833.0,
                                    "sim_time_ratio": 83.3},
                "highway-fast-v0": {"steps_per_s": 12.0, "frames_per_step": 5, "ratio_v2xbench_to_this": 416.0,
                                    "sim_time_ratio": 41.6},
            }},
            "sensors": {"parts": parts, "full_rig_ticks_per_s": 80.0},
            "batched": {"rows": [{"worlds": 1, "agent_steps_per_s": 900.0},
                                 {"worlds": 64, "agent_steps_per_s": 25000.0}]},
            "eval": {"seconds": 420.0, "returncode": 0},
            "scaling": {"rows": [{"actors": 10, "ticks_per_s": 900.0}, {"actors": 200, "ticks_per_s": 300.0}]},
            "memory": {"resets": 10000, "rss_start_mib": 400.0, "rss_end_mib": 401.0, "rss_max_mib": 402.0,
                       "growth_second_half_mib": 0.5, "trace": [(0, 400.0), (10000, 401.0)]},
        },
    }


def test_table_marks_targets_met_and_missed():
    md = suite.table(_report())
    lines = {ln.split("|")[1].strip(): ln for ln in md.splitlines() if ln.startswith("| ")}
    assert "test machine" in md and "2026-01-01" in md
    assert next(v for k, v in lines.items() if k.startswith("objects mode")).rstrip(" |").endswith("met")
    assert next(v for k, v in lines.items() if k.startswith("sensors mode")).rstrip(" |").endswith("missed")
    assert next(v for k, v in lines.items() if k.startswith("batched")).rstrip(" |").endswith("met")
    assert "7.0 min" in md


def test_plot_and_readme_update(tmp_path):
    png = tmp_path / "suite.png"
    suite.plot(_report(), png)
    assert png.stat().st_size > 1000
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\nbefore\n{suite.BEGIN}\nold table\n{suite.END}\nafter\n")
    suite.update_readme(readme, "NEW TABLE\n", "docs/media/bench_suite.png")
    text = readme.read_text()
    assert "NEW TABLE" in text and "old table" not in text and text.endswith("after\n")
    assert text.count(suite.BEGIN) == 1 and "bench_suite.png" in text
    readme.write_text("no markers")
    with pytest.raises(ValueError, match="bench:begin"):
        suite.update_readme(readme, "x", None)


def test_unknown_row_is_an_error():
    with pytest.raises(ValueError, match="unknown row"):
        suite.run_rows(("nope",), quick=True)


def test_settle_collects_cyclic_garbage():
    """``settle`` (called before every timed loop) runs a full collection: garbage in a
    reference cycle is gone after it."""
    import gc
    import weakref

    from v2xbench.benchmarks.settle import settle

    class Node:
        pass

    a, b = Node(), Node()
    a.other, b.other = b, a
    ref = weakref.ref(a)
    gc.disable()
    try:
        del a, b
        assert ref() is not None  # only the cycle collector can free it
        settle()
        assert ref() is None
    finally:
        gc.enable()


def test_batched_collector_name_is_checked():
    from v2xbench.benchmarks import batched_speed

    with pytest.raises(ValueError, match="collector"):
        batched_speed.measure_one(2, 10, collector="threads")


def test_batched_one_world_row_after_a_warm_up(monkeypatch):
    from v2xbench.benchmarks import batched_speed

    monkeypatch.setattr(batched_speed, "WARMUP_STEPS_ONE", 3)
    row = batched_speed.measure_one(1, 4, {"num_vehicles": 4, "num_pedestrians": 2}, warmup_seconds=1.0)
    assert row["worlds"] == 1 and row["agent_steps"] == 4 and row["agent_steps_per_s"] > 0


class _Episodes:
    """A stand-in env whose episodes end every ``length`` steps; records what it was asked."""

    def __init__(self, length: int) -> None:
        self.length, self.t, self.calls = length, 0, []

    def reset(self, seed=None):
        self.t = 0
        self.calls.append(("reset", seed))

    def step(self, action):
        self.t += 1
        self.calls.append(("step", None))
        return None, 0.0, self.t >= self.length, False, {}


@pytest.mark.parametrize("length, warmup, untimed", [(7, 3, 8), (7, 20, 20), (50, 0, 0)])
def test_warm_up_goes_through_an_episode_end_and_the_step_after_it(length, warmup, untimed):
    """The warm-up runs ``warmup`` steps and, with ``warmup > 0``, on past the first episode end,
    its reset and one more step (paths first taken there load numba code on first use)."""
    from v2xbench.benchmarks.env_speed import timed_steps

    env = _Episodes(length)
    timed_steps(env, None, steps=4, seed=10, warmup=warmup)
    last_reset = max(i for i, c in enumerate(env.calls) if c == ("reset", 10))  # the reset before the clock
    warm = env.calls[1:last_reset]
    assert sum(c[0] == "step" for c in warm) == untimed
    if warmup:
        assert ("reset", 10 + length) in warm  # the first episode's end was reset in the warm-up
    assert sum(c[0] == "step" for c in env.calls[last_reset:]) == 4


def test_warm_up_waits_for_an_episode_end_only_so_long(monkeypatch):
    from v2xbench.benchmarks import env_speed

    monkeypatch.setattr(env_speed, "WARMUP_EPISODE_CAP", 5)
    env = _Episodes(10**9)
    env_speed.timed_steps(env, None, steps=1, warmup=2)
    assert sum(c[0] == "step" for c in env.calls) == 2 + 5 + 1


def test_episodes_go_on_across_timed_stretches():
    """The envs of the objects row take turns in stretches: an episode is not cut between them."""
    from v2xbench.benchmarks.env_speed import Stepper

    env = _Episodes(5)
    st = Stepper(env, None, seed=3)
    st.run(steps=3)
    st.run(steps=4)
    assert st.steps == 7 and st.wall > 0 and st.cpu >= 0
    resets = [c for c in env.calls if c[0] == "reset"]
    assert resets == [("reset", 3), ("reset", 3), ("reset", 8)]  # warm-up's two, then the end at step 5
    st.run(seconds=1e-9)  # a stretch by time takes one step at least
    assert st.steps == 8


@pytest.mark.parametrize("seconds, rounds", [(0.0, 5), (1.0, 0), (float("nan"), 1)])
def test_objects_row_rejects_bad_sizes(seconds, rounds):
    from v2xbench.benchmarks.env_speed import measure

    with pytest.raises(ValueError, match="seconds"):
        measure(seconds, rounds=rounds)
