"""Pedestrians: walk along sidewalks, cross at crosswalks, and some jaywalk mid-block.

A walking pedestrian has ``path`` = sidewalk id and moves along it (``path_s``, direction
``path_dir``) with a lateral offset ``lat`` inside the sidewalk. A crossing pedestrian has
``path = -1`` and moves on the straight segment ``cross_from -> cross_to``; on arrival it snaps to
the nearest sidewalk and walks on.
"""

from __future__ import annotations

import numpy as np

from ..core import libm
from ..core.actors import WALKER, ActorTable
from ..core.classes import VEHICLE_CLASSES
from ..core.draws import signs
from ..core.geometry import world_to_local_2d
from ..core.jit import HAVE_JIT
from ..core.jit_rng import state_views
from ..town.model import PolylineIndex, Town
from .jit_walkers import walkers_tick_kernel


class SidewalkNetwork:
    """Sidewalk polylines plus, for each sidewalk end, the crosswalk (if any) reached from there."""

    def __init__(self, town: Town) -> None:
        self.town = town
        self.index = PolylineIndex([s.points for s in town.sidewalks]) if town.sidewalks else None
        # crossing segments of every crosswalk (centre line across the road, extended to the kerbs)
        segs = []
        for c in town.crosswalks:
            a = 0.5 * (c.corners[0] + c.corners[1])
            b = 0.5 * (c.corners[2] + c.corners[3])
            u = (b - a) / max(np.linalg.norm(b - a), 1e-9)
            segs.append((a - 1.5 * u, b + 1.5 * u))
        self.crossings = np.array(segs, float).reshape(-1, 2, 2)
        # the sidewalk across the road from each sidewalk (same road, other side)
        self.opposite = np.full(len(town.sidewalks), -1, np.int64)
        by_road: dict[int, list[int]] = {}
        for s in town.sidewalks:
            by_road.setdefault(s.road, []).append(s.id)
        for ids in by_road.values():
            if len(ids) == 2:
                self.opposite[ids[0]], self.opposite[ids[1]] = ids[1], ids[0]

    def crossing_near(self, xy: np.ndarray, radius: float = 6.0) -> int:
        """Index of a crossing with an end within ``radius`` m of ``xy`` (-1: none)."""
        if len(self.crossings) == 0:
            return -1
        d = np.linalg.norm(self.crossings - xy, axis=2).min(1)
        k = int(np.argmin(d))
        return k if d[k] < radius else -1


def step_walkers(t: ActorTable, net: SidewalkNetwork, rng: np.random.Generator, dt: float,
                 jaywalk_prob: float) -> None:
    """Advance all pedestrians by one tick, in place."""
    if net.index is None:
        return
    if HAVE_JIT:
        _step_walkers_jit(t, net, rng, dt, jaywalk_prob)
        return
    idx = np.flatnonzero(t.active & ~t.hold & (t.behaviour == WALKER))
    if len(idx) == 0:
        return
    walking = idx[t.path[idx] >= 0]
    crossing = idx[t.path[idx] < 0]

    # crossing pedestrians move on their segment (background walkers wait while the ego stands
    # in their way; scenario walkers are scripted hazards and walk on)
    if len(crossing):
        seg = t.cross_to[crossing] - t.cross_from[crossing]
        left = t.cross_to[crossing] - t.pos[crossing]
        dist = np.linalg.norm(left, axis=1)
        u = seg / np.maximum(np.linalg.norm(seg, axis=1, keepdims=True), 1e-9)
        blocked = ego_in_the_way(t, t.pos[crossing] + u * PED_LOOKAHEAD) & (t.scenario[crossing] < 0)
        step = np.where(blocked, 0.0, t.speed[crossing] * dt)
        t.pos[crossing] += u * np.minimum(step, dist)[:, None]
        t.yaw[crossing] = libm.arctan2(u[:, 1], u[:, 0])
        done = crossing[(dist <= step) & (t.scenario[crossing] < 0)]  # scenario walkers stop at the end
        t.speed[crossing[(dist <= step) & (t.scenario[crossing] >= 0)]] = 0.0
        if len(done):
            _back_on_sidewalk(t, net, rng, done)

    if len(walking) == 0:
        return
    ix = net.index
    s = t.path_s[walking] + t.path_dir[walking] * t.speed[walking] * dt
    length = ix.length[t.path[walking]]
    at_end = (s < 0.0) | (s > length)
    s = np.clip(s, 0.0, length)
    t.path_s[walking] = s
    p, h = ix.pose_at(t.path[walking], s)
    normal = np.stack([-np.sin(h), np.cos(h)], -1)
    t.pos[walking] = p + t.lat[walking][:, None] * normal
    t.yaw[walking] = np.where(t.path_dir[walking] > 0, h, h + np.pi)
    _ends_and_jaywalk(t, net, rng, dt, jaywalk_prob, walking, at_end)


def walkers_args(t: ActorTable, net: SidewalkNetwork, lanes: PolylineIndex) -> tuple:
    """What ``jit_tick.traffic_tick_kernel`` needs for the pedestrians besides the columns the
    followers use too (the same for a whole episode). A town without sidewalks passes ``lanes``'
    index arrays in place of theirs (never read: the kernel skips the walkers; same dtypes, so the
    same compiled kernel)."""
    ix = net.index if net.index is not None else lanes
    return (t.path, t.path_s, t.path_dir, t.cross_from, t.cross_to, net.crossings, net.opposite, ix.points,
            ix.heading, ix.offset, ix.n_points, ix.gs, ix.base, ix.length, ix.owner, PED_LOOKAHEAD, EGO_MARGIN)


def ego_is_vehicle(t: ActorTable) -> bool:
    """Row 0 is an active vehicle (walkers wait only for that)."""
    return bool(len(t.active) and t.active[0] and int(t.kind[0]) in _VEHICLE_KINDS)


def _step_walkers_jit(t: ActorTable, net: SidewalkNetwork, rng: np.random.Generator, dt: float,
                      jaywalk_prob: float) -> None:
    """:func:`step_walkers` in one kernel, random choices included (drawn from ``rng``'s own
    state in the NumPy path's order, :mod:`.jit_rng`)."""
    ix = net.index
    words, buf = state_views(rng)
    walkers_tick_kernel(
        words, buf, t.active, t.hold, t.behaviour, t.path, t.path_s, t.path_dir, t.speed, t.lat, t.pos, t.yaw,
        t.cross_from, t.cross_to, t.scenario, ego_is_vehicle(t), float(t.pos[0, 0]), float(t.pos[0, 1]),
        float(t.yaw[0]), float(t.length[0] / 2 + EGO_MARGIN), float(t.width[0] / 2 + EGO_MARGIN), PED_LOOKAHEAD, dt,
        jaywalk_prob * dt, net.crossings, net.opposite, ix.points, ix.heading, ix.offset, ix.n_points, ix.gs,
        ix.base, ix.length, ix.owner)


def _back_on_sidewalk(t: ActorTable, net: SidewalkNetwork, rng: np.random.Generator, done: np.ndarray) -> None:
    """Walkers ``done`` with their crossing walk on along the sidewalk where they stand."""
    sw, s, _ = net.index.project(t.pos[done])
    t.path[done], t.path_s[done] = sw, s
    p, h = net.index.pose_at(sw, s)  # keep the walker where it is: lateral offset from the path
    t.lat[done] = np.clip(((t.pos[done] - p) * np.stack([-np.sin(h), np.cos(h)], -1)).sum(-1), -1.2, 1.2)
    t.path_dir[done] = signs(rng, len(done))


def _ends_and_jaywalk(t: ActorTable, net: SidewalkNetwork, rng: np.random.Generator, dt: float,
                      jaywalk_prob: float, walking: np.ndarray, at_end: np.ndarray) -> None:
    """At a sidewalk's end cross (70 %) or turn around; elsewhere start jaywalking now and then."""
    ix = net.index
    for k in np.flatnonzero(at_end):  # end of the sidewalk: cross, or turn around
        i = walking[k]
        c = net.crossing_near(t.pos[i])
        if c >= 0 and rng.random() < 0.7:
            a, b = net.crossings[c]
            if np.linalg.norm(a - t.pos[i]) > np.linalg.norm(b - t.pos[i]):
                a, b = b, a
            _start_crossing(t, i, t.pos[i].copy(), b)
        else:
            t.path_dir[i] = -t.path_dir[i]
    # jaywalking: cross straight over the road to the opposite sidewalk
    jay = walking[(rng.random(len(walking)) < jaywalk_prob * dt) & ~at_end]
    for i in jay:
        opp = net.opposite[t.path[i]]
        if opp < 0:
            continue
        _, s_o, _ = ix.project(t.pos[i][None], np.array([opp]))
        target, _ = ix.pose_at(np.array([opp]), s_o)
        _start_crossing(t, i, t.pos[i].copy(), target[0])




PED_LOOKAHEAD = 1.0  # m: a crossing walker waits while this point ahead of it is inside the ego
EGO_MARGIN = 0.3  # m added around the ego's box for that test


def ego_in_the_way(t: ActorTable, points: np.ndarray, margin: float = EGO_MARGIN) -> np.ndarray:
    """``(M,)`` whether each of ``points`` ``(M, 2)`` lies inside the ego's box plus ``margin`` m.

    Only the ego is tested: walkers do not walk into the car being evaluated, while among
    background actors a wait rule could deadlock (car waits for walker waits for car)."""
    if not ego_is_vehicle(t):
        return np.zeros(len(points), bool)
    local = world_to_local_2d(points, t.pos[0], float(t.yaw[0]))
    return (np.abs(local[:, 0]) < t.length[0] / 2 + margin) & (np.abs(local[:, 1]) < t.width[0] / 2 + margin)


_VEHICLE_KINDS = frozenset(int(k) for k in VEHICLE_CLASSES)


def _start_crossing(t: ActorTable, i: int, a: np.ndarray, b: np.ndarray) -> None:
    """Switch walker ``i`` to crossing from its position ``a`` to ``b`` (no jump)."""
    t.path[i] = -1
    t.cross_from[i], t.cross_to[i] = a, b
