"""Global route planning over the lane graph: dense route points and navigation commands.

A :class:`Route` is a lane sequence turned into points every ``ROUTE_STEP`` metres, each with a
heading, the lane it lies on and a navigation command (``town.model.COMMAND_NAMES``: follow lane,
left, right, straight at junctions; change lane left/right during lane changes).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from ..core.draws import pick
from ..core.geometry import polyline_lengths, resample_polyline
from ..core.validation import ShortfallWarning, warn_once
from .model import (
    CHANGE_LANE_LEFT,
    CHANGE_LANE_RIGHT,
    CONNECTOR,
    FOLLOW_LANE,
    PARKING,
    Town,
)

ROUTE_STEP = 1.0  # m between route points
LANE_CHANGE_COST = 30.0  # m-equivalent penalty in the planner
LANE_CHANGE_LENGTH = 25.0  # m over which a lane change blends


@dataclass
class Route:
    """A planned route.

    Attributes:
        town: town name.
        lanes: lane ids in driving order (neighbours mean a lane change).
        points: ``(P, 2)`` route points (m), ``ROUTE_STEP`` apart.
        headings: ``(P,)`` (rad).
        lane_ids: ``(P,)`` lane under each point (the target lane during a lane change).
        commands: ``(P,)`` navigation command codes.
        s: ``(P,)`` arc length from the start (m).
    """

    town: str
    lanes: list[int]
    points: np.ndarray
    headings: np.ndarray
    lane_ids: np.ndarray
    commands: np.ndarray
    s: np.ndarray

    @property
    def length(self) -> float:
        """Route length (m)."""
        return float(self.s[-1])


def _neighbours(town: Town, lane: int, lane_changes: bool = True) -> list[tuple[int, float, str]]:
    ln = town.lanes[lane]
    out = [(s, town.index.length[s], "succ") for s in ln.successors]
    if not lane_changes:
        return out
    for nb, tag in ((ln.left, "left"), (ln.right, "right")):
        if nb >= 0 and ln.length > LANE_CHANGE_LENGTH + 10:
            out.append((nb, 0.5 * town.index.length[nb] + LANE_CHANGE_COST, tag))
    return out


def shortest_lane_path(town: Town, start: int, goal: int, lane_changes: bool = True) -> list[int]:
    """Dijkstra over the lane graph (successors, and lane changes unless disabled); raises
    ``ValueError`` if ``goal`` is unreachable."""
    if start == goal:
        return [start]
    dist = {start: 0.0}
    prev: dict[int, int] = {}
    heap = [(0.0, start)]
    while heap:
        d, u = heapq.heappop(heap)
        if u == goal:
            break
        if d > dist.get(u, np.inf):
            continue
        for v, c, _ in _neighbours(town, u, lane_changes):
            nd = d + c
            if nd < dist.get(v, np.inf):
                dist[v], prev[v] = nd, u
                heapq.heappush(heap, (nd, v))
    if goal not in dist:
        raise ValueError(f"route: lane {goal} is not reachable from lane {start} in {town.name}")
    path = [goal]
    while path[-1] != start:
        path.append(prev[path[-1]])
    return path[::-1]


def _project_driving(town: Town, xy: np.ndarray) -> tuple[int, float, float]:
    cand = np.array([ln.id for ln in town.lanes if ln.kind != PARKING])
    lane, s, d = town.index.project(np.asarray(xy, float)[None], cand)
    return int(lane[0]), float(s[0]), float(d[0])


def plan_route(town: Town, waypoints: np.ndarray, max_snap: float = 10.0) -> Route:
    """Plan through ``waypoints (K >= 2, 2)`` (m); each is snapped to the nearest driving lane.

    Raises:
        ValueError: a waypoint is more than ``max_snap`` m from any lane, or unreachable.
    """
    wps = np.asarray(waypoints, dtype=np.float64)
    if wps.ndim != 2 or wps.shape[1] != 2 or len(wps) < 2:
        raise ValueError(f"route: waypoints must have shape (K>=2, 2), got {wps.shape}")
    snaps = []
    for k, w in enumerate(wps):
        lane, s, d = _project_driving(town, w)
        if d > max_snap:
            raise ValueError(f"route: waypoint {k} {w.tolist()} is {d:.1f} m from the nearest lane")
        snaps.append((lane, s))
    lanes = [snaps[0][0]]
    for (la, sa), (lb, sb) in zip(snaps[:-1], snaps[1:]):
        if la == lb and sb >= sa:
            continue
        lanes += shortest_lane_path(town, la, lb)[1:] if la != lb else _loop(town, la)
    return route_from_lanes(town, lanes, s_start=snaps[0][1], s_end=snaps[-1][1])


def _loop(town: Town, lane: int) -> list[int]:
    path = None
    for succ in town.lanes[lane].successors:
        try:
            p = shortest_lane_path(town, succ, lane)
        except ValueError:
            continue
        if path is None or len(p) < len(path):
            path = p
    if path is None:
        raise ValueError(f"route: cannot come back to lane {lane}")
    return path


def route_from_lanes(town: Town, lanes: list[int], s_start: float = 0.0, s_end: float | None = None) -> Route:
    """Dense route along a lane sequence, blending lane changes over ``LANE_CHANGE_LENGTH``."""
    chunks, lane_tags, cmd_tags = [], [], []
    i = 0
    while i < len(lanes):
        ln = town.lanes[lanes[i]]
        pts = ln.points
        s = lane_arc(town, ln.id)
        a = s_start if i == 0 else 0.0
        b = s_end if (i == len(lanes) - 1 and s_end is not None) else s[-1]
        nxt = lanes[i + 1] if i + 1 < len(lanes) else None
        if nxt is not None and nxt in (ln.left, ln.right):
            # lane change: drive the first part of this lane, then blend into the neighbour
            other = town.lanes[nxt].points
            so = lane_arc(town, nxt)
            mid = max(a, 0.5 * (s[-1] - LANE_CHANGE_LENGTH))
            t0 = np.arange(a, mid, ROUTE_STEP)
            seg0 = np.stack([np.interp(t0, s, pts[:, 0]), np.interp(t0, s, pts[:, 1])], -1)
            t1 = np.linspace(mid, min(mid + LANE_CHANGE_LENGTH, s[-1]), int(LANE_CHANGE_LENGTH / ROUTE_STEP))
            frac = t1 / s[-1]
            to = frac * so[-1]
            pa = np.stack([np.interp(t1, s, pts[:, 0]), np.interp(t1, s, pts[:, 1])], -1)
            pb = np.stack([np.interp(to, so, other[:, 0]), np.interp(to, so, other[:, 1])], -1)
            w = (0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, len(t1))))[:, None]
            seg1 = (1 - w) * pa + w * pb
            cmd = CHANGE_LANE_LEFT if nxt == ln.left else CHANGE_LANE_RIGHT
            chunks += [seg0, seg1]
            lane_tags += [np.full(len(seg0), ln.id), np.full(len(seg1), nxt)]
            cmd_tags += [np.full(len(seg0), FOLLOW_LANE), np.full(len(seg1), cmd)]
            s_start = float(to[-1])  # continue on the neighbour after the blend
            i += 1
            # the neighbour lane starts at the blend end
            ln2 = town.lanes[nxt]
            s2 = lane_arc(town, nxt)
            b2 = s_end if (i == len(lanes) - 1 and s_end is not None) else s2[-1]
            t2 = np.arange(s_start, b2, ROUTE_STEP)
            seg2 = np.stack([np.interp(t2, s2, ln2.points[:, 0]), np.interp(t2, s2, ln2.points[:, 1])], -1)
            nxt2 = lanes[i + 1] if i + 1 < len(lanes) else None
            if nxt2 is not None and nxt2 in (ln2.left, ln2.right):
                raise ValueError("route: two consecutive lane changes are not supported")
            chunks.append(seg2)
            lane_tags.append(np.full(len(seg2), nxt))
            cmd_tags.append(np.full(len(seg2), ln2.turn if ln2.kind == CONNECTOR else FOLLOW_LANE))
            i += 1
            continue
        chunk = _lane_chunk(town, ln, s, a, b)
        chunks.append(chunk[0])
        lane_tags.append(chunk[1])
        cmd_tags.append(chunk[2])
        i += 1
    # close the route exactly at its end (np.arange above excludes the end point)
    last = town.lanes[lanes[-1]]
    s_last = lane_arc(town, last.id)
    end_s = s_end if s_end is not None else s_last[-1]
    chunks.append(np.array([[np.interp(end_s, s_last, last.points[:, 0]), np.interp(end_s, s_last, last.points[:, 1])]]))
    lane_tags.append(np.array([last.id]))
    cmd_tags.append(np.array([last.turn if last.kind == CONNECTOR else FOLLOW_LANE]))
    raw = np.concatenate(chunks, 0)
    lane_ids = np.concatenate(lane_tags)
    commands = np.concatenate(cmd_tags)
    # drop duplicate points (lane joins) and resample-free: keep spacing ~ROUTE_STEP
    keep = np.concatenate([[True], np.linalg.norm(np.diff(raw, axis=0), axis=1) > 0.05])
    raw, lane_ids, commands = raw[keep], lane_ids[keep], commands[keep]
    d = np.diff(raw, axis=0)
    headings = np.arctan2(d[:, 1], d[:, 0])
    headings = np.concatenate([headings, headings[-1:]])
    return Route(town.name, list(lanes), raw, headings, lane_ids.astype(np.int64),
                 commands.astype(np.int64), polyline_lengths(raw))


def lane_arc(town: Town, lane: int) -> np.ndarray:
    """``polyline_lengths`` of lane ``lane``'s points (cached on the town, read-only)."""
    store = town.cache("lane_arc")
    s = store.get(lane)
    if s is None:
        s = store[lane] = polyline_lengths(town.lanes[lane].points)
        s.setflags(write=False)
    return s


def _lane_chunk(town: Town, ln, s: np.ndarray, a: float, b: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Route points every ``ROUTE_STEP`` m on lane ``ln`` from arc length ``a`` to ``b`` (``b``
    excluded; ``[a]`` when empty), with their lane ids and commands; the whole lane's (``a = 0``,
    ``b`` = its length, most lanes of a route) is computed once per town (read-only arrays)."""
    whole = a == 0.0 and b == s[-1]
    store = town.cache("lane_chunk")
    if whole and ln.id in store:
        return store[ln.id]
    t = np.arange(a, b, ROUTE_STEP)
    if len(t) == 0:
        t = np.array([a])
    out = (np.stack([np.interp(t, s, ln.points[:, 0]), np.interp(t, s, ln.points[:, 1])], -1),
           np.full(len(t), ln.id), np.full(len(t), ln.turn if ln.kind == CONNECTOR else FOLLOW_LANE))
    if whole:
        for x in out:
            x.setflags(write=False)
        store[ln.id] = out
    return out


def random_route(town: Town, rng: np.random.Generator, min_length: float = 300.0,
                 lane_change_prob: float = 0.1, tries: int = 200) -> Route:
    """A random drive of at least ``min_length`` m starting at a random driving lane (the longest
    of ``tries`` draws, with a :class:`~.validation.ShortfallWarning`, where none is that long)."""
    store = town.cache("random_route")
    if not store:  # lane lengths and start lanes depend on the town only
        store["length"] = [ln.length for ln in town.lanes]
        store["starts"] = [ln.id for ln, n in zip(town.lanes, store["length"])
                           if ln.kind not in (PARKING, CONNECTOR) and n > 20]
    starts, lane_length = store["starts"], store["length"]
    best: list[int] = []
    best_len = 0.0
    for _ in range(tries):
        lanes = [int(pick(rng, starts))]
        total = town.index.length[lanes[0]]
        while total < min_length:
            ln = town.lanes[lanes[-1]]
            nbs = [x for x in (ln.left, ln.right) if x >= 0]
            changed_before = len(lanes) > 1 and lanes[-1] in (town.lanes[lanes[-2]].left, town.lanes[lanes[-2]].right)
            if nbs and not changed_before and lane_length[ln.id] > 60 and rng.random() < lane_change_prob:
                lanes.append(int(pick(rng, nbs)))
                continue
            if not ln.successors:
                break
            lanes.append(int(pick(rng, ln.successors)))
            total += town.index.length[lanes[-1]]
        if total > best_len:
            best, best_len = lanes, total
        if total >= min_length:
            break
    if best_len < min_length:
        warn_once(("route_length", town.name, float(min_length)),
                  f"route_length={min_length:g} m asked, but the longest random route found in "
                  f"{town.name} in {tries} tries is {best_len:.0f} m (its roads end sooner); this "
                  f"episode drives {best_len:.0f} m (warned once per town and value)",
                  ShortfallWarning, stacklevel=3)
    return route_from_lanes(town, best)


def resample_route_points(points: np.ndarray, step: float) -> np.ndarray:
    """Route points every ``step`` m (for route files and observations)."""
    return resample_polyline(points, step)
