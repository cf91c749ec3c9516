"""`v2xbench aurora eval-planning` (issue #33, open-loop planning): the metrics of a tiny run
through the command (files, shapes, errors, exported weights), the policy's inference pass on a
recorded frame, and the metrics on constructed frames (a constant-velocity expert, an overlap)."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
import torch
from v2xbench.agents.aurora import eval_planning as EP
from v2xbench.agents.aurora.export import export_run
from v2xbench.agents.aurora.pairs import AuroraPairs, collate_pairs
from v2xbench.agents.aurora.pipeline import run_pipeline
from v2xbench.agents.aurora.policy import AuroraPolicyNet
from v2xbench.agents.aurora.system import load_system
from v2xbench.collectors.chat.export import build as build_qa
from v2xbench.collectors.dataset.loader import V2XDataset
from v2xbench.collectors.dataset.record import REASONS
from v2xbench.envs.v2x_intersection.core.classes import CAR, PEDESTRIAN, TRAFFIC_SIGN
from v2xbench.envs.v2x_intersection.sensors import EGO_CAMERA_NAMES

from v2xbench.cli import main

HORIZON_KEYS = ("l2_1s", "l2_2s", "l2_3s")
COLLISION_KEYS = ("collision_1s", "collision_2s", "collision_3s")


@pytest.fixture(scope="module")
def tiny_run(tiny_dataset, tmp_path_factory):
    torch.set_num_threads(1)
    base = tmp_path_factory.mktemp("aurora_eval_planning")
    data = base / "data"
    shutil.copytree(tiny_dataset, data)
    build_qa(data)
    run_pipeline(data, base / "run", scale="tiny", progress=False, say=lambda _: None)
    return data, base / "run"


def _cli(*args: str) -> int:
    return main(["aurora", "eval-planning", "--quiet", "--threads", "1", *map(str, args)])


def test_command_writes_the_metrics(tiny_run, tmp_path, capsys, monkeypatch):
    data, run = tiny_run
    assert _cli("--run", run, "--data", data, "--split", "all", "--stride", 4) == 0
    out = run / "eval_planning"
    assert "written:" in capsys.readouterr().out
    m = json.loads((out / "metrics.json").read_text())
    ds = V2XDataset(data, "all", keys=["ego_speed"])
    lengths = np.diff(ds.offsets)
    assert m["frames"] + m["frames_without_expert_future"] == sum(math.ceil(n / 4)
                                                                  for n in lengths)
    assert m["source"]["fusion"] and m["source"]["stage"] == 5 and m["split"] == "all"
    assert m["command"].startswith("v2xbench aurora eval-planning")
    for g in [m["overall"], *m["per_command"].values()]:
        assert set(g) == {"frames", "model", "constant_velocity", "expert"}
        for plan in ("model", "constant_velocity"):
            assert all(g[plan][k] >= 0 for k in HORIZON_KEYS)
        for plan in ("model", "constant_velocity", "expert"):
            assert all(0 <= g[plan][k] <= 1 for k in COLLISION_KEYS)
            assert g[plan]["collision_1s"] <= g[plan]["collision_2s"] <= g[plan]["collision_3s"]
    assert sum(g["frames"] for g in m["per_command"].values()) == m["frames"]
    s = m["start_from_rest"]
    assert set(s) >= {"frames", "model", "expert"} and s["ego_speed_below"] == EP.START_SPEED
    table = (out / "metrics.md").read_text()
    assert "| all |" in table and "start from rest" in table
    assert m["stay_at_rest"]["expert_3s_within"] == EP.STAY_DIST
    reasons = EP.split_reasons(data, "all")  # the expert's binding constraint, every frame
    assert len(reasons) == ds.offsets[-1]
    per = m["per_reason"]
    assert sum(g["frames"] for g in per.values()) == m["frames"]
    assert set(per) <= set(REASONS) and "expert's reason" in table

    # exported float32 weights give the run's numbers; --out is honoured
    w = tmp_path / "w"
    export_run(run, None, w, dtype="float32")
    monkeypatch.chdir(tmp_path)  # an export's results go to ./eval_planning/NAME, not into it
    assert _cli("--weights", w, "--data", data, "--split", "all", "--stride", 4) == 0
    assert not (w / "eval_planning").exists()
    mw = json.loads((tmp_path / "eval_planning" / "w" / "metrics.json").read_text())
    assert mw["overall"] == m["overall"] and mw["source"]["weights"] == str(w)
    assert _cli("--run", run, "--data", data, "--split", "all", "--stride", 20, "--out",
                tmp_path / "o") == 0
    assert (tmp_path / "o" / "metrics.md").is_file()


def test_clear_errors(tiny_run, tmp_path, capsys):
    data, run = tiny_run
    assert _cli("--run", run, "--data", data, "--split", "test") == 2  # tiny data: train/val
    assert "split 'test'" in capsys.readouterr().err
    assert _cli("--run", tmp_path / "nope", "--data", data) == 2
    assert "nope does not exist" in capsys.readouterr().err
    assert _cli("--run", run, "--data", tmp_path / "nodata") == 2
    assert "nodata does not exist" in capsys.readouterr().err
    assert _cli("--weights", tmp_path / "now", "--data", data) == 2
    assert "now does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # both sources: argparse refuses
        _cli("--run", run, "--weights", tmp_path, "--data", data)
    with pytest.raises(ValueError, match="stride"):
        EP.evaluate_planning(data, run=run, stride=0)


def test_predictions_are_the_policy_modules(tiny_run):
    """The evaluation's pass on a recorded frame gives the waypoints the closed-loop policy
    module gives for the same cameras, speed and command (No Fusion: no message)."""
    data, run = tiny_run
    system, tok, _ = load_system(run)
    system.fusion = False
    ds = AuroraPairs(data, "all", system.cfg, tok, [(3, None, None), (17, None, None)],
                     fusion=False)
    batch = collate_pairs([ds[0], ds[1]], int(tok.pad_token_id))
    got = EP.predict(system, batch)
    rec = V2XDataset(data, "all", keys=[("cameras", c, "rgb") for c in EGO_CAMERA_NAMES]
                     + ["route"])
    cams = [torch.stack([rec[f]["cameras", c, "rgb"] for f in (3, 17)]) for c in EGO_CAMERA_NAMES]
    size = (int(cams[0].shape[2]), int(cams[0].shape[1]))
    ego = torch.zeros(2, 8)
    ego[:, 0] = batch["ego_speed"]
    route = torch.stack([rec[f]["route"] for f in (3, 17)])  # the recorded observation's route
    assert torch.equal(route[:, 0, 2].long(), batch["command"])  # the frame's command
    assert system.cfg.plan_route_points > 0 and batch["route_points"].shape[1] > 0
    net = AuroraPolicyNet(system, tok, size)
    with torch.no_grad():
        wps, _ = net(*cams, ego, route, torch.zeros(2, 8), torch.zeros(2, 4))
    np.testing.assert_allclose(got, wps.double().numpy(), atol=1e-5)


def _record(expert: np.ndarray, model: np.ndarray, speed: np.ndarray, command: np.ndarray,
            futures: np.ndarray) -> dict:
    rec = {"expert": expert, "model": model, "speed": speed, "command": command,
           "constant_velocity": EP.constant_velocity_plan(speed, 6, 0.5)}
    for plan in EP.PLANS:
        rec[f"col_{plan}"] = EP.collisions(rec[plan], futures)
    return rec


def test_constant_velocity_baseline_is_exact_on_a_straight_expert():
    t = np.arange(1, 7) * 0.5
    speed = np.array([4.0, 0.0, 7.5])
    expert = np.stack([np.stack([v * t, np.zeros(6)], -1) for v in speed])
    model = expert + np.array([0.0, 1.0])  # 1 m to the side everywhere...
    model[0, 5] += (3.0, 0.0)  # ... and the first frame's 3 s waypoint (3, 1) m off
    futures = np.full((3, 6, 1, 5), np.nan)
    rec = _record(expert, model, speed, np.array([0, 0, 3]), futures)
    m = EP.summarize(rec, 0.5)
    for k in HORIZON_KEYS:
        assert m["overall"]["constant_velocity"][k] == 0.0
    assert m["overall"]["model"]["l2_1s"] == pytest.approx(1.0)
    assert m["overall"]["model"]["l2_3s"] == pytest.approx((np.hypot(3, 1) + 2) / 3)
    assert m["per_command"]["follow_lane"]["frames"] == 2
    assert m["per_command"]["straight"]["model"]["l2_3s"] == pytest.approx(1.0)
    assert m["overall"]["model"]["collision_3s"] == 0.0
    s = m["start_from_rest"]  # the standing frame's expert does not drive off: none
    assert s["frames"] == 0 and s["model"]["speed_3s"] is None
    r = m["stay_at_rest"]  # ... it stays: the model's 3 s waypoint is 1 m to the side
    assert r["frames"] == 1 and r["expert"]["speed_3s"] == 0.0
    assert r["model"]["speed_wp0_wp1"] == 0.0 and r["model"]["speed_3s"] == pytest.approx(1 / 3)
    # a standing ego whose expert drives off: 1 m/s near, 2 m/s over 3 s
    off = np.stack([np.array([0.2, 0.7, 1.5, 2.8, 4.3, 6.0]), np.zeros(6)], -1)[None]
    s = EP.start_from_rest({"speed": np.array([0.1]), "expert": off, "model": off * 0}, 0.5)
    assert s["frames"] == 1 and s["expert"]["speed_wp0_wp1"] == pytest.approx(1.0)
    assert s["expert"]["speed_3s"] == pytest.approx(2.0) and s["model"]["speed_3s"] == 0.0


def test_collision_is_counted_on_an_overlap():
    # a car crossing the ego's path: at 2 s it stands where the plan puts the ego (x = 16 m)
    boxes = np.zeros((1, 3, 10), np.float32)
    boxes[0, 0] = (16.0, -10.0, 0, 4.5, 1.9, 1.5, 1.0, 0.0, 0.0, 5.0)  # heading +y at 5 m/s
    boxes[0, 1] = (16.0, -10.0, 0, 0.6, 0.6, 1.8, 0.0, 1.0, 0.0, 5.0)  # same path: a sign
    boxes[0, 2] = (0.0, 2.0, 0, 0.5, 0.5, 1.7, 0.0, 1.0, 0.0, 0.0)  # a pedestrian beside
    labels = np.array([[CAR, TRAFFIC_SIGN, PEDESTRIAN]])
    fut = EP.actor_futures(boxes, labels, np.ones((1, 3), bool), 6, 0.5)
    assert np.isnan(fut[0, :, 1]).all()  # a traffic sign is no actor
    np.testing.assert_allclose(fut[0, 3, 0], (16.0, 0.0, 4.5, 1.9, math.pi / 2), atol=1e-6)
    plan = EP.constant_velocity_plan(np.array([8.0]), 6, 0.5)  # 4, 8, ... 24 m
    col = EP.collisions(plan, fut)
    assert col[0].tolist() == [False, False, False, True, False, False]
    rec = _record(plan, plan, np.array([8.0]), np.array([0]), fut)
    g = EP.summarize(rec, 0.5)["overall"]["model"]
    assert (g["collision_1s"], g["collision_2s"], g["collision_3s"]) == (0.0, 1.0, 1.0)
    # a standing ego's centimetre jitter keeps its heading: the pedestrian beside stays clear
    jitter = np.tile([[0.003, 0.05]], (6, 1))[None]
    assert np.allclose(EP.plan_headings(jitter), 0.0)
    assert not EP.collisions(jitter, fut).any()


def test_per_reason_shows_a_planner_driving_through_a_red_light():
    """Two frames the expert stops at a red light (it plans to stay), one free: a model that
    plans 5 m/s everywhere has planned speed 5 on the red frames where the expert has 0."""
    dt, t = 0.5, 6
    drive = EP.constant_velocity_plan(np.full(3, 5.0), t, dt)
    expert = np.stack([np.zeros((t, 2)), np.zeros((t, 2)), drive[2]])
    rec = {"model": drive, "expert": expert, "speed": np.array([2.0, 0.0, 5.0]),
           "reason": np.array([REASONS.index("red"), REASONS.index("red"),
                               REASONS.index("free")])}
    per = EP.per_reason(rec, dt)
    assert set(per) == {"red", "free"} and per["red"]["frames"] == 2
    assert per["red"]["expert_speed_3s"] == 0 and per["red"]["model_speed_3s"] == pytest.approx(5)
    assert per["red"]["model_l2_3s"] == pytest.approx(15) and per["red"]["ego_speed"] == 1
    assert per["free"]["model_l2_3s"] == pytest.approx(0)
    assert per["red"]["moving"]["frames"] == 1 and per["red"]["moving"]["ego_speed"] == 2
    assert per["red"]["standing"]["frames"] == 1 and per["red"]["standing"]["model_speed_3s"] == \
        pytest.approx(5) and per["red"]["standing"]["expert_speed_3s"] == 0
    assert per["red"]["model_go_share"] == 1 and per["red"]["expert_go_share"] == 0
    assert per["free"]["expert_go_share"] == 1 and per["red"]["standing"]["model_go_share"] == 1
