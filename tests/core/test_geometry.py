"""Tests of frames, transforms, box corners and calibration (hand-computed answers)."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.geometry import (
    T_BODY_OPTICAL,
    box_corners_2d,
    camera_intrinsics,
    invert_transform,
    local_to_world_2d,
    polyline_lengths,
    pose_matrix,
    relative_transform,
    resample_polyline,
    rot2,
    transform_points,
    world_to_local_2d,
    wrap_angle,
)

PI = np.pi


# ------------------------------------------------------------------------------ angles


@pytest.mark.parametrize(
    "a, expected",
    [
        (0.0, 0.0),
        (0.5, 0.5),
        (PI / 2, PI / 2),
        (3 * PI / 2, -PI / 2),
        (-3 * PI / 2, PI / 2),
        (2 * PI, 0.0),
        (5 * PI + 0.25, -PI + 0.25),
        (-0.25 - 4 * PI, -0.25),
        (PI, -PI),  # the interval is [-pi, pi)
        (-PI, -PI),
    ],
)
def test_wrap_angle_values(a, expected):
    assert float(wrap_angle(a)) == pytest.approx(expected, abs=1e-12)


def test_wrap_angle_vectorized_range_and_equivalence():
    a = np.random.default_rng(0).uniform(-50, 50, 1000)
    w = wrap_angle(a)
    assert w.shape == a.shape
    assert np.all(w >= -PI) and np.all(w < PI)
    # same direction: the difference is a multiple of 2 pi
    k = (a - w) / (2 * PI)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)


def test_rot2_rotates_counter_clockwise():
    r = rot2(PI / 2)
    np.testing.assert_allclose(r @ np.array([1.0, 0.0]), [0.0, 1.0], atol=1e-12)
    rs = rot2(np.array([0.0, PI]))
    assert rs.shape == (2, 2, 2)
    np.testing.assert_allclose(rs[1] @ np.array([1.0, 2.0]), [-1.0, -2.0], atol=1e-12)


# ------------------------------------------------------------------------------ 2D frames


def test_world_to_local_known_values():
    origin = np.array([10.0, 5.0])
    # a frame heading +y (yaw 90 deg): a point 3 m further along +y is 3 m ahead; +x is to the right
    p = world_to_local_2d(np.array([[10.0, 8.0], [12.0, 5.0]]), origin, PI / 2)
    np.testing.assert_allclose(p, [[3.0, 0.0], [0.0, -2.0]], atol=1e-12)
    q = local_to_world_2d(np.array([[1.0, 1.0]]), origin, PI)
    np.testing.assert_allclose(q, [[9.0, 4.0]], atol=1e-12)


def test_world_local_round_trip():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-200, 200, (50, 2))
    for _ in range(10):
        origin = rng.uniform(-100, 100, 2)
        yaw = rng.uniform(-4, 4)
        local = world_to_local_2d(pts, origin, yaw)
        np.testing.assert_allclose(local_to_world_2d(local, origin, yaw), pts, atol=1e-9)
        # a rigid transform keeps distances
        np.testing.assert_allclose(
            np.linalg.norm(local - local[0], axis=1),
            np.linalg.norm(pts - pts[0], axis=1),
            atol=1e-9,
        )


# ------------------------------------------------------------------------------ boxes


def test_box_corners_axis_aligned():
    c = box_corners_2d(np.array([[1.0, 2.0]]), np.array([4.0]), np.array([2.0]), np.array([0.0]))
    assert c.shape == (1, 4, 2)
    # front-left, rear-left, rear-right, front-right
    np.testing.assert_allclose(c[0], [[3.0, 3.0], [-1.0, 3.0], [-1.0, 1.0], [3.0, 1.0]], atol=1e-12)


def test_box_corners_rotated_90deg():
    c = box_corners_2d(np.array([[0.0, 0.0]]), np.array([4.0]), np.array([2.0]), np.array([PI / 2]))
    # heading +y: front-left is (-1, 2), rear-left (-1, -2), rear-right (1, -2), front-right (1, 2)
    np.testing.assert_allclose(
        c[0], [[-1.0, 2.0], [-1.0, -2.0], [1.0, -2.0], [1.0, 2.0]], atol=1e-12
    )


def test_box_corners_batch_counter_clockwise_and_sizes():
    rng = np.random.default_rng(2)
    n = 20
    ctr = rng.uniform(-50, 50, (n, 2))
    length, width, yaw = rng.uniform(1, 10, n), rng.uniform(0.5, 3, n), rng.uniform(-4, 4, n)
    c = box_corners_2d(ctr, length, width, yaw)
    np.testing.assert_allclose(c.mean(1), ctr, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(c[:, 0] - c[:, 1], axis=1), length, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(c[:, 1] - c[:, 2], axis=1), width, atol=1e-9)
    # shoelace area is positive (counter-clockwise) and equals length * width
    x, y = c[..., 0], c[..., 1]
    area = 0.5 * np.sum(x * np.roll(y, -1, 1) - np.roll(x, -1, 1) * y, axis=1)
    np.testing.assert_allclose(area, length * width, rtol=1e-9)


# ------------------------------------------------------------------------------ 4x4 transforms


def test_pose_matrix_yaw_only():
    t = pose_matrix(1.0, 2.0, 3.0, PI / 2)
    np.testing.assert_allclose(
        transform_points(t, np.array([1.0, 0.0, 0.0])), [1.0, 3.0, 3.0], atol=1e-12
    )
    np.testing.assert_allclose(t[3], [0.0, 0.0, 0.0, 1.0])


def test_pose_matrix_yaw_only_path_matches_the_full_product():
    """The yaw-only shortcut gives the bits of ``Rz @ Ry(0) @ Rx(0)`` (zeros' signs included)."""
    rng = np.random.default_rng(0)
    yaws = [0.0, -0.0, PI, -PI, PI / 2, -PI / 2, 1e-300, *rng.uniform(-10, 10, 300)]
    for yaw in yaws:
        x, y, z = rng.normal(size=3)
        cy, sy = np.cos(yaw), np.sin(yaw)
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        ry = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-0.0, 0.0, 1.0]])
        rx = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, -0.0], [0.0, 0.0, 1.0]])
        full = np.eye(4)
        full[:3, :3] = rz @ ry @ rx
        full[:3, 3] = (x, y, z)
        assert pose_matrix(x, y, z, yaw).tobytes() == full.tobytes()


def test_pose_matrix_positive_pitch_points_x_down():
    t = pose_matrix(0.0, 0.0, 5.0, 0.0, pitch=np.deg2rad(30.0))
    fwd = transform_points(t, np.array([1.0, 0.0, 0.0])) - t[:3, 3]
    np.testing.assert_allclose(fwd, [np.cos(np.deg2rad(30)), 0.0, -0.5], atol=1e-12)


def test_pose_matrix_rotation_is_orthonormal():
    t = pose_matrix(3.0, -4.0, 5.0, 0.7, 0.2, -0.1)
    r = t[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)


def test_invert_transform():
    rng = np.random.default_rng(3)
    for _ in range(10):
        t = pose_matrix(*rng.uniform(-100, 100, 3), *rng.uniform(-3, 3, 3))
        np.testing.assert_allclose(invert_transform(t) @ t, np.eye(4), atol=1e-12)
        np.testing.assert_allclose(t @ invert_transform(t), np.eye(4), atol=1e-12)
        np.testing.assert_allclose(invert_transform(t), np.linalg.inv(t), atol=1e-9)
    batch = np.stack([pose_matrix(k, 0, 0, 0.1 * k) for k in range(4)])
    inv = invert_transform(batch)
    np.testing.assert_allclose(inv @ batch, np.broadcast_to(np.eye(4), (4, 4, 4)), atol=1e-12)


def test_relative_transform_ego_rsu_round_trip():
    rng = np.random.default_rng(4)
    for _ in range(20):
        t_world_ego = pose_matrix(*rng.uniform(-300, 300, 2), 0.0, rng.uniform(-PI, PI))
        t_world_rsu = pose_matrix(
            *rng.uniform(-300, 300, 2), 5.0, rng.uniform(-PI, PI), np.deg2rad(12.0), np.deg2rad(1.0)
        )
        t_ego_rsu = relative_transform(t_world_ego, t_world_rsu)
        t_rsu_ego = relative_transform(t_world_rsu, t_world_ego)
        np.testing.assert_allclose(t_ego_rsu @ t_rsu_ego, np.eye(4), atol=1e-12)
        np.testing.assert_allclose(t_rsu_ego @ t_ego_rsu, np.eye(4), atol=1e-12)
        p_rsu = rng.uniform(-80, 80, (30, 3))
        p_ego = transform_points(t_ego_rsu, p_rsu)
        np.testing.assert_allclose(transform_points(t_rsu_ego, p_ego), p_rsu, atol=1e-9)
        # consistent with going through the world frame
        p_world = transform_points(t_world_rsu, p_rsu)
        np.testing.assert_allclose(
            transform_points(invert_transform(t_world_ego), p_world), p_ego, atol=1e-9
        )


def test_relative_transform_known_answer():
    # ego at origin heading +x; RSU 10 m ahead, 5 m up, facing back toward the ego (yaw pi)
    t_world_ego = pose_matrix(0.0, 0.0, 0.0, 0.0)
    t_world_rsu = pose_matrix(10.0, 0.0, 5.0, PI)
    t_ego_rsu = relative_transform(t_world_ego, t_world_rsu)
    # a point 4 m in front of the RSU (along its x) is 6 m ahead of the ego at height 5
    np.testing.assert_allclose(
        transform_points(t_ego_rsu, np.array([4.0, 0.0, 0.0])), [6.0, 0.0, 5.0], atol=1e-12
    )
    # the RSU's left (+y) is the ego's right (-y)
    np.testing.assert_allclose(
        transform_points(t_ego_rsu, np.array([0.0, 1.0, 0.0])), [10.0, -1.0, 5.0], atol=1e-12
    )


# ------------------------------------------------------------------------------ cameras


@pytest.mark.parametrize("w, h, fov", [(640, 480, 90.0), (160, 90, 110.0), (64, 64, 60.0)])
def test_camera_intrinsics_principal_point_and_focal(w, h, fov):
    k = camera_intrinsics(w, h, fov)
    assert k.shape == (3, 3)
    assert k[0, 2] == pytest.approx(w / 2) and k[1, 2] == pytest.approx(h / 2)
    assert k[0, 0] == pytest.approx(k[1, 1])
    assert k[0, 0] == pytest.approx(0.5 * w / np.tan(np.deg2rad(fov) / 2))
    np.testing.assert_allclose(k[2], [0.0, 0.0, 1.0])
    assert k[0, 1] == 0.0 and k[1, 0] == 0.0
    # a ray at half the FOV projects to the image edge
    half = np.deg2rad(fov) / 2
    u = k @ np.array([np.tan(half), 0.0, 1.0])
    assert u[0] / u[2] == pytest.approx(w, abs=1e-9)


def test_camera_intrinsics_fov90_focal_is_half_width():
    assert camera_intrinsics(640, 480, 90.0)[0, 0] == pytest.approx(320.0)


def test_body_optical_maps_optical_axis_forward():
    # optical z (forward) -> body x; optical x (right) -> body -y; optical y (down) -> body -z
    np.testing.assert_allclose(T_BODY_OPTICAL[:3, :3] @ [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(T_BODY_OPTICAL[:3, :3] @ [1.0, 0.0, 0.0], [0.0, -1.0, 0.0])
    np.testing.assert_allclose(T_BODY_OPTICAL[:3, :3] @ [0.0, 1.0, 0.0], [0.0, 0.0, -1.0])
    assert np.linalg.det(T_BODY_OPTICAL[:3, :3]) == pytest.approx(1.0)


# ------------------------------------------------------------------------------ polylines


def test_polyline_lengths():
    pts = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 10.0]])
    np.testing.assert_allclose(polyline_lengths(pts), [0.0, 5.0, 11.0])


def test_resample_polyline_spacing_and_ends():
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 7.0]])  # 17 m, with a corner
    out = resample_polyline(pts, 1.0)
    assert len(out) == 18
    np.testing.assert_allclose(out[0], pts[0])
    np.testing.assert_allclose(out[-1], pts[-1])
    # samples are 1 m apart in arc length: each lies on the polyline at s = k
    s = np.arange(18.0)
    on_first = s <= 10.0
    np.testing.assert_allclose(
        out[on_first], np.stack([s[on_first], np.zeros(on_first.sum())], -1), atol=1e-12
    )
    np.testing.assert_allclose(
        out[~on_first],
        np.stack([np.full((~on_first).sum(), 10.0), s[~on_first] - 10.0], -1),
        atol=1e-12,
    )


def test_resample_polyline_uneven_length_spacing_close_to_step():
    theta = np.linspace(0.0, PI, 200)
    arc = np.stack([20 * np.cos(theta), 20 * np.sin(theta)], -1)  # about 62.8 m
    out = resample_polyline(arc, 2.0)
    d = np.linalg.norm(np.diff(out, axis=0), axis=1)
    assert np.all(d <= 2.0 + 1e-9)
    assert np.all(d > 1.9)
    np.testing.assert_allclose(out[[0, -1]], arc[[0, -1]])


def test_resample_polyline_short_keeps_two_points():
    out = resample_polyline(np.array([[0.0, 0.0], [0.3, 0.0]]), 2.0)
    np.testing.assert_allclose(out, [[0.0, 0.0], [0.3, 0.0]])


@pytest.mark.parametrize("shape", [(2,), (5, 2), (3, 4, 2), (0, 2)])
def test_frame_transforms_give_the_stacked_formula_bytes(shape):
    """``world_to_local_2d`` / ``local_to_world_2d`` fill their output column by column: the same
    bytes, shape and dtype as stacking the two rotated coordinates."""
    rng = np.random.default_rng(len(shape))
    p, o, yaw = rng.normal(0, 50, shape), rng.normal(0, 5, 2), float(rng.uniform(-3, 3))
    c, s = np.cos(yaw), np.sin(yaw)
    d = p - o
    want = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], -1)
    got = world_to_local_2d(p, o, yaw)
    assert got.shape == want.shape and got.dtype == want.dtype and got.tobytes() == want.tobytes()
    want = np.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], -1) + o
    got = local_to_world_2d(p, o, yaw)
    assert got.shape == want.shape and got.tobytes() == want.tobytes()
