"""Tests of the closed-loop, open-loop and perception metrics on hand-built data."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.classes import CAR, PEDESTRIAN, TRAFFIC_SIGN
from v2xbench.envs.v2x_intersection.evaluation import metrics as M
from v2xbench.envs.v2x_intersection.evaluation import metrics_perception as P
from v2xbench.envs.v2x_intersection.evaluation.infractions import (
    COLLISION_PEDESTRIAN,
    COLLISION_VEHICLE,
    OUTSIDE_LANES,
    RED_LIGHT,
)

DT = 0.1


def record(
    t: int = 100,
    speed=10.0,
    yaw=0.0,
    bg=10.0,
    length: float = 100.0,
    rc: float = 100.0,
    events=(),
    **kw,
) -> M.RouteRecord:
    """A straight drive along +x with ``t`` ticks; scalars broadcast to every tick."""
    speed = np.broadcast_to(np.asarray(speed, float), (t,)).copy()
    yaw = np.broadcast_to(np.asarray(yaw, float), (t,)).copy()
    x = np.concatenate([[0.0], np.cumsum(speed * DT)])[:t]
    base = dict(
        route_length=length,
        route_completion=rc,
        ego_xy=np.stack([x, np.zeros(t)], -1),
        ego_yaw=yaw,
        ego_speed=speed,
        background_speed=np.broadcast_to(np.asarray(bg, float), (t,)).copy(),
        route_s=np.clip(x, 0.0, length),
        events=np.asarray(events, float).reshape(-1, 4),
        outside_lanes_m=0.0,
        driven_m=float(x[-1]) if t else 0.0,
        bytes_sent=0,
        peak_bps=0.0,
        sim_seconds=t * DT,
        ended_by=M.ENDED_COMPLETED,
    )
    base.update(kw)
    return M.RouteRecord(**base)


# ------------------------------------------------------------------------------------ RC, IS, DS


def test_one_vehicle_collision_full_rc():
    r = record(events=[(COLLISION_VEHICLE, 10, 3, 0.0)])
    assert M.route_completion(r) == 100.0
    assert M.infraction_score(r) == pytest.approx(0.6)
    assert M.driving_score(r) == pytest.approx(60.0)


def test_pedestrian_and_red_light_multiply():
    r = record(rc=50.0, events=[(COLLISION_PEDESTRIAN, 5, 7, 0.0), (RED_LIGHT, 30, -1, 4.0)])
    assert M.infraction_score(r) == pytest.approx(0.5 * 0.7)
    assert M.driving_score(r) == pytest.approx(50.0 * 0.35)


def test_events_without_factor_do_not_penalise():
    assert M.infraction_score(record(events=[(OUTSIDE_LANES, 3, -1, 2.0)])) == 1.0


def test_outside_lanes_percentage():
    r = record(outside_lanes_m=10.0, driven_m=100.0)
    assert M.infraction_score(r) == pytest.approx(0.9)
    r = record(outside_lanes_m=10.0, driven_m=100.0, events=[(COLLISION_VEHICLE, 1, 2, 0.0)])
    assert M.infraction_score(r) == pytest.approx(0.9 * 0.6)


def test_scenario_timeout_and_yield_fields():
    r = record(scenario_timeouts=1, yield_emergency_failures=2)
    assert M.infraction_score(r) == pytest.approx(0.7 * 0.7 * 0.7)
    d = M.compute_metrics(r)
    assert d["n_scenario_timeout"] == 1 and d["n_yield_emergency"] == 2


def test_stop_sign_and_static_factors():
    from v2xbench.envs.v2x_intersection.evaluation.infractions import COLLISION_STATIC, STOP_SIGN

    r = record(events=[(STOP_SIGN, 1, -1, 0.0), (COLLISION_STATIC, 2, -5, 0.0)])
    assert M.infraction_score(r) == pytest.approx(0.8 * 0.65)


# ------------------------------------------------------------------------------------ efficiency


def test_efficiency_stopped_ego_among_traffic():
    assert M.efficiency(record(speed=0.0, bg=8.0)) == pytest.approx(0.0)


def test_efficiency_at_background_speed():
    r = record(t=120, speed=5.0, bg=5.0, length=50.0)
    assert M.efficiency(r) == pytest.approx(100.0)
    assert np.isfinite(M.efficiency_checkpoints(r)).sum() == M.NUM_CHECKPOINTS


def test_efficiency_skips_checkpoints_without_background():
    t = 100
    bg = np.full(t, np.nan)
    r = record(t=t, speed=10.0, bg=bg, length=100.0)
    assert np.isnan(M.efficiency(r))
    # background only in the first checkpoint (first 20 m), moving at twice the ego speed
    bg[r.route_s < 20.0] = 20.0
    r = record(t=t, speed=10.0, bg=bg, length=100.0)
    vals = M.efficiency_checkpoints(r)
    assert vals[0] == pytest.approx(50.0) and np.isnan(vals[1:]).all()
    assert M.efficiency(r) == pytest.approx(50.0)


def test_efficiency_discards_outliers():
    t = 100
    bg = np.where(np.arange(t) < 20, 0.5, 10.0)  # first 20 m: crawling traffic -> ratio 2000
    r = record(t=t, speed=10.0, bg=bg, length=100.0)
    vals = M.efficiency_checkpoints(r)
    assert np.isnan(vals[0]) and np.allclose(vals[1:], 100.0)
    assert M.efficiency(r) == pytest.approx(100.0)


# ------------------------------------------------------------------------------------ comfort


def test_savgol_coefficients_and_quadratic():
    # classic window-7, order-2 convolution coefficients at an interior sample
    i = 10
    m0 = M._sg_matrix(21, 7, 2, 0, 1.0)[i, i - 3 : i + 4]
    m1 = M._sg_matrix(21, 7, 2, 1, 1.0)[i, i - 3 : i + 4]
    m2 = M._sg_matrix(21, 7, 2, 2, 1.0)[i, i - 3 : i + 4]
    assert np.allclose(m0, np.array([-2, 3, 6, 7, 6, 3, -2]) / 21)
    assert np.allclose(m1, np.array([-3, -2, -1, 0, 1, 2, 3]) / 28)
    assert np.allclose(m2, np.array([5, 0, -3, -4, -3, 0, 5]) / 42)
    # derivatives of a quadratic are exact everywhere, edges included
    t = np.arange(20) * DT
    x = 1.5 - 2.0 * t + 3.0 * t**2
    assert np.allclose(M.savgol(x, 0), x)
    assert np.allclose(M.savgol(x, 1), -2.0 + 6.0 * t)
    assert np.allclose(M.savgol(x, 2), 6.0)
    # short input: window shrinks to the data, still exact
    assert np.allclose(M.savgol(x[:5], 1), -2.0 + 6.0 * t[:5])


def test_comfort_segmentation():
    assert M.comfort_segments(record(t=41)) == [(0, 20), (20, 40)]
    assert M.comfort_segments(record(t=15)) == [(0, 15)]
    assert M.comfort_segments(record(t=20)) == [(0, 20)]
    assert M.comfort_segments(record(t=0)) == []
    assert np.isnan(M.comfortness(record(t=0)))


def test_smooth_drive_is_comfortable():
    assert M.comfortness(record(t=100, speed=12.0)) == 100.0


def test_hard_brake_trips_longitudinal_acceleration():
    t = 40
    speed = np.maximum(
        15.0 - 6.0 * np.clip(np.arange(t) * DT - 2.0, 0, None), 0.0
    )  # brake from 2 s
    r = record(t=t, speed=speed)
    seg = M.comfort_breakdown(r)
    assert seg[0]["lon_accel"] and not seg[1]["lon_accel"]
    assert seg[1]["lat_accel"] and seg[1]["yaw_rate"] and seg[1]["yaw_accel"]
    assert M.comfortness(r) == 50.0
    # a gentle 2 m/s^2 brake is fine for the acceleration bound
    gentle = record(t=t, speed=np.maximum(15.0 - 2.0 * np.arange(t) * DT, 0.0))
    assert all(s["lon_accel"] for s in M.comfort_breakdown(gentle))


def test_steering_oscillation_trips_yaw_bounds():
    t = 40
    tt = np.arange(t) * DT
    yaw = 0.3 * np.sin(2 * np.pi * 1.0 * tt)  # yaw rate amplitude 1.9 rad/s
    seg = M.comfort_breakdown(record(t=t, speed=8.0, yaw=yaw))
    assert not seg[0]["yaw_rate"] and not seg[0]["yaw_accel"]
    assert M.comfortness(record(t=t, speed=8.0, yaw=yaw)) == 0.0
    # the same oscillation, 10x smaller, stays within the yaw bounds
    small = M.comfort_breakdown(record(t=t, speed=8.0, yaw=0.03 * np.sin(2 * np.pi * tt)))
    assert all(s["yaw_rate"] and s["yaw_accel"] for s in small)


def test_yaw_wraparound_is_unwrapped():
    t = 40
    yaw = M.COMFORT_BOUNDS["yaw_rate"][1] * 0.5 * np.arange(t) * DT + np.pi - 0.5
    wrapped = (yaw + np.pi) % (2 * np.pi) - np.pi
    assert M.comfortness(record(t=t, speed=3.0, yaw=wrapped)) == 100.0


# ------------------------------------------------------------------------------------ bandwidth


def test_bps():
    r = record(t=50, bytes_sent=12_000, peak_bps=4_000.0, sim_seconds=5.0)
    assert M.bps(r) == pytest.approx(2400.0)
    d = M.compute_metrics(r, ["bps", "peak_bps"])
    assert d == {"bps": pytest.approx(2400.0), "peak_bps": 4000.0}


# ------------------------------------------------------------------------------------ registry


def test_registry_and_roundtrip():
    r = record(events=[(COLLISION_VEHICLE, 10, 3, 0.0)])
    d = M.compute_metrics(r)
    for k in (
        "route_completion",
        "infraction_score",
        "driving_score",
        "efficiency",
        "comfortness",
        "bps",
        "peak_bps",
        "km_completed",
        "n_collision_vehicle",
    ):
        assert k in d
    assert M.compute_metrics(M.RouteRecord.from_dict(r.to_dict())) == pytest.approx(d, nan_ok=True)
    with pytest.raises(KeyError):
        M.compute_metrics(r, ["nope"])
    with pytest.raises(ValueError):
        M.register_metric("driving_score")(lambda r: 0.0)
    with pytest.raises(ValueError):
        M.RouteRecord.from_dict({**r.to_dict(), "bogus": 1})


def test_surrounding_mean_speed():
    from v2xbench.envs.v2x_intersection.core.actors import DRIVER, EGO, PARKED, ActorTable
    from v2xbench.envs.v2x_intersection.core.classes import LARGE_VEHICLE

    t = ActorTable.empty(5)
    t.active[:] = True
    t.kind[:] = (CAR, CAR, LARGE_VEHICLE, CAR, PEDESTRIAN)
    t.behaviour[:] = (EGO, DRIVER, DRIVER, PARKED, DRIVER)
    t.pos[:] = [[0, 0], [10, 0], [0, 40], [5, 0], [2, 0]]
    t.speed[:] = (9.0, 4.0, 8.0, 0.0, 1.5)
    assert M.surrounding_mean_speed(t) == pytest.approx(6.0)
    t.pos[2] = (0, M.SURROUNDING_RADIUS_M + 1)
    assert M.surrounding_mean_speed(t) == pytest.approx(4.0)
    t.active[1] = False
    assert np.isnan(M.surrounding_mean_speed(t))


def test_record_json_roundtrip():
    import json

    r = record(t=5, bytes_sent=np.int64(7), ended_by=np.int64(M.ENDED_TIMEOUT))
    back = M.RouteRecord.from_dict(json.loads(json.dumps(r.to_dict())))
    assert back.ended_by == M.ENDED_TIMEOUT and np.allclose(back.ego_xy, r.ego_xy)
    with pytest.raises(ValueError):
        record(t=5, route_s=np.zeros(4))


# ------------------------------------------------------------------------------------ suites


def test_suite_divides_by_suite_size():
    a = record(events=[(COLLISION_VEHICLE, 1, 1, 0.0)], outside_lanes_m=0.0)  # DS 60
    b = record(rc=90.0)  # DS 90
    agg = M.aggregate([a, b], n_routes_in_suite=3)
    assert agg["driving_score"] == pytest.approx(50.0)
    assert agg["route_completion"] == pytest.approx(190.0 / 3)
    assert agg["infraction_score"] == pytest.approx(0.8)
    assert agg["n_finished"] == 2 and agg["n_expected"] == 3
    # a crashed run counts 0 too
    c = record(ended_by=M.ENDED_ERROR)
    assert M.aggregate([a, b, c], 3)["driving_score"] == pytest.approx(50.0)
    # per km: 1 vehicle collision over 0.1 + 0.09 km completed
    assert agg["collision_vehicle_per_km"] == pytest.approx(1.0 / 0.19)
    with pytest.raises(ValueError):
        M.aggregate([a, b, c, c], 3)


def test_suite_nan_efficiency_ignored():
    a = record(speed=5.0, bg=5.0)
    b = record(bg=np.nan)
    assert M.aggregate([a, b], 2)["efficiency"] == pytest.approx(100.0)
    assert np.isnan(M.aggregate([b], 2)["efficiency"])


def test_bootstrap_ci():
    rng = np.random.default_rng(1)
    small, big = rng.normal(50, 20, 10), rng.normal(50, 20, 1000)
    lo_s, hi_s = M.bootstrap_ci(small)
    lo_b, hi_b = M.bootstrap_ci(big)
    assert lo_s <= small.mean() <= hi_s and lo_b <= big.mean() <= hi_b
    assert hi_b - lo_b < hi_s - lo_s
    assert M.bootstrap_ci(small) == M.bootstrap_ci(small)  # seeded


# ------------------------------------------------------------------------------------ open loop


def test_l2_known_offset():
    gt = np.stack([np.arange(1, 7) * 2.0, np.zeros(6)], -1)  # 6 waypoints at 0.5 s
    pred = gt + np.array([0.0, 1.0])
    pred[5] += np.array([3.0, 0.0])  # the 3 s waypoint is (3, 1) m off
    out = P.l2_at(pred, gt, dt=0.5)
    assert out["l2_1s"] == pytest.approx(1.0) and out["l2_2s"] == pytest.approx(1.0)
    assert out["l2_3s"] == pytest.approx(np.hypot(3.0, 1.0))
    avg = P.l2_at(pred, gt, dt=0.5, average=True)
    assert avg["l2_3s"] == pytest.approx((5 + np.hypot(3.0, 1.0)) / 6)
    with pytest.raises(ValueError):
        P.l2_at(pred, gt, horizons=(4.0,), dt=0.5)


def test_ego_box_matches_simulator():
    from v2xbench.envs.v2x_intersection.sim.world import EGO_LENGTH, EGO_WIDTH

    assert (P.EGO_BOX_LENGTH, P.EGO_BOX_WIDTH) == (EGO_LENGTH, EGO_WIDTH)


def test_collision_rate_through_a_box():
    pred = np.stack([np.arange(1, 7) * 3.0, np.zeros(6)], -1)  # 3 m per 0.5 s along +x
    boxes = np.full((6, 2, 5), np.nan)
    boxes[:, 0] = (10.0, 0.0, 2.0, 2.0, 0.3)  # a box sitting on the path; hit at x = 9 and 12
    boxes[:, 1] = (0.0, 20.0, 4.0, 2.0, 0.0)  # far away
    col = P.trajectory_collisions(pred, boxes)
    assert col.tolist() == [False, False, True, True, False, False]
    out = P.collision_rate(pred, boxes, dt=0.5)
    assert out["collision_1s"] == 0.0
    assert out["collision_2s"] == pytest.approx(0.5) and out["collision_3s"] == pytest.approx(2 / 6)
    anyc = P.collision_rate(pred, boxes, dt=0.5, average=False)
    assert anyc == {"collision_1s": 0.0, "collision_2s": 1.0, "collision_3s": 1.0}
    # a trajectory passing beside the box does not collide
    side = pred + np.array([0.0, 3.0])
    assert not P.trajectory_collisions(side, boxes).any()


# ------------------------------------------------------------------------------------ detection


def gt_boxes() -> P.DetBoxes:
    return P.DetBoxes(
        frame=[0, 0, 1, 1],
        cls=[CAR, PEDESTRIAN, CAR, TRAFFIC_SIGN],
        center=[[10, 0], [5, 5], [20, -3], [8, 8]],
        size=[[4.5, 1.9, 1.5], [0.5, 0.5, 1.7], [4.5, 1.9, 1.5], [0.6, 0.1, 0.8]],
        yaw=[0.0, 1.0, 0.5, 3.0],
        velocity=[[5, 0], [1, 1], [0, 8], [0, 0]],
    )


def test_detection_perfect():
    g = gt_boxes()
    out = P.detection_metrics(g, g)
    assert out["mAP"] == pytest.approx(1.0) and out["NDS"] == pytest.approx(1.0)
    for k in ("mATE", "mASE", "mAOE", "mAVE"):
        assert out[k] == pytest.approx(0.0, abs=1e-12)
    assert np.isnan(out["traffic_light/AP"])  # no ground truth: left out
    assert np.isnan(out["traffic_sign/AVE"])  # static group


def test_detection_offset_counts_at_2_and_4_only():
    g = gt_boxes().select(np.array([0]))
    p = P.DetBoxes(
        frame=[0],
        cls=[CAR],
        center=[[11.5, 0.0]],
        size=[[4.5, 1.9, 1.5]],
        yaw=[0.0],
        velocity=[[5, 0]],
        score=[0.9],
    )
    out = P.detection_metrics(p, g)
    assert [out[f"vehicle/AP@{t}"] for t in ("0.5", "1", "2", "4")] == pytest.approx(
        [0.0, 0.0, 1.0, 1.0]
    )
    assert out["vehicle/AP"] == pytest.approx(0.5) and out["mAP"] == pytest.approx(0.5)
    assert out["vehicle/ATE"] == pytest.approx(1.5)
    assert out["NDS"] == pytest.approx((5 * 0.5 + 0.0 + 1.0 + 1.0 + 1.0) / 9)


def test_detection_yaw_error():
    g = gt_boxes().select(np.array([0]))
    p = P.DetBoxes(
        frame=[0],
        cls=[CAR],
        center=[[10.0, 0.0]],
        size=[[4.5, 1.9, 1.5]],
        yaw=[np.pi / 2],
        velocity=[[5, 0]],
        score=[0.9],
    )
    out = P.detection_metrics(p, g)
    assert out["vehicle/AOE"] == pytest.approx(np.pi / 2)
    assert out["vehicle/AP"] == pytest.approx(1.0)


def test_detection_ase_false_positive_and_miss():
    g = gt_boxes().select(np.array([0]))
    p = P.DetBoxes(
        frame=[0, 0],
        cls=[CAR, CAR],
        center=[[10.0, 0.0], [30.0, 0.0]],
        size=[[2.25, 1.9, 1.5], [4.5, 1.9, 1.5]],
        yaw=[0.0, 0.0],
        score=[0.9, 0.95],
    )
    out = P.detection_metrics(p, g)
    assert out["vehicle/ASE"] == pytest.approx(0.5)  # half the volume -> IoU 0.5
    # the higher-scored false positive comes first: (recall, precision) (0, 0) then (1, 0.5)
    r = np.linspace(0.0, 1.0, 101)[11:]  # nuScenes: precision interpolated linearly in recall
    assert out["vehicle/AP"] == pytest.approx(np.mean(np.clip(0.5 * r - 0.1, 0, None)) / 0.9)
    assert P.detection_metrics(p.select(np.array([], int)), g)["vehicle/AP"] == 0.0
    assert P.detection_metrics(p.select(np.array([], int)), g)["vehicle/ATE"] == 1.0
