"""``v2xbench compare``: two agents on the runs they share, paired run by run."""

import json

import numpy as np
import pytest
from v2xbench.collectors import compare as C
from v2xbench.envs.v2x_intersection.evaluation.metrics import bootstrap_ci

from v2xbench.cli import main

PLATFORM = {"cpu": "x", "torch": "2.13.0"}


def _result(jid: str, ds: float, platform: dict | None = PLATFORM) -> dict:
    return {"job_id": jid, "suite": "test50", "route_id": jid.rsplit("_", 1)[0],
            "ended_by": "completed", "scenarios": [], "ticks": 100, "platform": platform,
            "metrics": {"driving_score": ds, "route_completion": 100.0, "infraction_score": ds / 100.0,
                        "km_completed": 1.0}}


def _folder(tmp_path, name: str, scores: dict, platform: dict | None = PLATFORM) -> str:
    d = tmp_path / name
    (d / "routes").mkdir(parents=True)
    for jid, ds in scores.items():
        (d / "routes" / f"{jid}.json").write_text(json.dumps(_result(jid, ds, platform)))
    return str(d)


def test_paired_difference_on_the_common_runs(tmp_path):
    a = _folder(tmp_path, "a", {"test50_000_s0": 80.0, "test50_001_s0": 50.0, "test50_002_s0": 30.0, "test50_003_s0": 10.0})
    b = _folder(tmp_path, "b", {"test50_000_s0": 60.0, "test50_001_s0": 50.0, "test50_002_s0": 40.0, "test50_004_s0": 99.0})
    d = C.compare_pair(("a", a), ("b", b))
    assert d["jobs"] == ["test50_000_s0", "test50_001_s0", "test50_002_s0"] and d["runs_only_in"] == {"a": 1, "b": 1}
    assert d["paired_ds_difference"] == pytest.approx((20.0 + 0.0 - 10.0) / 3)
    assert d["paired_ds_difference_ci"] == list(bootstrap_ci([20.0, 0.0, -10.0]))
    assert (d["runs_higher"], d["runs_lower"], d["runs_equal"]) == (1, 1, 1)
    assert d["a"]["driving_score"] == pytest.approx(160.0 / 3)  # only the common runs
    assert d["b"]["driving_score"] == pytest.approx(50.0)
    assert d["platform"] == "same"
    # of the common routes only test50_001 holds a V2X-specific scenario type (VehicleTurningRoute)
    assert d["v2x_runs"] == 1 and d["v2x_paired_ds_difference"] == 0.0


def test_platforms_and_cli(tmp_path, capsys):
    a = _folder(tmp_path, "a", {"test50_000_s0": 80.0, "test50_001_s0": 50.0})
    b = _folder(tmp_path, "b", {"test50_000_s0": 60.0, "test50_001_s0": 55.0}, platform={"cpu": "y", "torch": "2.13.0"})
    old = _folder(tmp_path, "old", {"test50_000_s0": 60.0}, platform=None)  # written before platforms
    out = tmp_path / "cmp"
    assert main(["compare", f"mine={a}", f"theirs={b}", old, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "### mine vs theirs" in text and "### mine vs old" in text
    assert "**+7.5** [" in text and "on different platforms" in text and "platform not recorded" in text
    res = json.loads(out.with_suffix(".json").read_text())
    assert res["mine vs theirs"]["platform"] == "different" and res["mine vs old"]["platform"] == "not recorded"
    assert res["mine vs old"]["platforms"]["old"] == []
    (tmp_path / "b" / "routes" / "test50_002_s0.json").write_text(json.dumps(_result("test50_002_s0", 1.0, None)))
    (tmp_path / "a" / "routes" / "test50_002_s0.json").write_text(json.dumps(_result("test50_002_s0", 1.0)))
    assert C.compare_pair(("a", a), ("b", b))["platform"] == "not recorded"  # one run of b has none
    assert out.with_suffix(".md").read_text().startswith("### mine vs theirs")


def test_bad_inputs_are_named(tmp_path):
    a = _folder(tmp_path, "a", {"test50_000_s0": 80.0})
    b = _folder(tmp_path, "b", {"test50_001_s0": 60.0})
    with pytest.raises(ValueError, match="share no run"):
        C.compare([("a", a), ("b", b)])
    with pytest.raises(ValueError, match="at least two"):
        C.compare([("a", a)])
    with pytest.raises(ValueError, match="two folders named 'a'"):
        C.compare([("a", a), ("a", a)])
    with pytest.raises(FileNotFoundError, match="no route results"):
        C.compare([("a", a), ("c", str(tmp_path / "nothing"))])
    assert np.isfinite(C.compare([("a", a), ("a2", a)])["a vs a2"]["paired_ds_difference"])


def _scen(t: str, v2x: bool, success: bool, collision: bool = False, triggered: bool = True) -> dict:
    return {"type": t, "v2x": v2x, "triggered": triggered, "passed": success or collision,
            "timed_out": False, "collision": collision, "success": success}


def test_scenario_instances_are_paired_instance_by_instance(tmp_path):
    a = _folder(tmp_path, "a", {"test50_000_s0": 80.0, "test50_001_s0": 50.0})
    b = _folder(tmp_path, "b", {"test50_000_s0": 60.0, "test50_001_s0": 55.0})
    runs = {  # (a's instances, b's instances) per job
        "test50_000_s0": ([_scen("ParkingExit", False, True), _scen("PedestrianCrossing", True, True)],
                          [_scen("ParkingExit", False, True), _scen("PedestrianCrossing", True, False, True)]),
        "test50_001_s0": ([_scen("VehicleTurningRoute", True, False, True)],
                          [_scen("VehicleTurningRoute", True, False, False, triggered=False)]),
    }
    for jid, (xs, ys) in runs.items():
        for folder, sc in ((a, xs), (b, ys)):
            p = tmp_path / folder / "routes" / f"{jid}.json"
            p.write_text(json.dumps({**json.loads(p.read_text()), "scenarios": sc}))
    d = C.compare_pair(("a", a), ("b", b))["scenarios"]
    assert d["all"]["instances"] == 3 and d["v2x"]["instances"] == 2
    assert d["all"]["success"] == {"a": 2, "b": 1} and d["all"]["only"] == {"a": 1, "b": 0}
    assert d["v2x"]["collision"] == {"a": 1, "b": 1} and d["v2x"]["reached"] == {"a": 2, "b": 1}
    assert d["all"]["sign_test_p"] == 1.0  # one discordant instance says nothing
    md = C.compare_markdown(C.compare([("a", a), ("b", b)]))
    assert "| V2X-specific types | 2 | 1 | 0 | 1 | 0 | 1.00 | 1 | 1 | 2 | 1 |" in md
    # the exact sign test: 10 of 10 discordant one way is p = 2 / 2**10
    assert C.sign_test_p(10, 10) == pytest.approx(2 / 1024) and C.sign_test_p(5, 10) == 1.0
    assert C.sign_test_p(0, 0) == 1.0 and C.sign_test_p(2, 10) == C.sign_test_p(8, 10)
    p = tmp_path / b / "routes" / "test50_001_s0.json"
    p.write_text(json.dumps({**json.loads(p.read_text()), "scenarios": [_scen("Accident", False, True)]}))
    with pytest.raises(ValueError, match="other scenario instances"):
        C.compare_pair(("a", a), ("b", b))
