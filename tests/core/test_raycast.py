"""Tests of the 2.5D ray-casting core, with hand-computed answers."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.raycast import (
    GROUND,
    NO_HIT,
    Boxes,
    first_hit,
    first_hit_fan,
    ray_box_intervals,
    segments_blocked,
)

TOL = 1e-4  # float32 computation


def one_box(cx=10.0, cy=0.0, length=4.0, width=2.0, yaw=0.0, height=1.5, z0=0.0) -> Boxes:
    return Boxes.from_arrays([[cx, cy]], length, width, yaw, height, z0)


def random_scene(seed: int, n: int = 40, r: int = 500):
    rng = np.random.default_rng(seed)
    boxes = Boxes.from_arrays(
        rng.uniform(-30, 30, (n, 2)),
        rng.uniform(0.5, 9, n),
        rng.uniform(0.5, 3, n),
        rng.uniform(-np.pi, np.pi, n),
        rng.uniform(0.5, 4, n),
        rng.choice([0.0, 0.0, 0.5, 2.0], n),
    )
    origins = np.concatenate([rng.uniform(-30, 30, (r, 2)), rng.uniform(0.1, 5, (r, 1))], 1)
    dirs = rng.normal(size=(r, 3)) * [1.0, 1.0, 0.3]
    return boxes, origins, dirs


def reference_first_hit(origin, d, boxes: Boxes):
    """Plain float64 per-ray, per-box slab test (independent of the vectorized code)."""
    best, best_j = np.inf, NO_HIT
    for j in range(len(boxes)):
        c, s = np.cos(boxes.yaw[j]), np.sin(boxes.yaw[j])
        rel = origin[:2] - boxes.center[j]
        o = [c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1], origin[2]]
        v = [c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]]
        lo = [-boxes.length[j] / 2, -boxes.width[j] / 2, boxes.z0[j]]
        hi = [boxes.length[j] / 2, boxes.width[j] / 2, boxes.z0[j] + boxes.height[j]]
        t0, t1 = 0.0, np.inf
        for k in range(3):
            if v[k] == 0:
                if not lo[k] <= o[k] <= hi[k]:
                    t0, t1 = np.inf, -np.inf
                continue
            a, b = (lo[k] - o[k]) / v[k], (hi[k] - o[k]) / v[k]
            t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
        if t0 <= t1 and t0 < best:
            best, best_j = t0, j
    if d[2] < 0 and origin[2] / -d[2] < best:
        best, best_j = origin[2] / -d[2], GROUND
    return best, best_j


def test_boxes_container():
    a = Boxes.from_arrays([[0.0, 0.0], [5.0, 1.0]], 4.0, [2.0, 1.0], height=1.5)
    b = one_box()
    ab = Boxes.concat(a, b)
    assert len(a) == 2 and len(ab) == 3
    np.testing.assert_allclose(ab.width, [2.0, 1.0, 2.0])
    np.testing.assert_allclose(ab.center[2], [10.0, 0.0])
    np.testing.assert_allclose(ab.z0, 0.0)
    with pytest.raises(ValueError):
        ab.height[0] = 3.0  # read-only
    with pytest.raises(ValueError):
        Boxes(np.zeros((2, 2)), np.ones(3), np.ones(2), np.zeros(2), np.zeros(2), np.ones(2))
    assert len(Boxes.empty()) == 0


def test_axis_aligned_box_known_distance():
    # box x in [8, 12], y in [-1, 1], z in [0, 1.5]; ray along +x at z = 1
    t_in, t_out = ray_box_intervals([[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]], one_box())
    assert t_in.shape == (1, 1)
    assert t_in[0, 0] == pytest.approx(8.0, abs=TOL) and t_out[0, 0] == pytest.approx(12.0, abs=TOL)
    # t is in units of dirs: a direction of length 2 halves the parameters
    t_in, t_out = ray_box_intervals([[0.0, 0.0, 1.0]], [[2.0, 0.0, 0.0]], one_box())
    assert t_in[0, 0] == pytest.approx(4.0, abs=TOL) and t_out[0, 0] == pytest.approx(6.0, abs=TOL)
    t, idx = first_hit([0.0, 0.0, 1.0], [[1.0, 0.0, 0.0]], one_box())
    assert idx[0] == 0 and t[0] == pytest.approx(8.0, abs=TOL)


def test_miss_behind_and_inside():
    o = [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [10.0, 0.5, 1.0], [0.0, 5.0, 1.0]]
    d = [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
    t_in, t_out = ray_box_intervals(o, d, one_box())
    assert np.isposinf(t_in[0, 0]) and np.isneginf(t_out[0, 0])  # box behind the origin
    assert t_in[2, 0] == 0.0 and t_out[2, 0] == pytest.approx(2.0, abs=TOL)  # origin inside
    assert np.isposinf(t_in[3, 0]) and np.isneginf(t_out[3, 0])  # passes beside
    t, idx = first_hit(o, d, one_box(), ground=False)
    np.testing.assert_array_equal(idx, [NO_HIT, 0, 0, NO_HIT])
    assert t[2] == 0.0 and np.isposinf(t[0])


def test_rotated_box():
    # 4 x 2 box turned 90 deg: occupies x in [9, 11], y in [-2, 2]
    box = one_box(yaw=np.pi / 2)
    o = [[0.0, 0.0, 1.0], [10.0, -10.0, 1.0]]
    t_in, t_out = ray_box_intervals(o, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], box)
    np.testing.assert_allclose(t_in[:, 0], [9.0, 8.0], atol=TOL)
    np.testing.assert_allclose(t_out[:, 0], [11.0, 12.0], atol=TOL)
    # 2 x 2 square turned 45 deg: a ray along its diagonal enters at the corner 10 - sqrt(2)
    t, idx = first_hit([0.0, 0.0, 1.0], [[1.0, 0.0, 0.0]], one_box(length=2.0, yaw=np.pi / 4))
    assert idx[0] == 0 and t[0] == pytest.approx(10.0 - np.sqrt(2.0), abs=TOL)
    # a ray 1.2 m to the side misses that diamond (half-diagonal 1.414 at y = 0, 0.21 left at 1.2)
    t, idx = first_hit([0.0, 1.2, 1.0], [[1.0, 0.0, 0.0]], one_box(length=2.0, yaw=np.pi / 4))
    assert idx[0] == 0 and t[0] == pytest.approx(10.0 - (np.sqrt(2.0) - 1.2), abs=TOL)
    t, idx = first_hit([0.0, 1.5, 1.0], [[1.0, 0.0, 0.0]], one_box(length=2.0, yaw=np.pi / 4))
    assert idx[0] == NO_HIT


def test_ray_above_low_box_and_onto_roof():
    # horizontal ray at 2 m passes over a 1.5 m box; a horizontal ray never meets the ground
    t, idx = first_hit([0.0, 0.0, 2.0], [[1.0, 0.0, 0.0]], one_box())
    assert idx[0] == NO_HIT and np.isposinf(t[0])
    # from 2.5 m descending 0.1 per metre: z = 1.5 at x = 10, over the roof (x in [8, 12])
    t, idx = first_hit([0.0, 0.0, 2.5], [[1.0, 0.0, -0.1]], one_box())
    assert idx[0] == 0 and t[0] == pytest.approx(10.0, abs=TOL)
    # a raised box (z in [2, 3]) is passed under at 1 m and hit at 2.5 m
    t, idx = first_hit([[0.0, 0.0, 1.0], [0.0, 0.0, 2.5]], [[1, 0, 0], [1, 0, 0]], one_box(z0=2.0))
    np.testing.assert_array_equal(idx, [NO_HIT, 0])
    assert t[1] == pytest.approx(8.0, abs=TOL)


def test_ground_hit_from_2_5_m():
    # unit direction 30 deg below horizontal from 2.5 m: ground at 2.5 / sin 30 deg = 5 m
    d = [np.cos(np.pi / 6), 0.0, -np.sin(np.pi / 6)]
    t, idx = first_hit([0.0, 0.0, 2.5], [d], Boxes.empty())
    assert idx[0] == GROUND and t[0] == pytest.approx(5.0, abs=TOL)
    # the same ray meets the box (x in [8, 12]) only after the ground, so the ground wins;
    # without the ground it is a miss (z < 0 there)
    t, idx = first_hit([0.0, 0.0, 2.5], [d], one_box())
    assert idx[0] == GROUND
    # a ray descending 0.2 per metre from 2.5 m: ground at x = 12.5, box front at x = 8 first
    t, idx = first_hit([0.0, 0.0, 2.5], [[1.0, 0.0, -0.2]], one_box())
    assert idx[0] == 0 and t[0] == pytest.approx(8.0, abs=TOL)
    t, idx = first_hit([0.0, 0.0, 2.5], [[1.0, 0.0, -0.2]], Boxes.empty(), ground=False)
    assert idx[0] == NO_HIT
    # a flat (height 0) box on the ground is never hit: the ground is (12.5 m along x)
    t, idx = first_hit([0.0, 0.0, 2.5], [[1.0, 0.0, -0.2]], one_box(cx=12.0, height=0.0))
    assert idx[0] == GROUND and t[0] == pytest.approx(12.5, abs=TOL)
    u = [[1.0, 0.0]]
    t, idx = first_hit_fan([0.0, 0.0, 2.5], u, [-0.2], one_box(cx=12.0, height=0.0))
    assert idx[0, 0] == GROUND and t[0, 0] == pytest.approx(12.5, abs=TOL)


def test_max_t_and_ignore():
    boxes = Boxes.concat(one_box(cx=10.0), one_box(cx=20.0))  # fronts at x = 8 and 18
    o, d = [0.0, 0.0, 1.0], [[1.0, 0.0, 0.0]] * 3
    t, idx = first_hit(o, d, boxes, max_t=5.0)
    np.testing.assert_array_equal(idx, [NO_HIT] * 3)
    np.testing.assert_allclose(t, 5.0)
    t, idx = first_hit(o, d, boxes, max_t=[50.0, 50.0, 15.0], ignore=[0, -1, 0])  # per ray
    np.testing.assert_array_equal(idx, [1, 0, NO_HIT])
    np.testing.assert_allclose(t, [18.0, 8.0, 15.0], atol=TOL)
    t, idx = first_hit(o, d, boxes, ignore=0)  # for all rays
    np.testing.assert_array_equal(idx, [1, 1, 1])
    t, idx = first_hit(o, d, boxes, ignore=np.array([True, True]))
    np.testing.assert_array_equal(idx, [NO_HIT] * 3)


def test_segments_blocked():
    boxes = Boxes.concat(one_box(cx=10.0), one_box(cx=20.0, height=3.0))
    start = [0.0, 0.0, 1.0]
    ends = [
        [30.0, 0.0, 1.0],  # through both boxes
        [5.0, 0.0, 1.0],  # stops short of the first
        [30.0, 0.0, 4.0],  # z = 1 + x / 10: 1.8-2.2 over box 0 (1.5), 2.8 at box 1 (3 m)
        [30.0, 5.0, 1.0],  # y = x / 6: 1.33 at x = 8 and 3 at x = 18, beside both (|y| <= 1)
        [30.0, 2.0, 1.0],  # y = x / 15: 0.53 at x = 8, inside box 0's footprint
        [10.0, 0.0, 1.0],  # ends inside box 0 (its target)
    ]
    np.testing.assert_array_equal(
        segments_blocked(start, ends, boxes), [True, False, True, False, True, True]
    )
    np.testing.assert_array_equal(
        segments_blocked(start, ends, boxes, ignore=[-1, -1, -1, -1, -1, 0]),
        [True, False, True, False, True, False],
    )
    # line from 1 m to 4 m over 30 m: only box 1 (3 m tall) blocks it
    blk = segments_blocked(start, [[30.0, 0.0, 4.0]] * 2, boxes, ignore=[[1, -1], [0, -1]])
    np.testing.assert_array_equal(blk, [False, True])
    # a segment ending exactly on a face is not blocked by that box
    assert not segments_blocked(start, [[8.0, 0.0, 1.0]], boxes)[0]


def test_matches_reference_and_chunking():
    boxes, origins, dirs = random_scene(0)
    t, idx = first_hit(origins, dirs, boxes)
    ref = [reference_first_hit(o, d, boxes) for o, d in zip(origins, dirs, strict=True)]
    ref_t, ref_idx = np.array([r[0] for r in ref]), np.array([r[1] for r in ref])
    assert np.mean(idx == ref_idx) > 0.99  # float32 vs float64 may flip near-grazing cases
    same = idx == ref_idx
    assert (ref_idx != NO_HIT).sum() > 100
    np.testing.assert_allclose(t[same & (idx != NO_HIT)], ref_t[same & (idx != NO_HIT)], 1e-4, 1e-3)
    for f in (
        lambda c: first_hit(origins, dirs, boxes, max_t=40.0, chunk_elems=c),
        lambda c: ray_box_intervals(origins, dirs, boxes, chunk_elems=c),
        lambda c: (segments_blocked(origins, origins + 5 * dirs, boxes, chunk_elems=c),),
        lambda c: first_hit(origins[0], dirs, boxes, chunk_elems=c),  # shared origin
    ):
        for a, b in zip(f(1), f(4_000_000), strict=True):
            np.testing.assert_array_equal(a, b)


def test_fan_matches_first_hit():
    boxes, origins, _ = random_scene(1)
    az = np.linspace(-np.pi, np.pi, 90, endpoint=False)
    el = np.deg2rad(np.linspace(-25.0, 15.0, 16))
    a_g, e_g = np.meshgrid(az, el)
    dirs = np.stack([np.cos(e_g) * np.cos(a_g), np.cos(e_g) * np.sin(a_g), np.sin(e_g)], -1)
    origin = np.array([1.0, 2.0, 2.5])
    t1, i1 = first_hit(origin, dirs.reshape(-1, 3), boxes, max_t=60.0, ignore=3)
    u = np.stack([np.cos(az), np.sin(az)], -1)
    cos_e = np.cos(el)[:, None]
    t2, i2 = first_hit_fan(origin, u, np.tan(el), boxes, max_t=60.0 * cos_e, ignore=3)
    assert i2.shape == (16, 90) and (i1 >= 0).sum() > 50 and (i1 == GROUND).sum() > 50
    assert np.mean(i1 == i2.reshape(-1)) > 0.995
    np.testing.assert_allclose((t2 / cos_e).reshape(-1), t1, rtol=1e-4, atol=1e-3)


def test_far_from_world_origin():
    # same geometry shifted 5 km: float32 computation relative to the first origin stays exact
    off = np.array([5000.0, -3000.0, 0.0])
    box = one_box(cx=10.0 + off[0], cy=off[1], yaw=np.pi / 2)
    t, idx = first_hit(np.array([0.0, 0.0, 1.0]) + off, [[1.0, 0.0, 0.0]], box)
    assert idx[0] == 0 and t[0] == pytest.approx(9.0, abs=1e-4)
