"""CoDriving baseline (issue #34): the request-driven choice of roadside cells (none for a zero
request, more for a wider one, the budget), the sparse message's bytes (the documented formula,
the serializer's, the channel's) and the oversized message, the scatter of a roadside cell into
the ego grid by E_{r->e}, the native controller, training lowering the loss on a tiny collected
data set, and `v2xbench baselines train codriving` -> `v2xbench eval --agent codriving`."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil

import numpy as np
import pytest
import torch
from v2xbench.agents.baselines.codriving.config import CoDrivingConfig
from v2xbench.agents.baselines.codriving.controller import LightBrake, NativeController
from v2xbench.agents.baselines.codriving.fusion import scatter_to_ego
from v2xbench.agents.baselines.codriving.losses import boxes_to_rsu
from v2xbench.agents.baselines.codriving.message import (
    dense_message,
    deserialize_message,
    sent_cells,
    serialize_message,
)
from v2xbench.agents.baselines.codriving.model import CoDriving, RoadsideNet
from v2xbench.agents.baselines.codriving.request import request_map, route_ahead, select_cells
from v2xbench.envs.v2x_intersection.core.geometry import pose_matrix

from tests import baselines_common as bc
from v2xbench.cli import main

torch.set_num_threads(1)
CFG = CoDrivingConfig.for_scale("tiny")  # unit grid: 16 x 16 cells of 5 m, x 0..80, y -40..40
# the unit's ground frame: 90 deg left of the ego's, its foot at ego (-20, 10)
E = torch.from_numpy(pose_matrix(-20.0, 10.0, 0.0, math.pi / 2).astype(np.float32))[None]


@pytest.fixture(scope="module")
def lidar_dataset(tmp_path_factory):
    """The tiny data set (``tests/dataset_helpers.TINY``) recorded with LiDAR points only."""
    return bc.collect_lidar(tmp_path_factory.mktemp("v2x_lidar_codriving"))


def test_the_request_follows_the_route_into_the_units_grid():
    # a straight route along the unit's x axis at its y = -12.5 m, given in the ego frame
    xs = torch.arange(5.0, 80.0, 2.0)
    rsu_pts = torch.stack([xs, torch.full_like(xs, -12.5)], -1)
    ego_pts = rsu_pts @ E[0, :2, :2].T + E[0, :2, 3]
    r = request_map(ego_pts[None], E, CFG)[0]
    assert r.shape == (16, 16)
    j = math.floor((-12.5 + 40.0) / 5.0)  # the cells whose centres the route crosses
    assert torch.allclose(r[2:15, j], torch.ones(13), atol=1e-4)
    far = r[:, j + 4]  # 20 m away: exp(-400 / 72) ~ 0.004
    assert float(far.max()) < 0.01 and float(r[5, j + 1]) == pytest.approx(math.exp(-25 / 72),
                                                                          abs=1e-3)


def test_choice_of_cells_zero_request_budget_and_wider_request():
    conf = torch.full((1, 16, 16), 0.9)
    assert not select_cells(conf * 0.0, CFG).any()  # nothing requested: nothing sent
    narrow = torch.zeros(1, 16, 16)
    narrow[0, :, 7] = 1.0  # one column of 16 cells
    wide = torch.zeros(1, 16, 16)
    wide[0, :, 6:9] = 1.0  # three columns: 48 cells, more than the budget of 32
    n_narrow = int(select_cells(conf * narrow, CFG).sum())
    chosen = select_cells(conf * wide, CFG)
    assert n_narrow == 16 and int(chosen.sum()) == CFG.max_cells == 32
    assert not chosen[0, :, :6].any() and not chosen[0, :, 9:].any()
    small = dataclasses.replace(CFG, max_cells=5)  # the budget knob
    assert int(select_cells(conf * wide, small).sum()) == 5
    dim = conf * 0.01 * wide  # below the threshold (0.02): not worth sending
    assert not select_cells(dim, CFG).any()
    # the network's choice: a zero request sends nothing, whatever the unit sees
    torch.manual_seed(0)
    net = RoadsideNet(CFG).eval()
    with torch.no_grad():
        net.confidence[-1].bias.fill_(5.0)  # confident everywhere
        pts = torch.rand(1, 200, 4) * torch.tensor([80.0, 80.0, 4.0, 1.0]) - torch.tensor(
            [0.0, 40.0, 2.0, 0.0])
        mask = torch.ones(1, 200, dtype=torch.bool)
        assert not net(pts, mask, torch.zeros(1, 16, 16))["sent"].any()
        assert int(net(pts, mask, narrow)["sent"].sum()) == 16
        assert int(net(pts, mask, wide)["sent"].sum()) == 32


def test_message_bytes_follow_the_formula_and_oversized_raises():
    torch.manual_seed(0)
    c = CFG.sent_channels()
    for k in (1, 7, CFG.max_cells):
        cells = torch.stack([torch.arange(k) % 16, torch.arange(k) // 16], -1)
        feats = torch.randn(k, c)
        payload = serialize_message(cells, feats, CFG)
        f = 6 + k * (2 + c)  # docs/baselines.md: F(K) = 6 + K (2 + C)
        assert payload.shape == (f,) and CFG.message_floats(k) == f
        bc.assert_channel_counts(payload, f)  # 16 + 2 F bytes on air, as encoded
        back_cells, back = deserialize_message(payload, CFG)
        assert torch.equal(back_cells, cells)
        assert torch.allclose(back, feats.to(torch.float16).float(), atol=1e-6)
    assert CFG.message_floats() == 6 + 32 * 6 == 198
    cells = torch.stack([torch.arange(33) % 16, torch.arange(33) // 16], -1)
    with pytest.raises(ValueError, match="oversized message: 33 cells.*max_cells=32"):
        serialize_message(cells, torch.zeros(33, c), CFG)
    big = dataclasses.replace(CFG, max_cells=33)
    with pytest.raises(ValueError, match="oversized message: K=33 cells"):
        deserialize_message(serialize_message(cells, torch.zeros(33, c), big), CFG)
    with pytest.raises(ValueError, match="not a CoDriving roadside message"):
        deserialize_message(np.r_[2022.0, payload[1:]], CFG)
    with pytest.raises(ValueError, match="197 floats"):
        deserialize_message(payload[:-1], CFG)
    with pytest.raises(ValueError, match="outside the 16 x 16"):
        serialize_message(torch.tensor([[16, 0]]), torch.zeros(1, c), CFG)
    with pytest.raises(ValueError, match="max_payload_floats <= 65535"):
        CoDrivingConfig.for_scale("tiny", max_cells=2000, compress_channels=0, width=64)


def test_a_sent_roadside_cell_lands_at_the_ego_cell_of_its_place():
    feat = torch.zeros(1, 3, 16, 16)
    feat[0, :, 5, 5] = torch.tensor([1.0, -2.0, 3.0])  # cell centre (27.5, -12.5) in its frame
    sent = torch.zeros(1, 16, 16, dtype=torch.bool)
    sent[0, 5, 5] = True
    cells, feats = sent_cells(feat, sent)  # through the message and back
    received, got = dense_message(cells, feats, dataclasses.replace(CFG, compress_channels=3))
    warped, covered = scatter_to_ego(received, got, E, CFG)
    ego_xy = (-20.0 + 12.5, 10.0 + 27.5)  # Rz(90 deg) (27.5, -12.5) + (-20, 10)
    cell = 102.4 / 16
    i, j = math.floor((ego_xy[0] + 51.2) / cell), math.floor((ego_xy[1] + 51.2) / cell)
    assert (i, j) == (6, 13)
    assert covered[0, i, j] and int(covered.sum()) == 1  # one cell sent, one cell covered
    assert torch.equal(warped[0, :, i, j], torch.tensor([1.0, -2.0, 3.0]))
    warped[0, :, i, j] = 0.0
    assert float(warped.abs().max()) == 0.0
    # an object at that place, moved into the unit's frame for its confidence target
    box = torch.zeros(1, 1, 10)
    box[0, 0, :2] = torch.tensor(ego_xy)
    assert torch.allclose(boxes_to_rsu(box, E)[0, 0, :2], torch.tensor([27.5, -12.5]), atol=1e-5)


def test_route_ahead_rebuilds_the_observations_route_rows():
    route = np.stack([np.arange(300.0), np.zeros(300)], -1)  # 1 m apart along world x
    rows, k = route_ahead(route, np.array([0.3, 1.0]), 0, CFG, advance=False)
    assert k == 0 and rows.shape == (20, 2)  # the env's first observation: progress 0
    # the env's rule: the furthest point within 3 m among the 40 from the last progress
    rows, k = route_ahead(route, np.array([20.2, 1.0]), 0, CFG)
    assert k == 23 and np.allclose(rows[:, 0], 23 + 2 * np.arange(20))
    # no unit served the ego for a while: progress catches up where the ego is
    rows, k = route_ahead(route, np.array([150.0, 0.0]), k, CFG)
    assert k == 152
    # off the route (nothing within 3 m): progress stays, as the env's
    assert route_ahead(route, np.array([160.0, 10.0]), k, CFG)[1] == 152
    rows, k = route_ahead(route, np.array([298.0, 0.0]), k, CFG)
    assert k == 299 and np.allclose(rows[-1], [299.0, 0.0])  # clipped to the route's end
    with pytest.raises(ValueError, match="route has shape"):
        route_ahead(np.zeros((0, 2)), np.zeros(2), 0, CFG)


def test_waypoint_head_switches_route_frame_and_no_speed():
    import dataclasses
    import math

    from v2xbench.agents.aurora.route_input import route_path
    from v2xbench.agents.baselines.v2x_vit.head import WaypointHead

    cfg = dataclasses.replace(CFG, plan_frame="route", plan_ego_speed=False)
    head = WaypointHead(cfg).eval()
    with torch.no_grad():  # constant outputs: 2 m along the route per step, 0 m across
        head.mlp[-1].weight.zero_()
        head.mlp[-1].bias.copy_(torch.tensor([2.0, 0.0] * cfg.plan_waypoints))
    ang = torch.linspace(0, 1, 20)[:, None] * math.pi / 2  # a left turn of radius 20 m
    path = route_path(torch.cat([20 * torch.sin(ang), 20 * (1 - torch.cos(ang))], -1)[None],
                      40, 2.0)
    bev, cmd = torch.randn(1, cfg.width, 16, 16), torch.tensor([0])
    route = torch.zeros(1, cfg.plan_route_points, 2)
    wps = head(bev, cmd, torch.zeros(1), route, path)[0]
    arc = 2.0 * torch.arange(1, cfg.plan_waypoints + 1)
    want = torch.stack([20 * torch.sin(arc / 20), 20 * (1 - torch.cos(arc / 20))], -1)
    assert torch.allclose(wps, want, atol=0.05), (wps, want)
    with pytest.raises(ValueError, match="route polyline"):
        head(bev, cmd, torch.zeros(1), route)
    speedy = WaypointHead(dataclasses.replace(CFG, plan_ego_speed=False, plan_frame="ego")).eval()
    assert torch.equal(speedy(bev, cmd, torch.zeros(1), route),
                       speedy(bev, cmd, torch.full((1,), 9.0), route))
    with pytest.raises(ValueError, match="plan_frame"):
        dataclasses.replace(CFG, plan_frame="bev")


def test_native_controller_steers_toward_the_waypoints_and_brakes_to_stop():
    ctl = NativeController()
    left = np.stack([np.arange(1.0, 7.0) * 2.0, np.arange(1.0, 7.0) * 0.8], -1)
    throttle, steer, brake = ctl.control(left, 2.0, 5.0)
    assert steer > 0.1 and throttle > 0 and brake == 0
    ctl.reset()
    assert ctl.control(left * [1, -1], 2.0, 5.0)[1] < -0.1  # right
    assert ctl.control(left, 5.0, 0.0)[2] == 1.0  # target 0 m/s: full brake, no throttle
    with pytest.raises(ValueError, match="must be finite"):
        ctl.control(np.full((6, 2), np.nan), 1.0, 1.0)


def test_light_brake_stops_for_red_before_the_line_and_not_after():
    from v2xbench.envs.v2x_intersection.traffic.signals import GREEN, NO_SIGNAL, RED, YELLOW

    brake = LightBrake(decel=4.0, margin=2.5, yellow_decel=3.0)
    # 10 m/s: stopping needs 12.5 m + 2.5 m margin before the stop line
    assert brake(RED, 14.0, 10.0) and not brake(RED, 16.0, 10.0)
    assert not brake(GREEN, 5.0, 10.0) and not brake(NO_SIGNAL, 5.0, 10.0)
    assert not brake(RED, -1.0, 10.0)  # no stop line ahead (or past it: the ego vector's -1)
    assert brake(RED, 1.0, 0.0) and brake(RED, 0.0, 0.5)  # standing at the line: stay
    # yellow: only where 3 m/s^2 still stops before the line (16.7 m at 10 m/s)
    assert not brake(YELLOW, 14.0, 10.0) and brake(YELLOW, 2.0, 1.0)


def test_training_a_few_steps_lowers_the_loss(lidar_dataset):
    from v2xbench.agents.baselines.codriving.data import CoDrivingFrames
    from v2xbench.agents.baselines.codriving.losses import CoDrivingCriterion

    ds = CoDrivingFrames(lidar_dataset, "all", CFG, stride=5, delay=0)
    batch = bc.unit_batch(ds)
    assert batch["route"].shape == (2, CFG.request_route_points, 2)
    torch.manual_seed(0)
    model = CoDriving(CFG)
    losses, parts = bc.overfit(model, CoDrivingCriterion(CFG), batch, steps=40)
    assert parts[-1]["conf"] < parts[0]["conf"]  # the unit's confidence learns its objects
    assert losses[-1] < 0.6 * losses[0], losses[::10]


def test_bad_input_raises_clear_errors(tiny_dataset, lidar_dataset):
    from v2xbench.agents.baselines.codriving.agent import CoDrivingAgent
    from v2xbench.agents.baselines.codriving.data import CoDrivingFrames
    from v2xbench.agents.baselines.codriving.policy import CoDrivingDriver, CoDrivingRoadside

    with pytest.raises(ValueError, match="no LiDAR points.*--sensors lidar"):
        CoDrivingFrames(tiny_dataset, "all", CFG)
    with pytest.raises(ValueError, match="request_route_points=50 needs"):
        CoDrivingFrames(lidar_dataset, "all", CoDrivingConfig.for_scale(
            "tiny", request_route_points=50))
    with pytest.raises(ValueError, match="select_threshold=0"):
        CoDrivingConfig.for_scale("tiny", select_threshold=0.0)
    with pytest.raises(ValueError, match="must each be <= 2048"):
        CoDrivingConfig.for_scale("tiny", max_cells=3000, compress_channels=1)
    model = CoDriving(CFG)
    driver = CoDrivingDriver(model.ego, CFG, 0.5)
    f = CFG.message_floats()
    obs = {"lidar": {"points": np.zeros((10, 6), np.float32), "count": 0},
           "v2x_payload": np.zeros(f - 1, np.float32), "v2x_info": np.zeros(8),
           "route": np.zeros((10, 3), np.float32), "ego": np.zeros(9, np.float32)}
    with pytest.raises(ValueError, match=f"--set max_payload_floats={f}"):
        driver.plan(obs)
    with pytest.raises(ValueError, match="CoDriving: the ego observation has no lidar"):
        driver.plan({k: v for k, v in obs.items() if k != "lidar"})
    rsu = CoDrivingRoadside(model.rsu, CFG, 0.5)
    with pytest.raises(ValueError, match="no route"):
        rsu.act({"unit": np.zeros(6)})
    with pytest.raises(ValueError, match="no route_points"):
        rsu.reset({})
    with pytest.raises(FileNotFoundError, match="not a trained CoDriving run"):
        CoDrivingAgent(run=str(tiny_dataset / "no_such_run"))  # (no run: the shipped weights)


def test_cli_trains_plans_open_loop_and_the_agent_drives_through_eval(lidar_dataset, tmp_path,
                                                                       capsys):
    from v2xbench.agents.aurora.trainer import save_checkpoint
    from v2xbench.agents.baselines.codriving.train import load_run

    data, run = tmp_path / "data", tmp_path / "run"
    shutil.copytree(lidar_dataset, data)
    # the published planner (told the speed, ego-frame steps); the defaults: UniV2X's test
    base, log = bc.train_and_resume("codriving", data, run, capsys,
                                    ("--ego-speed", "--ego-frame"))
    assert {"heat", "box", "plan_l1", "plan_col", "conf"} <= set(log[-1])
    assert "seed differ" in bc.refused_error(base, capsys)
    model, cfg, info = load_run(run)
    assert cfg.plan_ego_speed is True and cfg.plan_frame == "ego"
    bc.assert_same_weights(model, CoDriving(cfg), tmp_path / "again.safetensors")
    bc.open_loop_matches_the_model("codriving", run, data, tmp_path, capsys)
    assert main(["baselines", "eval-perception", "codriving", "--run", str(run), "--data",
                 str(data), "--split", "val", "--stride", "10", "--quiet"]) == 0
    res = json.loads((run / "eval_val" / "perception.json").read_text())
    assert res["message_bytes"] == 16 + 2 * cfg.message_floats() and res["frames"] > 0
    assert res["mean_message_bytes"] == pytest.approx(
        16 + 2 * (6 + res["mean_cells"] * cfg.cell_floats()))
    # a unit confident everywhere: it sends the requested cells, up to the budget
    with torch.no_grad():
        model.rsu.confidence[-1].bias.fill_(5.0)
    save_checkpoint(model, run / "checkpoint.safetensors")
    conf = tmp_path / "codriving.json"
    conf.write_text(json.dumps({"run": str(run)}))
    res_dir = tmp_path / "eval"
    assert main(["eval", "--agent", "codriving", "--agent-config", str(conf), "--suite",
                 "test50", "--max-routes", "1", "--set", "max_steps=15", "--out",
                 str(res_dir), "--quiet"]) == 0
    route = json.loads(next((res_dir / "routes").glob("*.json")).read_text())
    assert route["error"] is None and route["ticks"] == 15
    summ = json.loads((res_dir / "summary.json").read_text())
    assert summ["config_overrides"]["max_payload_floats"] == cfg.message_floats()
    assert summ["rsu_policy"] == "custom:CoDrivingRoadside"
    sent = route["record"]["bytes_sent"]  # the channel's count: messages of 16 + 2 F(K) bytes
    assert sent > 0 and summ["metrics"]["bps"] > 0
    per_cell, empty = 2 * cfg.cell_floats(), 16 + 2 * cfg.message_floats(0)  # 12, 28 bytes
    assert any((sent - empty * n) % per_cell == 0 and 1 <= (sent - empty * n) // per_cell
               <= n * cfg.max_cells for n in range(1, 16)), sent


def test_shipped_weights_load_and_drive(tmp_path):
    bc.assert_shipped_weights("codriving", "CoDrivingRoadside", tmp_path, fixed_size=False)


def test_light_brake_is_a_checked_option_in_the_fingerprint():
    from v2xbench.agents.baselines.codriving.agent import CoDrivingAgent

    with pytest.raises(ValueError, match="light_brake"):
        CoDrivingAgent(light_brake="yes")
    plain, braking = CoDrivingAgent(), CoDrivingAgent(light_brake=True)
    assert "light-brake" in braking.fingerprint() and "light-brake" not in plain.fingerprint()
