"""AURORA samples from a collected data set: shapes, frames, targets, calibration, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from v2xbench.agents.aurora.calib import (
    CAMERA_NAMES,
    frame_camera_tensors,
    project_points,
    rig_calib,
    world_frame_pose,
)
from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.data import AuroraFrames, collate, in_range, make_loader
from v2xbench.collectors.dataset.loader import V2XDataset
from v2xbench.envs.v2x_intersection.core.geometry import transform_points, wrap_angle
from v2xbench.envs.v2x_intersection.sensors import SensorRig, boxes_in_frame, project
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.map_vectors import map_vectors

CFG = AuroraConfig.for_scale("tiny")
KEYS = ["calib", ("gt", "ego"), ("gt", "rsu"), "light_state"]


@pytest.fixture(scope="module")
def raw(tiny_dataset):
    """The recorded frames themselves (the reference the samples are checked against)."""
    return V2XDataset(tiny_dataset, "all", keys=KEYS)


@pytest.mark.parametrize("branch", ["ego", "rsu"])
def test_sample_shapes_dtypes_and_ranges(tiny_dataset, raw, branch):
    ds = AuroraFrames(tiny_dataset, "all", branch, CFG)
    n_cam = len(CAMERA_NAMES[branch])
    w, h = CFG.image_size(branch)
    b = collate([ds[i] for i in range(0, len(ds), max(1, len(ds) // 4))][:4])
    bs = len(b["frame_id"])
    k, p = CFG.num_map_queries, CFG.map_points
    want = {"images": ((bs, n_cam, 3, h, w), torch.float32),
            "intrinsics": ((bs, n_cam, 3, 3), torch.float32),
            "cam_to_frame": ((bs, n_cam, 4, 4), torch.float32),
            "det_boxes": ((bs, 96, 10), torch.float32), "det_labels": ((bs, 96), torch.int64),
            "det_mask": ((bs, 96), torch.bool), "map_points": ((bs, k, p, 2), torch.float32),
            "map_labels": ((bs, k), torch.int64), "map_mask": ((bs, k), torch.bool),
            "map_closed": ((bs, k), torch.bool), "frame_id": ((bs,), torch.int64)}
    if branch == "ego":
        want["light"] = ((bs,), torch.int64)
    assert set(b) == set(want)
    for key, (shape, dtype) in want.items():
        assert tuple(b[key].shape) == shape and b[key].dtype == dtype, key
    assert 0.0 <= float(b["images"].min()) and float(b["images"].max()) <= 1.0
    assert float(b["images"].std()) > 0.05  # real pictures, not blank
    rng = CFG.pc_range(branch)
    boxes = b["det_boxes"][b["det_mask"]].numpy()
    assert len(boxes) and in_range(boxes[:, :3], rng).all()
    np.testing.assert_allclose(boxes[:, 6] ** 2 + boxes[:, 7] ** 2, 1.0, atol=1e-5)
    pts = b["map_points"][b["map_mask"]].numpy()
    assert len(pts) and (pts[..., 0] >= rng[0] - 1e-3).all()
    assert (pts[..., 0] <= rng[3] + 1e-3).all()
    assert (pts[..., 1] >= rng[1] - 1e-3).all() and (pts[..., 1] <= rng[4] + 1e-3).all()
    # the recorded 32 x 16 cameras are resized: the intrinsics scale with them
    fid = int(b["frame_id"][0])
    cal = raw[fid]["calib"]
    kk = cal["cam_intrinsics"].numpy()[list(range(6)) if branch == "ego" else [6]]
    np.testing.assert_allclose(b["intrinsics"][0, :, 0, 0].numpy(), kk[:, 0, 0] * w / 32, rtol=1e-5)
    np.testing.assert_allclose(b["intrinsics"][0, :, 1, 2].numpy(), kk[:, 1, 2] * h / 16, rtol=1e-5)
    # every box of the recorded set inside the range is a target (none lost, none invented)
    for i in range(bs):
        rec = raw[int(b["frame_id"][i])]
        gt = rec["gt", "ego" if branch == "ego" else "rsu"]
        m = gt["mask"].numpy()
        if branch == "ego":
            ref = gt["boxes"].numpy()[m]
        else:
            t_f_e = (np.linalg.inv(world_frame_pose(rec["calib"], "rsu"))
                     @ rec["calib", "T_world_ego"].numpy())
            ref = gt["boxes"].numpy()[m].astype(np.float64)
            ref[:, :3] = transform_points(t_f_e, ref[:, :3])
        assert int(b["det_mask"][i].sum()) == int(in_range(ref[:, :3], rng).sum())
    if branch == "ego":
        states = np.array([int(raw[int(f)]["light_state"]) for f in b["frame_id"]])
        np.testing.assert_array_equal(b["light"].numpy(), states + 1)


def test_rsu_targets_are_the_ego_boxes_in_the_units_ground_frame(tiny_dataset, raw):
    """Through the world: an object's centre, height above the ground, heading and velocity
    are the same whether read from gt/rsu in the ego frame or from the rsu sample."""
    ds = AuroraFrames(tiny_dataset, "all", "rsu", CFG)
    checked = 0
    for i in range(0, len(ds), 3):
        s = ds[i]
        rec = raw[int(s["frame_id"])]
        cal = rec["calib"]
        t_we = cal["T_world_ego"].numpy()
        t_wr = cal["T_world_rsu"].numpy()
        heading = np.arctan2(t_wr[1, 0], t_wr[0, 0])
        gt = rec["gt", "rsu"]
        ego = gt["boxes"].numpy()[gt["mask"].numpy()].astype(np.float64)
        cls = gt["class"].numpy()[gt["mask"].numpy()]
        got = s["det_boxes"][s["det_mask"]].numpy().astype(np.float64)
        got_cls = s["det_labels"][s["det_mask"]].numpy()
        ego_world = transform_points(t_we, ego[:, :3])
        ego_yaw = ego[:, 6] + np.arctan2(t_we[1, 0], t_we[0, 0])
        ego_vel = ego[:, 7:9] @ t_we[:2, :2].T
        for box, c in zip(got, got_cls):
            c_w = np.array([t_wr[0, 3], t_wr[1, 3], 0.0])
            c_w[:2] += np.array([[np.cos(heading), -np.sin(heading)],
                                 [np.sin(heading), np.cos(heading)]]) @ box[:2]
            c_w[2] = box[2]  # the unit's ground frame is level, at the ground
            j = int(np.argmin(np.linalg.norm(ego_world - c_w, axis=1)))
            assert np.linalg.norm(ego_world[j] - c_w) < 1e-3 and cls[j] == c
            np.testing.assert_allclose(box[3:6], ego[j, 3:6], atol=1e-5)
            yaw = np.arctan2(box[6], box[7]) + heading
            assert abs(wrap_angle(yaw - ego_yaw[j])) < 1e-4
            vel = np.array([[np.cos(heading), -np.sin(heading)],
                            [np.sin(heading), np.cos(heading)]]) @ box[8:10]
            np.testing.assert_allclose(vel, ego_vel[j], atol=1e-4)
            checked += 1
    assert checked >= 5


def test_rsu_frames_without_a_unit_are_skipped_and_stride(tiny_dataset, raw, monkeypatch):
    units = np.concatenate([raw.shard(e)["calib", "rsu_unit"].numpy()
                            for e in range(len(raw.episodes))])
    ds = AuroraFrames(tiny_dataset, "all", "rsu", CFG)
    np.testing.assert_array_equal(ds.frame_ids, np.flatnonzero(units >= 0))
    ego2 = AuroraFrames(tiny_dataset, "all", "ego", CFG, stride=2)
    t_in_ep = np.concatenate([np.arange(m["frames"]) for m in raw.meta])
    np.testing.assert_array_equal(ego2.frame_ids, np.flatnonzero(t_in_ep % 2 == 0))
    # frames whose unit is switched off (copy-on-write mapping: the files do not change)
    orig = V2XDataset.shard

    def shard(self, e):
        td = orig(self, e)
        td["calib", "rsu_unit"][::3] = -1
        return td

    monkeypatch.setattr(V2XDataset, "shard", shard)
    off = AuroraFrames(tiny_dataset, "all", "rsu", CFG)
    t_off = np.concatenate([np.arange(m["frames"]) % 3 == 0 for m in raw.meta])
    np.testing.assert_array_equal(off.frame_ids, np.flatnonzero((units >= 0) & ~t_off))


def test_map_targets_are_the_towns_vectors_at_the_frame_pose(tiny_dataset, raw):
    for branch in ("ego", "rsu"):
        ds = AuroraFrames(tiny_dataset, "all", branch, CFG)
        s = ds[len(ds) // 2]
        fid = int(s["frame_id"])
        cal = raw[fid]["calib"]
        town = get_town(ds.town(fid))
        mv = map_vectors(town, world_frame_pose(cal, branch), CFG.pc_range(branch),
                         CFG.map_points, CFG.num_map_queries)
        n = len(mv)
        assert n and int(s["map_mask"].sum()) == n
        np.testing.assert_array_equal(s["map_points"][:n].numpy(), mv.points)
        np.testing.assert_array_equal(s["map_labels"][:n].numpy(), mv.labels)
        np.testing.assert_array_equal(s["map_closed"][:n].numpy(), mv.closed)


def test_recorded_calibration_projects_as_the_world_cameras(tiny_dataset, raw):
    """``K`` and ``cam_to_frame`` of a recorded frame project branch-frame points where the
    recorded world camera pose (``calib/T_world_cam``) does."""
    for branch in ("ego", "rsu"):
        ds = AuroraFrames(tiny_dataset, "all", branch, CFG)
        fid = int(ds.frame_ids[len(ds) // 2])
        cal = raw[fid]["calib"]
        k, c2f = frame_camera_tensors(cal, branch, (32, 16))
        t_wf = world_frame_pose(cal, branch)
        rows = range(6) if branch == "ego" else [6]
        pts = np.random.default_rng(0).uniform([-20, -20, 0], [20, 20, 3], (50, 3))
        for n, row in enumerate(rows):
            entry = {"intrinsics": cal["cam_intrinsics"].numpy()[row],
                     "T_world_sensor": cal["T_world_cam"].numpy()[row]}
            uv_ref, z_ref = project(entry, transform_points(t_wf, pts))
            uv, z = project_points(pts, k[n].numpy(), c2f[n].numpy())
            ok = z_ref > 0.5
            assert ok.sum() >= 5
            np.testing.assert_allclose(z[ok], z_ref[ok], atol=1e-3)
            np.testing.assert_allclose(uv[ok], uv_ref[ok], atol=1e-2)


def test_rig_calibration_projects_box_centres_onto_their_instances():
    """Closed loop: tensors from the sensor rig put a box centre (branch frame) on its own
    actor's pixels of the rendered instance image (OpenCV optical convention)."""
    w = World(make_config(town="Town05", num_vehicles=12, num_parked=6, num_pedestrians=6,
                          num_bicycles=2))
    w.reset(seed=3)
    for _ in range(20):
        w.step(np.array([0.4, 0.0, 0.0]))
    fr = SensorRig().capture(w)
    cal = rig_calib(fr["calibration"])
    boxes = fr["gt"]["boxes"]
    hits = 0
    for branch in ("ego", "rsu"):
        if branch == "rsu" and int(cal["rsu_unit"]) < 0:
            continue
        t_wf = world_frame_pose(cal, branch)
        local = boxes_in_frame(boxes, np.linalg.inv(t_wf))["center"]
        k, c2f = frame_camera_tensors(cal, branch, cal["image_size"][CAMERA_NAMES[branch][0]])
        for n, name in enumerate(CAMERA_NAMES[branch]):
            inst = fr["cameras"][name]["instance"]
            uv, z = project_points(local, k[n].numpy(), c2f[n].numpy())
            for i in range(len(boxes["id"])):
                if z[i] <= 0.5 or (inst == boxes["instance"][i]).sum() < 9:
                    continue
                c, r = int(np.floor(uv[i, 0])), int(np.floor(uv[i, 1]))
                if 0 <= c < inst.shape[1] and 0 <= r < inst.shape[0]:
                    near = inst[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2]
                    assert (near == boxes["instance"][i]).any(), (branch, name, i)
                    hits += 1
    assert hits >= 5


def test_loader_batches_and_repeatable_shuffle(tiny_dataset):
    ds = AuroraFrames(tiny_dataset, "all", "ego", CFG, stride=4)
    ids = [torch.cat([b["frame_id"] for b in make_loader(ds, 3, seed=7)]) for _ in range(2)]
    assert torch.equal(ids[0], ids[1]) and sorted(ids[0].tolist()) == ds.frame_ids.tolist()
    assert not torch.equal(ids[0], torch.as_tensor(ds.frame_ids))
    with pytest.raises(ValueError, match="batch_size"):
        make_loader(ds, 0)


def test_bad_input_is_named(tiny_dataset, tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        AuroraFrames(tmp_path / "nope", "train", "ego", CFG)
    with pytest.raises(ValueError, match="branch"):
        AuroraFrames(tiny_dataset, "all", "fused", CFG)
    with pytest.raises(ValueError, match="stride"):
        AuroraFrames(tiny_dataset, "all", "ego", CFG, stride=0)
    with pytest.raises(ValueError, match="split"):
        AuroraFrames(tiny_dataset, "everything", "ego", CFG)


def test_shard_without_cameras_is_named(tmp_path):
    from v2xbench.collectors.dataset.collect import CollectConfig, collect

    cfg = CollectConfig(max_routes=1, max_ticks=3, camera_size=(32, 16), lidar_scale=0.5,
                        sensors=("bev",), val_fraction=0.0)
    collect(cfg, tmp_path / "nocam", workers=1, progress=False)
    with pytest.raises(ValueError, match=r"train_000_s0.*cameras/cam_front/rgb"):
        AuroraFrames(tmp_path / "nocam", "all", "ego", CFG)


def test_test50_collection_is_the_test_split(tmp_path):
    """The held-out town's suite is collected as split ``test`` (test50.json names its split
    ``test50``), so ``--split test`` finds it and no hash puts its routes in train / val."""
    from v2xbench.collectors.dataset.collect import CollectConfig, collect, route_split

    assert route_split("test50_007", "test50", 0.5) == "test"
    assert route_split("val_001", "val", 0.5) == "val"
    cfg = CollectConfig(suite="test50", max_routes=1, max_ticks=2, camera_size=(32, 16),
                        lidar_scale=0.5)
    collect(cfg, tmp_path / "test", workers=1, progress=False)
    ds = AuroraFrames(tmp_path / "test", "test", "ego", CFG)
    assert len(ds) >= 2 and ds.town(int(ds.frame_ids[0])) == "Town12"
    with pytest.raises(ValueError, match="no shard of split 'train'"):
        AuroraFrames(tmp_path / "test", "train", "ego", CFG)
