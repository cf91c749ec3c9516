"""numba kernels for a tick's perception side: which RSUs serve the ego (``rsu.select_active``)
and the object lists of what an observer sees, in its frame (``world.object_rows``, used by the
ego observation and the RSU's message).

Like :mod:`.jit`, the kernels repeat the NumPy path's float operations in the same order and
dtype, so both paths give bit-identical results (``tests/core/test_jit.py``).
"""

from __future__ import annotations

import numpy as np

from ..core.jit import _njit, _njit_inline, pose_at_kernel, project_refine
from ..core.jit_grid import project_grid_kernel
from ..core.jit_raycast import half_diagonal, visible_fraction_kernel

UNSEEN_KEY = 1.0e6  # m: units that do not see the ego's look-ahead point rank after all that do
#: bound of the observation boxes (``observations.BIG``): received objects whose ego-frame position
#: or velocity would leave it are clipped to it (:func:`_rsu_row_to_ego`)
OBS_BOUND = 1.0e4


@_njit_inline
def _frame_order(idx, pos, ox, oy, c, s):  # pragma: no cover
    """Actors ``idx`` in the frame at ``(ox, oy)`` with heading cosine/sine ``c``/``s``:
    ``(lx, ly, order)``, ``order`` sorting them by distance."""
    m = idx.shape[0]
    lx = np.empty(m)
    ly = np.empty(m)
    dist = np.empty(m)
    for k in range(m):
        i = idx[k]
        d0 = pos[i, 0] - ox
        d1 = pos[i, 1] - oy
        lx[k] = c * d0 + s * d1
        ly[k] = -s * d0 + c * d1
        dist[k] = np.sqrt(lx[k] * lx[k] + ly[k] * ly[k])
    return lx, ly, np.argsort(dist)


@_njit_inline
def _object_row(out, r, col, i, lx, ly, yaw, speed, kind, length, width, height, actor_id, oyaw, c,
                s):  # pragma: no cover
    """Write actor ``i``'s ``channel.OBJECT_FIELDS`` (position ``lx, ly`` in the frame of heading
    ``oyaw``, cosine/sine ``c``/``s``) into ``out[r, col:col + 10]`` (float32)."""
    two_pi = 2 * np.pi
    vx = speed[i] * np.cos(yaw[i])
    vy = speed[i] * np.sin(yaw[i])
    out[r, col] = np.float64(kind[i])
    out[r, col + 1] = lx
    out[r, col + 2] = ly
    out[r, col + 3] = (yaw[i] - oyaw + np.pi) % two_pi - np.pi
    out[r, col + 4] = length[i]
    out[r, col + 5] = width[i]
    out[r, col + 6] = height[i]
    out[r, col + 7] = c * vx + s * vy
    out[r, col + 8] = -s * vx + c * vy
    out[r, col + 9] = np.float64(actor_id[i])


@_njit
def object_rows_kernel(idx, pos, yaw, speed, kind, length, width, height, actor_id, ox, oy, oyaw):  # pragma: no cover
    """``world.object_rows``: ``(K, 10)`` float32 rows of ``channel.OBJECT_FIELDS`` for actors
    ``idx`` in the frame at ``(ox, oy)`` / ``oyaw``, sorted by distance."""
    c, s = np.cos(oyaw), np.sin(oyaw)
    lx, ly, order = _frame_order(idx, pos, ox, oy, c, s)
    out = np.empty((idx.shape[0], 10), np.float32)
    for r in range(idx.shape[0]):
        k = order[r]
        _object_row(out, r, 0, idx[k], lx[k], ly[k], yaw, speed, kind, length, width, height, actor_id, oyaw, c, s)
    return out


#: m of distance to the watched point that weigh as much as 1 rad off a unit's axis when the
#: active unit is chosen (``rsu.select_active``): the unit looking most directly at the road ahead
#: wins unless it stands much farther from it
SELECT_M_PER_RAD = 50.0


@_njit
def select_active_kernel(pose, ex, ey, eyaw, max_range, slots, max_angle, lookahead, view_half):  # pragma: no cover
    """``rsu.select_active``: among the units ahead, facing the ego and in range, the ``slots``
    best: units whose view (``view_half`` either side of their axis, within range) holds the
    point ``lookahead`` m ahead of the ego, smallest ``angle off the axis + distance / SELECT_M_PER_RAD`` first, then the others by
    their distance to the ego; -1 pads; slot 0 falls back to the nearest unit when none
    qualifies.

    Ties between equal keys go to the lower index.
    """
    n = pose.shape[0]
    c, s = np.cos(eyaw), np.sin(eyaw)
    px, py = ex + lookahead * c, ey + lookahead * s
    key = np.empty(n)
    dist = np.empty(n)
    two_pi = 2 * np.pi
    for u in range(n):
        d0 = pose[u, 0] - ex
        d1 = pose[u, 1] - ey
        dist[u] = np.sqrt(d0 * d0 + d1 * d1)
        ahead = d0 * c + d1 * s > -10.0
        to_ego = np.arctan2(-d1, -d0)
        facing = abs((to_ego - pose[u, 3] + np.pi) % two_pi - np.pi) < max_angle
        if ahead and facing and dist[u] < max_range:
            q0 = px - pose[u, 0]
            q1 = py - pose[u, 1]
            dq = np.sqrt(q0 * q0 + q1 * q1)
            off = abs((np.arctan2(q1, q0) - pose[u, 3] + np.pi) % two_pi - np.pi)
            sees = dq < max_range and off < view_half
            key[u] = off + dq / SELECT_M_PER_RAD if sees else UNSEEN_KEY + dist[u]
        else:
            key[u] = np.inf
    out = np.full(slots, -1, np.int64)
    taken = np.zeros(n, np.bool_)
    for k in range(min(slots, n)):
        best, bu = np.inf, -1
        for u in range(n):
            if not taken[u] and key[u] < best:
                best, bu = key[u], u
        if bu < 0:
            break
        taken[bu] = True
        out[k] = bu
    if out[0] < 0:
        out[0] = np.argmin(dist)
    return out


@_njit
def sidewalk_snap_kernel(x, y, points, owner, offset, n_points, gs, base):  # pragma: no cover
    """``rsu._on_sidewalk``'s two searches over all sidewalk vertices in one pass: the distance to
    the sidewalks (``PolylineIndex.project``: nearest vertex by squared distance, then the segments
    beside it) and the nearest vertex by distance (``np.argmin`` of the norms: the first minimum).

    Returns:
        ``(distance, vertex)``.
    """
    best, j = np.inf, 0
    best_n, k = np.inf, 0
    for p in range(points.shape[0]):
        dx = x - points[p, 0]
        dy = y - points[p, 1]
        d2 = dx * dx + dy * dy
        if d2 < best:
            best, j = d2, p
        nrm = np.sqrt(d2)
        if nrm < best_n:
            best_n, k = nrm, p
    _, _, d = project_refine(x, y, j, points, owner, offset, n_points, gs, base)
    return d, k


@_njit_inline
def _rsu_row_to_ego(out, r, col, src, b, x, y, yaw, ex, ey, eyaw, c, s, ce, se, cr, sr):  # pragma: no cover
    """Object fields ``src[b:b + 10]`` (float32, in the frame of the unit at ``(x, y, yaw)``,
    cosine/sine ``c``/``s``) re-expressed in the ego frame into ``out[r, col:col + 10]``:
    positions, headings and velocities (``ce``/``se``: the ego's heading, ``cr``/``sr``: the
    difference), positions and velocities clipped to ``+-OBS_BOUND``; the other fields copied
    (a payload holds values within ``wire.PAYLOAD_LIMIT`` = ``OBS_BOUND``)."""
    two_pi = 2.0 * np.pi
    lim = OBS_BOUND
    for f in range(10):
        out[r, col + f] = src[b + f]
    p0 = np.float64(src[b + 1])
    p1 = np.float64(src[b + 2])
    d0 = (c * p0 - s * p1 + x) - ex
    d1 = (s * p0 + c * p1 + y) - ey
    out[r, col + 1] = min(max(ce * d0 + se * d1, -lim), lim)
    out[r, col + 2] = min(max(-se * d0 + ce * d1, -lim), lim)
    out[r, col + 3] = (np.float64(src[b + 3]) + yaw - eyaw + np.pi) % two_pi - np.pi
    vx = np.float64(src[b + 7])
    vy = np.float64(src[b + 8])
    out[r, col + 7] = min(max(cr * vx - sr * vy, -lim), lim)
    out[r, col + 8] = min(max(sr * vx + cr * vy, -lim), lim)


def perceive_workspace(n, static_boxes, static_heights, static_cos, static_sin, static_half_diag) -> tuple:
    """:func:`perceive_kernel`'s box arrays for ``n`` actor rows then the static boxes: ``(center
    (n + S, 2), cos_yaw, sin_yaw, length, width, height, z0, half_diag)``, the static boxes' rows
    filled (they hold for the episode), the actors' rows written by each call."""
    ns = static_boxes.shape[0]
    ws = (np.empty((n + ns, 2)), *(np.empty(n + ns) for _ in range(5)), np.zeros(n + ns), np.empty(n + ns))
    center, cos_yaw, sin_yaw, blen, bwid, bh, _, half_diag = ws
    center[n:] = static_boxes[:, :2]
    cos_yaw[n:], sin_yaw[n:] = static_cos, static_sin
    blen[n:], bwid[n:], bh[n:] = static_boxes[:, 2], static_boxes[:, 3], static_heights
    half_diag[n:] = static_half_diag
    return ws


def perceive_outputs(n: int, slots: int) -> tuple:
    """:func:`perceive_all_kernel`'s outputs, written by each call: ``(active_rsu (slots,),
    ego_vis (n,), rsu_vis (slots, n))`` (returning fresh arrays to Python costs ~0.4 us each,
    measured 2026-11-26)."""
    return np.full(slots, -1, np.int64), np.zeros(n), np.zeros((slots, n))


@_njit
def perceive_kernel(pos, length, width, yaw, height, active, center, cos_yaw, sin_yaw, blen, bwid, bh, z0, half_diag,
                    ego_z, ego_r2, ego_range, rsu_pose, rsu_r2, rsu_range, half_fov, levels, pattern, shrink, lo,
                    hi, ego_vis, rsu_vis):  # pragma: no cover
    """``world.World.perceive`` after the RSU selection: visible fraction of every active actor
    (rows >= 1) from the ego's sensor and from each selected RSU (``rsu_pose (slots, 4)``, NaN
    rows for empty slots), against all actors and static boxes as occluders.

    ``center`` ... ``half_diag``: :func:`perceive_workspace` (the static boxes' rows filled); the
    actors' rows are written here. ``ego_vis (N,)``, ``rsu_vis (slots, N)``: the outputs, overwritten.
    """
    n = pos.shape[0]
    for i in range(n):
        center[i, 0], center[i, 1] = pos[i, 0], pos[i, 1]
        cos_yaw[i], sin_yaw[i] = np.cos(yaw[i]), np.sin(yaw[i])
        blen[i], bwid[i] = length[i], width[i]
        bh[i] = height[i] if active[i] else 0.0
        half_diag[i] = half_diagonal(length[i], width[i])
    ego_vis[:] = 0.0
    slots = rsu_pose.shape[0]
    rsu_vis[:] = 0.0
    sensor = np.empty(3)
    for q in range(slots + 1):
        if q == 0:
            sx, sy, sz, syaw, rng, r2, fov, extra = pos[0, 0], pos[0, 1], ego_z, 0.0, ego_range, ego_r2, False, \
                np.zeros(1, np.int64)
        else:
            if rsu_pose[q - 1, 0] != rsu_pose[q - 1, 0]:
                continue
            sx, sy, sz, syaw = rsu_pose[q - 1, 0], rsu_pose[q - 1, 1], rsu_pose[q - 1, 2], rsu_pose[q - 1, 3]
            rng, r2, fov, extra = rsu_range, rsu_r2, True, np.zeros(0, np.int64)
        cnt = 0
        near = np.empty(n, np.int64)
        for i in range(1, n):
            if not active[i]:
                continue
            dx = pos[i, 0] - sx
            dy = pos[i, 1] - sy
            if np.sqrt(dx * dx + dy * dy) < rng:
                near[cnt] = i
                cnt += 1
        if cnt == 0:
            continue
        sensor[0], sensor[1], sensor[2] = sx, sy, sz
        vis = visible_fraction_kernel(sensor, center, cos_yaw, sin_yaw, blen, bwid, z0, bh, half_diag, near[:cnt],
                                      extra, r2, fov, syaw, half_fov if fov else 0.0, levels, pattern, shrink, lo, hi)
        for a in range(cnt):
            if q == 0:
                ego_vis[near[a]] = vis[a]
            else:
                rsu_vis[q - 1, near[a]] = vis[a]


@_njit
def perceive_all_kernel(rsu_pose, max_angle, lookahead, view_half, slots, pos, length, width, yaw,
                        height, active, center, cos_yaw, sin_yaw, blen, bwid, bh, z0, half_diag, ego_z, ego_r2,
                        ego_range, rsu_r2, rsu_range, half_fov, levels, pattern, shrink, lo, hi, active_rsu, ego_vis,
                        rsu_vis):  # pragma: no cover
    """``world.World.perceive`` in one call: the RSU selection (:func:`select_active_kernel`;
    all ``-1`` without units), then :func:`perceive_kernel` from the selected units' poses
    (``center`` ... ``half_diag``: :func:`perceive_workspace`), written into the outputs
    ``active_rsu (slots,)``, ``ego_vis (N,)``, ``rsu_vis (slots, N)`` (:func:`perceive_outputs`).

    Returns:
        the outputs ``(active_rsu, ego_vis, rsu_vis)``.
    """
    if rsu_pose.shape[0] == 0:
        active_rsu[:] = -1
    else:
        active_rsu[:] = select_active_kernel(rsu_pose, pos[0, 0], pos[0, 1], yaw[0], rsu_range, slots,
                                             max_angle, lookahead, view_half)
    pose = np.full((slots, 4), np.nan)
    for k in range(slots):
        u = active_rsu[k]
        if u >= 0:
            for j in range(4):
                pose[k, j] = rsu_pose[u, j]
    perceive_kernel(pos, length, width, yaw, height, active, center, cos_yaw, sin_yaw, blen, bwid, bh, z0, half_diag,
                    ego_z, ego_r2, ego_range, pose, rsu_r2, rsu_range, half_fov, levels, pattern, shrink, lo, hi,
                    ego_vis, rsu_vis)
    return active_rsu, ego_vis, rsu_vis


@_njit
def route_monitor_kernel(route_points, progress, ex, ey, points, pid, owner, offset, n_points, gs, base, heading,
                         length, x0, y0, cell, nx, ny, cell_start, order):  # pragma: no cover
    """The geometric part of ``infractions.EventMonitor.update``: the new route progress (the
    furthest route point within 3 m among the next 40), the distance to the route around it, and
    the nearest drivable lane (``project`` over ``pid``, its nearest vertex found on the
    ``jit_grid.point_grid`` of ``pid``) with its heading there.

    Returns:
        ``(progress, deviation, lane, s, dist, heading)``.
    """
    n = route_points.shape[0]
    hi = min(progress + 40, n)
    last = -1
    for k in range(progress, hi):
        dx = route_points[k, 0] - ex
        dy = route_points[k, 1] - ey
        if np.sqrt(dx * dx + dy * dy) < 3.0:
            last = k - progress
    if last >= 0:
        progress += last
    dev = np.inf
    for k in range(max(progress - 20, 0), min(progress + 40, n)):
        dx = route_points[k, 0] - ex
        dy = route_points[k, 1] - ey
        d = np.sqrt(dx * dx + dy * dy)
        if d < dev:
            dev = d
    lane, s, dist = project_grid_kernel(ex, ey, points, pid, owner, offset, n_points, gs, base, x0, y0, cell, nx, ny,
                                        cell_start, order)
    one, at = np.full(1, lane, np.int64), np.full(1, s)
    _, h = pose_at_kernel(one, at, points, heading, offset, n_points, gs, base, length)
    return progress, dev, lane, s, dist, h[0]


@_njit
def v2x_rows_kernel(out, payload, n_rows, x, y, yaw, ex, ey, eyaw):  # pragma: no cover
    """``observations._v2x``'s rows, written into ``out (m, 11)`` float32: the first ``n_rows``
    objects of a received payload, moved from the RSU frame at ``(x, y, yaw)`` to the ego frame
    (:func:`_rsu_row_to_ego`) as observation rows (present flag, 9 fields, visible
    fraction 1); zeros after them."""
    m = out.shape[0]
    c, s = np.cos(yaw), np.sin(yaw)
    ce, se = np.cos(eyaw), np.sin(eyaw)
    cr, sr = np.cos(yaw - eyaw), np.sin(yaw - eyaw)
    rows = min(n_rows, m)
    for k in range(rows):
        _rsu_row_to_ego(out, k, 1, payload, k * 10, x, y, yaw, ex, ey, eyaw, c, s, ce, se, cr, sr)
        out[k, 0] = 1.0
        out[k, 10] = 1.0
    out[rows:] = 0.0


@_njit
def visible_objects_kernel(out, vis, threshold, pos, yaw, speed, kind, length, width, height, actor_id, ox, oy,
                           oyaw):  # pragma: no cover
    """``ego_observation``'s ``objects``, written into ``out (m, 11)`` float32: the actors with
    ``vis >= threshold`` as :func:`object_rows_kernel` rows (the nearest ``m``), each with its
    present flag and visible fraction (``vis`` at its track id, read back from the float32 row as
    ``observations._rows`` does); zeros after them."""
    m = out.shape[0]
    idx = np.flatnonzero(vis >= threshold)
    c, s = np.cos(oyaw), np.sin(oyaw)
    lx, ly, order = _frame_order(idx, pos, ox, oy, c, s)
    rows = min(idx.shape[0], m)
    for r in range(rows):
        k = order[r]
        _object_row(out, r, 1, idx[k], lx[k], ly[k], yaw, speed, kind, length, width, height, actor_id, oyaw, c, s)
        out[r, 0] = 1.0
        out[r, 10] = vis[np.int64(out[r, 10])]
    out[rows:] = 0.0


@_njit
def seen_rows_kernel(vis, threshold, pos, yaw, speed, kind, length, width, height, actor_id, ox, oy,
                     oyaw):  # pragma: no cover
    """``world.World.rsu_objects``: the actors with ``vis >= threshold`` as
    :func:`object_rows_kernel` rows in the frame at ``(ox, oy, oyaw)``, sorted by distance."""
    idx = np.flatnonzero(vis >= threshold)
    if idx.shape[0] == 0:
        return np.zeros((0, 10), np.float32)
    return object_rows_kernel(idx, pos, yaw, speed, kind, length, width, height, actor_id, ox, oy, oyaw)


@_njit
def route_window_kernel(out, points, commands, k0, step, ex, ey, eyaw):  # pragma: no cover
    """``observations.ego_observation``'s route, written into ``out (count, 3)`` float32: ``count``
    route points every ``step`` from ``k0`` (clamped to the last point) in the ego frame, with their
    commands."""
    c, s = np.cos(eyaw), np.sin(eyaw)
    last = points.shape[0] - 1
    for a in range(out.shape[0]):
        k = min(k0 + a * step, last)
        d0 = points[k, 0] - ex
        d1 = points[k, 1] - ey
        out[a, 0] = c * d0 + s * d1
        out[a, 1] = -s * d0 + c * d1
        out[a, 2] = commands[k]
