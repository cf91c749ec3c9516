"""The ego's route as the planner sees it: localization, a path window and the path frame.

:class:`RouteTrack` precomputes, once per route, the speed limit of every route point (lane limit
and a curvature limit) and the junction entries along the route (stop line, connector, control);
every tick it localizes the ego on the route and cuts a :class:`PathWindow` ahead of it, in which
objects are expressed as (station along the path, lateral offset).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from v2xbench.envs.v2x_intersection.core.geometry import stack_xy
from v2xbench.envs.v2x_intersection.town.model import (
    CHANGE_LANE_LEFT,
    CHANGE_LANE_RIGHT,
    CONNECTOR,
    Town,
)
from v2xbench.envs.v2x_intersection.town.routes import Route
from v2xbench.envs.v2x_intersection.traffic.vehicles import STOP_LINE_SETBACK

from .assign_jit import HAVE_JIT, window_project_kernel

MAX_LAT_ACCEL = 2.2  # m/s^2 in curves
SUBSAMPLE = 2  # path points used for projection (every 2 m)


@dataclass
class JunctionEntry:
    """A junction the route enters from an incoming lane through a connector.

    Attributes:
        lane: incoming lane id. junction: junction id. connector: connector lane id (-1 when the
            route ends before the junction).
        s_line: route arc length of the stop line (m; lane end minus the setback).
        s_enter, s_exit: route arc lengths of the connector's start and end (m).
        stop_sign: the incoming lane has a stop sign. signal: it has a traffic light.
        turn: the connector's manoeuvre code.
    """

    lane: int
    junction: int
    connector: int
    s_line: float
    s_enter: float
    s_exit: float
    stop_sign: bool
    signal: bool
    turn: int


MERGE_APPROACH_M = 15.0  # m before a lane-change segment from which the ego checks for a gap


class RouteTrack:
    """Route geometry for the planner (see module docstring)."""

    def __init__(self, town: Town, route: Route) -> None:
        self.town, self.route = town, route
        ix = town.index
        self.points = route.points
        self.s = route.s
        self.cos, self.sin = np.cos(route.headings), np.sin(route.headings)
        n = len(route.points)
        k = np.arange(n)
        a, b = np.clip(k - 3, 0, n - 1), np.clip(k + 3, 0, n - 1)
        dh = np.abs((route.headings[b] - route.headings[a] + np.pi) % (2 * np.pi) - np.pi)
        kappa = dh / np.maximum(self.s[b] - self.s[a], 1e-3)
        self.vlim = np.minimum(
            ix.speed_limit[route.lane_ids], np.sqrt(MAX_LAT_ACCEL / np.maximum(kappa, 1e-4))
        )
        self.entries = self._entries(town, route)
        self.merges = self._merges(route)
        self.idx = 0

    @staticmethod
    def _merges(route: Route) -> list[tuple[float, float]]:
        """``(s_start, s_end)`` route arc lengths (m) of every lane-change segment (a run of
        ``change_lane_*`` commands: the path moves sideways into another lane or out of a slot)."""
        lc = np.isin(route.commands, (CHANGE_LANE_LEFT, CHANGE_LANE_RIGHT)).astype(np.int8)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], lc, [0]])))
        return [(float(route.s[a]), float(route.s[min(b, len(route.s) - 1)])) for a, b in edges.reshape(-1, 2)]

    def merging(self, s_ego: float, commit: float = 0.35) -> float | None:
        """If the ego is in (or just before) a lane-change segment and has covered less than
        ``commit`` of it, the distance (m, >= 0) to the segment start, where it waits for a gap;
        None otherwise."""
        for a, b in self.merges:
            if a - MERGE_APPROACH_M <= s_ego < a + commit * (b - a):
                return max(a - s_ego, 0.0)
        return None

    @staticmethod
    def _entries(town: Town, route: Route) -> list[JunctionEntry]:
        ix = town.index
        lanes = route.lane_ids
        change = np.flatnonzero(lanes[1:] != lanes[:-1]) + 1
        starts = np.concatenate([[0], change])
        ends = np.concatenate([change, [len(lanes)]])
        out = []
        for r in range(len(starts)):
            lane = int(lanes[starts[r]])
            j = int(ix.junction_ahead[lane])
            last = r == len(starts) - 1
            nxt = -1 if last else int(lanes[starts[r + 1]])
            if j < 0 or not (
                last or (ix.kind[nxt] == CONNECTOR and nxt in town.lanes[lane].successors)
            ):
                continue
            if last:  # the route ends on a lane with a stop line: obey it, nothing to cross
                if not ix.stop_at_end[lane]:
                    continue
                _, s_lane, _ = ix.project(route.points[-1:], np.array([lane]))
                s_enter = float(route.s[-1] + ix.length[lane] - s_lane[0])
                s_exit = s_enter
            else:
                s_enter = float(route.s[starts[r + 1]])
                s_exit = float(route.s[min(ends[r + 1], len(lanes) - 1)])
            stops = lane in town.junctions[j].stop_lanes
            out.append(
                JunctionEntry(
                    lane=lane,
                    junction=j,
                    connector=nxt,
                    s_line=s_enter - STOP_LINE_SETBACK,
                    s_enter=s_enter,
                    s_exit=s_exit,
                    stop_sign=stops,
                    signal=bool(ix.stop_at_end[lane]) and not stops,
                    turn=int(ix.turn[nxt]) if nxt >= 0 else -1,
                )
            )
        return out

    def localize(self, pos: np.ndarray) -> tuple[int, float]:
        """Nearest route index to ``pos`` (searched near the last one) and the arc length (m)."""
        n = len(self.points)
        lo, hi = max(self.idx - 10, 0), min(self.idx + 60, n)
        d = self.points[lo:hi] - pos
        j = lo + int((d[:, 0] ** 2 + d[:, 1] ** 2).argmin())
        self.idx = j
        dx, dy = pos[0] - self.points[j, 0], pos[1] - self.points[j, 1]
        return j, float(self.s[j] + self.cos[j] * dx + self.sin[j] * dy)

    def window(self, j: int, s_ego: float, ahead_m: float, offsets=None) -> PathWindow:
        """The path from a few metres behind the ego to ``ahead_m`` ahead (stations relative to
        the ego); ``offsets(st) -> (P,)`` shifts it laterally (m, left positive)."""
        n = len(self.points)
        a = max(j - 8, 0)
        b = int(self.s.searchsorted(s_ego + ahead_m))
        b = min(max(b, j + 2), n)
        st = self.s[a:b] - s_ego
        c, s = self.cos[a:b], self.sin[a:b]
        xy = self.points[a:b]
        off = np.zeros(len(st)) if offsets is None else offsets(st)
        if (off != 0.0).any():
            xy = xy + off[:, None] * stack_xy(-s, c)
        return PathWindow(
            xy=xy,
            st=st,
            cos=c,
            sin=s,
            offset=off,
            vlim=self.vlim[a:b],
            lanes=self.route.lane_ids[a:b],
        )


@dataclass
class PathWindow:
    """Route points ahead of the ego (``P`` of them, 1 m apart).

    Attributes:
        xy: ``(P, 2)`` path points after the lateral offset (m). st: ``(P,)`` stations relative to
        the ego (m). cos, sin: ``(P,)`` route heading. offset: ``(P,)`` lateral offset (m).
        vlim: ``(P,)`` speed limit (m/s). lanes: ``(P,)`` route lane ids.
    """

    xy: np.ndarray
    st: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    offset: np.ndarray
    vlim: np.ndarray
    lanes: np.ndarray

    def project(self, pts: np.ndarray, dirn: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        """Express points ``(N, 2)`` in the path frame (relative to the *unshifted* route).

        Args:
            pts: positions (m).
            dirn: optional ``(N, 2)`` unit headings of the objects.

        Returns:
            ``(st, lat, off, cos_rel, sin_rel)``: station (m), lateral offset from the route (m),
            the path's lateral offset there (m), and the heading of each object relative to the
            path (cos, sin; zeros when ``dirn`` is None).
        """
        if HAVE_JIT and len(self.st) and len(pts):
            has = dirn is not None
            return window_project_kernel(
                np.asarray(pts, np.float64), np.asarray(dirn if has else pts, np.float64), has, self.xy, self.st,
                self.cos, self.sin, self.offset, SUBSAMPLE)
        sub = slice(0, len(self.st), SUBSAMPLE)
        ox, oy = (
            self.xy[sub, 0] - self.offset[sub] * -self.sin[sub],
            self.xy[sub, 1] - self.offset[sub] * self.cos[sub],
        )
        dx = pts[:, 0:1] - ox[None]
        dy = pts[:, 1:2] - oy[None]
        j = (dx * dx + dy * dy).argmin(axis=1)
        r = np.arange(len(pts))
        ex, ey = dx[r, j], dy[r, j]
        c, s = self.cos[sub][j], self.sin[sub][j]
        st = self.st[sub][j] + c * ex + s * ey
        lat = c * ey - s * ex
        if dirn is None:
            z = np.zeros(len(pts))
            return st, lat, self.offset[sub][j], z, z
        return (
            st,
            lat,
            self.offset[sub][j],
            c * dirn[:, 0] + s * dirn[:, 1],
            c * dirn[:, 1] - s * dirn[:, 0],
        )
