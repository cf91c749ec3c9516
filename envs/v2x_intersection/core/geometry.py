"""Frames, transforms, box corners and calibration matrices: the one home for geometry.

Conventions (see ``docs/environment.md``): SI units, right-handed frames, z up, yaw counter-clockwise
from +x. An actor's local frame has x forward, y left, z up, origin at the box centre on the ground.
Poses are ``(x, y, z, yaw)`` or 4x4 homogeneous matrices ``T_a_b`` that map points expressed in
frame ``b`` into frame ``a`` (``p_a = T_a_b @ p_b``).
"""

from __future__ import annotations

import numpy as np


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles (rad) to ``[-pi, pi)``."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def row_norms(d: np.ndarray) -> np.ndarray:
    """Euclidean norms of the last axis: ``np.linalg.norm(d, axis=-1)`` with the same floats
    (NumPy computes that as ``sqrt(add.reduce(d * d))`` too) at a third of its call overhead."""
    return np.sqrt(np.add.reduce(d * d, axis=-1))


def rot2(yaw: np.ndarray | float) -> np.ndarray:
    """2x2 rotation matrices for yaw (rad); shape ``(..., 2, 2)``."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def world_to_local_2d(points: np.ndarray, origin: np.ndarray, yaw: float) -> np.ndarray:
    """Express world points ``(..., 2)`` in the frame at ``origin (2,)`` with heading ``yaw``."""
    d = np.asarray(points, dtype=np.float64) - origin
    c, s = np.cos(yaw), np.sin(yaw)
    x, y = d[..., 0], d[..., 1]
    return stack_xy(c * x + s * y, -s * x + c * y)


def local_to_world_2d(points: np.ndarray, origin: np.ndarray, yaw: float) -> np.ndarray:
    """Inverse of :func:`world_to_local_2d`."""
    p = np.asarray(points, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    x, y = p[..., 0], p[..., 1]
    return stack_xy(c * x - s * y, s * x + c * y) + origin


def stack_xy(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.stack([a, b], -1)``, the same bytes: two arrays of one shape and dtype (or NumPy
    scalars) filled into a new ``(..., 2)`` array without ``np.stack``'s ~4 us of checks (other
    inputs go through ``np.stack``)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.dtype != b.dtype:
        return np.stack([a, b], -1)
    out = np.empty(a.shape + (2,), a.dtype)
    out[..., 0] = a
    out[..., 1] = b
    return out


def box_corners_2d(center: np.ndarray, length: np.ndarray, width: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Corners of oriented boxes, counter-clockwise from front-left.

    Args:
        center: ``(N, 2)`` box centres (m).
        length, width: ``(N,)`` full extents along local x and y (m).
        yaw: ``(N,)`` headings (rad).

    Returns:
        ``(N, 4, 2)`` corners: front-left, rear-left, rear-right, front-right.
    """
    center = np.asarray(center, dtype=np.float64).reshape(-1, 2)
    hl = 0.5 * np.asarray(length, dtype=np.float64).reshape(-1, 1)
    hw = 0.5 * np.asarray(width, dtype=np.float64).reshape(-1, 1)
    sx = np.array([1.0, -1.0, -1.0, 1.0])
    sy = np.array([1.0, 1.0, -1.0, -1.0])
    lx = hl * sx  # (N, 4)
    ly = hw * sy
    yaw = np.asarray(yaw, dtype=np.float64).reshape(-1, 1)
    c, s = np.cos(yaw), np.sin(yaw)
    x = center[:, :1] + c * lx - s * ly
    y = center[:, 1:] + s * lx + c * ly
    return np.stack([x, y], -1)


def pose_matrix(x: float, y: float, z: float, yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """4x4 homogeneous transform from a pose; rotation is ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    Positive pitch tilts the x axis down (nose down), as for a roadside camera looking at the road.
    """
    cy, sy = np.cos(yaw), np.sin(yaw)
    if pitch == 0.0 and roll == 0.0:  # yaw only: the same bits as the product below (tested)
        t = np.array([[cy, -sy, 0.0, x], [sy, cy, 0.0, y], [0.0, 0.0, 1.0, z], [0.0, 0.0, 0.0, 1.0]])
        t[:2, :2] += 0.0  # the product's zeros are +0.0 (-sin(0) is -0.0)
        return t
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    # rotation about +y by +pitch: with z up, positive pitch tilts the x axis downward
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    t = np.eye(4)
    t[:3, :3] = rz @ ry @ rx
    t[:3, 3] = (x, y, z)
    return t


def memo_matrix(owner: object, name: str, build) -> np.ndarray:
    """``build()`` computed once per ``owner`` (a frozen dataclass) and kept read-only on it.

    For the constant mount matrices of sensor specs, asked for several times every frame.
    """
    m = owner.__dict__.get(name)
    if m is None:
        m = build()
        m.setflags(write=False)
        object.__setattr__(owner, name, m)
    return m


def invert_transform(t: np.ndarray) -> np.ndarray:
    """Inverse of rigid 4x4 transforms ``(..., 4, 4)``."""
    r = t[..., :3, :3]
    p = t[..., :3, 3]
    out = np.zeros_like(t)
    rt = np.swapaxes(r, -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, p)
    out[..., 3, 3] = 1.0
    return out


def transform_points(t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to points ``(..., 3)``."""
    p = np.asarray(points, dtype=np.float64)
    return p @ t[:3, :3].T + t[:3, 3]


def relative_transform(t_world_a: np.ndarray, t_world_b: np.ndarray) -> np.ndarray:
    """``T_a_b``: maps points in frame ``b`` to frame ``a`` given both frames' world poses.

    This is the single function for ego <-> RSU transforms (``T_ego_rsu = relative_transform(
    T_world_ego, T_world_rsu)``).
    """
    return invert_transform(t_world_a) @ t_world_b


def camera_intrinsics(width: int, height: int, fov_deg: float) -> np.ndarray:
    """3x3 pinhole intrinsics for a horizontal field of view (deg); square pixels."""
    fx = 0.5 * width / np.tan(np.deg2rad(fov_deg) / 2.0)
    return np.array([[fx, 0.0, width / 2.0], [0.0, fx, height / 2.0], [0.0, 0.0, 1.0]])


#: Maps camera optical frame (x right, y down, z forward) to a sensor body frame (x fwd, y left, z up).
T_BODY_OPTICAL = np.array(
    [[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


def polyline_lengths(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length ``(P,)`` of a polyline ``(P, 2)``, starting at 0."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def resample_polyline(points: np.ndarray, step: float) -> np.ndarray:
    """Resample a polyline at (about) uniform spacing ``step`` metres, keeping both ends."""
    s = polyline_lengths(points)
    n = max(2, int(np.ceil(s[-1] / step)) + 1)
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])], -1)


def offset_polyline(points: np.ndarray, d: float) -> np.ndarray:
    """Offset a polyline ``(P, 2)`` by ``d`` metres to its left (negative: right)."""
    seg = np.diff(points, axis=0)
    seg /= np.maximum(np.linalg.norm(seg, axis=1, keepdims=True), 1e-9)
    tang = np.concatenate([seg[:1], seg[:-1] + seg[1:], seg[-1:]], 0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-9)
    return points + d * np.stack([-tang[:, 1], tang[:, 0]], -1)


def cut_polyline(points: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of a polyline between arc lengths ``s0 < s1`` (empty if shorter than 2 points)."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    s0, s1 = max(s0, 0.0), min(s1, s[-1])
    if s1 - s0 < 1e-6:
        return np.zeros((0, 2))
    inner = points[(s > s0) & (s < s1)]
    a = [np.interp(s0, s, points[:, 0]), np.interp(s0, s, points[:, 1])]
    b = [np.interp(s1, s, points[:, 0]), np.interp(s1, s, points[:, 1])]
    return np.concatenate([[a], inner, [b]], 0)


def dash_polyline(points: np.ndarray, on: float, off: float) -> list[np.ndarray]:
    """Dashes of ``on`` metres every ``on + off`` metres along a polyline."""
    total = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    return [cut_polyline(points, a, a + on) for a in np.arange(0.0, total, on + off)]


def convex_hull(p: np.ndarray) -> np.ndarray:
    """Convex hull (Andrew's monotone chain) of points ``(N, 2)``, counter-clockwise."""
    pts = sorted({(round(float(x), 6), round(float(y), 6)) for x, y in p})
    if len(pts) < 3:
        return np.array(pts, float).reshape(-1, 2)

    def half(seq: list) -> list:
        out: list = []
        for q in seq:
            while (
                len(out) >= 2
                and (
                    (out[-1][0] - out[-2][0]) * (q[1] - out[-2][1])
                    - (out[-1][1] - out[-2][1]) * (q[0] - out[-2][0])
                )
                <= 0
            ):
                out.pop()
            out.append(q)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1], float)
