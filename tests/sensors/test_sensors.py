"""Sensors: shapes, geometry, occlusion, semantics, calibration and the ground-truth sets.

Two kinds of worlds:

- ``populated``: Town05 with its default-style population (a handful of each actor class), for
  shapes, label consistency and the GT sets on a real scene;
- ``staged``: the same town emptied of NPCs, with actors written into ``world.table`` rows and
  one RSU written into ``world.rsus`` (``active_rsu = [0]``), on a straight stretch of a long
  lane (:func:`lane_frame`), far from junctions, so no pole is near and buildings stand beyond
  the sidewalks. Along the lane (s forward, l to the left): ego at s = 10, an occluder (truck or
  car) at s = 19, a pedestrian at s = 26; the RSU stands 7 m right of the lane at s = 40, 5 m
  up, looking back down the lane at the pedestrian. The ego's LiDAR (2.5 m) and cameras (1.8 m)
  are below the truck's roof (3.5 m), so every ray toward the pedestrian ends on the truck; the
  RSU sees the pedestrian from the other side, with nothing in between.
"""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.classes import CAR, LARGE_VEHICLE, PEDESTRIAN
from v2xbench.envs.v2x_intersection.core.geometry import camera_intrinsics, pose_matrix
from v2xbench.envs.v2x_intersection.core.raycast import first_hit_fan
from v2xbench.envs.v2x_intersection.perception.visibility import VISIBLE_THRESHOLD
from v2xbench.envs.v2x_intersection.sensors import (
    BEV_CHANNELS,
    EGO_CAMERA_NAMES,
    NUM_SEMANTIC,
    SEMANTIC_NAMES,
    BevSpec,
    LidarSpec,
    SensorConfig,
    SensorRig,
    calibration,
    capture_bev,
    capture_lidar,
    decode_instance,
    mosaic,
    project,
)
from v2xbench.envs.v2x_intersection.sensors.calibration import ego_pose
from v2xbench.envs.v2x_intersection.sensors.fan import fan_for, unoccluded_pixels
from v2xbench.envs.v2x_intersection.sensors.semantics import M_CROSS_GAP, M_CROSS_STRIPE
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town.model import DRIVING
from v2xbench.envs.v2x_intersection.traffic.signals import GREEN, RED
from v2xbench.envs.v2x_intersection.v2x.rsu import RSUSet

TOWN = "Town05"


@pytest.fixture(scope="module")
def rig():
    return SensorRig()


@pytest.fixture(scope="module")
def populated(rig):
    w = World(
        make_config(town=TOWN, num_vehicles=12, num_parked=6, num_pedestrians=8, num_bicycles=3)
    )
    w.reset(seed=3)
    for _ in range(20):
        w.step(np.array([0.4, 0.0, 0.0]))
    return w, rig.capture(w)


def empty_world(rows: int = 4) -> World:
    w = World(
        make_config(
            town=TOWN, num_vehicles=rows - 1, num_parked=0, num_pedestrians=0, num_bicycles=0
        )
    )
    w.reset(seed=0)
    w.table.active[1:] = False
    w.table.height[1:] = 0.0
    return w


def lane_frame(w: World):
    """Origin and unit axes (forward, left) of the first long, straight driving lane."""
    for ln in w.town.lanes:
        if ln.kind != DRIVING or ln.length < 80.0:
            continue
        seg = np.diff(ln.points, axis=0)
        h = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
        if np.ptp(h) < np.deg2rad(2.0):
            f = (ln.points[-1] - ln.points[0]) / np.linalg.norm(ln.points[-1] - ln.points[0])
            return ln.points[0], f, np.array([-f[1], f[0]])
    raise AssertionError("no long straight lane in the test town")


def put(w: World, row: int, kind: int, xy, yaw: float, size) -> None:
    t = w.table
    t.kind[row], t.active[row], t.pos[row], t.yaw[row], t.speed[row] = kind, True, xy, yaw, 0.0
    t.length[row], t.width[row], t.height[row] = size


def staged(occluder_kind: int, occluder_size) -> World:
    w = empty_world()
    o, f, left = lane_frame(w)
    yaw = float(np.arctan2(f[1], f[0]))
    put(w, 0, CAR, o + 10 * f, yaw, (4.7, 1.9, 1.5))
    put(w, 1, occluder_kind, o + 19 * f, yaw, occluder_size)
    put(w, 2, PEDESTRIAN, o + 26 * f, yaw + np.pi / 2, (0.55, 0.55, 1.8))
    rsu = o + 40 * f - 7 * left
    to_ped = o + 26 * f - rsu
    w.rsus = RSUSet(
        np.array([[*rsu, 5.0, np.arctan2(to_ped[1], to_ped[0])]]), np.zeros(1, int), np.zeros(1)
    )
    w.active_rsu = np.array([0])
    return w


# --------------------------------------------------------------------------- shapes and dtypes
def test_output_shapes_and_dtypes(populated, rig):
    w, fr = populated
    cfg = rig.config
    assert set(fr["cameras"]) == set(EGO_CAMERA_NAMES) | {"rsu_cam"}
    for cam in fr["cameras"].values():
        wd, ht = cfg.camera_size
        assert cam["rgb"].shape == (ht, wd, 3) and cam["rgb"].dtype == np.uint8
        assert cam["depth"].shape == (ht, wd) and cam["depth"].dtype == np.float32
        assert cam["semantic"].shape == (ht, wd) and cam["semantic"].dtype == np.uint8
        assert cam["instance"].shape == (ht, wd) and cam["instance"].dtype == np.int32
        assert cam["semantic"].max() < NUM_SEMANTIC
        assert np.all(cam["depth"] > 0) and np.all(cam["depth"] <= cfg.far)
    for spec in (cfg.ego_lidar, cfg.rsu_lidar):
        lid = fr["lidars"][spec.name]
        n = lid["count"]
        assert lid["points"].shape == (n, 6) and lid["points"].dtype == np.float32
        assert lid["padded"].shape == (spec.max_points, 6) and n > 100
        np.testing.assert_array_equal(lid["padded"][:n], lid["points"])
        assert not lid["padded"][n:].any()
        assert lid["range_image"].shape == (spec.channels, spec.azimuth_steps)
        r = np.linalg.norm(lid["points"][:, :3], axis=1)
        assert r.max() <= spec.max_range + 1e-3
        assert np.all((lid["points"][:, 3] >= 0) & (lid["points"][:, 3] <= 1))
        assert (lid["range_image"] > 0).sum() == n
    assert fr["bev"].shape == (len(BEV_CHANNELS), 128, 128) and fr["bev"].dtype == np.uint8
    assert fr["bev"].max() == 1
    bev = dict(zip(BEV_CHANNELS, fr["bev"]))
    assert bev["drivable"][64, 64] == 1 and bev["ego"][62:66, 62:66].all()
    cal = fr["calibration"]
    for name in EGO_CAMERA_NAMES + ("rsu_cam",):
        assert cal[name]["intrinsics"].shape == (3, 3) and cal[name]["extrinsics"].shape == (4, 4)
    assert cal["lidar"]["parent"] == "ego" and cal["rsu_lidar"]["parent"] == "world"
    np.testing.assert_allclose(cal["T_world_ego"] @ cal["T_ego_rsu"], cal["T_world_rsu"], atol=1e-9)
    space = rig.observation_space()
    assert space.contains(rig.observation(fr))
    img = mosaic(fr)
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert len(SEMANTIC_NAMES) == NUM_SEMANTIC


# --------------------------------------------------------------------------- labels
def test_semantic_ids_match_object_classes(populated):
    w, fr = populated
    seen = 0
    for cam in fr["cameras"].values():
        inst, sem = cam["instance"], cam["semantic"]
        m = inst > 0
        static, index = decode_instance(inst[m])
        kind = np.where(
            static,
            w.static_kinds[np.where(static, index, 0)],
            w.table.kind[np.where(static, 0, index)],
        )
        np.testing.assert_array_equal(sem[m], kind)
        assert not np.any(sem[~m] < 8), "object class without an instance id"
        seen += m.sum()
    assert seen > 200
    for lid in fr["lidars"].values():
        p = lid["points"]
        m = p[:, 5] > 0
        static, index = decode_instance(p[m, 5].astype(np.int64))
        kind = np.where(
            static,
            w.static_kinds[np.where(static, index, 0)],
            w.table.kind[np.where(static, 0, index)],
        )
        np.testing.assert_array_equal(p[m, 4].astype(np.int64), kind)


def test_ground_semantics_present(populated):
    _, fr = populated
    sem = np.concatenate([c["semantic"].ravel() for c in fr["cameras"].values()])
    for name in ("road", "lane_marking", "sidewalk", "sky"):
        assert (sem == SEMANTIC_NAMES.index(name)).sum() > 20, name


# --------------------------------------------------------------------------- occlusion
def test_pedestrian_behind_truck_hidden_from_ego_seen_by_rsu(rig):
    w = staged(LARGE_VEHICLE, (8.0, 2.5, 3.5))
    fr = rig.capture(w)
    ped = 3  # instance id of row 2
    ego_pts = fr["lidars"]["lidar"]["points"]
    rsu_pts = fr["lidars"]["rsu_lidar"]["points"]
    assert (ego_pts[:, 5] == 2).sum() > 50  # the truck fills the view ahead
    assert (ego_pts[:, 5] == ped).sum() == 0
    assert (rsu_pts[:, 5] == ped).sum() >= 10
    assert not any((c["instance"] == ped).any() for n, c in fr["cameras"].items() if n != "rsu_cam")
    assert (fr["cameras"]["rsu_cam"]["instance"] == ped).sum() >= 4
    gt = fr["gt"]
    pid = w.table.actor_id[2]
    assert pid not in gt["ego"]["id"] and pid in gt["rsu"]["id"] and pid in gt["fused"]["id"]
    assert pid not in gt["joint"]["id"]


def test_ego_bev_draws_only_what_the_ego_sees(rig):
    w = staged(LARGE_VEHICLE, (8.0, 2.5, 3.5))  # the pedestrian stands hidden behind the truck
    w.perceive()
    assert w.ego_vis[1] >= VISIBLE_THRESHOLD > w.ego_vis[2]
    ego = dict(zip(BEV_CHANNELS, rig.capture_bev(w)))
    full = dict(zip(BEV_CHANNELS, capture_bev(w, rig.ground(w), BevSpec(privileged=True))))
    assert ego["vehicle"].sum() > 50 and ego["ego"].sum() > 20
    assert ego["vru"].sum() == 0 and full["vru"].sum() >= 1
    for name in BEV_CHANNELS:
        if name != "vru":
            np.testing.assert_array_equal(ego[name], full[name], err_msg=name)
    w.table.height[1] = 0.0  # without the truck the pedestrian is seen, and drawn
    w.table.active[1] = False
    w.perceive()
    assert w.ego_vis[2] >= VISIBLE_THRESHOLD
    np.testing.assert_array_equal(rig.capture_bev(w)[BEV_CHANNELS.index("vru")], full["vru"])


def test_pedestrian_behind_car_seen_by_rsu(rig):
    w = staged(CAR, (4.5, 1.9, 1.5))
    fr = rig.capture(w)
    rsu_pts = fr["lidars"]["rsu_lidar"]["points"]
    assert (rsu_pts[:, 5] == 3).sum() >= 10
    assert w.table.actor_id[2] in fr["gt"]["rsu"]["id"]


# --------------------------------------------------------------------------- geometry
def test_depth_agrees_with_lidar_along_the_same_rays(populated, rig):
    w, fr = populated
    spec = rig.ego_cameras[0]
    cam = fr["cameras"][spec.name]
    k = camera_intrinsics(spec.width, spec.height, spec.fov_deg)
    scene, ground = rig.scene(w), rig.ground(w)
    t_we = ego_pose(w)
    rows = np.arange(spec.height // 2 + 2, spec.height, 5)
    cols = np.arange(3, spec.width, 11)
    checked = {"box": 0, "ground": 0}
    for r in rows:
        for c in cols:
            xn = (c + 0.5 - k[0, 2]) / k[0, 0]
            yn = (r + 0.5 - k[1, 2]) / k[1, 1]
            ray = np.array([1.0, -xn, -yn])  # camera body frame
            az = np.arctan2(ray[1], ray[0])
            el = np.degrees(np.arctan2(ray[2], np.hypot(ray[0], ray[1])))
            lid = LidarSpec(
                "probe", 1, 1, 1e-6, (el, el), 500.0, spec.x, spec.y, spec.z, spec.yaw + az
            )
            out = capture_lidar(scene, ground, lid, t_we @ lid.T_parent_sensor(), np.array([0]))
            if out["count"] == 0:
                continue
            rng = float(np.linalg.norm(out["points"][0, :3]))
            depth = float(cam["depth"][r, c])
            if depth >= spec.far:
                continue
            assert rng == pytest.approx(depth * np.linalg.norm(ray), rel=1e-4, abs=2e-3)
            assert out["points"][0, 5] == cam["instance"][r, c]
            checked["box" if cam["instance"][r, c] > 0 else "ground"] += 1
    assert checked["ground"] > 10 and checked["box"] >= 1


def _centre_hits(fr, boxes, name, k_min=9):
    cal = fr["calibration"][name]
    inst = fr["cameras"][name]["instance"]
    h, w = inst.shape
    uv, z = project(cal, boxes["center"])
    hits = []
    for i in range(len(boxes["id"])):
        if z[i] <= 0.5 or (inst == boxes["instance"][i]).sum() < k_min:
            continue
        c, r = int(np.floor(uv[i, 0])), int(np.floor(uv[i, 1]))
        if 0 <= c < w and 0 <= r < h:
            hits.append(inst[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2] == boxes["instance"][i])
    return hits


def test_projected_box_centres_land_on_their_instance(populated, rig):
    w = staged(CAR, (4.5, 1.9, 1.5))
    fr = rig.capture(w)
    b = fr["gt"]["boxes"]
    # exact: the occluding car ahead in the front camera, the pedestrian in the RSU camera
    for name, row in (("cam_front", 1), ("rsu_cam", 2)):
        i = int(np.flatnonzero(b["instance"] == row + 1)[0])
        uv, z = project(fr["calibration"][name], b["center"][i : i + 1])
        assert z[0] > 0
        c, r = int(uv[0, 0]), int(uv[0, 1])
        assert fr["cameras"][name]["instance"][r, c] == row + 1, name
    # populated world: every well-visible object's centre lands on (or next to) its pixels
    _, frp = populated
    bp = frp["gt"]["boxes"]
    total = 0
    for name in frp["cameras"]:
        frac = bp["rsu_pixel_fraction"] if name == "rsu_cam" else bp["ego_pixel_fraction"]
        sel = {k: v[frac >= 0.9] for k, v in bp.items()}
        hits = _centre_hits(frp, sel, name)
        assert all(h.any() for h in hits), name
        total += len(hits)
    assert total >= 3


def test_calibration_maps_lidar_points_between_frames(populated):
    _, fr = populated
    cal = fr["calibration"]
    p = fr["lidars"]["rsu_lidar"]["points"][:50, :3].astype(np.float64)
    via_ego = (cal["T_world_ego"] @ cal["rsu_lidar"]["T_ego_sensor"])[:3] @ np.c_[
        p, np.ones(len(p))
    ].T
    direct = cal["rsu_lidar"]["T_world_sensor"][:3] @ np.c_[p, np.ones(len(p))].T
    np.testing.assert_allclose(via_ego, direct, atol=1e-6)
    # LiDAR ground returns lie on z = 0 in the world
    g = fr["lidars"]["lidar"]["points"]
    g = g[g[:, 5] == 0, :3].astype(np.float64)
    world = g @ cal["lidar"]["T_world_sensor"][:3, :3].T + cal["lidar"]["T_world_sensor"][:3, 3]
    assert np.abs(world[:, 2]).max() < 2e-3


# --------------------------------------------------------------------------- ground truth
def test_ground_truth_sets_are_consistent(populated):
    w, fr = populated
    gt = fr["gt"]
    ego, rsu, fused, joint = (set(gt[k]["id"].tolist()) for k in ("ego", "rsu", "fused", "joint"))
    assert len(gt["fused"]["id"]) == len(fused), "duplicate ids in the fused set"
    assert fused == ego | rsu and joint <= ego & rsu
    assert len(ego) > 0 and len(rsu) > 0
    b = gt["boxes"]
    for g, lid in (("ego", "lidar"), ("rsu", "rsu_lidar")):
        pts = fr["lidars"][lid]["points"][:, 5].astype(np.int64)
        np.testing.assert_array_equal(
            b[f"{g}_lidar_points"], [(pts == i).sum() for i in b["instance"]]
        )
    assert np.all((b["ego_pixel_fraction"] >= 0) & (b["ego_pixel_fraction"] <= 1))
    assert np.all((gt["joint"]["ego_lidar_points"] >= 10) & (gt["joint"]["rsu_lidar_points"] >= 10))
    # candidates: active actors but the ego, plus the non-building static boxes
    n_static = len(w.static_boxes) - len(w.town.buildings)
    assert len(b["id"]) == int(w.table.active[1:].sum()) + n_static
    for key in ("center", "size", "velocity"):
        assert b[key].shape == (len(b["id"]), 3)


# --------------------------------------------------------------------------- traffic lights
def test_red_light_shows_red_pixels(rig):
    w = empty_world()
    lights = w.town.lights
    i = int(np.argmax([w.town.lanes[int(lid)].length for lid in lights[:, 3]]))
    lane = int(lights[i, 3])
    ln = w.town.lanes[lane]
    p, h = w.town.index.pose_at(np.array([lane]), np.array([ln.length - 4.5 - 11.0]))
    put(w, 0, CAR, p[0], float(h[0]), (4.7, 1.9, 1.5))
    pole = int(np.flatnonzero(np.all(np.isclose(w.static_boxes[:, :2], lights[i, :2]), axis=1))[0])
    inst = 1_000_000 + pole

    def lamp_pixels(state):
        w.lane_signal = w.lane_signal.copy()
        w.lane_signal[lane] = state
        cam = rig.capture_camera(w, "cam_front")
        rgb = cam["rgb"][cam["instance"] == inst].astype(int)
        assert len(rgb) >= 4, "the light is not in view"
        red = (rgb[:, 0] > 170) & (rgb[:, 1] < 110) & (rgb[:, 2] < 110)
        green = (rgb[:, 1] > 170) & (rgb[:, 0] < 120)
        return red.sum(), green.sum()

    r, g = lamp_pixels(RED)
    assert r >= 1 and g == 0
    r, g = lamp_pixels(GREEN)
    assert g >= 1 and r == 0


def test_rig_config_switches_sensors_off():
    rig = SensorRig(
        SensorConfig(
            camera_size=(32, 16),
            ego_cameras=("cam_front",),
            rsu_camera_size=None,
            rsu_lidar=None,
            bev=None,
            groundtruth=False,
        )
    )
    w = empty_world()
    fr = rig.capture(w)
    assert set(fr["cameras"]) == {"cam_front"} and set(fr["lidars"]) == {"lidar"}
    assert "bev" not in fr and "gt" not in fr
    assert fr["cameras"]["cam_front"]["rgb"].shape == (16, 32, 3)
    with pytest.raises(ValueError):
        SensorConfig(ego_cameras=("cam_roof",))
    assert pose_matrix(0, 0, 0, 0).shape == (4, 4)


def test_no_active_rsu_gives_blank_rsu_sensors(rig):
    w = empty_world()
    w.rsus = RSUSet(np.zeros((0, 4)), np.zeros(0, int), np.zeros(0))
    w.active_rsu = np.array([-1])
    fr = rig.capture(w)
    assert fr["rsu_unit"] == -1 and fr["calibration"]["rsu_unit"] == -1
    assert fr["lidars"]["rsu_lidar"]["count"] == 0
    assert fr["cameras"]["rsu_cam"]["rgb"].shape == fr["cameras"]["cam_front"]["rgb"].shape
    assert len(fr["gt"]["rsu"]["id"]) == 0 and rig.observation_space().contains(rig.observation(fr))


def test_pixel_fraction_of_an_unoccluded_object_is_one(rig):
    w = staged(CAR, (4.5, 1.9, 1.5))
    b = rig.capture(w)["gt"]["boxes"]
    car = int(np.flatnonzero(b["instance"] == 2)[0])
    ped = int(np.flatnonzero(b["instance"] == 3)[0])
    assert b["ego_pixel_fraction"][car] == 1.0 and b["rsu_pixel_fraction"][ped] == 1.0
    assert 0.0 < b["ego_pixel_fraction"][ped] < 0.7  # the pedestrian's head over the car roof


def test_unoccluded_pixels_match_casting_each_object_alone(populated, rig):
    w, fr = populated
    scene = rig.scene(w)
    spec = rig.ego_cameras[0]
    pose = ego_pose(w) @ spec.T_parent_body()
    inst = np.unique(fr["cameras"][spec.name]["instance"])
    inst = inst[inst > 0]
    got = unoccluded_pixels(scene, spec, pose, inst)
    fan, yaw = fan_for(spec, pose)
    a = yaw + fan.az
    dirs = np.stack([np.cos(a), np.sin(a)], -1)
    for v, g in zip(inst, got):
        alone = scene.boxes.subset(np.flatnonzero(scene.inst == v))
        _, idx = first_hit_fan(pose[:3, 3], dirs, fan.slopes, alone, max_t=fan.max_t, ground=False)
        assert g == (idx >= 0).sum() >= (fr["cameras"][spec.name]["instance"] == v).sum()
    assert len(inst) >= 3


def test_bev_places_objects_in_the_ego_frame(rig):
    w = staged(CAR, (4.5, 1.9, 1.5))  # car 9 m ahead of the ego, pedestrian 16 m ahead
    w.perceive()
    # the privileged raster: every actor, seen by the ego or not
    bev = dict(zip(BEV_CHANNELS, capture_bev(w, rig.ground(w), BevSpec(privileged=True))))
    n, mpp = rig.config.bev.size, rig.config.bev.mpp
    r, c = np.nonzero(bev["vehicle"])
    x, y = (n / 2 - r - 0.5) * mpp, (n / 2 - c - 0.5) * mpp
    assert x.mean() == pytest.approx(9.0, abs=0.3) and y.mean() == pytest.approx(0.0, abs=0.3)
    assert len(r) == pytest.approx(4.5 * 1.9 / mpp**2, rel=0.25)
    r, c = np.nonzero(bev["vru"])
    assert 1 <= len(r) <= 4 and np.all(np.abs((n / 2 - r - 0.5) * mpp - 16.0) <= 0.75)
    assert bev["ego"].sum() == pytest.approx(4.7 * 1.9 / mpp**2, rel=0.25)
    assert bev["drivable"][n // 2 - 10 : n // 2 + 10, n // 2].all()


def test_ground_raster_zebra_stripes_lie_inside_their_crossings(populated, rig):
    w, _ = populated
    g = rig.ground(w)
    rng = np.random.default_rng(0)
    for cw in w.town.crosswalks:
        c = cw.corners
        s, t = rng.uniform(0.05, 0.95, (2, 400))
        pts = c[1] + s[:, None] * (c[0] - c[1]) + t[:, None] * (c[2] - c[1])
        code = g.lookup(pts[:, 0], pts[:, 1]) & 0x7F
        stripe = np.mean(code == M_CROSS_STRIPE)
        assert 0.3 < stripe < 0.8 and np.all(np.isin(code, (M_CROSS_STRIPE, M_CROSS_GAP))), cw.id
        # just outside the crossing, across the road: no stripes
        out = c[1] + s[:, None] * (c[0] - c[1]) * -0.9 + t[:, None] * (c[2] - c[1])
        if np.linalg.norm(c[0] - c[1]) > np.linalg.norm(c[2] - c[1]):
            out = c[1] + s[:, None] * (c[0] - c[1]) + t[:, None] * (c[2] - c[1]) * -0.9
        assert np.mean((g.lookup(out[:, 0], out[:, 1]) & 0x7F) == M_CROSS_STRIPE) < 0.1, cw.id


def test_same_seed_same_actions_give_identical_frames(rig):
    frames = []
    for _ in range(2):
        w = World(make_config(town=TOWN, num_vehicles=4, num_parked=2, num_pedestrians=3))
        w.reset(seed=7)
        for _ in range(5):
            w.step(np.array([0.5, 0.1, 0.0]))
        frames.append(rig.capture(w))
    a, b = frames
    for name in a["cameras"]:
        for k, v in a["cameras"][name].items():
            np.testing.assert_array_equal(v, b["cameras"][name][k])
    for name in a["lidars"]:
        np.testing.assert_array_equal(a["lidars"][name]["padded"], b["lidars"][name]["padded"])
    np.testing.assert_array_equal(a["bev"], b["bev"])


def test_module_calibration_matches_the_rig(populated, rig):
    w, fr = populated
    cal = calibration(w)
    for name in EGO_CAMERA_NAMES + ("rsu_cam", "lidar", "rsu_lidar"):
        np.testing.assert_allclose(cal[name]["extrinsics"], fr["calibration"][name]["extrinsics"])
    # ego camera extrinsics map the optical axis (+z) to the camera's yaw in the ego frame
    for spec in rig.ego_cameras:
        ext = cal[spec.name]["extrinsics"]
        np.testing.assert_allclose(
            ext[:3, 2], [np.cos(spec.yaw), np.sin(spec.yaw), 0.0], atol=1e-12
        )
        np.testing.assert_allclose(ext[:3, 3], [spec.x, spec.y, 1.8])
