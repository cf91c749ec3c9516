"""Occlusion: which boxes a sensor can see, built only on :mod:`raycast`.

A target's visibility is estimated from a fixed set of ``K = 15`` sample points on its box
(:func:`sample_points`): the fraction of them with an unblocked line of sight from the sensor,
inside the sensor's range and horizontal field of view (:func:`visible_fraction`). A target counts
as visible when that fraction reaches :data:`VISIBLE_THRESHOLD` (:func:`visible_mask`).

Sample pattern, per box (local frame, x forward, y left):

- horizontally, 5 positions: the centre and the four corners pulled in to :data:`XY_SHRINK`
  (70 %) of the half extents, so that points lie inside the box and not on faces shared with a
  touching neighbour;
- vertically, 3 levels at :data:`LEVELS` = 15 %, 45 % and 75 % of the height above the base
  (a 1.8 m pedestrian: 0.27, 0.81 and 1.35 m; a 1.5 m car: 0.23, 0.68, 1.13 m).

The top quarter of the box is deliberately not sampled: a sliver of roof or the top of a head
showing over an occluder is not what a detector needs, and it is exactly the case in which an ego
sensor at 1.8 m "sees" a pedestrian's head over a 1.5 m car. With these levels a pedestrian close
behind a parked car is hidden from the ego (fraction 0) but visible from a 5 m pole.

The target's own box never blocks its sample points (it is transparent to itself); boxes listed in
``ignore`` (e.g. the sensor's own vehicle) never block anything. The ground does not occlude
(segments between points above ground never go below it).
"""

from __future__ import annotations

import numpy as np

from ..core import libm
from ..core.geometry import local_to_world_2d, wrap_angle
from ..core.jit import HAVE_JIT
from ..core.jit_raycast import half_diagonals_kernel, visible_fraction_kernel
from ..core.raycast import END_TOLERANCES, Boxes, segments_blocked

#: Sample heights as fractions of each box's height above its base.
LEVELS = (0.15, 0.45, 0.75)
#: Horizontal sample offsets are these fractions of the half length / half width.
XY_SHRINK = 0.7
#: Unit horizontal sample pattern: centre, then front-left, rear-left, rear-right, front-right.
_XY = np.array([[0.0, 0.0], [1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
#: Sample points per box.
K = len(LEVELS) * len(_XY)
_LEVELS = np.asarray(LEVELS)
#: ``visible_mask`` threshold on the visible fraction: at least 2 of the 15 points.
VISIBLE_THRESHOLD = 0.1
_LO, _HI = END_TOLERANCES  # segments_blocked's default end-point tolerance
#: the sample pattern's arguments of ``visible_fraction_kernel`` (levels, pattern, shrink, lo, hi)
VISIBILITY_SAMPLING = (_LEVELS, _XY, 0.5 * XY_SHRINK, _LO, _HI)


def sample_points(boxes: Boxes, idx: np.ndarray) -> np.ndarray:
    """World sample points on the selected boxes (pattern in the module docstring).

    Args:
        boxes: ``N`` boxes.
        idx: ``(M,)`` indices of the target boxes.

    Returns:
        ``(M, K, 3)`` points (m), ``K = 15``, ordered level-major (level 0's five horizontal
        positions first: centre, front-left, rear-left, rear-right, front-right).
    """
    idx = np.asarray(idx, dtype=np.intp).reshape(-1)
    half = 0.5 * XY_SHRINK * np.stack([boxes.length[idx], boxes.width[idx]], -1)  # (M, 2)
    local = _XY * half[:, None, :]  # (M, 5, 2)
    xy = local_to_world_2d(local, boxes.center[idx, None, :], boxes.yaw[idx, None])
    z = boxes.z0[idx, None] + np.asarray(LEVELS) * boxes.height[idx, None]  # (M, L)
    m, nl, nxy = len(idx), len(LEVELS), len(_XY)
    xy = np.broadcast_to(xy[:, None], (m, nl, nxy, 2))
    zz = np.broadcast_to(z[:, :, None, None], (m, nl, nxy, 1))
    return np.concatenate([xy, zz], -1).reshape(m, nl * nxy, 3)


def visible_fraction(
    sensor_pos: np.ndarray,
    boxes: Boxes,
    targets: np.ndarray,
    ignore=(),
    max_range: float = np.inf,
    sensor_yaw: float = 0.0,
    hfov: float | None = None,
    chunk_elems: int | None = None,
) -> np.ndarray:
    """Fraction of each target's sample points that the sensor sees.

    A sample point counts when it is within ``max_range`` (3D distance), inside the horizontal
    field of view and the segment from the sensor to it is not blocked by any box other than the
    target itself and those in ``ignore``.

    Args:
        sensor_pos: ``(3,)`` sensor position (m, world frame).
        boxes: ``N`` boxes: every occluder and every target.
        targets: ``(M,)`` indices into ``boxes`` of the targets.
        ignore: box indices that never occlude (e.g. the sensor's own vehicle).
        max_range: sensor range (m).
        sensor_yaw: direction the sensor faces (rad, world frame); used only with ``hfov``.
        hfov: full horizontal field of view (rad); ``None`` (or ``>= 2 pi``) = all around.
        chunk_elems: passed to :func:`raycast.segments_blocked`.

    Returns:
        ``(M,)`` float64 in ``[0, 1]``, in steps of ``1 / K``.
    """
    sensor_pos = np.asarray(sensor_pos, dtype=np.float64).reshape(3)
    targets = np.asarray(targets, dtype=np.intp).reshape(-1)
    m = len(targets)
    if m == 0:
        return np.zeros(0)
    if HAVE_JIT and chunk_elems is None:
        fov = hfov is not None and hfov < 2.0 * np.pi
        return visible_fraction_kernel(
            sensor_pos, boxes.center, *boxes.trig(), boxes.length, boxes.width, boxes.z0, boxes.height,
            half_diagonals_kernel(boxes.length, boxes.width), targets,
            np.asarray(ignore, dtype=np.intp).reshape(-1), float(max_range) ** 2, fov, float(sensor_yaw),
            0.5 * hfov if fov else 0.0, _LEVELS, _XY, 0.5 * XY_SHRINK, _LO, _HI)
    pts = sample_points(boxes, targets).reshape(-1, 3)  # (M*K, 3)
    rel = pts - sensor_pos
    rel2 = np.einsum("ij,ij->i", rel, rel)
    ok = rel2 <= float(max_range) ** 2
    if hfov is not None and hfov < 2.0 * np.pi:
        bearing = libm.arctan2(rel[:, 1], rel[:, 0])
        ok &= np.abs(wrap_angle(bearing - sensor_yaw)) <= 0.5 * hfov
    cand = np.flatnonzero(ok)
    if len(cand):
        extra = np.asarray(ignore, dtype=np.intp).reshape(-1)
        own = np.repeat(targets, K)[cand]  # each point's target box never blocks it
        # Only boxes that reach into the disc swept by the segments can block one: drop the others
        # (exact: a dropped box cannot intersect any segment, and every kept (segment, box) pair
        # is computed by the same element-wise operations as without the cut).
        reach = np.sqrt(np.max(rel2[cand])) + 1.0
        dc = boxes.center - sensor_pos[:2]
        radius = 0.5 * np.hypot(boxes.length, boxes.width)
        keep = np.einsum("ij,ij->i", dc, dc) < (reach + radius) ** 2
        remap = np.cumsum(keep) - 1
        remap[~keep] = -1  # ignored boxes that were dropped: nothing to ignore
        ig = np.empty((len(cand), 1 + len(extra)), np.intp)
        ig[:, 0] = remap[own]
        ig[:, 1:] = np.where(extra >= 0, remap[extra], -1)
        blocked = segments_blocked(sensor_pos, pts[cand], boxes.subset(keep), ig, chunk_elems=chunk_elems)
        ok[cand[blocked]] = False
    return ok.reshape(m, K).mean(axis=1)


def visible_mask(
    sensor_pos: np.ndarray,
    boxes: Boxes,
    targets: np.ndarray,
    ignore=(),
    max_range: float = np.inf,
    sensor_yaw: float = 0.0,
    hfov: float | None = None,
    threshold: float = VISIBLE_THRESHOLD,
) -> np.ndarray:
    """Whether each target is visible: ``visible_fraction(...) >= threshold`` and ``> 0``.

    Args are those of :func:`visible_fraction`, plus ``threshold`` (default
    :data:`VISIBLE_THRESHOLD` = 0.1, i.e. at least 2 of the 15 sample points).

    Returns:
        ``(M,)`` bool.
    """
    frac = visible_fraction(sensor_pos, boxes, targets, ignore, max_range, sensor_yaw, hfov)
    return (frac >= threshold) & (frac > 0)
