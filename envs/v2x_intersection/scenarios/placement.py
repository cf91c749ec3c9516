"""Helpers scenarios use: find sites, build a route through a site, spawn actors, clear space."""

from __future__ import annotations

import numpy as np

from ..core.actors import DRIVER, PARKED, SCRIPTED, STATIC, WALKER, ActorTable, draw_size
from ..core.classes import BICYCLE, LARGE_VEHICLE, PEDESTRIAN
from ..core.draws import pick
from ..town.model import CONNECTOR, DRIVING, PARKING, Town
from ..town.routes import Route, route_from_lanes
from .base import Scenario, Site


def lane_point(town: Town, lane: int, s: float, lateral: float = 0.0) -> tuple[np.ndarray, float]:
    """Position (m) and heading (rad) at arc length ``s`` on ``lane``, shifted ``lateral`` m left."""
    p, h = town.index.pose_at(np.array([lane]), np.array([s]))
    return _shifted(p[0], h[0], lateral), float(h[0])


def lane_points(town: Town, lane: int, s: np.ndarray, lateral) -> np.ndarray:
    """``(K, 2)``: :func:`lane_point`'s positions at arc lengths ``s (K,)`` with offsets ``lateral``
    (``(K,)``), the lane poses in one ``pose_at`` call (the same numbers as K calls)."""
    p, h = town.index.pose_at(np.full(len(s), lane), s)
    return np.array([_shifted(p[k], h[k], lateral[k]) for k in range(len(s))])


def _shifted(p: np.ndarray, h, lateral: float) -> np.ndarray:
    """Point ``p`` moved ``lateral`` m to the left of heading ``h``."""
    return p + lateral * np.array([-np.sin(h), np.cos(h)])


def extend_lanes(town: Town, rng: np.random.Generator, lanes: list[int], before: float, after: float) -> tuple[list[int], int]:
    """Extend a lane sequence backwards by >= ``before`` m and forwards by >= ``after`` m through
    predecessors / successors (no lane changes). Returns ``(lanes, shift)`` where ``shift`` is how
    many lanes were prepended."""
    lanes = list(lanes)
    ix = town.index
    shift, got = 0, 0.0
    while got < before:
        preds = [p for p in town.lanes[lanes[0]].predecessors if ix.kind[p] != PARKING]
        if not preds:
            break
        p = int(pick(rng, preds))
        if p in lanes:
            break
        lanes.insert(0, p)
        shift += 1
        got += ix.length[p]
    got = 0.0
    while got < after:
        succ = [s for s in town.lanes[lanes[-1]].successors if ix.kind[s] != PARKING]
        if not succ:
            break
        n = int(pick(rng, succ))
        if n in lanes:
            break
        lanes.append(n)
        got += ix.length[n]
    return lanes, shift


def route_through(town: Town, rng: np.random.Generator, site: Site, before: float = 90.0,
                  after: float = 70.0, tries: int = 20) -> tuple[Route, float]:
    """A route that drives through ``site``; returns it and the route arc length of the conflict.

    Tries several random extensions and keeps the one with the longest run-up (up to ``before``).
    """
    best = None
    for _ in range(tries):
        lanes, shift = extend_lanes(town, rng, list(site.lanes), before, after)
        run_up = sum(town.index.length[lanes[:site.key + shift]]) + site.s_on_key
        if best is None or run_up > best[0]:
            best = (run_up, lanes, shift)
        if run_up >= before:
            break
    _, lanes, shift = best
    route = route_from_lanes(town, lanes)
    key_lane = lanes[site.key + shift]
    first = int(np.flatnonzero(route.lane_ids == key_lane)[0])
    return route, float(route.s[first] + site.s_on_key)


def clear_near(world, center: np.ndarray, radius: float) -> None:
    """Remove background actors (not the ego, not scenario actors) within ``radius`` m."""
    t: ActorTable = world.table
    d = np.linalg.norm(t.pos - center, axis=1)
    t.active[(d < radius) & (t.scenario < 0) & (np.arange(len(t)) > 0)] = False


def clear_lanes(world, lanes: list[int]) -> None:
    """Remove background followers driving on ``lanes``."""
    t = world.table
    on = np.zeros(len(t), bool)
    for lane in lanes:  # np.isin for a few lanes (its set-up costs ~15 us)
        on |= t.lane == lane
    t.active[on & (t.scenario < 0) & (np.arange(len(t)) > 0) & (t.behaviour == DRIVER)] = False


def _base(t: ActorTable, row: int, kind: int, behaviour: int, size: tuple[float, float, float]) -> None:
    t.kind[row], t.behaviour[row], t.active[row] = kind, behaviour, True
    t.length[row], t.width[row], t.height[row] = size
    t.speed[row] = t.accel[row] = 0.0
    t.lane[row], t.plan[row], t.lat[row] = -1, -1, 0.0
    t.hold[row] = t.ignore_rules[row] = False


def spawn_driver(world, row: int, lane: int, s: float, kind: int = 0, speed: float = 0.0,
                 v0: float = 1.0, plan: list[int] | None = None, hold: bool = False,
                 ignore_rules: bool = False, size: tuple[float, float, float] | None = None) -> None:
    """A lane-following vehicle (IDM) on ``lane`` at ``s``; ``v0`` is a factor of the speed limit;
    ``plan`` fixes its lane sequence (it leaves the world at the plan's end)."""
    t = world.table
    _base(t, row, kind, DRIVER, size or draw_size(kind, world.rng))
    p, h = lane_point(world.town, lane, s)
    t.pos[row], t.yaw[row], t.lane[row], t.s[row] = p, h, lane, s
    t.speed[row], t.v0[row], t.hold[row], t.ignore_rules[row] = speed, v0, hold, ignore_rules
    t.stopped_at_sign[row], t.wait[row] = False, 0.0
    if plan is not None:
        world.plans.append(list(plan))
        t.plan[row], t.plan_pos[row] = len(world.plans) - 1, 0


def spawn_walker(world, row: int, start: np.ndarray, end: np.ndarray, speed: float = 1.4,
                 hold: bool = True, kind: int = PEDESTRIAN) -> None:
    """A pedestrian (or pushed bicycle) that walks straight from ``start`` to ``end`` once released
    (``hold=False``) and stops there."""
    t = world.table
    _base(t, row, kind, WALKER, draw_size(kind, world.rng))
    start, end = np.asarray(start, float), np.asarray(end, float)
    t.pos[row] = start
    t.yaw[row] = float(np.arctan2(*(end - start)[::-1]))
    t.path[row], t.cross_from[row], t.cross_to[row] = -1, start, end
    t.speed[row], t.hold[row] = speed, hold


def spawn_static(world, row: int, kind: int, pos: np.ndarray, yaw: float,
                 size: tuple[float, float, float], parked: bool = False) -> None:
    """A standing box: parked vehicle (``parked=True``), cone, debris, barrier..."""
    t = world.table
    _base(t, row, kind, PARKED if parked else STATIC, size)
    t.pos[row], t.yaw[row] = np.asarray(pos, float), yaw


def spawn_scripted(world, row: int, kind: int, pos: np.ndarray, yaw: float,
                   size: tuple[float, float, float] | None = None) -> None:
    """An actor the scenario moves itself every tick (``SCRIPTED`` behaviour)."""
    t = world.table
    _base(t, row, kind, SCRIPTED, size or draw_size(kind, world.rng))
    t.pos[row], t.yaw[row] = np.asarray(pos, float), yaw


def truck_size(rng: np.random.Generator) -> tuple[float, float, float]:
    """A box truck / van tall enough to hide a pedestrian from an ego camera (its width drawn
    from the background large vehicles' range, so that no size tells a scenario truck apart)."""
    return float(rng.uniform(7.0, 9.0)), float(rng.uniform(2.3, 2.6)), float(rng.uniform(3.2, 3.8))


def car_size(rng: np.random.Generator, min_height: float = 1.4) -> tuple[float, float, float]:
    """A parked car's box (m): length U(4.2, 4.8), width 1.9, height U(``min_height``, 1.6) (two
    draws, in that order)."""
    return float(rng.uniform(4.2, 4.8)), 1.9, float(rng.uniform(min_height, 1.6))


def straight_sites(town: Town, min_length: float = 70.0, parking: bool | None = None,
                   two_way: bool | None = None, multi_lane: bool | None = None,
                   kinds: tuple[int, ...] = (DRIVING,)) -> list[Site]:
    """Sites on long plain lanes; the conflict point is at 60% of the lane."""
    sites = []
    parked_roads = {ln.road for ln in town.lanes if ln.kind == PARKING}
    for ln in town.lanes:
        if ln.kind not in kinds or ln.length < min_length or not ln.successors:
            continue
        if parking is not None and (ln.road in parked_roads and ln.right < 0) != parking:
            continue
        if two_way is not None and (ln.opposite >= 0) != two_way:
            continue
        if multi_lane is not None and ((ln.left >= 0 or ln.right >= 0) != multi_lane):
            continue
        sites.append(Site((ln.id,), 0, 0.6 * ln.length))
    return sites


def junction_sites(town: Town, controls: tuple[int, ...], turn: int) -> list[Site]:
    """Sites entering a junction of a given control with a given manoeuvre: lanes =
    (incoming lane, connector); the conflict point is the middle of the connector."""
    sites = []
    for j in town.junctions:
        if j.control not in controls:
            continue
        for cid in j.connectors:
            c = town.lanes[cid]
            if c.turn != turn or not c.predecessors:
                continue
            inc = c.predecessors[0]
            if town.index.length[inc] < 30:
                continue
            sites.append(Site((inc, cid), 1, 0.5 * c.length))
    return sites


def run_up(town: Town, site: Site, limit: float = 200.0) -> float:
    """Longest drivable distance (m, capped at ``limit``) before a site's conflict point."""
    ix = town.index
    before = float(sum(ix.length[list(site.lanes[: site.key])]) + site.s_on_key)

    def back(lane: int, depth: int) -> float:
        if depth == 0:
            return 0.0
        preds = [p for p in town.lanes[lane].predecessors if ix.kind[p] != PARKING]
        return max((ix.length[p] + back(p, depth - 1) for p in preds), default=0.0)

    return min(before + back(site.lanes[0], 4), limit)


def pick_site(cls: type[Scenario], town: Town, rng: np.random.Generator, min_run_up: float = 50.0) -> Site:
    """A random site of ``cls`` in ``town`` with at least ``min_run_up`` m of road before it.

    Raises:
        ValueError: the town has no such site.
    """
    sites = [s for s in cls.find_sites(town) if run_up(town, s) >= min_run_up]
    if not sites:
        raise ValueError(f"scenario {cls.name} does not fit town {town.name} (no suitable site)")
    return sites[int(rng.integers(len(sites)))]


__all__ = [
    "BICYCLE", "CONNECTOR", "LARGE_VEHICLE", "PEDESTRIAN", "clear_lanes", "clear_near", "extend_lanes",
    "junction_sites", "lane_point", "pick_site", "route_through", "spawn_driver", "spawn_scripted",
    "spawn_static", "spawn_walker", "straight_sites", "truck_size",
]
