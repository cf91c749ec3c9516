"""numba kernels for a tick's perception side: which RSUs serve the ego (``rsu.select_active``)
and the object lists of what an observer sees, in its frame (``world.object_rows``, used by the
ego observation and the RSU's message).

Like :mod:`.jit`, the kernels repeat the NumPy path's float operations in the same order and
dtype, so both paths give bit-identical results (``tests/test_jit.py``).
"""

from __future__ import annotations

import numpy as np

from .jit import _njit


@_njit
def object_rows_kernel(idx, pos, yaw, speed, kind, length, width, height, actor_id, ox, oy, oyaw):  # pragma: no cover
    """``world.object_rows``: ``(K, 10)`` float32 rows of ``channel.OBJECT_FIELDS`` for actors
    ``idx`` in the frame at ``(ox, oy)`` / ``oyaw``, sorted by distance."""
    m = idx.shape[0]
    c, s = np.cos(oyaw), np.sin(oyaw)
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
    order = np.argsort(dist)
    out = np.empty((m, 10), np.float32)
    two_pi = 2 * np.pi
    for r in range(m):
        k = order[r]
        i = idx[k]
        vx = speed[i] * np.cos(yaw[i])
        vy = speed[i] * np.sin(yaw[i])
        out[r, 0] = np.float64(kind[i])
        out[r, 1] = lx[k]
        out[r, 2] = ly[k]
        out[r, 3] = (yaw[i] - oyaw + np.pi) % two_pi - np.pi
        out[r, 4] = length[i]
        out[r, 5] = width[i]
        out[r, 6] = height[i]
        out[r, 7] = c * vx + s * vy
        out[r, 8] = -s * vx + c * vy
        out[r, 9] = np.float64(actor_id[i])
    return out


@_njit
def select_active_kernel(pose, trigger, ex, ey, eyaw, max_range, slots, preference, max_angle):  # pragma: no cover
    """``rsu.select_active``: the ``slots`` units with the smallest key (distance, minus
    ``preference`` for scenario units) among those ahead, facing the ego and in range; -1 pads;
    slot 0 falls back to the nearest unit when none qualifies.

    Ties between equal keys go to the lower index.
    """
    n = pose.shape[0]
    c, s = np.cos(eyaw), np.sin(eyaw)
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
        key[u] = dist[u] - preference * trigger[u] if (ahead and facing and dist[u] < max_range) else np.inf
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
def rsu_to_ego_kernel(rows, x, y, yaw, ex, ey, eyaw):  # pragma: no cover
    """Object rows received from the RSU at ``(x, y, yaw)`` re-expressed in the ego frame
    (``observations._v2x``): positions, headings and velocities; a new float32 array."""
    m = rows.shape[0]
    out = rows.copy()
    c, s = np.cos(yaw), np.sin(yaw)
    ce, se = np.cos(eyaw), np.sin(eyaw)
    cr, sr = np.cos(yaw - eyaw), np.sin(yaw - eyaw)
    two_pi = 2.0 * np.pi
    for k in range(m):
        p0 = np.float64(rows[k, 1])
        p1 = np.float64(rows[k, 2])
        d0 = (c * p0 - s * p1 + x) - ex
        d1 = (s * p0 + c * p1 + y) - ey
        out[k, 1] = ce * d0 + se * d1
        out[k, 2] = -se * d0 + ce * d1
        out[k, 3] = (np.float64(rows[k, 3]) + yaw - eyaw + np.pi) % two_pi - np.pi
        vx = np.float64(rows[k, 7])
        vy = np.float64(rows[k, 8])
        out[k, 7] = cr * vx - sr * vy
        out[k, 8] = sr * vx + cr * vy
    return out
