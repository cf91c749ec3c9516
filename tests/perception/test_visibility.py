"""Occlusion tests with hand geometry.

Sample pattern (see ``visibility``): 15 points per box, 3 levels at 15/45/75 % of the height and
5 horizontal positions (centre, corners at 70 % of the half extents). For the pedestrian used
below (0.6 x 0.6 x 1.8 m, centre (14.5, 0)) the points are at x in {14.29, 14.5, 14.71},
y in {-0.21, 0, 0.21}, z in {0.27, 0.81, 1.35}.

Every line of sight below runs along +x with |y| <= 0.21, inside the occluders' footprints
(|y| <= 0.9 or 1.25), and descends towards the pedestrian, so it is lowest over an occluder at the
occluder's rear face x = 12. Its height there is ``z_p + (z_s - z_p) * (x_p - 12) / (x_p - x_s)``
for a sensor at ``(x_s, 0, z_s)`` and a point at ``(x_p, y_p, z_p)``; the point is hidden when that
height is below the occluder's roof.
"""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.raycast import Boxes
from v2xbench.envs.v2x_intersection.perception.visibility import (
    VISIBLE_THRESHOLD,
    K,
    sample_points,
    visible_fraction,
    visible_mask,
)

EGO = np.array([0.0, 0.0, 1.8])  # ego camera height (DESIGN section 5)
RSU = np.array([2.0, 0.0, 5.0])  # a 5 m pole just ahead of the ego, looking along +x


def los_height_at(x_occ, sensor, x_p, z_p):
    return z_p + (sensor[2] - z_p) * (x_p - x_occ) / (x_p - sensor[0])


def ped(cx=14.5, cy=0.0) -> Boxes:
    return Boxes.from_arrays([[cx, cy]], 0.6, 0.6, 0.0, 1.8)


CAR = Boxes.from_arrays([[10.0, 0.0]], 4.0, 1.8, 0.0, 1.5)  # x in [8, 12], roof 1.5 m
TRUCK = Boxes.from_arrays([[8.0, 0.0]], 8.0, 2.5, 0.0, 3.5)  # x in [4, 12], roof 3.5 m


def test_sample_points_pattern():
    pts = sample_points(ped(), [0])
    assert pts.shape == (1, K, 3) and K == 15
    np.testing.assert_allclose(np.unique(pts[0, :, 0]), [14.29, 14.5, 14.71])
    np.testing.assert_allclose(np.unique(pts[0, :, 1]), [-0.21, 0.0, 0.21])
    np.testing.assert_allclose(np.unique(pts[0, :, 2]), [0.27, 0.81, 1.35])
    # rotated, raised box: points turn with the box and sit above its base
    box = Boxes.from_arrays([[1.0, 2.0]], 4.0, 2.0, np.pi / 2, 1.0, 2.0)
    p = sample_points(box, [0])[0]
    np.testing.assert_allclose(p[1], [1.0 - 0.7, 2.0 + 1.4, 2.15])  # front-left, lowest level
    assert p[:, 2].min() == pytest.approx(2.15) and p[:, 2].max() == pytest.approx(2.75)


def test_ped_behind_car_hidden_from_ego_seen_from_rsu():
    # Ego: the highest, farthest point (z 1.35, x 14.71) is the least hidden; its line of sight
    # is at 1.35 + 0.45 * 2.71 / 14.71 = 1.433 m < 1.5 m over the car's rear, so all 15 points
    # are hidden: fraction 0. (The top of the head at 1.8 m would show over the roof; the
    # pattern does not sample the top quarter, see visibility's docstring.)
    assert los_height_at(12.0, EGO, 14.71, 1.35) == pytest.approx(1.4329, abs=1e-3)
    # RSU at 5 m, 2 m ahead: the *nearest* points of the 0.81 m level are the worst placed,
    # 0.81 + 4.19 * 2.29 / 12.29 = 1.591 m > 1.5 m: the whole middle level (and the top level)
    # is visible; the farthest 0.27 m point is at 0.27 + 4.73 * 2.71 / 12.71 = 1.278 m < 1.5 m,
    # so the whole lowest level is hidden: fraction 10 / 15.
    assert los_height_at(12.0, RSU, 14.29, 0.81) == pytest.approx(1.5907, abs=1e-3)
    assert los_height_at(12.0, RSU, 14.71, 0.27) == pytest.approx(1.2785, abs=1e-3)
    boxes = Boxes.concat(CAR, ped())
    assert visible_fraction(EGO, boxes, [1])[0] == 0.0
    assert visible_fraction(RSU, boxes, [1])[0] == pytest.approx(10 / 15)
    assert not visible_mask(EGO, boxes, [1])[0]
    assert visible_mask(RSU, boxes, [1])[0]
    # the car itself is seen by both; without the car the ego sees the whole pedestrian
    np.testing.assert_allclose(visible_fraction(EGO, boxes, [0]), 1.0)
    np.testing.assert_allclose(visible_fraction(EGO, ped(), [0]), 1.0)


def test_ped_behind_truck_hidden_from_both():
    # RSU: the best placed point (z 1.35, x 14.71) is at 1.35 + 3.65 * 2.71 / 12.71 = 2.128 m
    # over the truck's rear, far below its 3.5 m roof; the ego at 1.8 m never clears 3.5 m.
    assert los_height_at(12.0, RSU, 14.71, 1.35) == pytest.approx(2.128, abs=1e-3)
    boxes = Boxes.concat(TRUCK, ped())
    np.testing.assert_array_equal(visible_fraction(EGO, boxes, [1]), [0.0])
    np.testing.assert_array_equal(visible_fraction(RSU, boxes, [1]), [0.0])
    assert not visible_mask(RSU, boxes, [1])[0]


def test_ped_6m_behind_parked_truck():
    # truck 8 x 2.5 x 3.5 m at x in [6, 14]; pedestrian 6 m behind it (centre x 20.3). From the
    # ego at 1.8 m every sight line stays below 1.8 m < 3.5 m while crossing the truck: hidden.
    truck = Boxes.from_arrays([[10.0, 0.0]], 8.0, 2.5, 0.0, 3.5)
    boxes = Boxes.concat(truck, ped(cx=20.3))
    assert visible_fraction(EGO, boxes, [1])[0] == 0.0
    # an RSU on a 5 m pole 18 m to the side of the pedestrian looks along +y, never across the
    # truck's footprint (x in [6, 14] vs x in [20.09, 20.51]): all points visible
    assert visible_fraction([20.3, -18.0, 5.0], boxes, [1])[0] == 1.0


def test_ignore_own_vehicle_and_range():
    # sensor at 1.2 m inside its own car's box (x in [-2.25, 2.25]): blind unless ignored
    own = Boxes.from_arrays([[0.0, 0.0]], 4.5, 1.8, 0.0, 1.5)
    boxes = Boxes.concat(own, ped(cx=15.0))
    sensor = [1.0, 0.0, 1.2]
    assert visible_fraction(sensor, boxes, [1])[0] == 0.0
    assert visible_fraction(sensor, boxes, [1], ignore=[0])[0] == 1.0
    # range: the pedestrian's sample points are 13.8-14.3 m (3D) from the sensor
    assert visible_fraction(sensor, boxes, [1], ignore=[0], max_range=15.0)[0] == 1.0
    assert visible_fraction(sensor, boxes, [1], ignore=[0], max_range=10.0)[0] == 0.0


def test_field_of_view():
    # RSU at the origin facing +x with a 90 deg field of view (+-45 deg)
    boxes = Boxes.concat(Boxes.concat(ped(10.0, 0.0), ped(-10.0, 0.0)), ped(10.0, 9.0))
    boxes = Boxes.concat(boxes, ped(10.0, 11.0))
    # bearings of sample points: ahead 0 deg; behind 180 deg; (10, 9): at most
    # atan2(9.21, 9.79) = 43.3 deg; (10, 11): at least atan2(10.79, 10.21) = 46.6 deg
    sensor = [0.0, 0.0, 5.0]
    frac = visible_fraction(sensor, boxes, [0, 1, 2, 3], sensor_yaw=0.0, hfov=np.pi / 2)
    np.testing.assert_array_equal(frac, [1.0, 0.0, 1.0, 0.0])
    # facing -x instead: only the one behind
    frac = visible_fraction(sensor, boxes, [0, 1, 2, 3], sensor_yaw=np.pi, hfov=np.pi / 2)
    np.testing.assert_array_equal(frac, [0.0, 1.0, 0.0, 0.0])
    np.testing.assert_array_equal(visible_fraction(sensor, boxes, [0, 1, 2, 3]), 1.0)


def test_field_of_view_edge_matches_the_reference_path():
    """Sample points within a hair of the field of view's edge: the kernel's shortcut (a bearing's
    cosine) leaves them to the exact test, so it agrees with the NumPy path (``chunk_elems``)."""
    boxes = Boxes.concat(Boxes.concat(ped(10.0, 0.0), ped(6.0, 7.0)), ped(-3.0, 8.0))
    sensor = np.array([0.0, 0.0, 5.0])
    pts = sample_points(boxes, np.arange(3)).reshape(-1, 3)
    bearings = np.arctan2(pts[:, 1], pts[:, 0])
    half = np.deg2rad(60.0)
    rng = np.random.default_rng(0)
    yaws = [b - half + d for b in bearings[::7] for d in (-1e-6, -1e-7, -1e-9, -1e-12, 0.0, 1e-12, 1e-9, 1e-7, 1e-6)]
    yaws += list(rng.uniform(-np.pi, np.pi, 50))
    for yaw in yaws:
        fast = visible_fraction(sensor, boxes, [0, 1, 2], sensor_yaw=yaw, hfov=2 * half)
        ref = visible_fraction(sensor, boxes, [0, 1, 2], sensor_yaw=yaw, hfov=2 * half, chunk_elems=1 << 16)
        np.testing.assert_array_equal(fast, ref, err_msg=f"sensor_yaw={yaw!r}")


def test_threshold_and_many_targets():
    assert VISIBLE_THRESHOLD == 0.1
    # 40 pedestrians facing the ego on a 20 m circle, every 3 deg from -58.5 to 58.5 deg; their
    # sample points lie within +-0.21 m / 19.7 m = 0.6 deg of their bearing and their footprints
    # within +-0.87 deg, so they do not hide each other. A 3 m wall at x in [9, 11], |y| <= 3,
    # blocks every sight line with |bearing| <= atan(3 / 9) = 18.43 deg: pedestrians at
    # |bearing| <= 16.5 deg (points <= 17.1 deg) are hidden, those at >= 19.5 deg (points
    # >= 18.9 deg) are not.
    th = np.deg2rad(-58.5 + 3.0 * np.arange(40))
    centers = 20.0 * np.stack([np.cos(th), np.sin(th)], 1)
    peds = Boxes.from_arrays(centers, 0.6, 0.6, th, 1.8)
    wall = Boxes.from_arrays([[10.0, 0.0]], 2.0, 6.0, 0.0, 3.0)
    boxes = Boxes.concat(peds, wall)
    frac = visible_fraction(EGO, boxes, np.arange(40))
    expected = np.where(np.abs(np.rad2deg(th)) < 18.0, 0.0, 1.0)
    assert (expected == 0).sum() == 12
    np.testing.assert_array_equal(frac, expected)
    np.testing.assert_array_equal(visible_mask(EGO, boxes, np.arange(40)), expected > 0)
    # chunking does not change the answer
    np.testing.assert_array_equal(visible_fraction(EGO, boxes, np.arange(40), chunk_elems=1), frac)
    assert visible_fraction(EGO, boxes, []).shape == (0,)
