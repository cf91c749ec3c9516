"""V2X-ViT baseline (issue #34): pillarization, the roadside map warped into the ego grid, the
message's bytes through the channel, the delay encoding, the attention's agent mask, the LiDAR
frames of the data set and of closed loop, overfitting, `v2xbench baselines train v2x_vit` ->
`v2xbench eval --agent v2x_vit`, and bad input."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil

import numpy as np
import pytest
import torch
from v2xbench.agents.baselines.v2x_vit.config import V2XViTConfig
from v2xbench.agents.baselines.v2x_vit.fusion import (
    DelayEncoding,
    HeteroAgentAttention,
    warp_to_ego,
)
from v2xbench.agents.baselines.v2x_vit.message import deserialize_message, serialize_message
from v2xbench.agents.baselines.v2x_vit.model import RoadsideNet, V2XViT
from v2xbench.agents.baselines.v2x_vit.pillars import PillarEncoder, pillarize
from v2xbench.envs.v2x_intersection.core.geometry import pose_matrix

from tests import baselines_common as bc
from v2xbench.cli import main

torch.set_num_threads(1)
CFG = V2XViTConfig.for_scale("tiny")


@pytest.fixture(scope="module")
def lidar_dataset(tmp_path_factory):
    """The tiny data set (``tests/dataset_helpers.TINY``) recorded with LiDAR points only."""
    return bc.collect_lidar(tmp_path_factory.mktemp("v2x_lidar"))


def test_pillarization_puts_a_point_in_its_pillar_and_nothing_elsewhere():
    # roadside range x 0..80, y -40..40, z -3..5 m; 32 x 32 pillars of 2.5 m
    pts = torch.tensor([[[11.0, -3.0, 0.5, 0.7], [-1.0, 0.0, 0.0, 0.5], [20.0, 0.0, 6.0, 0.5],
                         [79.9, 39.9, 0.0, 0.1], [11.0, -3.0, 0.0, 0.0]]])
    mask = torch.tensor([[True, True, True, True, False]])  # the last row is padding
    index, keep = pillarize(pts, mask, CFG.rsu_range, CFG.rsu_pillars)
    i, j = math.floor(11.0 / 2.5), math.floor((-3.0 + 40.0) / 2.5)
    assert (i, j) == (4, 14)
    assert keep.tolist() == [[True, False, False, True, False]]  # x < 0, z > 5 and padding out
    assert int(index[0, 0]) == i * 32 + j and int(index[0, 3]) == 31 * 32 + 31
    enc = PillarEncoder(CFG, "rsu")
    with torch.no_grad():
        pseudo = enc(pts[:, :1], mask[:, :1])  # one point
    assert pseudo.shape == (1, CFG.pillar_channels, 32, 32)
    assert float(pseudo[0, :, i, j].abs().sum()) > 0
    pseudo[0, :, i, j] = 0.0
    assert float(pseudo.abs().max()) == 0.0


def test_a_roadside_feature_lands_at_the_ego_cell_of_its_place():
    # the unit's ground frame: 90 deg left of the ego's, its foot at ego (-20, 10)
    e = torch.from_numpy(pose_matrix(-20.0, 10.0, 0.0, math.pi / 2).astype(np.float32))[None]
    nx, ny = CFG.feature_size("rsu")  # 16 x 16 cells of 5 m over x 0..80, y -40..40
    feat = torch.zeros(1, 3, nx, ny)
    feat[0, :, 5, 5] = torch.tensor([1.0, 2.0, 3.0])  # cell centre (27.5, -12.5) in its frame
    warped, covered = warp_to_ego(feat, e, torch.tensor([True]), CFG)
    ego_xy = (-20.0 + 12.5, 10.0 + 27.5)  # Rz(90 deg) (27.5, -12.5) + (-20, 10)
    cell = 102.4 / 16
    i, j = math.floor((ego_xy[0] + 51.2) / cell), math.floor((ego_xy[1] + 51.2) / cell)
    assert (i, j) == (6, 13)
    assert divmod(int(warped[0, 0].argmax()), 16) == (i, j)
    assert torch.allclose(warped[0, :, i, j] / warped[0, 0, i, j], torch.tensor([1.0, 2.0, 3.0]))
    assert covered[0, i, j] and not covered[0, 0, 0]  # inside / outside the unit's range
    warped, covered = warp_to_ego(feat, e, torch.tensor([False]), CFG)  # no unit: nothing
    assert float(warped.abs().max()) == 0.0 and not covered.any()


def _rsu_payload() -> tuple[np.ndarray, torch.Tensor]:
    torch.manual_seed(0)
    net = RoadsideNet(CFG).eval()
    pts = torch.rand(1, 300, 4) * torch.tensor([80.0, 80.0, 4.0, 1.0]) - torch.tensor(
        [0.0, 40.0, 2.0, 0.0])
    with torch.no_grad():
        feats = net(pts, torch.ones(1, 300, dtype=torch.bool))
    return serialize_message(feats), feats


def test_message_bytes_are_what_the_channel_counts():
    payload, feats = _rsu_payload()
    f = CFG.message_floats()
    assert feats.shape == (1, CFG.compress_channels, 16, 16)
    assert payload.shape == (f,) and f == 5 + 4 * 16 * 16
    bc.assert_channel_counts(payload, f)
    back = deserialize_message(payload, CFG)
    assert torch.allclose(back, feats.to(torch.float16).float(), atol=1e-6)
    with pytest.raises(ValueError, match="not a V2X-ViT roadside message"):
        deserialize_message(np.r_[2025.0, payload[1:]], CFG)
    with pytest.raises(ValueError, match="C=2 channels"):  # another model's bottleneck
        deserialize_message(serialize_message(feats[:, :2]), CFG)
    with pytest.raises(ValueError, match="1028 floats"):
        deserialize_message(payload[:-1], CFG)
    no_bottleneck = V2XViTConfig.for_scale("tiny", compress_channels=0)
    assert no_bottleneck.message_floats() == 5 + CFG.width * 16 * 16


def test_the_delay_encoding_differs_for_different_ages():
    torch.manual_seed(0)
    enc = DelayEncoding(CFG.width, CFG.max_age)
    p = enc.sinusoid(torch.tensor([0.0, 1.0, 3.0, 50.0, 20.0]))
    assert torch.allclose(p[0, 1::2], torch.ones(CFG.width // 2))  # cos(0) = 1, sin(0) = 0
    for a, b in ((0, 1), (1, 2), (0, 2)):
        assert (p[a] - p[b]).abs().max() > 1e-2
    assert torch.equal(p[3], p[4])  # older than max_age: encoded as max_age
    model = V2XViT(dataclasses.replace(CFG, plan_frame="ego")).eval()  # the ego half sees the age
    batch = {"ego/points": torch.rand(1, 50, 4) * 20, "ego/point_mask": torch.ones(1, 50,
                                                                                  dtype=bool),
             "command": torch.tensor([0]), "ego_speed": torch.tensor([3.0]),
             "route_points": torch.zeros(1, CFG.plan_route_points, 2)}
    _, feats = _rsu_payload()
    e = torch.eye(4)[None]
    with torch.no_grad():
        outs = [model.ego(batch, feats, e, torch.tensor([True]), torch.tensor([a]))
                for a in (1, 3)]
    assert (outs[0]["heat_logits"] - outs[1]["heat_logits"]).abs().max() > 1e-4


def test_heterogeneous_attention_gives_a_masked_agent_no_weight():
    torch.manual_seed(0)
    att = HeteroAgentAttention(8, 2)
    x = torch.randn(1, 2, 4, 4, 8)
    mask = torch.ones(1, 2, 4, 4, dtype=torch.bool)
    mask[0, 1, :2] = False  # the unit does not cover the first two rows of cells
    y = att(x, [0, 1], mask)
    x2 = x.clone()
    x2[0, 1] = torch.randn(4, 4, 8)
    y2 = att(x2, [0, 1], mask)
    assert torch.allclose(y[0, 0, :2], y2[0, 0, :2])  # ego cells: the masked unit is ignored
    assert (y[0, 0, 2:] - y2[0, 0, 2:]).abs().max() > 1e-4  # ... and heard where it covers
    swapped = att(x, [1, 0], mask)  # node types have their own projections
    assert (swapped - y).abs().max() > 1e-4


def test_data_set_and_closed_loop_put_the_lidars_in_the_same_frames(lidar_dataset):
    from v2xbench.agents.baselines.v2x_vit.data import V2XViTFrames, rsu_ground_from_lidar
    from v2xbench.agents.baselines.v2x_vit.policy import rsu_lidar_to_ground
    from v2xbench.envs.v2x_intersection.sensors.lidar import scaled_lidar_specs

    ds = V2XViTFrames(lidar_dataset, "all", CFG, stride=5)
    assert ds.lidar_scale == 0.5
    x = ds.ds[int(ds.frame_ids[3])]
    lid = x["calib", "T_ego_lidar"].numpy()
    assert np.allclose(lid[0], scaled_lidar_specs(0.5)[0].T_parent_sensor())
    with_unit = [i for i in range(len(ds)) if bool(ds[i]["has_rsu"])]
    assert with_unit, "the tiny data set has no frame with a roadside unit"
    fid = int(ds.frame_ids[with_unit[0]])
    x = ds.ds[fid]
    calib = {k: x["calib", k].numpy() for k in ("T_world_ego", "T_world_rsu", "T_ego_rsu",
                                                 "rsu_unit", "T_ego_lidar")}
    unit_z = float(calib["T_world_rsu"][2, 3])
    assert np.allclose(rsu_ground_from_lidar(calib), rsu_lidar_to_ground(unit_z, 0.5), atol=1e-6)
    s = ds[with_unit[0]]
    pts = s["rsu/points"][s["rsu/point_mask"]]
    assert len(pts) > 0 and float(pts[:, 2].min()) > -0.5  # ground returns at z ~ 0, not -5 m


def test_training_messages_are_as_old_as_the_channel_makes_them(lidar_dataset):
    from v2xbench.agents.baselines.v2x_vit.data import V2XViTFrames

    cfg = dataclasses.replace(CFG, train_max_delay=1)  # ages drawn from 1..1: always 1
    assert cfg.msg_latency_ticks == 1
    lagged = V2XViTFrames(lidar_dataset, "all", cfg, delay=None)
    same = V2XViTFrames(lidar_dataset, "all", cfg, delay=0)
    legacy = V2XViTFrames(lidar_dataset, "all", dataclasses.replace(cfg, msg_latency_ticks=0),
                          delay=None)
    checked = 0
    for e in range(len(lagged.ds.episodes)):
        off, end = int(lagged.ds.offsets[e]), int(lagged.ds.offsets[e + 1])
        first = lagged[off]
        assert not bool(first["has_rsu"]), "a message at the episode's first tick"
        assert not first["rsu/point_mask"].any()
        assert bool(legacy[off]["has_rsu"]) == bool(same[off]["has_rsu"])  # legacy: age 0..1
        for t in range(off + 1, min(end, off + 6)):
            s, prev = lagged[t], same[t - 1]
            if not bool(s["has_rsu"]):
                continue
            assert int(s["age"]) == 1
            assert torch.equal(s["rsu/point_mask"], prev["rsu/point_mask"])  # tick t - 1's
            assert torch.equal(s["rsu/points"], prev["rsu/points"])
            assert torch.equal(s["rsu_to_ego"], same[t]["rsu_to_ego"])  # the pose at reading
            checked += 1
    assert checked, "no frame with a message"
    ages = {int(lagged[i]["age"]) for i in range(0, len(lagged), 7)
            if bool(lagged[i]["has_rsu"])}
    assert ages == {1}
    v2xvit = V2XViTFrames(lidar_dataset, "all", CFG, delay=None)  # 1..3
    drawn = [v2xvit[i] for i in range(0, len(v2xvit), 3)]  # each sample drawn once
    assert {int(s["age"]) for s in drawn if bool(s["has_rsu"])} <= {1, 2, 3}


def test_tiny_model_overfits_two_samples(lidar_dataset):
    from v2xbench.agents.baselines.v2x_vit.data import V2XViTFrames
    from v2xbench.agents.baselines.v2x_vit.losses import V2XViTCriterion

    batch = bc.unit_batch(V2XViTFrames(lidar_dataset, "all", CFG, stride=5, delay=0))
    torch.manual_seed(0)
    model = V2XViT(CFG)
    losses, _ = bc.overfit(model, V2XViTCriterion(CFG), batch)
    assert model.rsu.compress.weight.grad.abs().sum() > 0  # the roadside half trained too
    assert losses[-1] < 0.5 * losses[0], losses[::10]


def test_bad_input_raises_clear_errors(tiny_dataset, lidar_dataset):
    from v2xbench.agents.baselines.v2x_vit.agent import V2XViTAgent
    from v2xbench.agents.baselines.v2x_vit.data import V2XViTFrames, lidar_points
    from v2xbench.agents.baselines.v2x_vit.policy import V2XViTDriver, V2XViTRoadside

    with pytest.raises(ValueError, match="no LiDAR points.*--sensors lidar"):
        V2XViTFrames(tiny_dataset, "all", CFG)  # recorded with rgb,bev only
    with pytest.raises(ValueError, match="delay=-1"):
        V2XViTFrames(lidar_dataset, "all", CFG, delay=-1)
    with pytest.raises(ValueError, match="windows \\[3\\] do not divide"):
        V2XViTConfig.for_scale("tiny", windows=(3,), window_heads=(1,))
    with pytest.raises(ValueError, match="max_payload_floats <= 65535"):
        V2XViTConfig.for_scale("tiny", compress_channels=0, width=512, rsu_pillars=(64, 64))
    with pytest.raises(ValueError, match="count=9 outside 0..4"):
        lidar_points(np.zeros((4, 6)), 9, np.eye(4))
    model = V2XViT(CFG)
    driver = V2XViTDriver(model.ego, CFG, 0.5)
    f = CFG.message_floats()
    obs = {"lidar": {"points": np.zeros((10, 6), np.float32), "count": 0},
           "v2x_payload": np.zeros(f - 1, np.float32), "v2x_info": np.zeros(8),
           "route": np.zeros((10, 3), np.float32), "ego": np.zeros(9, np.float32)}
    with pytest.raises(ValueError, match=f"--set max_payload_floats={f}"):
        driver.plan(obs)
    with pytest.raises(ValueError, match="no lidar points/count"):
        driver.plan({k: v for k, v in obs.items() if k != "lidar"})
    with pytest.raises(ValueError, match="roadside observation has no lidar"):
        V2XViTRoadside(model.rsu, CFG, 0.5).act({"unit": np.zeros(6)})
    with pytest.raises(FileNotFoundError, match="no run given"):
        V2XViTAgent()


def test_cli_trains_resumes_and_drives_a_route(lidar_dataset, tmp_path, capsys):
    from v2xbench.agents.baselines.v2x_vit.train import load_run

    data, run = tmp_path / "data", tmp_path / "run"
    shutil.copytree(lidar_dataset, data)
    base, log = bc.train_and_resume("v2x_vit", data, run, capsys)
    assert {"heat", "box", "plan_l1", "plan_col"} <= set(log[-1])
    assert "seed differ" in bc.refused_error(base, capsys)
    model, cfg, info = load_run(run)  # checkpoint round trip
    bc.assert_same_weights(model, V2XViT(cfg), tmp_path / "again.safetensors")
    assert info["lidar_scale"] == 0.5
    assert main(["baselines", "eval-perception", "v2x_vit", "--run", str(run), "--data",
                 str(data), "--split", "val", "--stride", "10", "--quiet"]) == 0
    res = json.loads((run / "eval_val" / "perception.json").read_text())
    assert res["message_bytes"] == 16 + 2 * cfg.message_floats() and res["frames"] > 0
    summ = bc.drive_one_route("v2x_vit", run, tmp_path, cfg.message_floats(), "V2XViTRoadside")
    assert summ["config_overrides"]["lidar_scale"] == 0.5
