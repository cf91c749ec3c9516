"""Ray layout of a camera as a fan of vertical planes (see :mod:`.camera` for why).

A camera's rays are cast by :func:`..raycast.first_hit_fan` from its centre: ``A`` azimuths (fan
columns) times ``E`` slopes (rows), in the camera's *level frame* (the world frame turned by the
camera's yaw). :func:`fan_for` returns the cached layout (:class:`Fan`) of a camera at a pose:

- level camera (no pitch or roll): one column per pixel column, one row per pixel row, exact;
- pitched camera: a uniform azimuth x elevation grid covering its frustum at
  ``1 / (fx * oversample)`` rad spacing; ``pix`` maps each pixel to its nearest grid ray.

:func:`unoccluded_pixels` counts, on the same layout, the pixels an object would cover with every
other box removed (the denominator of the visible pixel fraction in :mod:`.groundtruth`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..core.geometry import camera_intrinsics
from ..core.jit import HAVE_JIT
from ..core.raycast import Boxes, ray_box_intervals, ray_box_setup
from .kernels import unoccluded_counts_kernel
from .scene import Scene
from .shading import sky_colors

if TYPE_CHECKING:
    from .camera import CameraSpec


@dataclass(frozen=True)
class Fan:
    """Ray layout of a camera in its level frame (yaw removed); see module docstring.

    The fan has ``E x A`` rays; ``pix`` maps each of the ``P = H * W`` pixels to its ray. Per
    pixel (float32, level frame): ``dirs`` unit ray direction, ``norm`` 3D length per metre of
    horizontal travel, ``dpt`` optical-axis depth per metre of horizontal travel, ``sky`` colour.
    """

    az: np.ndarray  # (A,) azimuths of the fan's columns (rad, level frame)
    slopes: np.ndarray  # (E, A) rise per metre of horizontal travel = row_s[e] * col_c[a]
    row_s: np.ndarray  # (E,) decreasing
    col_c: np.ndarray  # (A,) positive
    max_t: np.ndarray  # (E, A) horizontal distance at which depth reaches `far`
    max_t_col: np.ndarray  # (A,) its largest value in each column
    pix: np.ndarray  # (P,) flat index into (E, A) of each pixel
    cumw: np.ndarray  # (E + 1, A) cumulative pixels per fan ray down each column
    dirs: np.ndarray  # (P, 3)
    norm: np.ndarray  # (P,)
    dpt: np.ndarray  # (P,)
    sky: np.ndarray  # (P, 3)
    half_az: float  # largest |azimuth| (rad)
    max_t32: np.ndarray  # max_t as contiguous float32 (the kernels' far cut)
    k32: np.ndarray  # slopes as contiguous float32 (the kernels' slopes)
    neg_row_s: np.ndarray  # -row_s (increasing)
    reach: float  # largest max_t (m): the cull range


def _level_rotation(t_world_body: np.ndarray) -> tuple[float, np.ndarray]:
    """Split a body rotation into world yaw and the rotation in the yaw-aligned level frame."""
    r = t_world_body[:3, :3]
    yaw = float(np.arctan2(r[1, 0], r[0, 0]))
    c, s = np.cos(yaw), np.sin(yaw)
    rz = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # Rz(-yaw)
    return yaw, rz @ r


@functools.lru_cache(maxsize=64)
def _fan(width: int, height: int, fov: float, far: float, r_level: tuple, oversample: float) -> Fan:
    k = camera_intrinsics(width, height, fov)
    fx, cx, cy = k[0, 0], k[0, 2], k[1, 2]
    xn = (np.arange(width) + 0.5 - cx) / fx
    yn = (np.arange(height) + 0.5 - cy) / fx
    rl = np.array(r_level).reshape(3, 3)
    axis = rl[:, 0]  # optical axis in the level frame
    if np.allclose(rl, np.eye(3), atol=1e-9):  # exact: one fan column per pixel column
        az = np.arctan2(-xn, 1.0)
        row_s, col_c = -yn, 1.0 / np.sqrt(1.0 + xn**2)
        pix = np.arange(width * height)
    else:  # virtual uniform azimuth x elevation grid covering the frustum
        b = np.stack(np.broadcast_arrays(1.0, -xn[None, :], -yn[:, None]), -1).reshape(-1, 3)
        lv = b @ rl.T
        paz = np.arctan2(lv[:, 1], lv[:, 0])
        pel = np.arctan2(lv[:, 2], np.hypot(lv[:, 0], lv[:, 1]))
        step = 1.0 / (fx * oversample)
        na = int(np.ceil((paz.max() - paz.min()) / step)) + 1
        ne = int(np.ceil((pel.max() - pel.min()) / step)) + 1
        az = np.linspace(paz.min(), paz.max(), na)
        el = np.linspace(pel.max(), pel.min(), ne)  # top row first
        col = np.rint((paz - az[0]) / max(az[-1] - az[0], 1e-12) * (na - 1)).astype(np.int64)
        row = np.rint((el[0] - pel) / max(el[0] - el[-1], 1e-12) * (ne - 1)).astype(np.int64)
        pix = np.clip(row, 0, ne - 1) * na + np.clip(col, 0, na - 1)
        row_s, col_c = np.tan(el), np.ones(na)
    slopes = row_s[:, None] * col_c[None, :]
    e, a = slopes.shape
    dpt = np.cos(az)[None, :] * axis[0] + np.sin(az)[None, :] * axis[1] + slopes * axis[2]
    max_t = far / np.maximum(dpt, 1e-3)
    weight = np.bincount(pix, minlength=e * a).reshape(e, a).astype(np.float64)
    cumw = np.concatenate([np.zeros((1, a)), np.cumsum(weight, axis=0)])
    kp = slopes.ravel()[pix]
    azp = np.broadcast_to(az, (e, a)).ravel()[pix]
    norm = np.sqrt(1.0 + kp * kp)
    dirs = np.stack([np.cos(azp), np.sin(azp), kp], -1) / norm[:, None]
    return Fan(
        az,
        slopes,
        row_s,
        col_c,
        max_t,
        max_t.max(axis=0),
        pix,
        cumw,
        dirs.astype(np.float32),
        norm.astype(np.float32),
        dpt.ravel()[pix].astype(np.float32),
        sky_colors(dirs[:, 2].astype(np.float32)),
        float(np.abs(az).max()),
        np.ascontiguousarray(max_t, np.float32),
        np.ascontiguousarray(slopes, np.float32),
        -row_s,
        float(max_t.max()),
    )


_LEVEL_KEY = tuple(np.eye(3).ravel().tolist())


def fan_for(spec: CameraSpec, t_world_body: np.ndarray, oversample: float = 1.0):
    """``(fan, yaw)``: the cached ray layout of ``spec`` at this pose, and its world yaw."""
    r = t_world_body
    if r[2, 0] == 0.0 and r[2, 1] == 0.0 and r[0, 2] == 0.0 and r[1, 2] == 0.0 and r[2, 2] == 1.0:
        # level (a yaw only): the level rotation is the identity (rounds to it exactly)
        yaw, key = float(np.arctan2(r[1, 0], r[0, 0])), _LEVEL_KEY
    else:
        yaw, rl = _level_rotation(t_world_body)
        key = tuple(np.round(rl, 9).ravel().tolist())
    return _fan(spec.width, spec.height, spec.fov_deg, spec.far, key, float(oversample)), yaw


def unoccluded_pixels(
    scene: Scene,
    spec: CameraSpec,
    t_world_body: np.ndarray,
    instances: np.ndarray,
    oversample: float = 1.0,
) -> np.ndarray:
    """Pixels each instance would cover in this camera with every other box removed.

    A pixel counts when its ray (for pitched cameras: the virtual ray it takes, as in
    :func:`.camera.render_camera`) meets one of the instance's boxes before the far clip. This
    is the denominator of the visible pixel fraction. Per fan column the rays that meet a box
    form an interval of slopes, from the box's horizontal entry/exit distances and its height
    range (exact for level cameras; for pitched ones a column's far clip is taken at its
    farthest row).

    Args:
        scene: the render scene. spec, t_world_body, oversample: the camera and its pose, as
            :func:`.camera.render_camera`.
        instances: ``(M,)`` instance ids.

    Returns:
        ``(M,)`` float64 pixel counts.
    """
    return unoccluded_pixels_many(scene, [(spec, t_world_body, oversample, instances)])[0]


def unoccluded_pixels_many(scene: Scene, requests: list) -> list[np.ndarray]:
    """:func:`unoccluded_pixels` for several cameras in one ray-box pass.

    Args:
        scene: the render scene.
        requests: ``[(spec, t_world_body, oversample, instances (M_i,)), ...]``.

    Returns:
        ``[(M_i,) float64 pixel counts, ...]``.
    """
    outs = [np.zeros(len(r[3])) for r in requests]
    want = np.unique(np.concatenate([np.asarray(r[3], np.int64) for r in requests] + [[]]))
    boxes = np.flatnonzero(np.isin(scene.inst, want) & scene.active)
    if len(boxes) == 0:
        return outs
    fans, azimuths = [], []
    for spec, pose, oversample, _ in requests:
        fan, yaw = fan_for(spec, pose, oversample)
        fans.append(fan)
        azimuths.append(yaw + fan.az)
    a = np.concatenate(azimuths)  # every camera's fan columns: one vertical plane each
    origins = np.repeat(np.array([r[1][:3, 3] for r in requests], np.float64), [len(f.az) for f in fans], axis=0)
    dirs = np.zeros((len(a), 3))
    dirs[:, 0], dirs[:, 1] = np.cos(a), np.sin(a)
    b = scene.boxes.subset(boxes)
    tall = Boxes.trusted(b.center, b.length, b.width, b.yaw, np.full(len(b), -1e4), np.full(len(b), 2e4))
    box_inst = scene.inst[boxes]
    if HAVE_JIT:  # the kernel computes the intervals of each camera's own boxes only
        o, d, p, _ = ray_box_setup(origins, dirs, tall)
        start = 0
        for k, (fan, req) in enumerate(zip(fans, requests)):
            outs[k] = unoccluded_counts_kernel(
                o, d, start, p.c, p.s, p.bx, p.by, p.hl, p.hw, p.z0, p.z1, fan.max_t_col, box_inst, b.z0, b.height,
                float(origins[start, 2]), fan.col_c, fan.neg_row_s, fan.cumw, np.asarray(req[3], np.int64))
            start += len(fan.az)
        return outs
    t_in_all, t_out_all = ray_box_intervals(origins, dirs, tall)
    start = 0
    for k, (fan, req) in enumerate(zip(fans, requests)):
        na = len(fan.az)
        t_in, t_out = t_in_all[start : start + na], t_out_all[start : start + na]
        org = origins[start : start + na]
        start += na
        inst_k = np.asarray(req[3], np.int64)
        mine = np.isin(box_inst, inst_k)
        cols, bi = np.nonzero(np.isfinite(t_in) & mine & (t_in < fan.max_t_col[:, None]))
        if len(cols):
            _counts(fan, org[0, 2], b, box_inst, cols, bi, t_in, t_out, inst_k, outs[k])
    return outs


def _counts(fan: Fan, oz, b, box_inst, cols, bi, t_in, t_out, instances, out) -> None:
    """Weighted pixel counts of the (column, box) hits into ``out`` (per instance)."""
    ai, ao = t_in[cols, bi].astype(np.float64), t_out[cols, bi].astype(np.float64)
    dz0 = b.z0[bi] - oz
    dz1 = dz0 + b.height[bi]
    with np.errstate(divide="ignore", invalid="ignore"):
        lo_in = np.where(ai > 0, dz0 / ai, np.where(dz0 <= 0, -np.inf, np.inf))
        hi_in = np.where(ai > 0, dz1 / ai, np.where(dz1 >= 0, np.inf, -np.inf))
        cc = fan.col_c[cols]
        klo, khi = np.fmin(lo_in, dz0 / ao) / cc, np.fmax(hi_in, dz1 / ao) / cc
    neg = -fan.row_s  # increasing
    r0 = np.searchsorted(neg, -khi, "left")  # rows [r0, r1) have klo <= slope <= khi
    r1 = np.maximum(np.searchsorted(neg, -klo, "right"), r0)
    inst = box_inst[bi]
    # one box per instance and column: its interval; two (pole + head, bicycle + rider): union
    key = inst * (len(fan.az) + 1) + cols
    order = np.lexsort((bi, key))
    key, r0, r1, cols, inst = key[order], r0[order], r1[order], cols[order], inst[order]
    total = fan.cumw[r1, cols] - fan.cumw[r0, cols]
    dup = np.flatnonzero(key[1:] == key[:-1]) + 1  # second interval of a pair (3+: rare, approx.)
    lo, hi = np.maximum(r0[dup], r0[dup - 1]), np.minimum(r1[dup], r1[dup - 1])
    hi = np.maximum(hi, lo)
    total[dup] -= fan.cumw[hi, cols[dup]] - fan.cumw[lo, cols[dup]]
    uniq, which = np.unique(inst, return_inverse=True)
    sums = np.bincount(which, weights=total)
    sorter = np.argsort(instances)
    out[sorter[np.searchsorted(instances, uniq, sorter=sorter)]] = sums


__all__ = ["Fan", "fan_for", "unoccluded_pixels", "unoccluded_pixels_many"]
