"""Vehicles and riders in the ego's way: a parked car pulling out in front of the ego, a car
cutting in from a stopped queue, the ego itself leaving a parking slot into traffic, slow bicycles
at the lane edge, a car blocking a junction exit and a hard-braking lead car.

The cut-in vehicles are ordinary lane followers (``DRIVER``) placed on the ego lane with a lateral
offset ``lat`` equal to their parking-lane / neighbour-lane position and held; once released, the
engine's lane-change decay (``traffic.LANE_CHANGE_RATE``) brings them into the ego lane.

Every class here registers itself with ``@register_scenario``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..core.actors import DRIVER, RIDER, SCRIPTED, draw_size
from ..core.classes import BICYCLE, CAR, LARGE_VEHICLE
from ..core.geometry import polyline_lengths
from ..town import get_town
from ..town.builder import PARKING_WIDTH
from ..town.model import CHANGE_LANE_LEFT, DRIVING, LEFT, PARKING, RIGHT, Town
from ..town.routes import ROUTE_STEP
from .base import Scenario, Site
from .obstacles import (
    FLOW_DEFAULTS,
    FLOW_ROWS,
    TWO_WAY_TOWNS,
    LaneFlow,
    is_multi_lane,
    is_two_way_single,
    lane_sites,
    plan_from,
)
from .placement import clear_lanes, clear_near, lane_point, lane_points, spawn_driver, spawn_static
from .registry import register_scenario

PARKING_TOWNS = ("Town03", "Town06", "Town01", "Town05", "Town02")
SLOT = 6.5  # m between parking slots


def kerb_parking(town: Town, lane: int) -> float:
    """Lateral offset (m, negative = right) of the parking lane beside driving ``lane``."""
    return -(float(town.index.width[lane]) / 2 + PARKING_WIDTH / 2)


def slot_positions(town: Town, lane: int) -> np.ndarray:
    """Sorted arc lengths on ``lane`` of the town's parking slots on its right (kerb) side."""
    if len(town.parking) == 0:
        return np.zeros(0)
    xy = town.parking[:, :2]
    _, s, _ = town.index.project(xy, np.array([lane]))
    p, h = town.index.pose_at(np.full(len(s), lane), s)
    lat = -np.sin(h) * (xy[:, 0] - p[:, 0]) + np.cos(h) * (xy[:, 1] - p[:, 1])
    ok = (
        (np.abs(lat - kerb_parking(town, lane)) < 0.5)
        & (s > 1.0)
        & (s < town.index.length[lane] - 1.0)
    )
    return np.sort(s[ok])


def parking_sites(
    town: Town, lo: float, hi_margin: float, frac: float = 0.55, need_behind: bool = False
) -> list[Site]:
    """One site per driving lane with a parking lane on its right: the slot nearest ``frac`` of
    the lane with ``s >= lo`` and ``s <= length - hi_margin`` (and, with ``need_behind``, another
    slot one slot length behind it)."""
    parked = {ln.road for ln in town.lanes if ln.kind == PARKING}
    sites = []
    for ln in town.lanes:
        if ln.kind != DRIVING or ln.right >= 0 or ln.road not in parked:
            continue
        s = slot_positions(town, ln.id)
        ok = (s >= lo) & (s <= ln.length - hi_margin)
        if need_behind:
            ok &= np.array([np.any(np.abs(s - (x - SLOT)) < 0.6) for x in s], bool)
        if np.any(ok):
            c = s[ok][np.argmin(np.abs(s[ok] - frac * ln.length))]
            sites.append(Site((ln.id,), 0, float(c)))
    return sites


def _release_due(sc: Scenario, world, reaction_time: float, min_dist: float) -> bool:
    """The ego's time to reach the conflict point is below ``reaction_time`` s, or it is closer
    than ``min_dist`` m (CARLA's InTimeToArrivalToLocation / InTriggerDistanceToLocation)."""
    dist = sc.conflict_s - sc.ego_s(world)
    return dist <= min_dist or dist / max(float(world.table.speed[0]), 0.5) <= reaction_time


@register_scenario
class ParkingCutIn(Scenario):
    """A car parked in the parking lane beside the ego lane (another parked car right behind it)
    pulls out into the ego lane just in front of the ego: it starts when the ego's time to reach it
    drops below ``reaction_time`` s (or the ego is within 10 m), at ``start_speed`` m/s, merging in
    ~2.5 s and accelerating toward ``speed`` m/s.

    Parameters: ``reaction_time`` (s), ``start_speed`` (m/s), ``speed`` (m/s).
    """

    name = "ParkingCutIn"
    family = "cut_in"
    max_actors = 2
    towns = PARKING_TOWNS
    trigger_distance = 35.0
    defaults = {"reaction_time": 2.0, "start_speed": 2.0, "speed": 13.0}

    @classmethod
    def find_sites(cls, town):
        return parking_sites(town, 25.0, 20.0, need_behind=True)

    def spawn(self, world) -> None:
        town, t, rng = world.town, world.table, world.rng
        lane, s = self.site.lanes[self.site.key], self.site.s_on_key
        lat = kerb_parking(town, lane)
        clear_near(world, self.conflict_point, 25.0)
        p, h = lane_point(town, lane, s - SLOT, lat)
        spawn_static(world, int(self.rows[0]), CAR, p, h, draw_size(CAR, rng), parked=True)
        row = int(self.rows[1])
        v0 = min(float(self.params["speed"]) / float(town.index.speed_limit[lane]), 1.0)
        spawn_driver(world, row, lane, s, CAR, hold=True, v0=v0, plan=plan_from(self.route, lane))
        t.lat[row] = lat
        t.pos[row], _ = lane_point(town, lane, s, lat)
        self.hazard_rows = [row]

    def update(self, world) -> None:
        t, row = world.table, self.hazard_rows[0]
        if t.hold[row] and _release_due(self, world, float(self.params["reaction_time"]), 10.0):
            t.hold[row], t.speed[row] = False, float(self.params["start_speed"])


@register_scenario
class StaticCutIn(Scenario):
    """A queue of stopped vehicles fills the lane beside the ego lane (``queue`` of them,
    ``vehicle_gap`` m apart); the one level with the conflict point suddenly cuts into the ego
    lane when the ego's time to reach it drops below ``reaction_time`` s (or the ego is within
    15 m), starting at ``start_speed`` m/s and merging in ~3 s.

    Parameters: ``side`` -1 queue on the right, +1 on the left (the other side is used where the
    lane has no such neighbour); ``queue``, ``vehicle_gap`` (m), ``reaction_time`` (s),
    ``start_speed`` (m/s).
    """

    name = "StaticCutIn"
    family = "cut_in"
    max_actors = 5
    towns = ("Town03", "Town04", "Town01", "Town05")
    trigger_distance = 40.0
    defaults = {
        "side": -1.0,
        "queue": 4,
        "vehicle_gap": 10.0,
        "reaction_time": 2.4,
        "start_speed": 2.0,
    }

    @classmethod
    def find_sites(cls, town):
        return lane_sites(town, 24.0, frac=0.5, min_lead=26.0, pred=is_multi_lane, back=24.0)

    def spawn(self, world) -> None:
        town, t, rng = world.town, world.table, world.rng
        ix = town.index
        lane, s = self.site.lanes[self.site.key], self.site.s_on_key
        side = float(self.params["side"])
        nb = int(ix.right[lane] if side < 0 else ix.left[lane])
        if nb < 0:
            side = -side
            nb = int(ix.right[lane] if side < 0 else ix.left[lane])
        gap = float(self.params["vehicle_gap"])
        n = min(int(self.params["queue"]), self.max_actors - 1)
        clear_near(world, self.conflict_point, 2 * gap + 15.0)
        clear_lanes(world, [nb])
        scale = ix.length[nb] / ix.length[lane]
        offsets = [k * gap for k in range(-(n // 2), n - n // 2 + 1) if k != 0]
        for row, ds in zip(self.rows[1:], offsets):
            kind = LARGE_VEHICLE if rng.random() < 0.2 else CAR
            size = draw_size(kind, rng)
            size = (min(size[0], gap - 2.5), size[1], size[2])
            spawn_driver(world, int(row), nb, (s + ds) * scale, kind, hold=True, size=size)
        row = int(self.rows[0])
        spawn_driver(world, row, lane, s, CAR, hold=True, plan=plan_from(self.route, lane))
        lat = side * (ix.width[lane] + ix.width[nb]) / 2
        t.lat[row] = lat
        t.pos[row], _ = lane_point(town, lane, s, lat)
        self.hazard_rows = [row]

    def update(self, world) -> None:
        t, row = world.table, self.hazard_rows[0]
        if t.hold[row] and _release_due(self, world, float(self.params["reaction_time"]), 15.0):
            t.hold[row], t.speed[row] = False, float(self.params["start_speed"])


@register_scenario
class ParkingExit(Scenario):
    """The ego starts parked in a parking slot, between a car ``front_gap`` m ahead and one
    ``behind_gap`` m behind (centre to centre), and must merge into the driving lane beside it,
    where a flow of vehicles (mean spacing ``flow_gap`` m, ``flow_speed`` x the speed limit)
    comes from behind. The route is rewritten to start in the slot and blend into the lane over
    ``exit_length`` m (navigation command ``change_lane_left``); the conflict point is where it
    joins the lane. As CARLA switches off its outside-lanes test while the ego leaves the slot,
    the distance driven outside the lanes before the merge point is not counted
    (``EventMonitor.outside_m`` is held).

    Parameters: ``front_gap``, ``behind_gap``, ``exit_length``, ``flow_gap`` (m), ``flow_speed``.
    """

    name = "ParkingExit"
    family = "parking"
    starts_route = True  # the ego starts in the slot: the route is cut to begin there
    max_actors = 2 + 6
    towns = PARKING_TOWNS
    trigger_distance = 35.0
    defaults = {
        "front_gap": 14.0,
        "behind_gap": 7.5,
        "exit_length": 12.0,
        "flow_gap": 30.0,
        "flow_speed": 0.7,
    }

    @classmethod
    def find_sites(cls, town):
        return parking_sites(town, 30.0, 35.0, frac=0.45)

    def __init__(self, route, site, conflict_s, params=None) -> None:
        p = {**self.defaults, **(params or {})}
        town = get_town(route.town)
        lane, s_p = site.lanes[site.key], site.s_on_key
        n_curve, fields = _exit_route(town, route, lane, s_p, float(p["exit_length"]))
        if fields is not None:  # (None: this route was rewritten already)
            route.points, route.headings, route.lane_ids, route.commands, route.s = fields
            route.lanes = list(route.lanes[route.lanes.index(lane) :])
        super().__init__(route, site, float(route.s[n_curve]), params)

    def spawn(self, world) -> None:
        town, rng = world.town, world.rng
        lane, s_p = self.site.lanes[self.site.key], self.site.s_on_key
        lat = kerb_parking(town, lane)
        clear_near(world, self.route.points[0], 25.0)
        clear_lanes(world, [lane])
        for row, ds in zip(
            self.rows[:2], (float(self.params["front_gap"]), -float(self.params["behind_gap"]))
        ):
            p, h = lane_point(town, lane, s_p + ds, lat)
            spawn_static(world, int(row), CAR, p, h, draw_size(CAR, rng), parked=True)
        self.flow = LaneFlow(
            self.rows[2:],
            lane,
            float(self.params["flow_gap"]),
            float(self.params["flow_speed"]),
            s_lo=1.0,
            s_hi=s_p - 8.0,
            plan=[lane],
            ignore_rules=False,
        )
        self.flow.spawn(world)
        self.hazard_rows = list(self.flow.rows)
        self._outside = float(world.monitor.outside_m) if hasattr(world, "monitor") else 0.0

    def tick(self, world) -> None:
        self.flow.update(world)
        if self.ego_s(world) < self.conflict_s:  # leaving the slot is not driving outside the lanes
            world.monitor.outside_m = self._outside
        super().tick(world)


#: rewritten routes remembered per town (:func:`_exit_route`; a replayed route file reuses its own)
EXIT_ROUTE_CACHE_SIZE = 64


def _exit_route(town: Town, route, lane: int, s_p: float, length: float) -> tuple[int, tuple | None]:
    """:class:`ParkingExit`'s route rewrite: the route starts in the slot at ``s_p`` on ``lane``'s
    parking lane and blends into ``lane`` over ``length`` m (``ROUTE_STEP`` apart, a cosine blend).

    Returns:
        ``(n, fields)``: ``n`` points of the blend, ``fields`` the new ``(points, headings,
        lane_ids, commands, s)`` (read-only), or ``None`` where ``route`` starts with the blend
        already. Deterministic, so remembered per town and input route.
    """
    key = (route.points.tobytes(), route.lane_ids.tobytes(), route.commands.tobytes(), route.s.tobytes(), lane, s_p,
           length)
    cache = town.cache("parking_exit_routes")
    hit = cache.get(key)
    if hit is not None:
        return hit
    lat0 = kerb_parking(town, lane)
    u = np.arange(0.0, length, ROUTE_STEP)
    curve = lane_points(town, lane, s_p + u, [lat0 * (0.5 + 0.5 * np.cos(np.pi * x / length)) for x in u])
    if np.linalg.norm(route.points[0] - curve[0]) < 0.1:
        out = (len(curve), None)
    else:
        first = int(np.flatnonzero(route.lane_ids == lane)[0])
        k = first + int(np.searchsorted(route.s[first:] - route.s[first], s_p + length))
        points = np.concatenate([curve, route.points[k:]], 0)
        d = np.diff(points, axis=0)
        heading = np.arctan2(d[:, 1], d[:, 0])
        fields = (
            points,
            np.concatenate([heading, heading[-1:]]),
            np.concatenate([np.full(len(curve), lane), route.lane_ids[k:]]).astype(np.int64),
            np.concatenate([np.full(len(curve), CHANGE_LANE_LEFT), route.commands[k:]]).astype(np.int64),
            polyline_lengths(points),
        )
        for a in fields:
            a.setflags(write=False)
        out = (len(curve), fields)
    while cache and len(cache) >= EXIT_ROUTE_CACHE_SIZE:
        cache.pop(next(iter(cache)))
    cache[key] = out
    return out


# -------------------------------------------------------------------------------- slow bicycles
class _SideHazardBase(Scenario):
    """``count`` (1-3) bicycles ride ``spacing`` m apart at ``speed`` m/s at the right edge of the
    ego lane (the engine keeps riders 0.6 m inside the edge, so they overlap the ego's path) of an
    urban road (speed limit <= 20 m/s); they wait and start when the ego, after the trigger, has
    entered their lane or is within 30 m (not while it waits at a junction before it)."""

    family = "hazard"
    two_way: ClassVar[bool] = False
    lanes_free = True  # overtaking the riders in another lane is the manoeuvre
    trigger_distance = 45.0
    timeout_s = 80.0
    defaults = {"count": 2, "speed": 3.0, "spacing": 6.0}

    @classmethod
    def find_sites(cls, town):
        kind = is_two_way_single if cls.two_way else (lambda ln: ln.left >= 0)
        return lane_sites(
            town,
            40.0,
            frac=0.25,
            min_lead=10.0,
            pred=lambda ln: kind(ln) and ln.speed_limit <= 20.0,
        )

    def __init__(self, route, site, conflict_s, params=None) -> None:
        super().__init__(route, site, conflict_s, params)
        self.end_s = min(self.conflict_s + 60.0, route.length - 1.0)
        self.flow: LaneFlow | None = None

    def spawn(self, world) -> None:
        town, t = world.town, world.table
        lane = self.site.lanes[self.site.key]
        s0 = self.site.s_on_key
        edge = -(float(town.index.width[lane]) / 2 - 0.6)
        n = int(np.clip(self.params["count"], 1, 3))
        clear_near(world, lane_point(town, lane, s0)[0], 30.0)
        clear_lanes(world, [lane])
        plan = plan_from(self.route, lane)
        for k in range(n):
            row = int(self.rows[k])
            s = s0 + k * float(self.params["spacing"])
            spawn_driver(world, row, lane, s, BICYCLE, hold=True, plan=plan)
            t.behaviour[row], t.v0[row], t.lat[row] = RIDER, float(self.params["speed"]), edge
            t.pos[row], _ = lane_point(town, lane, s, edge)
        self.hazard_rows = [int(r) for r in self.rows[:n]]
        if self.two_way:
            self.flow = LaneFlow(
                self.rows[3:],
                town.lanes[lane].opposite,
                float(self.params["flow_gap"]),
                float(self.params["flow_speed"]),
            )
            self.flow.spawn(world)

    def update(self, world) -> None:
        t = world.table
        if not t.hold[self.hazard_rows[0]]:
            return
        on_lane = world.route.lane_ids[world.monitor.progress] == self.site.lanes[self.site.key]
        if on_lane or self.conflict_s - self.ego_s(world) < 30.0:
            for row in self.hazard_rows:
                t.hold[row], t.speed[row] = False, float(self.params["speed"])

    def tick(self, world) -> None:
        if self.flow is not None:
            self.flow.update(world)
        super().tick(world)


@register_scenario
class HazardAtSideLane(_SideHazardBase):
    """Slow bicycles ride at the right edge of the ego lane of a multi-lane road; the ego must
    overtake them through the left neighbour lane (or follow them).

    Parameters: ``count``, ``speed`` (m/s), ``spacing`` (m) of the bicycles.
    """

    name = "HazardAtSideLane"
    max_actors = 3
    towns = ("Town03", "Town01", "Town05")


@register_scenario
class HazardAtSideLaneTwoWays(_SideHazardBase):
    """:class:`HazardAtSideLane` on a two-way road with one lane per direction and oncoming
    traffic: overtaking means invading the opposite lane when clear.

    Parameters: ``count``, ``speed``, ``spacing`` as :class:`HazardAtSideLane`; ``flow_gap``,
    ``flow_speed`` of the oncoming flow.
    """

    name = "HazardAtSideLaneTwoWays"
    two_way = True
    max_actors = 3 + FLOW_ROWS
    towns = TWO_WAY_TOWNS
    defaults = {**_SideHazardBase.defaults, **FLOW_DEFAULTS}


# ----------------------------------------------------------------------------- blocked junction
@register_scenario
class BlockedIntersection(Scenario):
    """After turning left or right at a junction, the ego finds its exit blocked by a stopped car
    (its tail ``into_junction`` m inside the junction). The car drives off once the ego has been
    within ``release_distance`` m of it for ``wait_s`` s (CARLA removes it after 10 s); from then on
    it is background traffic (no scenario, no fixed plan), so the background rules apply to it: one
    stuck behind a later scenario's obstacle on the route is respawned elsewhere instead of
    blocking the ego's lane for good.

    Parameters: ``into_junction`` (m), ``release_distance`` (m), ``wait_s`` (s).
    """

    name = "BlockedIntersection"
    family = "obstacle"
    max_actors = 1
    towns = ("Town01", "Town05", "Town02", "Town06", "Town03")
    trigger_distance = 35.0
    defaults = {"into_junction": 1.0, "release_distance": 13.0, "wait_s": 10.0}

    @classmethod
    def find_sites(cls, town):
        sites = []
        ix = town.index
        for j in town.junctions:
            for cid in j.connectors:
                c = town.lanes[cid]
                if c.turn not in (LEFT, RIGHT) or not c.predecessors or not c.successors:
                    continue
                inc, ex = c.predecessors[0], c.successors[0]
                if ix.length[inc] >= 30.0 and ix.length[ex] >= 25.0 and ix.kind[ex] == DRIVING:
                    sites.append(Site((inc, cid, ex), 2, 0.0))
        return sites

    def spawn(self, world) -> None:
        ex = self.site.lanes[2]
        size = draw_size(CAR, world.rng)
        s = max(size[0] / 2 - float(self.params["into_junction"]), 0.5)
        clear_near(world, lane_point(world.town, ex, s)[0], 20.0)
        clear_lanes(world, [ex])
        row = int(self.rows[0])
        spawn_driver(
            world, row, ex, s, CAR, hold=True, v0=0.8, plan=plan_from(self.route, ex), size=size
        )
        self.hazard_rows = [row]
        self._near_s = 0.0

    def update(self, world) -> None:
        t = world.table
        row = self.hazard_rows[0]
        if not t.hold[row]:
            return
        if np.linalg.norm(t.pos[0] - t.pos[row]) < float(self.params["release_distance"]):
            self._near_s += world.config.dt
        if self._near_s >= float(self.params["wait_s"]):
            t.hold[row] = False
            t.scenario[row], t.plan[row], t.plan_pos[row] = -1, -1, 0


# ----------------------------------------------------------------------------- hard-braking lead
@register_scenario
class HardBreakRoute(Scenario):
    """A lead car hard-brakes in front of the ego. It waits on the route ``start_before`` m before
    the trigger point (off any junction), pulls away when the ego is ``release_gap`` m behind it and
    drives ahead of the ego at ``lead_speed`` m/s (slower while the ego is more than ``max_gap`` m
    behind; after the trigger, more than ``brake_gap`` m). After the trigger, as soon as it is at
    most ``brake_gap`` m ahead of the ego (centre to centre, along the route), or reaches the
    conflict point at most ``max_gap`` m ahead, on a plain lane at more than 4 m/s, it brakes at
    ``decel`` m/s^2 to a stop, stands ``stop_time`` s and drives on.

    Parameters: ``start_before``, ``release_gap``, ``max_gap``, ``brake_gap`` (m), ``lead_speed``
    (m/s), ``decel`` (m/s^2), ``stop_time`` (s).
    """

    name = "HardBreakRoute"
    family = "braking"
    max_actors = 1
    towns = ("Town01", "Town02", "Town05", "Town06", "Town03")
    trigger_distance = 35.0
    defaults = {
        "start_before": 30.0,
        "release_gap": 55.0,
        "lead_speed": 7.5,
        "max_gap": 30.0,
        "brake_gap": 22.0,
        "decel": 7.0,
        "stop_time": 4.0,
    }

    @classmethod
    def find_sites(cls, town):
        return lane_sites(town, 25.0, frac=0.5, min_lead=25.0)

    def spawn(self, world) -> None:
        town, route = world.town, self.route
        start = min(
            max(self.trigger_s - float(self.params["start_before"]), 20.0), self.conflict_s - 10.0
        )
        k = int(np.searchsorted(route.s, start))
        while k < len(route.s) - 1 and town.index.kind[route.lane_ids[k]] != DRIVING:
            k += 1  # not inside a junction
        lane = int(route.lane_ids[k])
        s = float(town.index.project(route.points[k][None], np.array([lane]))[1][0])
        row = int(self.rows[0])
        clear_near(world, route.points[k], 25.0)
        self._v0 = min(float(self.params["lead_speed"]) / float(town.index.speed_limit[lane]), 1.0)
        spawn_driver(world, row, lane, s, CAR, hold=True, v0=self._v0, plan=plan_from(route, lane))
        self.hazard_rows = [row]
        self.state, self._stop_ticks = "wait", 0

    def _gap(self, world) -> float:
        t, r = world.table, world.route
        prog = world.monitor.progress
        pts = r.points[prog : prog + 150]
        d = np.linalg.norm(pts - t.pos[self.hazard_rows[0]], axis=1)
        j = int(np.argmin(d))
        return np.inf if d[j] > 3.0 else float(r.s[prog + j] - r.s[prog])

    def tick(self, world) -> None:
        t, town = world.table, world.town
        row, dt = self.hazard_rows[0], world.config.dt
        if self.state == "wait" and self._gap(world) <= float(self.params["release_gap"]):
            t.hold[row], self.state = False, "lead"
        elif self.state == "lead":
            gap = self._gap(world)
            if gap > float(self.params["max_gap"]):  # wait for the ego
                want = 0.0
            elif self.triggered and gap > float(self.params["brake_gap"]):  # let it close in
                want = 0.8 * self._v0
            else:
                want = self._v0
            step = dt / float(town.index.speed_limit[t.lane[row]])  # v0 changes by <= 1 m/s^2
            t.v0[row] += float(np.clip(want - t.v0[row], -step, step))
            lane = int(t.lane[row])
            plain = town.index.kind[lane] == DRIVING and town.index.length[lane] - t.s[row] > 12.0
            close = gap <= float(self.params["brake_gap"]) or (
                gap <= float(self.params["max_gap"]) and self.ego_s(world) + gap >= self.conflict_s
            )
            if self.triggered and not self.passed and plain and close and t.speed[row] > 4.0:
                t.behaviour[row], self.state = SCRIPTED, "brake"
        elif self.state == "brake":
            v = max(float(t.speed[row]) - float(self.params["decel"]) * dt, 0.0)
            t.accel[row] = (v - t.speed[row]) / dt
            t.speed[row] = v
            t.s[row] = min(t.s[row] + v * dt, town.index.length[t.lane[row]])
            t.pos[row], t.yaw[row] = lane_point(town, int(t.lane[row]), float(t.s[row]))
            if v == 0.0:
                self.state = "stopped"
        elif self.state == "stopped":
            t.accel[row] = 0.0
            self._stop_ticks += 1
            if self._stop_ticks * dt >= float(self.params["stop_time"]):
                t.behaviour[row], t.v0[row], self.state = DRIVER, self._v0, "go"
        super().tick(world)
