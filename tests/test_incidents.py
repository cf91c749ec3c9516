"""``v2xbench incidents``: red lights by how the ego came to them, vehicle collisions by side."""

import json

import numpy as np
import pytest
from v2xbench.collectors import incidents as I
from v2xbench.collectors import jobs as J
from v2xbench.envs.v2x_intersection.evaluation.infractions import (
    COLLISION_VEHICLE,
    RED_LIGHT,
    SIDE_FRONT,
    SIDE_LEFT,
    SIDE_REAR,
    STOP_SIGN,
)

from v2xbench.cli import main

DT = 0.1


def _result(jid: str, speed, events, km: float = 0.5) -> dict:
    return {"job_id": jid, "ended_by": "completed", "scenarios": [], "ticks": len(speed), "metrics": {"km_completed": km},
            "record": {"dt": DT, "ego_speed": list(map(float, speed)), "events": [list(map(float, e)) for e in events]}}


def _folder(tmp_path, results) -> str:
    d = tmp_path / "eval"
    (d / "routes").mkdir(parents=True)
    for r in results:
        (d / "routes" / f"{r['job_id']}.json").write_text(json.dumps(r))
    return str(d)


def test_red_light_approaches():
    # stood 3 s, then 2 s from rest to the line: a set-off
    speed = np.r_[np.full(50, 5.0), np.zeros(30), np.linspace(0.5, 2.5, 20)]
    r = I.red_light_approach(speed, 99, DT)
    assert r["kind"] == "set_off" and r["standing_s"] == pytest.approx(3.0) and r["to_line_s"] == pytest.approx(2.0)
    assert r["speed"] == pytest.approx(2.5)
    assert I.red_light_approach(np.r_[np.full(150, 5.0), np.full(50, 1.0)], 199, DT)["kind"] == "slowed"
    assert I.red_light_approach(np.full(200, 5.0), 199, DT)["kind"] == "drove_through"
    # a stand longer ago than the look-back does not make it a set-off
    assert I.red_light_approach(np.r_[np.zeros(10), np.full(150, 5.0)], 159, DT)["kind"] == "drove_through"


def test_vehicle_collisions_sides_and_repeats():
    speed = np.r_[np.full(100, 3.0), np.zeros(100)]
    ev = np.array([(COLLISION_VEHICLE, 50, 7, SIDE_FRONT), (COLLISION_VEHICLE, 101, 7, SIDE_FRONT),
                   (COLLISION_VEHICLE, 150, 8, SIDE_REAR), (COLLISION_VEHICLE, 160, 9, SIDE_LEFT),
                   (STOP_SIGN, 170, -1, 0.0), (COLLISION_VEHICLE, 190, 7, 0.0)], float)
    cols = I.vehicle_collisions(ev, speed, DT)
    assert [c["side"] for c in cols] == ["front", "front", "rear", "side", "unknown"]
    assert [c["repeat"] for c in cols] == [False, True, False, False, False]  # 190 is 8.9 s after 101
    assert [c["speed"] for c in cols] == [3.0, 0.0, 0.0, 0.0, 0.0]


def test_folder_summary_and_cli(tmp_path, capsys):
    set_off = np.r_[np.full(50, 5.0), np.zeros(30), np.linspace(0.5, 2.5, 20)]
    folder = _folder(tmp_path, [
        _result("r0_s0", set_off, [(RED_LIGHT, 99, -1, 1.0), (COLLISION_VEHICLE, 60, 3, SIDE_FRONT)]),
        _result("r1_s0", np.full(200, 5.0), [(RED_LIGHT, 199, -1, 1.0), (COLLISION_VEHICLE, 20, 4, SIDE_REAR),
                                              (COLLISION_VEHICLE, 71, 4, SIDE_REAR)], km=1.5),
    ])
    failed = _result("r2_s0", [], [])
    failed["record"] = None  # a failed run: counted apart, not read
    (tmp_path / "eval" / "routes" / "r2_s0.json").write_text(json.dumps(failed))
    s = I.folder_incidents(folder)
    assert s["runs"] == 2 and s["runs_without_record"] == 1 and s["km_completed"] == pytest.approx(2.0)
    assert (s["red_lights"], s["red_set_off"], s["red_drove_through"], s["red_slowed"]) == (2, 1, 1, 0)
    assert s["red_lights_per_km"] == pytest.approx(1.0)
    assert s["red_set_off_median_standing_s"] == pytest.approx(3.0) and s["red_set_off_stood_under_2s"] == 0
    assert (s["collisions_front"], s["collisions_rear"], s["collisions_repeats"]) == (1, 2, 1)
    assert s["collisions_distinct_per_km"] == pytest.approx(1.0)
    out = tmp_path / "inc"
    assert main(["incidents", f"mine={folder}", "--out", str(out)]) == 0
    assert "| mine | 2 |" in capsys.readouterr().out
    assert json.loads(out.with_suffix(".json").read_text())["mine"]["vehicle_collisions"] == 3
    assert "set off after standing" in out.with_suffix(".md").read_text()


def test_bad_folders_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="no route results"):
        I.folder_incidents(tmp_path)
    (tmp_path / "routes").mkdir()
    (tmp_path / "routes" / "x.json").write_text("{not json")
    with pytest.raises(ValueError, match="x.json is not valid JSON"):
        I.folder_incidents(tmp_path)
    (tmp_path / "routes" / "x.json").write_text(json.dumps(_result("x", [1.0, 2.0], [(RED_LIGHT, 1, -1)])))
    with pytest.raises(ValueError, match="x.json: not a readable eval result"):  # events of 3 columns
        I.folder_incidents(tmp_path)


def test_all_results_reads_every_file_in_job_order(tmp_path):
    folder = _folder(tmp_path, [_result(j, [1.0], []) for j in ("b_s0", "a_s1", "a_s0")])
    assert [r["job_id"] for r in J.all_results(folder)] == ["a_s0", "a_s1", "b_s0"]
    (tmp_path / "eval" / "routes" / "a_s1.json").write_text(json.dumps(_result("other", [1.0], [])))
    with pytest.raises(ValueError, match="a_s1.json holds job 'other'"):
        J.all_results(folder)
