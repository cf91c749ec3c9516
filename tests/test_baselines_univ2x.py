"""UniV2X baseline (issue #34): Lift-Splat geometry, the roadside reference point and occupancy in
the ego frame, the message's bytes through the channel, oversized messages, overfitting two
samples, and `v2xbench baselines train univ2x` -> `v2xbench eval --agent univ2x`."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil

import numpy as np
import pytest
import torch
from v2xbench.agents.aurora.position import lid_depths
from v2xbench.agents.baselines.univ2x.bev import LiftSplatEncoder, box_occupancy
from v2xbench.agents.baselines.univ2x.config import UniV2XConfig
from v2xbench.agents.baselines.univ2x.fusion import AgentFusion, OccupancyFusion
from v2xbench.agents.baselines.univ2x.message import (
    deserialize_message,
    rsu_message,
    serialize_message,
)
from v2xbench.agents.baselines.univ2x.model import RoadsideNet, UniV2X
from v2xbench.envs.v2x_intersection.core.geometry import pose_matrix
from v2xbench.envs.v2x_intersection.v2x.channel import Channel, ChannelConfig, validate_message
from v2xbench.envs.v2x_intersection.v2x.wire import FORMAT_RAW

from tests import baselines_common as bc
from v2xbench.cli import main

torch.set_num_threads(1)
CFG = UniV2XConfig.for_scale("tiny")


def _forward_camera() -> tuple[torch.Tensor, torch.Tensor]:
    """A 64 x 32 camera at the frame's origin looking along +x (fx = fy = 32, centre 32, 16)."""
    k = torch.tensor([[32.0, 0, 32], [0, 32, 16], [0, 0, 1]])
    c2f = torch.eye(4)
    c2f[:3, :3] = torch.tensor([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])  # optical -> x fwd, y left
    return k[None, None], c2f[None, None]


def test_lift_splat_puts_a_feature_at_a_known_pixel_and_depth_into_its_bev_cell():
    enc = LiftSplatEncoder(CFG, "rsu")  # range x 0..80, y -40..40 m, 16 x 16 cells of 5 m
    k, c2f = _forward_camera()
    tokens = (64 // 8) * (32 // 8)
    depth = torch.zeros(1, 1, tokens, CFG.depth_bins)
    t, d = 1 * 8 + 3, 3  # token row 1, column 3: pixel centre (28, 12); depth bin 3
    depth[0, 0, t, d] = 1.0
    context = torch.randn(1, 1, tokens, CFG.bev_channels)
    bev = enc.lift_splat(depth, context, k, c2f)
    z = float(lid_depths(CFG.depth_bins, CFG.depth_near, CFG.rsu_depth_far)[d])
    assert abs(z - 37.2) < 1e-4  # 2 + 88 * 3 * 4 / 30
    x, y = z, -(28 - 32) / 32 * z  # 37.2 m ahead, 4.65 m to the left (and 4.65 m up)
    i, j = math.floor(x / 5.0), math.floor((y + 40.0) / 5.0)
    assert (i, j) == (7, 8)
    assert torch.allclose(bev[0, :, i, j], context[0, 0, t], atol=1e-6)
    bev[0, :, i, j] = 0.0
    assert float(bev.abs().max()) == 0.0  # nothing anywhere else
    depth[0, 0, t] = 0.0
    depth[0, 0, t, CFG.depth_bins - 1] = 1.0  # 90 m: beyond the range, dropped
    assert float(enc.lift_splat(depth, context, k, c2f).abs().max()) == 0.0


def test_roadside_reference_points_reach_the_right_ego_points_and_associate():
    fusion = AgentFusion(CFG)
    e = torch.from_numpy(pose_matrix(10.0, 5.0, 0.0, math.pi / 2).astype(np.float32))[None]
    k = CFG.msg_topk
    msg = {"queries": torch.randn(1, k, CFG.width), "ref": torch.zeros(1, k, 3),
           "scores": torch.full((1, k), 0.9), "mask": torch.zeros(1, k, dtype=torch.bool),
           "occ": torch.zeros(1, *CFG.msg_occ)}
    msg["ref"][0, 0] = torch.tensor([3.0, 0.0, 0.0])  # -> ego (10, 8, 0)
    msg["ref"][0, 1] = torch.tensor([3.0, 2.0, 0.5])  # -> ego (8, 8, 0.5)
    msg["mask"][0, :2] = True
    q = CFG.num_queries
    ego_ref = torch.full((1, q, 3), 40.0)
    ego_ref[0, 0] = torch.tensor([8.5, 8.0, 0.0])  # one confident ego agent near roadside agent 1
    scores = torch.zeros(1, q)
    scores[0, 0] = 0.9
    out = fusion(torch.randn(1, q, CFG.width), ego_ref, scores, msg, e)
    assert torch.allclose(out["rsu_ref"][0, 0], torch.tensor([10.0, 8.0, 0.0]), atol=1e-5)
    assert torch.allclose(out["rsu_ref"][0, 1], torch.tensor([8.0, 8.0, 0.5]), atol=1e-5)
    assert out["match"][0, 0] == 1 and (out["match"][0, 1:] == -1).all()
    appended = out["mask"][0, q:]
    assert appended[0] and not appended[1] and not appended[2:].any()  # 1 fused, 0 appended
    assert torch.allclose(out["ref"][0, q], torch.tensor([10.0, 8.0, 0.0]), atol=1e-5)


def test_roadside_occupancy_warps_onto_the_ego_cell_of_its_object():
    occ_f = OccupancyFusion(CFG)
    e = torch.from_numpy(pose_matrix(-20.0, 10.0, 0.0, math.pi / 2).astype(np.float32))[None]
    box = torch.tensor([[[25.0, -15.0, 0.0, 4.0, 2.0, 1.5, 0.0, 1.0, 0.0, 0.0]]])
    occ = box_occupancy(box, torch.zeros(1, 1, dtype=torch.long), torch.ones(1, 1, dtype=bool),
                        CFG.rsu_range, CFG.msg_occ)  # an object in the unit's frame
    assert int(occ.sum()) >= 1
    warped = occ_f.warp(occ, e)
    ego_xy = (-20.0 + 15.0, 10.0 + 25.0)  # Rz(90 deg) (25, -15) + (-20, 10)
    cell = 102.4 / 16
    i, j = math.floor((ego_xy[0] + 51.2) / cell), math.floor((ego_xy[1] + 51.2) / cell)
    prob = warped[0, 0]
    assert prob[i, j] > 0.5 and divmod(int(prob.argmax()), 16) == (i, j)
    assert warped[0, 1, i, j] == 1.0 and warped[0, 1, 0, 0] == 0.0  # inside / outside the range


def _rsu_payload() -> tuple[np.ndarray, dict]:
    torch.manual_seed(0)
    net = RoadsideNet(CFG).eval()
    k, c2f = _forward_camera()
    with torch.no_grad():
        out = net({"images": torch.rand(1, 1, 3, 32, 64), "intrinsics": k, "cam_to_frame": c2f})
    msg = rsu_message(out, CFG)
    return serialize_message(msg), msg


def test_message_bytes_are_what_the_channel_counts():
    payload, msg = _rsu_payload()
    f = CFG.message_floats()
    assert payload.shape == (f,) and f == 6 + CFG.msg_topk * (4 + CFG.width) + 8 * 8
    bc.assert_channel_counts(payload, f)
    back = deserialize_message(payload, CFG)
    for key in ("queries", "ref", "scores", "occ"):
        assert torch.allclose(back[key], msg[key].to(torch.float16).float(), atol=1e-6)
    with pytest.raises(ValueError, match="not a UniV2X roadside message"):
        deserialize_message(np.r_[1717.0, payload[1:]], CFG)
    with pytest.raises(ValueError, match="K=3"):  # another model's sizes
        deserialize_message(serialize_message({k: v[:, :3] if k != "occ" else v
                                               for k, v in msg.items()}), CFG)


def test_an_oversized_message_is_refused():
    payload, _ = _rsu_payload()
    f = len(payload)
    small = ChannelConfig(max_payload_floats=f - 1)
    with pytest.raises(ValueError, match=f"oversized message: length {f} .*{f - 1}"):
        Channel(small, np.random.default_rng(0)).send(0, 0, f, payload, FORMAT_RAW)
    with pytest.raises(ValueError, match="oversized"):
        validate_message({"length": f, "payload": np.zeros(f - 1, np.float32)}, small)
    with pytest.raises(ValueError, match="max_payload_floats <= 65535"):
        UniV2XConfig.for_scale("tiny", msg_topk=16, width=4096, heads=2)
    from v2xbench.agents.baselines.univ2x.policy import UniV2XDriver

    driver = UniV2XDriver(UniV2X(CFG).ego, CFG, (32, 16))
    obs = {"v2x_payload": np.zeros(f - 1, np.float32), "v2x_info": np.zeros(8)}
    with pytest.raises(ValueError, match=f"--set max_payload_floats={f}"):
        driver._message(obs)


def test_tiny_model_overfits_two_samples(tiny_dataset):
    from v2xbench.agents.baselines.univ2x.data import UniV2XFrames
    from v2xbench.agents.baselines.univ2x.losses import UniV2XCriterion

    batch = bc.unit_batch(UniV2XFrames(tiny_dataset, "all", CFG, stride=5))
    torch.manual_seed(0)
    losses, parts = bc.overfit(UniV2X(CFG), UniV2XCriterion(CFG), batch)
    parts = parts[-1]
    assert parts["rsu_cls"] > 0 and parts["plan_l1"] >= 0  # the roadside half trained too
    assert losses[-1] < 0.5 * losses[0], losses[::10]


def test_no_ego_speed_planner_never_hears_the_speed(tiny_dataset, tmp_path, capsys):
    from v2xbench.agents.baselines.univ2x.planner import QueryPlanner
    from v2xbench.agents.baselines.univ2x.train import load_run

    torch.manual_seed(0)
    args = (torch.randn(2, 5, CFG.width), torch.randn(2, 5, CFG.width),
            torch.ones(2, 5, dtype=torch.bool), torch.randn(2, 8, CFG.width),
            torch.randn(2, 8, CFG.width), torch.tensor([0, 1]))
    route = torch.randn(2, CFG.plan_route_points, 2)
    slow, fast = torch.zeros(2), torch.full((2,), 8.0)
    for hears in (True, False):
        p = QueryPlanner(dataclasses.replace(CFG, plan_ego_speed=hears, plan_frame="ego")).eval()
        moved = (p(*args, slow, route) - p(*args, fast, route)).abs().max()
        assert (moved > 1e-4) if hears else (moved == 0), (hears, moved)
    with pytest.raises(ValueError, match="plan_ego_speed"):
        dataclasses.replace(CFG, plan_ego_speed=1)
    # the defaults: never told the speed, the route frame; the command line's switches reach
    # the run's configuration (and so the closed loop)
    for scale in UniV2XConfig.SCALES:
        cfg = UniV2XConfig.for_scale(scale)
        assert cfg.plan_ego_speed is False and cfg.plan_frame == "route", scale
    data = tmp_path / "data"
    shutil.copytree(tiny_dataset, data)
    for flags, want in ((("--ego-speed", "--ego-frame"), (True, "ego")),
                        (("--no-ego-speed", "--route-frame"), (False, "route"))):
        run = tmp_path / flags[0]
        assert main(["baselines", "train", "univ2x", "--data", str(data), "--out", str(run),
                     "--scale", "tiny", "--quiet", "--max-steps", "1", *flags]) == 0
        capsys.readouterr()
        cfg = load_run(run)[1]
        assert (cfg.plan_ego_speed, cfg.plan_frame) == want, flags
    # a run written before the switches existed planned in the ego frame, told the speed
    old = {k: v for k, v in cfg.to_dict().items() if k not in ("plan_ego_speed", "plan_frame")}
    legacy = UniV2XConfig.from_dict({k: v for k, v in old.items() if k != "msg_latency_ticks"})
    assert (legacy.plan_ego_speed, legacy.plan_frame, legacy.msg_latency_ticks) == (True, "ego", 0)
    # such a run resumes with the settings it was trained with, and the refusal names a field
    info = json.loads((run / "univ2x.json").read_text())
    info["config"] = {k: v for k, v in info["config"].items()
                      if k not in ("plan_ego_speed", "plan_frame", "msg_latency_ticks")}
    (run / "univ2x.json").write_text(json.dumps(info))
    base = ["baselines", "train", "univ2x", "--data", str(data), "--out", str(run), "--scale",
            "tiny", "--quiet", "--max-steps", "1"]
    assert main(base) == 2
    assert "config.plan_frame" in capsys.readouterr().err
    assert main([*base, "--ego-frame", "--ego-speed", "--msg-latency-ticks", "0"]) == 0


def test_route_frame_planner_plans_along_the_observed_route(tiny_dataset):
    from v2xbench.agents.aurora.data import collate
    from v2xbench.agents.aurora.route_input import PATH_KEY, route_path
    from v2xbench.agents.baselines.univ2x.data import UniV2XFrames
    from v2xbench.agents.baselines.univ2x.planner import QueryPlanner

    cfg = dataclasses.replace(CFG, plan_frame="route")
    p = QueryPlanner(cfg).eval()
    with torch.no_grad():  # constant outputs: 2 m along the route per step, 0 m across
        last = p.head[-1]
        last.weight.zero_()
        last.bias.copy_(torch.tensor([2.0, 0.0] * cfg.plan_waypoints))
    t = torch.linspace(0, 1, 20)[:, None]  # a route turning left: quarter circle of radius 20 m
    ang = t * math.pi / 2
    route = torch.cat([20 * torch.sin(ang), 20 * (1 - torch.cos(ang))], -1)
    path = route_path(route[None], 40, 2.0)
    args = (torch.zeros(1, 2, CFG.width), torch.zeros(1, 2, CFG.width),
            torch.ones(1, 2, dtype=torch.bool), torch.zeros(1, 3, CFG.width),
            torch.zeros(1, 3, CFG.width), torch.tensor([0]), torch.zeros(1),
            torch.zeros(1, CFG.plan_route_points, 2))
    wps = p(*args, path)[0]
    # on the curve, 2, 4, ... 12 m of arc along it (chords of a 20 m circle), left of straight on
    arc = 2.0 * torch.arange(1, cfg.plan_waypoints + 1)
    want = torch.stack([20 * torch.sin(arc / 20), 20 * (1 - torch.cos(arc / 20))], -1)
    assert torch.allclose(wps, want, atol=0.05), (wps, want)
    with pytest.raises(ValueError, match="route polyline"):
        p(*args)
    with pytest.raises(ValueError, match="plan_frame"):
        dataclasses.replace(CFG, plan_frame="bev")
    # the data set and the closed loop give the planner the same polyline of the same route rows
    from v2xbench.agents.baselines.common.policy import planning_inputs

    frames = UniV2XFrames(tiny_dataset, "all", cfg, stride=5)
    s = frames[3]
    assert s[PATH_KEY].shape == (40, 2)
    ego_cfg = dataclasses.replace(CFG, plan_frame="ego")
    assert PATH_KEY not in UniV2XFrames(tiny_dataset, "all", ego_cfg, stride=5)[3]
    route = np.asarray(frames.extra[int(frames.frame_ids[3])]["route"])  # the recorded rows
    obs = {"route": route, "ego": np.zeros(4, np.float32)}
    assert torch.equal(planning_inputs(obs, cfg)[PATH_KEY][0], s[PATH_KEY])
    assert collate([s, s])[PATH_KEY].shape == (2, 40, 2)


def test_cli_trains_resumes_round_trips_plans_open_loop_and_drives_a_route(tiny_dataset, tmp_path,
                                                                            capsys):
    from v2xbench.agents.baselines.univ2x.train import load_run

    data, run = tmp_path / "data", tmp_path / "run"
    shutil.copytree(tiny_dataset, data)
    base, _ = bc.train_and_resume("univ2x", data, run, capsys)
    assert (run / "loss.png").is_file()
    assert "seed differ" in bc.refused_error(base, capsys)
    model, cfg, info = load_run(run)  # checkpoint round trip: same weights, same outputs
    bc.assert_same_weights(model, UniV2X(cfg), tmp_path / "again.safetensors")
    assert info["camera_size"] == [32, 16]
    bc.open_loop_matches_the_model("univ2x", run, data, tmp_path, capsys)
    # exported weights (what the repository ships) drive through eval as the run would
    export = tmp_path / "export"
    assert main(["baselines", "export", "univ2x", "--run", str(run), "--out", str(export)]) == 0
    assert "plan_frame 'route'" in capsys.readouterr().out
    bc.assert_export_is_the_run("univ2x", run, export)
    bc.drive_one_route("univ2x", export, tmp_path, cfg.message_floats(), "UniV2XRoadside")


def test_shipped_weights_load_and_drive(tmp_path):
    bc.assert_shipped_weights("univ2x", "UniV2XRoadside", tmp_path)
