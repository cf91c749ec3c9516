"""numba kernel of :meth:`.lanes.LaneMap.assign` (same float operations, same tie-breaking)."""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT, _njit

__all__ = ["HAVE_JIT", "DenseGrid", "assign_kernel", "window_project_kernel"]


class DenseGrid:
    """The hash grid ``{(cx, cy): point ids}`` as a dense ``(X, Y)`` table of slices of one flat array.

    Args:
        grid: cell -> point ids (order kept).
    """

    def __init__(self, grid: dict[tuple[int, int], np.ndarray]) -> None:
        keys = np.array(list(grid.keys()), np.int64).reshape(-1, 2)
        self.x0, self.y0 = (int(keys[:, 0].min()), int(keys[:, 1].min())) if len(keys) else (0, 0)
        nx = int(keys[:, 0].max()) - self.x0 + 1 if len(keys) else 1
        ny = int(keys[:, 1].max()) - self.y0 + 1 if len(keys) else 1
        self.start = np.zeros((nx, ny), np.int64)
        self.count = np.zeros((nx, ny), np.int64)
        flat, at = [], 0
        for (a, b), ids in grid.items():
            self.start[a - self.x0, b - self.y0] = at
            self.count[a - self.x0, b - self.y0] = len(ids)
            flat.append(ids)
            at += len(ids)
        self.flat = np.concatenate(flat).astype(np.int64) if flat else np.zeros(0, np.int64)


@_njit
def assign_kernel(pos, cos_yaw, sin_yaw, cell_m, x0, y0, start, count, flat, px, py, pc, ps, owner, gs, base,
                  length, max_dist, cos_max_dyaw):  # pragma: no cover
    """``LaneMap.assign`` for ``K`` objects; returns ``(lane (K, 2), s (K, 2), lat (K, 2))``."""
    k = pos.shape[0]
    lane = np.full((k, 2), -1, np.int64)
    s_out = np.zeros((k, 2))
    lat_out = np.zeros((k, 2))
    nx, ny = start.shape
    for q in range(k):
        cx = np.int64(np.floor(pos[q, 0] / cell_m)) - x0
        cy = np.int64(np.floor(pos[q, 1] / cell_m)) - y0
        if cx < 0 or cy < 0 or cx >= nx or cy >= ny or count[cx, cy] == 0:
            continue
        a0, n = start[cx, cy], count[cx, cy]
        cost = np.empty(n)
        along = np.empty(n)
        lat = np.empty(n)
        for e in range(n):
            p = flat[a0 + e]
            dx = pos[q, 0] - px[p]
            dy = pos[q, 1] - py[p]
            c, s = pc[p], ps[p]
            al = c * dx + s * dy
            la = c * dy - s * dx
            cos_d = c * cos_yaw[q] + s * sin_yaw[q]
            along[e], lat[e] = al, la
            if abs(la) < max_dist and abs(al) < 2.5 and cos_d > cos_max_dyaw:
                cost[e] = abs(la) + 0.3 * abs(al) + 6.0 * (1.0 - cos_d)
            else:
                cost[e] = np.inf
        best_cost = np.inf
        lid0 = -1
        for slot in range(2):
            j = 0
            cj = cost[0]
            for e in range(1, n):
                if cost[e] < cj:
                    cj, j = cost[e], e
            ok = cj < np.inf
            if slot == 1:
                ok = ok and cj < best_cost + 1.0
            p = flat[a0 + j]
            lid = owner[p]
            if ok:
                lane[q, slot] = lid
                s_out[q, slot] = min(max(gs[p] - base[lid] + along[j], 0.0), length[lid])
                lat_out[q, slot] = lat[j]
            if slot == 0:
                best_cost = cj
                lid0 = lid
                for e in range(n):
                    if owner[flat[a0 + e]] == lid0:
                        cost[e] = np.inf
    return lane, s_out, lat_out


@_njit
def window_project_kernel(pts, dirn, has_dir, xy, st, cos, sin, offset, step):  # pragma: no cover
    """:meth:`.route_track.PathWindow.project` (nearest subsampled path point, then the frame there).

    Returns:
        ``(st (N,), lat (N,), off (N,), cos_rel (N,), sin_rel (N,))``.
    """
    n = pts.shape[0]
    m = (st.shape[0] + step - 1) // step
    ox = np.empty(m)
    oy = np.empty(m)
    for q in range(m):
        k = q * step
        ox[q] = xy[k, 0] - offset[k] * -sin[k]
        oy[q] = xy[k, 1] - offset[k] * cos[k]
    o_st, o_lat, o_off = np.empty(n), np.empty(n), np.empty(n)
    o_cr, o_sr = np.zeros(n), np.zeros(n)
    for i in range(n):
        best = np.inf
        j = 0
        for q in range(m):
            dx = pts[i, 0] - ox[q]
            dy = pts[i, 1] - oy[q]
            d2 = dx * dx + dy * dy
            if d2 < best:
                best, j = d2, q
        ex = pts[i, 0] - ox[j]
        ey = pts[i, 1] - oy[j]
        k = j * step
        c, s = cos[k], sin[k]
        o_st[i] = st[k] + c * ex + s * ey
        o_lat[i] = c * ey - s * ex
        o_off[i] = offset[k]
        if has_dir:
            o_cr[i] = c * dirn[i, 0] + s * dirn[i, 1]
            o_sr[i] = c * dirn[i, 1] - s * dirn[i, 0]
    return o_st, o_lat, o_off, o_cr, o_sr
