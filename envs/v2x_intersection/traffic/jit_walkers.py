"""numba kernels for pedestrians (``pedestrians.step_walkers``): walking a sidewalk polyline,
crossing on a straight segment, and the random choices at a sidewalk's end and for jaywalking,
drawn from the world's generator in the NumPy path's order (:mod:`.jit_rng`).
"""

from __future__ import annotations

import numpy as np

from ..core.actors import WALKER as _WALKER
from ..core.jit import _njit, _np_max, _np_min, pose_at_kernel, project_kernel
from ..core.jit_rng import integers, next_double

_SIGNS = (-1.0, 1.0)


@_njit
def crossing_kernel(crossing, pos, yaw, speed, cross_from, cross_to, scenario, ego_ok, ego_x, ego_y, ego_yaw,
                    ego_hl, ego_hw, lookahead, dt):  # pragma: no cover
    """Walkers ``crossing`` move along their crossing segment (``pedestrians.step_walkers``); a
    background walker waits while the point ``lookahead`` m ahead of it is inside the ego's box
    (half extents ``ego_hl``/``ego_hw``, margin included; ``ego_ok``: the ego is a vehicle).
    In place on ``pos``, ``yaw`` and ``speed`` (scenario walkers stop at the end).

    Returns:
        ``(M,)`` bool: background walkers that reached the end of their crossing.
    """
    m = crossing.shape[0]
    done = np.zeros(m, np.bool_)
    c, s = np.cos(ego_yaw), np.sin(ego_yaw)
    for k in range(m):
        i = crossing[k]
        g0 = cross_to[i, 0] - cross_from[i, 0]
        g1 = cross_to[i, 1] - cross_from[i, 1]
        l0 = cross_to[i, 0] - pos[i, 0]
        l1 = cross_to[i, 1] - pos[i, 1]
        dist = np.sqrt(l0 * l0 + l1 * l1)
        norm = _np_max(np.sqrt(g0 * g0 + g1 * g1), 1e-9)
        u0 = g0 / norm
        u1 = g1 / norm
        blocked = False
        if ego_ok and scenario[i] < 0:
            d0 = (pos[i, 0] + u0 * lookahead) - ego_x
            d1 = (pos[i, 1] + u1 * lookahead) - ego_y
            blocked = abs(c * d0 + s * d1) < ego_hl and abs(-s * d0 + c * d1) < ego_hw
        step = 0.0 if blocked else speed[i] * dt
        move = _np_min(step, dist)
        pos[i, 0] += u0 * move
        pos[i, 1] += u1 * move
        yaw[i] = np.arctan2(u1, u0)
        if dist <= step:
            if scenario[i] < 0:
                done[k] = True
            else:
                speed[i] = 0.0
    return done


@_njit
def walking_kernel(walking, path, path_s, path_dir, speed, lat, pos, yaw, dt, points, heading, offset, n_points, gs,
                   base, length):  # pragma: no cover
    """Walkers ``walking`` advance along their sidewalk polyline (``pedestrians.step_walkers``),
    in place on ``path_s``, ``pos`` and ``yaw``.

    Returns:
        ``(M,)`` bool: the walker reached an end of its sidewalk (its arc length was clipped).
    """
    m = walking.shape[0]
    at_end = np.zeros(m, np.bool_)
    sw = np.empty(m, np.int64)
    s = np.empty(m)
    for k in range(m):
        i = walking[k]
        sw[k] = path[i]
        v = path_s[i] + path_dir[i] * speed[i] * dt
        top = length[sw[k]]
        at_end[k] = v < 0.0 or v > top
        v = v if (v > 0.0 or v != v) else 0.0  # np.clip
        v = v if (v < top or v != v) else top
        s[k] = v
        path_s[i] = v
    p, h = pose_at_kernel(sw, s, points, heading, offset, n_points, gs, base, length)
    for k in range(m):
        i = walking[k]
        pos[i, 0] = p[k, 0] + lat[i] * -np.sin(h[k])
        pos[i, 1] = p[k, 1] + lat[i] * np.cos(h[k])
        yaw[i] = h[k] if path_dir[i] > 0 else h[k] + np.pi
    return at_end


@_njit
def walkers_kernel(active, hold, behaviour, path, path_s, path_dir, speed, lat, pos, yaw, cross_from, cross_to,
                   scenario, ego_ok, ego_x, ego_y, ego_yaw, ego_hl, ego_hw, lookahead, dt, points, heading, offset,
                   n_points, gs, base, length):  # pragma: no cover
    """The deterministic part of ``pedestrians.step_walkers`` in one call: pick the free walkers,
    move the crossing ones (:func:`crossing_kernel`) and the walking ones
    (:func:`walking_kernel`).

    Returns:
        ``(walking rows, crossing rows that finished their crossing, at_end (len(walking),))``.
    """
    n = active.shape[0]
    walking = np.empty(n, np.int64)
    crossing = np.empty(n, np.int64)
    nw = nc = 0
    for i in range(n):
        if active[i] and not hold[i] and behaviour[i] == _WALKER:
            if path[i] >= 0:
                walking[nw] = i
                nw += 1
            else:
                crossing[nc] = i
                nc += 1
    walking, crossing = walking[:nw], crossing[:nc]
    done = crossing[crossing_kernel(crossing, pos, yaw, speed, cross_from, cross_to, scenario, ego_ok, ego_x, ego_y,
                                    ego_yaw, ego_hl, ego_hw, lookahead, dt)]
    at_end = walking_kernel(walking, path, path_s, path_dir, speed, lat, pos, yaw, dt, points, heading, offset,
                            n_points, gs, base, length)
    return walking, done, at_end


@_njit
def _start_crossing(i, ax, ay, bx, by, path, cross_from, cross_to):  # pragma: no cover
    """``pedestrians._start_crossing``: walker ``i`` crosses from ``(ax, ay)`` to ``(bx, by)``."""
    path[i] = -1
    cross_from[i, 0], cross_from[i, 1] = ax, ay
    cross_to[i, 0], cross_to[i, 1] = bx, by


@_njit
def walkers_tick_kernel(words, buf, active, hold, behaviour, path, path_s, path_dir, speed, lat, pos, yaw,
                        cross_from, cross_to, scenario, ego_ok, ego_x, ego_y, ego_yaw, ego_hl, ego_hw, lookahead, dt,
                        jaywalk_p, crossings, opposite, points, heading, offset, n_points, gs, base, length,
                        owner):  # pragma: no cover
    """``pedestrians.step_walkers`` in one call, in place on the table's columns: the movement
    (:func:`walkers_kernel`), then, drawing from ``words``/``buf`` in the NumPy path's order,
    finished crossings back onto the nearest sidewalk with a random direction, sidewalk ends
    (cross at a crosswalk within 6 m with probability 0.7, else turn around) and jaywalking
    (probability ``jaywalk_p`` per walker and tick, over to the ``opposite`` sidewalk).

    ``crossings``: ``(C, 2, 2)`` crosswalk segments (``SidewalkNetwork.crossings``).
    """
    walking, done, at_end = walkers_kernel(
        active, hold, behaviour, path, path_s, path_dir, speed, lat, pos, yaw, cross_from, cross_to, scenario, ego_ok,
        ego_x, ego_y, ego_yaw, ego_hl, ego_hw, lookahead, dt, points, heading, offset, n_points, gs, base, length)
    nd = done.shape[0]
    if nd:  # pedestrians._back_on_sidewalk
        xy = np.empty((nd, 2))
        for k in range(nd):
            xy[k, 0], xy[k, 1] = pos[done[k], 0], pos[done[k], 1]
        sw, s, _ = project_kernel(xy, points, np.arange(points.shape[0]), owner, offset, n_points, gs, base)
        p, h = pose_at_kernel(sw, s, points, heading, offset, n_points, gs, base, length)
        for k in range(nd):
            i = done[k]
            path[i], path_s[i] = sw[k], s[k]
            # ``(d * n).sum(-1)``: NumPy's reduction starts from +0.0 (a signed zero matters here)
            v = 0.0 + (xy[k, 0] - p[k, 0]) * -np.sin(h[k])
            v += (xy[k, 1] - p[k, 1]) * np.cos(h[k])
            lat[i] = _np_min(_np_max(v, -1.2), 1.2)
        for k in range(nd):
            path_dir[done[k]] = _SIGNS[integers(words, buf, 2)]
    nw = walking.shape[0]
    if nw == 0:
        return
    nc = crossings.shape[0]
    for k in range(nw):  # pedestrians._ends_and_jaywalk: sidewalk ends
        if not at_end[k]:
            continue
        i = walking[k]
        x, y = pos[i, 0], pos[i, 1]
        c = -1
        if nc:  # SidewalkNetwork.crossing_near (6 m)
            best = np.inf
            for q in range(nc):
                da = np.sqrt((crossings[q, 0, 0] - x) ** 2 + (crossings[q, 0, 1] - y) ** 2)
                db = np.sqrt((crossings[q, 1, 0] - x) ** 2 + (crossings[q, 1, 1] - y) ** 2)
                d = _np_min(da, db)
                if d < best:
                    best = d
                    c = q
            if not best < 6.0:
                c = -1
        if c >= 0 and next_double(words) < 0.7:
            ax, ay = crossings[c, 0, 0], crossings[c, 0, 1]
            bx, by = crossings[c, 1, 0], crossings[c, 1, 1]
            if np.sqrt((ax - x) ** 2 + (ay - y) ** 2) > np.sqrt((bx - x) ** 2 + (by - y) ** 2):
                bx, by = ax, ay
            _start_crossing(i, x, y, bx, by, path, cross_from, cross_to)
        else:
            path_dir[i] = -path_dir[i]
    jay = np.empty(nw, np.bool_)
    for k in range(nw):
        jay[k] = next_double(words) < jaywalk_p and not at_end[k]
    for k in range(nw):  # jaywalking: straight over the road to the opposite sidewalk
        if not jay[k]:
            continue
        i = walking[k]
        opp = opposite[path[i]]
        if opp < 0:
            continue
        xy = np.empty((1, 2))
        xy[0, 0], xy[0, 1] = pos[i, 0], pos[i, 1]
        pid = np.arange(offset[opp], offset[opp] + n_points[opp])
        _, s_o, _ = project_kernel(xy, points, pid, owner, offset, n_points, gs, base)
        target, _ = pose_at_kernel(np.full(1, opp, np.int64), s_o, points, heading, offset, n_points, gs, base,
                                   length)
        _start_crossing(i, xy[0, 0], xy[0, 1], target[0, 0], target[0, 1], path, cross_from, cross_to)
