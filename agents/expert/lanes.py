"""Per-town lookup tables for the planner: lane assignment, lane branches, connector conflicts.

:class:`LaneMap` is built once per town (cached by name) and answers, vectorized:

- *which lane is this object on?* (:meth:`LaneMap.assign`): a hash grid of lane centre points,
  matched by distance and heading;
- *where can a lane follower go?* (branches): every lane's possible continuations through the lane
  graph over ``BRANCH_AHEAD_M`` metres, resampled every metre into one flat array, with the
  first stop line on each branch;
- *which junction connectors cross?* (:meth:`LaneMap.conflicts`): for a connector, the other
  connectors of its junction that come within ``CONFLICT_CLEARANCE_M`` of it, and where.
"""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.core.geometry import polyline_lengths
from v2xbench.envs.v2x_intersection.town.model import CONNECTOR, PARKING, Town
from v2xbench.envs.v2x_intersection.traffic.vehicles import STOP_LINE_SETBACK

from .assign_jit import HAVE_JIT, DenseGrid, assign_kernel

CELL_M = 4.0  # m, hash grid cell
ASSIGN_MAX_DIST = 2.8  # m, farthest an object may be from a lane centre to be on it
ASSIGN_MAX_DYAW = 0.7  # rad, largest heading difference to a lane
BRANCH_AHEAD_M = 90.0  # m of continuation stored beyond each lane
MAX_BRANCHES = 8
CONFLICT_CLEARANCE_M = 2.5  # m, connectors whose centre lines come closer than this conflict


class LaneMap:
    """Lookup tables of one town (see module docstring).

    Attributes:
        town: the town.
        br_start: ``(B,)`` offset of each branch in the flat arrays; br_n: ``(B,)`` its points.
        br_pts: ``(N, 2)`` flat branch points, 1 m apart; br_head: ``(N,)`` their headings.
        br_stop_s: ``(B,)`` branch arc length of the first stop line (inf: none).
        br_stop_lane: ``(B,)`` lane of that stop line (-1: none).
        br_stop_sign: ``(B,)`` that line has a stop sign.
        br_lanes: per branch, ``{lane: arc length where it starts on the branch}``.
        lane_branches: ``(L, MAX_BRANCHES)`` branch ids per lane (-1 padded).
        br_cos, br_sin: ``(N,)`` heading components of the flat branch points.
    """

    def __init__(self, town: Town) -> None:
        self.town = town
        ix = town.index
        self._build_grid(ix)
        self._build_branches(town)
        self._conflicts: dict[int, list[tuple[int, float, float]]] = {}
        self._clear: dict[tuple[int, int], float] = {}

    # ------------------------------------------------------------------ assignment
    def _build_grid(self, ix) -> None:
        keep = ix.kind[ix.owner] != PARKING
        pid = np.flatnonzero(keep)
        cells = np.floor(ix.points[pid] / CELL_M).astype(np.int64)
        grid: dict[tuple[int, int], list[np.ndarray]] = {}
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                keys = cells + (dx, dy)
                order = np.lexsort((keys[:, 1], keys[:, 0]))
                k_sorted = keys[order]
                brk = np.flatnonzero(np.any(np.diff(k_sorted, axis=0) != 0, axis=1)) + 1
                for grp in np.split(order, brk):
                    key = (int(keys[grp[0], 0]), int(keys[grp[0], 1]))
                    grid.setdefault(key, []).append(pid[grp])
        self._grid = {k: np.concatenate(v) for k, v in grid.items()}
        self._px, self._py = ix.points[:, 0].copy(), ix.points[:, 1].copy()
        self._pc, self._ps = np.cos(ix.heading), np.sin(ix.heading)
        self._empty = np.zeros(0, np.int64)
        self._dense = DenseGrid(self._grid) if HAVE_JIT else None

    def assign(
        self, pos: np.ndarray, yaw: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Lane of each object (best match, and a second lane when ambiguous).

        Args:
            pos: ``(K, 2)`` positions (m). yaw: ``(K,)`` headings (rad).

        Returns:
            ``(lane (K, 2), s (K, 2), lat (K, 2), ok (K, 2))``: up to two candidate lanes per object
            with arc length and signed lateral offset (m, left positive); ``ok`` marks valid ones.
        """
        k = len(pos)
        lane = np.full((k, 2), -1, np.int64)
        s_out, lat_out = np.zeros((k, 2)), np.zeros((k, 2))
        if k == 0:
            return lane, s_out, lat_out, lane >= 0
        ix = self.town.index
        if self._dense is not None:
            g = self._dense
            lane, s_out, lat_out = assign_kernel(
                np.asarray(pos, np.float64), np.cos(yaw), np.sin(yaw), CELL_M, g.x0, g.y0, g.start, g.count,
                g.flat, self._px, self._py, self._pc, self._ps, ix.owner, ix.gs, ix.base, ix.length,
                ASSIGN_MAX_DIST, float(np.cos(ASSIGN_MAX_DYAW)))
            return lane, s_out, lat_out, lane >= 0
        keys = np.floor(pos / CELL_M).astype(np.int64)
        lists = [self._grid.get((int(a), int(b)), self._empty) for a, b in keys.tolist()]
        counts = np.array([len(x) for x in lists])
        m = int(counts.max())
        if m == 0:
            return lane, s_out, lat_out, lane >= 0
        flat = np.concatenate(lists)
        q = np.repeat(np.arange(k), counts)
        col = np.arange(len(flat)) - np.repeat(np.cumsum(counts) - counts, counts)
        pid = np.zeros((k, m), np.int64)
        present = np.zeros((k, m), bool)
        pid[q, col] = flat
        present[q, col] = True
        dx = pos[:, 0:1] - self._px[pid]
        dy = pos[:, 1:2] - self._py[pid]
        c, s = self._pc[pid], self._ps[pid]
        along = c * dx + s * dy
        lat = c * dy - s * dx
        cos_d = c * np.cos(yaw)[:, None] + s * np.sin(yaw)[:, None]
        valid = (
            present
            & (np.abs(lat) < ASSIGN_MAX_DIST)
            & (np.abs(along) < 2.5)
            & (cos_d > np.cos(ASSIGN_MAX_DYAW))
        )
        cost = np.where(valid, np.abs(lat) + 0.3 * np.abs(along) + 6.0 * (1.0 - cos_d), np.inf)
        owner = ix.owner[pid]
        rows = np.arange(k)
        best_cost = np.full(k, np.inf)
        for slot in range(2):
            j = np.argmin(cost, axis=1)
            cj = cost[rows, j]
            ok = np.isfinite(cj)
            if slot == 1:
                ok &= cj < best_cost + 1.0
            lid = owner[rows, j]
            lane[ok, slot] = lid[ok]
            s_out[ok, slot] = np.clip(
                (ix.gs[pid[rows, j]] - ix.base[lid] + along[rows, j])[ok], 0.0, ix.length[lid[ok]]
            )
            lat_out[ok, slot] = lat[rows, j][ok]
            if slot == 0:
                best_cost = cj
                cost = np.where(owner == lid[:, None], np.inf, cost)
        return lane, s_out, lat_out, lane >= 0

    # ------------------------------------------------------------------ branches
    def _build_branches(self, town: Town) -> None:
        ix = town.index
        pts, heads, starts, ns, stop_s, stop_lane, lanes_of = [], [], [], [], [], [], []
        lane_br = np.full((len(town.lanes), MAX_BRANCHES), -1, np.int64)
        offset = 0
        for ln in town.lanes:
            if ln.kind == PARKING:
                continue
            seqs = self._sequences(town, ln.id)
            for b, seq in enumerate(seqs[:MAX_BRANCHES]):
                poly = np.concatenate(
                    [town.lanes[seq[0]].points] + [town.lanes[x].points[1:] for x in seq[1:]], 0
                )
                s = polyline_lengths(poly)
                keep = np.concatenate([[True], np.diff(s) > 1e-6])
                poly, s = poly[keep], s[keep]
                grid = np.arange(0.0, s[-1] + 1e-9, 1.0)
                p = np.stack([np.interp(grid, s, poly[:, 0]), np.interp(grid, s, poly[:, 1])], -1)
                d = np.diff(p, axis=0)
                hd = np.arctan2(d[:, 1], d[:, 0])
                hd = np.concatenate([hd, hd[-1:]]) if len(hd) else np.zeros(1)
                starts_on = {}
                acc, first_stop, first_lane = 0.0, np.inf, -1
                for x in seq:
                    starts_on.setdefault(x, acc)
                    acc += ix.length[x]
                    if first_lane < 0 and ix.stop_at_end[x]:
                        first_stop, first_lane = acc - STOP_LINE_SETBACK, x
                lane_br[ln.id, b] = len(starts)
                pts.append(p)
                heads.append(hd)
                starts.append(offset)
                ns.append(len(p))
                stop_s.append(first_stop)
                stop_lane.append(first_lane)
                lanes_of.append(starts_on)
                offset += len(p)
        self.br_pts = np.concatenate(pts, 0)
        self.br_head = np.concatenate(heads)
        self.br_cos, self.br_sin = np.cos(self.br_head), np.sin(self.br_head)
        self.br_start = np.array(starts, np.int64)
        self.br_n = np.array(ns, np.int64)
        self.br_stop_s = np.array(stop_s)
        self.br_stop_lane = np.array(stop_lane, np.int64)
        jn = ix.junction_ahead[np.maximum(self.br_stop_lane, 0)]
        self.br_stop_sign = np.array(
            [
                lane >= 0 and j >= 0 and lane in town.junctions[j].stop_lanes
                for lane, j in zip(stop_lane, jn)
            ],
            bool,
        )
        self.br_lanes = lanes_of
        self.lane_branches = lane_br

    @staticmethod
    def _sequences(town: Town, lane: int) -> list[list[int]]:
        ix = town.index
        out: list[list[int]] = []

        def walk(seq: list[int], ahead: float) -> None:
            last = town.lanes[seq[-1]]
            succ = [x for x in last.successors if ix.kind[x] != PARKING and x not in seq]
            if ahead >= BRANCH_AHEAD_M or not succ or len(seq) >= 6 or len(out) >= MAX_BRANCHES:
                out.append(seq)
                return
            for x in succ:
                walk(seq + [x], ahead + ix.length[x])

        walk([lane], 0.0)
        return out

    def branch_points(self, br: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions ``(..., 2)`` and unit directions ``(..., 2)`` at arc lengths ``sigma`` (m) on
        branches ``br`` (broadcast together); beyond the end the branch is extended straight."""
        n = self.br_n[br]
        start = self.br_start[br]
        f = np.clip(sigma, 0.0, None)
        i0 = np.minimum(np.floor(f).astype(np.int64), n - 1)
        i1 = np.minimum(i0 + 1, n - 1)
        w = np.clip(f - i0, 0.0, None)[..., None]
        p0, p1 = self.br_pts[start + i0], self.br_pts[start + i1]
        dirn = np.stack([self.br_cos[start + i0], self.br_sin[start + i0]], -1)
        beyond = (i1 == i0)[..., None]
        p = np.where(beyond, p0 + w * dirn, p0 + w * (p1 - p0))
        return p, dirn

    # ------------------------------------------------------------------ conflicts
    def conflicts(self, connector: int) -> list[tuple[int, float, float]]:
        """Connectors of the same junction crossing or merging with ``connector``.

        Returns:
            ``[(other, s_on_connector, s_on_other), ...]`` (m), excluding connectors that leave
            the same incoming lane (they diverge: followers, not crossers).
        """
        if connector in self._conflicts:
            return self._conflicts[connector]
        town, ix = self.town, self.town.index
        c = town.lanes[connector]
        out = []
        if c.kind == CONNECTOR and c.junction >= 0:
            sa = np.arange(0.0, ix.length[connector] + 1e-9, 0.5)
            pa, _ = ix.pose_at(np.full(len(sa), connector), sa)
            for other in town.junctions[c.junction].connectors:
                o = town.lanes[other]
                if other == connector or set(o.predecessors) & set(c.predecessors):
                    continue
                sb = np.arange(0.0, ix.length[other] + 1e-9, 0.5)
                pb, _ = ix.pose_at(np.full(len(sb), other), sb)
                d = np.linalg.norm(pa[:, None] - pb[None], axis=-1)
                hit = np.flatnonzero(d.min(1) < CONFLICT_CLEARANCE_M)
                if len(hit):
                    k = int(hit[0])
                    out.append((other, float(sa[k]), float(sb[int(np.argmin(d[k]))])))
        self._conflicts[connector] = out
        return out

    def clear_station(
        self, connector: int, other: int, half_length: float, half_width: float, margin: float = 0.6
    ) -> float:
        """Farthest centre station (m) on ``connector`` up to which a box of the given halves
        (m), centred on it and aligned with it, stays ``margin`` m clear of ``other``'s lane
        (its centre line widened by half its width); -inf if not even at the start."""
        key = (connector, other, round(half_length, 2), round(half_width, 2), round(margin, 2))
        if key in self._clear:
            return self._clear[key]
        ix = self.town.index
        sa = np.arange(0.0, ix.length[connector] + 1e-9, 0.5)
        pa, ha = ix.pose_at(np.full(len(sa), connector), sa)
        sb = np.arange(0.0, ix.length[other] + 1e-9, 0.5)
        pb, _ = ix.pose_at(np.full(len(sb), other), sb)
        c, s = np.cos(ha)[:, None], np.sin(ha)[:, None]
        lx = np.array([1, 1, 1, 0, -1, -1, -1, 0]) * half_length
        ly = np.array([1, 0, -1, -1, -1, 0, 1, 1]) * half_width
        px = pa[:, 0:1] + c * lx - s * ly
        py = pa[:, 1:2] + s * lx + c * ly
        d2 = (px[:, :, None] - pb[None, None, :, 0]) ** 2 + (
            py[:, :, None] - pb[None, None, :, 1]
        ) ** 2
        need = 0.5 * float(ix.width[other]) + margin
        bad = np.flatnonzero(np.sqrt(d2.min(axis=(1, 2))) < need)
        out = (
            -np.inf
            if len(bad) and bad[0] == 0
            else float(sa[bad[0] - 1])
            if len(bad)
            else float(sa[-1])
        )
        self._clear[key] = out
        return out


_MAPS: dict[int, LaneMap] = {}


def lane_map(town: Town) -> LaneMap:
    """The (cached) :class:`LaneMap` of ``town``."""
    key = id(town)
    m = _MAPS.get(key)
    if m is None or m.town is not town:
        m = LaneMap(town)
        if len(_MAPS) > 16:
            _MAPS.clear()
        _MAPS[key] = m
    return m
