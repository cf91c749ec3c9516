"""The planner's route input (issue #33, route deviation): the route points ahead in the ego frame,
one function for training and run time, the config switch ``plan_route_points`` (old run files
read as 0), and retraining stages 4-5 of a run whose stages 1-3 predate it (tiny scale)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from v2xbench.agents.aurora.config import AuroraConfig, same_config
from v2xbench.agents.aurora.route_input import planner_route_points, route_points_ahead
from v2xbench.envs.v2x_intersection.api.observations import ego_observation
from v2xbench.envs.v2x_intersection.core.geometry import world_to_local_2d
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World

from tests.dataset_helpers import ONE_STEP, branches_run

CFG2 = AuroraConfig.for_scale("tiny", plan_route_points=2, plan_route_spacing=10.0)


def _ego_frame(points: np.ndarray, ego_xy: np.ndarray, yaw: float) -> np.ndarray:
    """World points into the ego frame (x forward, y left), written out."""
    d = np.asarray(points, np.float64) - ego_xy
    c, s = math.cos(yaw), math.sin(yaw)
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], -1)


def _along(points: np.ndarray, start: int, dist: float) -> np.ndarray:
    """The world point ``dist`` m along the polyline ``points`` from index ``start``."""
    p = np.asarray(points[start:], np.float64)
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    return np.stack([np.interp(dist, arc, p[:, 0]), np.interp(dist, arc, p[:, 1])])


# ---------------------------------------------------------------------- the ego frame
def test_a_point_straight_ahead_of_a_yawed_ego_is_on_its_x_axis():
    ego, yaw = np.array([3.0, -2.0]), 0.7
    heading = np.array([math.cos(yaw), math.sin(yaw)])
    world = ego + np.arange(-1, 60)[:, None] * heading  # 1-m route points through the ego
    rows = np.zeros((20, 3), np.float32)  # the observation's rows: every 2 m from the ego's point
    rows[:, :2] = world_to_local_2d(world[1 + 2 * np.arange(20)], ego, yaw)
    assert np.allclose(rows[:, :2], _ego_frame(world[1 + 2 * np.arange(20)], ego, yaw), atol=1e-5)
    got = planner_route_points(torch.from_numpy(rows), CFG2)
    assert got.shape == (2, 2) and got.dtype == torch.float32
    assert torch.allclose(got, torch.tensor([[10.0, 0.0], [20.0, 0.0]]), atol=1e-4)
    # a route bending left of a yawed ego: its points have y > 0 and lie on the route
    bend = np.array([[3.0 + 10.0 * math.sin(a), -2.0 + 10.0 * (1 - math.cos(a))]
                     for a in np.linspace(0, math.pi / 2, 40)])
    rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    world = (bend - ego) @ rot.T + ego  # the same bend, turned to the ego's heading
    rows = np.zeros((40, 3), np.float32)
    rows[:, :2] = world_to_local_2d(world, ego, yaw)
    got = planner_route_points(torch.from_numpy(rows), CFG2).numpy()
    want = _ego_frame(np.stack([_along(world, 0, 10.0), _along(world, 0, 20.0)]), ego, yaw)
    assert np.allclose(got, want, atol=1e-3) and got[0, 1] > 1.0


def test_points_of_a_real_observation_are_the_route_ahead_in_the_ego_frame():
    """Town12, seed 2: the ego starts at yaw -2.31 rad; the env's observed route rows give the
    world route's points 10 and 20 m ahead of the ego's route point, in its frame."""
    w = World(make_config(town="Town12", num_vehicles=0, num_parked=0, num_pedestrians=0,
                          num_bicycles=0))
    w.reset(seed=2)
    for t in range(30):
        w.step(np.array([0.6, 0.0, 0.0]) if t < 20 else np.array([0.0, 0.0, 0.3]))
        ego, yaw = np.asarray(w.table.pos[0], np.float64), float(w.table.yaw[0])
        route = ego_observation(w)["route"]
        got = planner_route_points(torch.from_numpy(route), CFG2).numpy()
        k0 = int(w.monitor.progress)
        want = _ego_frame(np.stack([_along(w.route.points, k0, d) for d in (10.0, 20.0)]), ego,
                          yaw)
        assert np.allclose(got, want, atol=0.05), (t, got, want)
    assert abs(math.remainder(yaw, math.pi / 2)) > 0.3  # a yawed ego, not an axis-aligned one


def test_rows_spacing_end_of_route_and_errors():
    t = np.linspace(0, 1.2, 400)  # a curve sampled finely, then every 1, 2 and 5 m of arc
    curve = np.stack([30 * np.sin(t), 30 * (1 - np.cos(t))], -1)
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))]
    outs = []
    for step in (1.0, 2.0, 5.0):
        s = np.arange(0, 34, step)
        rows = np.stack([np.interp(s, arc, curve[:, 0]), np.interp(s, arc, curve[:, 1])], -1)
        outs.append(route_points_ahead(rows, 3, 10.0))
    assert torch.allclose(outs[0], outs[1], atol=0.05) and torch.allclose(outs[0], outs[2],
                                                                           atol=0.2)
    # past the route's end (rows clamped to its last point): the last point
    rows = torch.zeros(20, 3)
    rows[:6, 0] = torch.arange(6) * 2.0
    rows[6:, 0] = 10.0
    assert torch.equal(route_points_ahead(rows, 3, 4.0), torch.tensor([[4.0, 0], [8, 0], [10, 0]]))
    # batched like the policy's (B, R, 3); off: (B, 0, 2)
    batch = torch.stack([rows, rows.flip(-1)])
    assert route_points_ahead(batch, 3, 4.0).shape == (2, 3, 2)
    assert torch.equal(route_points_ahead(batch, 3, 4.0)[0], route_points_ahead(rows, 3, 4.0))
    assert route_points_ahead(batch, 0, 4.0).shape == (2, 0, 2)
    for bad, match in (((torch.zeros(5),), "route has shape"), ((torch.zeros(0, 3),), "shape"),
                       ((torch.zeros(4, 1),), "shape")):
        with pytest.raises(ValueError, match=match):
            route_points_ahead(*bad, 2, 5.0)
    with pytest.raises(ValueError, match="count"):
        route_points_ahead(rows, -1, 5.0)
    with pytest.raises(ValueError, match="spacing"):
        route_points_ahead(rows, 2, 0.0)
    nan = rows.clone()
    nan[3, 1] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        route_points_ahead(nan, 2, 5.0)


# ---------------------------------------------------------------------- the config switch
def test_on_at_every_scale_and_old_run_files_read_as_off():
    for scale in ("tiny", "default", "paper"):
        cfg = AuroraConfig.for_scale(scale)
        assert cfg.plan_route_points > 0 and cfg.plan_route_spacing > 0
        d = json.loads(json.dumps(cfg.to_dict()))
        assert d["plan_route_points"] == cfg.plan_route_points  # saved with the run
        assert AuroraConfig.from_dict(d) == cfg
        old = {k: v for k, v in d.items() if not k.startswith("plan_route")}
        assert AuroraConfig.from_dict(old).plan_route_points == 0  # an old file: no route input
        # resuming stages 1-2 of an old run is not refused: the field is the new one's
        assert same_config(old, d) and not same_config({**d, "plan_route_points": 1}, d)
    for bad in (dict(plan_route_points=-1), dict(plan_route_points=17),
                dict(plan_route_points=True), dict(plan_route_spacing=0.0)):
        with pytest.raises(ValueError, match="plan_route"):
            AuroraConfig.for_scale("tiny", **bad)


def test_planner_errors_name_the_route_input():
    from v2xbench.agents.aurora.planners import build_planner

    cfg = AuroraConfig.for_scale("tiny")
    planner = build_planner(cfg, cfg.lm_width)
    h, cmd = torch.zeros(2, cfg.lm_width), torch.tensor([3, 3])
    with pytest.raises(ValueError, match="route_points"):
        planner(h, cmd)
    with pytest.raises(ValueError, match="route points have shape"):
        planner(h, cmd, route=torch.zeros(2, cfg.plan_route_points + 1, 2))
    off = AuroraConfig.for_scale("tiny", plan_route_points=0, plan_frame="ego")
    plain = build_planner(off, off.lm_width)
    assert not any(n.startswith("route.") for n, _ in plain.named_parameters())
    assert plain(h, cmd, route=torch.zeros(2, 0, 2))["waypoints"].shape == (2, 6, 2)
    with pytest.raises(ValueError, match="plan_route_points=0"):
        plain(h, cmd, route=torch.zeros(2, 2, 2))


# ---------------------------------------------------------------------- stages 4-5 again
def _strip_route_keys(path):
    info = json.loads(path.read_text())
    info["config"] = {k: v for k, v in info["config"].items() if not k.startswith("plan_route")}
    path.write_text(json.dumps(info))


def test_stages_4_5_retrained_with_route_points_on_an_old_run(tiny_dataset, tmp_path):
    """Stages 1-3 made before the field (run files without it): stage 4 adds the route encoder
    on top of stage 3, stage 5 keeps it, a different K for stage 5 or a resume is refused."""
    from v2xbench.agents.aurora.stages import train_late_stage
    from v2xbench.agents.aurora.system import load_system

    data, run = branches_run(tiny_dataset, tmp_path)
    common = ONE_STEP
    train_late_stage(data, run, 3, route_points=0, **common)
    for s in (1, 2, 3):
        _strip_route_keys(run / f"stage{s}" / "aurora.json")
    old, _, _ = load_system(run, 3)
    assert old.cfg.plan_route_points == 0 and not hasattr(old.planner, "route")

    train_late_stage(data, run, 4, **common)  # the scale's default: route points on
    k = AuroraConfig.for_scale("tiny").plan_route_points
    info4 = json.loads((run / "stage4" / "aurora.json").read_text())
    assert info4["config"]["plan_route_points"] == k
    sys4, _, _ = load_system(run, 4)
    assert sys4.cfg.plan_route_points == k and hasattr(sys4.planner, "route")
    new = sys4.state_dict()  # stage 3's weights came along (frozen ones unchanged since)
    assert all(torch.equal(p, new[n]) for n, p in old.state_dict().items()
               if n.startswith(("ego.", "rsu.")))
    assert set(new) - set(old.state_dict()) == {n for n in new if n.startswith("planner.route.")}
    with pytest.raises(ValueError, match="stage 5 continues it"):
        train_late_stage(data, run, 5, route_points=0, **common)
    with pytest.raises(ValueError, match="other settings"):
        train_late_stage(data, run, 4, route_points=0, **common)
    train_late_stage(data, run, 5, **common)
    sys5, _, info5 = load_system(run, 5)
    assert info5["config"]["plan_route_points"] == k and sys5.cfg == sys4.cfg


def test_cli_option_applies_to_late_stages_only(tmp_path, capsys):
    from v2xbench.cli import main

    for stage in ("0", "1"):
        assert main(["aurora", "train", "--stage", stage, "--data", str(tmp_path), "--out",
                     str(tmp_path / "run"), "--plan-route-points", "2"]) == 2
        assert "--plan-route-points and --speed-dropout apply to stages 3-5" in \
            capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse: not a count
        main(["aurora", "train", "--stage", "4", "--data", str(tmp_path), "--out",
              str(tmp_path / "run"), "--plan-route-points", "-1"])
