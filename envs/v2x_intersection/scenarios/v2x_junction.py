"""V2X-specific junction scenarios: the ego turns at a junction and meets a hazard it cannot see.

Two families:

- ``turning``: a cyclist (:class:`VehicleTurningRoute`) or a pedestrian
  (:class:`VehicleTurningRoutePedestrian`) crosses the road the ego turns into. After a right
  turn it comes from the inner corner, hidden by a truck parked at the right kerb of the ego's
  approach; after a left turn it steps out from behind a truck parked at the right kerb of the
  exit road (the inner corner of a left turn lies open across the junction).
- ``junction``: at an unsignalized junction the ego (on a road that must yield) turns across or
  into an actor flow as CARLA LB2.0's :class:`NonSignalizedJunctionLeftTurn` (oncoming flow) and
  :class:`NonSignalizedJunctionRightTurn` (flow from the left), or a flow of bicycles with
  priority arrives on the crossing road (:class:`CrossingBicycleFlow`). What makes them V2X
  scenarios is a truck that hides the flow from the ego: waiting to turn left in the oncoming
  approach, or parked at the near kerb of the crossing road (see each class).

Hazards start by CARLA-style triggers and then ignore the ego (see :class:`~.timed.TimedScenario`);
the vehicle flows run from reset on, whatever the ego does.
"""

from __future__ import annotations

import numpy as np

from ..core.actors import RIDER, draw_size
from ..core.classes import BICYCLE, CAR, LARGE_VEHICLE, PEDESTRIAN
from ..core.geometry import world_to_local_2d
from ..town.model import DRIVING, LEFT, PRIORITY, RIGHT, STOP, STRAIGHT, Town
from ..traffic.vehicles import STOP_LINE_SETBACK
from .base import Site
from .flows import FlowScenario, connectors, crossing_sites, merge_sites
from .flows import first_conflict as lanes_conflict
from .placement import (
    clear_lanes,
    clear_near,
    lane_point,
    spawn_driver,
    spawn_static,
    spawn_walker,
    truck_size,
)
from .registry import register_scenario
from .timed import POSITION_JITTER_M, SPEED_SCALE, TimedScenario
from .v2x import (
    CROSSWALK_HALF,
    box_points,
    carriageway_edge,
    eta,
    has_crosswalk,
    kerb_offset,
    park_vehicle,
    route_eyes,
    route_rsu_eye,
    sight_blocked,
)

#: m into the exit lane where the hazard of a left turn crosses (crosswalk, 4.5 m, truck, 0.6 m)
LEFT_TURN_CONFLICT = 2 * CROSSWALK_HALF + 4.5 + 9.0 + 0.6
#: m between a truck parked at the exit road's kerb and the carriageway (a straight-corridor
#: driver leaving the turn slightly askew must not mistake it for an obstacle in its lane)
KERB_GAP = 1.0


def lane_path(town: Town, lanes: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``(P, 2)`` of a lane sequence, the lane index of each point and its arc length on it."""
    pts, owner, s_on = [], [], []
    ix = town.index
    for k, lane in enumerate(lanes):
        s = np.arange(0.0, ix.length[lane], 0.5)
        p, _ = ix.pose_at(np.full(len(s), lane), s)
        pts.append(p)
        owner.append(np.full(len(s), k))
        s_on.append(s)
    return np.concatenate(pts), np.concatenate(owner), np.concatenate(s_on)


def first_conflict(
    town: Town, ego_lanes: list[int], other_lanes: list[int], radius: float = 1.6
) -> tuple[int, float, float] | None:
    """Where the ego's lane sequence first comes within ``radius`` m of another one.

    Returns:
        ``(index into ego_lanes, arc length on that lane, arc length along other_lanes)`` or
        ``None`` when the paths never meet.
    """
    a, a_owner, a_s = lane_path(town, ego_lanes)
    b, _, _ = lane_path(town, other_lanes)
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    close = np.flatnonzero(d.min(1) < radius)
    if len(close) == 0:
        return None
    k = int(close[0])
    j = int(np.argmin(d[k]))
    return int(a_owner[k]), float(a_s[k]), 0.5 * j


def side_of(town: Town, lane: int, xy: np.ndarray) -> float:
    """-1 if ``xy`` lies right of ``lane`` (seen at its end), +1 if left."""
    ln = town.lanes[lane]
    h = np.arctan2(*(ln.points[-1] - ln.points[-2])[::-1])
    return 1.0 if world_to_local_2d(xy, ln.points[-1], h)[1] > 0 else -1.0


def extend_plan(town: Town, lanes: list[int], extra: int = 1) -> list[int]:
    """``lanes`` plus up to ``extra`` driving successors (so a hazard drives on after the junction)."""
    out = list(lanes)
    for _ in range(extra):
        succ = [s for s in town.lanes[out[-1]].successors if town.lanes[s].kind in (DRIVING,)]
        if not succ:
            break
        out.append(succ[0])
    return out


# ---------------------------------------------------------------------------------------------
class _TurnCrossing(TimedScenario):
    """Shared logic of the turning family (see the subclasses)."""

    family = "turning"
    v2x = True
    max_actors = 2
    trigger_distance = 45.0
    hazard_kind = PEDESTRIAN
    towns = ("Town01", "Town05", "Town02")

    @classmethod
    def find_sites(cls, town):
        sites = []
        for j in town.junctions:
            for cid in j.connectors:
                c = town.lanes[cid]
                if c.turn not in (LEFT, RIGHT) or not c.predecessors or not c.successors:
                    continue
                inc, ex = c.predecessors[0], c.successors[0]
                if town.index.length[inc] < 30 or town.index.length[ex] < 35:
                    continue
                if not (has_crosswalk(town, ex, j.id) and has_crosswalk(town, inc, j.id)):
                    continue
                s_x = CROSSWALK_HALF if c.turn == RIGHT else LEFT_TURN_CONFLICT
                sites.append(Site((inc, cid, ex), 2, s_x))
        return sites

    def spawn(self, world) -> None:
        town, rng = world.town, world.rng
        inc, conn, ex = self.site.lanes[:3]
        ix = town.index
        clear_near(world, self.conflict_point, 20.0)
        size = truck_size(rng)
        s_x = self.site.s_on_key
        if town.lanes[conn].turn == RIGHT:
            # a truck at the right kerb of the approach, its front at the crosswalk, hides the
            # inner corner, where the hazard waits to cross the exit road on the crosswalk
            lat = -(carriageway_edge(town, inc, -1.0) + size[1] / 2 + 0.3)
            park_vehicle(
                world, self.rows[0], inc, ix.length[inc] - 2 * CROSSWALK_HALF - 0.3, lat, size
            )
            self._lat0 = kerb_offset(town, ex, -1.0) + float(self.params["wait"])
            start, _ = lane_point(town, ex, s_x + 0.5 * self.position_jitter, -self._lat0)
        else:
            # a truck parked at the right kerb of the exit road past the crosswalk; the hazard
            # waits behind its front and crosses just ahead of it (hidden until the ego is in
            # the exit lane)
            edge = carriageway_edge(town, ex, -1.0)
            park_vehicle(world, self.rows[0], ex, s_x - 0.6, -(edge + size[1] / 2 + KERB_GAP), size)
            self._lat0 = edge + size[1] + KERB_GAP + float(self.params["wait"])
            start, _ = lane_point(town, ex, s_x - 1.2 + 0.5 * self.position_jitter, -self._lat0)
        end, _ = lane_point(town, ex, s_x + 0.3, kerb_offset(town, ex, 1.0) + 1.0)
        spawn_walker(
            world,
            self.rows[1],
            start,
            end,
            speed=self.hazard_speed(),
            kind=self.hazard_kind,
        )
        self.hold_walker(world, self.rows[1])
        self.hazard_rows = [int(self.rows[1])]

    def update(self, world) -> None:
        self.step_one_walker(world, int(self.rows[1]), self._lat0)


@register_scenario
class VehicleTurningRoute(_TurnCrossing):
    """The ego turns at a junction and a cyclist crosses the road it turns into.

    Right turn: a truck parked at the right kerb of the ego's approach, its front at the junction
    crosswalk, hides the inner corner; the cyclist waits there and rides across the exit road on
    its crosswalk. Left turn: a truck is parked at the right kerb of the exit road about 5 m past
    the crosswalk; the cyclist waits behind its front and rides across the road just ahead of it
    (about 18 m into the exit road, as CARLA's cyclist some 11 m after the junction). Either way
    it starts once the trigger fires (see :class:`~.timed.TimedScenario`).

    Parameters: ``speed`` (m/s) of the cyclist; ``wait`` (m) how far from the kerb (right turn)
    or the truck's side (left turn) it waits.
    """

    name = "VehicleTurningRoute"
    hazard_kind = BICYCLE
    defaults = {"speed": 4.0, "wait": 1.5}


@register_scenario
class VehicleTurningRoutePedestrian(_TurnCrossing):
    """The ego turns at a junction and a pedestrian crosses the road it turns into.

    As :class:`VehicleTurningRoute` with a pedestrian: after a right turn it walks from the inner
    corner (hidden by a truck at the approach's right kerb) across the exit road on the
    crosswalk; after a left turn it steps out from behind a truck parked at the exit road's right
    kerb. Started by the trigger of :class:`~.timed.TimedScenario`.

    Parameters: ``speed`` (m/s) of the pedestrian; ``wait`` (m) how far from the kerb (right
    turn) or the truck's side (left turn) it waits.
    """

    name = "VehicleTurningRoutePedestrian"
    hazard_kind = PEDESTRIAN
    defaults = {"speed": 1.8, "wait": 1.0}


# ---------------------------------------------------------------------------------------------
def priority_sites(town: Town, turn: int, hazard_side: float | None) -> list[Site]:
    """Sites where the ego turns (``turn``) from a road that must yield at an unsignalized junction
    while straight-through traffic with priority crosses or joins its path.

    ``hazard_side``: -1 hazards from the ego's right, +1 from its left, ``None`` either. Priority
    junctions are used where the town has suitable ones (the hazard's road has no sign), else
    all-way stops (the hazard then takes priority it does not have). ``Site.extra`` holds the
    hazard's lane sequence and the arc length of the conflict along it.
    """
    found: dict[int, list[Site]] = {PRIORITY: [], STOP: []}
    for j in town.junctions:
        if j.control not in found:
            continue
        for cid in j.connectors:
            c = town.lanes[cid]
            if c.turn != turn or not c.predecessors or not c.successors:
                continue
            inc, ex = c.predecessors[0], c.successors[0]
            if inc not in j.stop_lanes or town.index.length[inc] < 30 or town.index.length[ex] < 20:
                continue
            for hid in j.connectors:
                h = town.lanes[hid]
                if h.turn != STRAIGHT or not h.predecessors or not h.successors:
                    continue
                h_inc = h.predecessors[0]
                if town.lanes[h_inc].road == town.lanes[inc].road or town.index.length[h_inc] < 25:
                    continue
                if j.control == PRIORITY and h_inc in j.stop_lanes:
                    continue
                side = side_of(town, inc, town.lanes[h_inc].points[-1])
                if hazard_side is not None and side != hazard_side:
                    continue
                hz = [h_inc, hid, h.successors[0]]
                hit = first_conflict(town, [cid, ex], hz)
                if hit is None:
                    continue
                key, s_key, s_h = hit
                found[j.control].append(Site((inc, cid, ex), 1 + key, s_key, (tuple(hz), s_h)))
    return found[PRIORITY] or found[STOP]


class _PriorityHazard(TimedScenario):
    """Shared logic of the junction family: ``hazard_count`` actors with priority approach on a
    crossing road, held hidden ``distance`` m before the junction behind a truck parked at the near
    kerb.

    Trigger (CARLA's InTriggerDistanceToLocation at the stop line): the ego's centre comes within
    :attr:`line_trigger_m` of its stop line. At that moment, once, the hazard's start delay is set
    from the ego's state: the time the ego would need to reach the conflict point driving off
    from its current speed (:func:`~.v2x.eta`: 1.5 m/s^2 up to :attr:`ego_v_max`, plus the
    drawn jitter) minus the hazard's own time to it; a hazard too far to make it at its drawn
    speed goes faster, up to :attr:`speed_cap`. The hazard then starts after that delay,
    ignoring the ego. An ego standing at its stop line never sets it off."""

    family = "junction"
    v2x = True
    trigger_distance = 45.0
    timeout_s = 90.0
    ego_v_max = 5.0  # m/s: the driving-off model of the trigger's arrival estimate
    line_trigger_m = 1.0  # m before the stop line (ego centre) where the trigger fires
    speed_cap = 14.0  # m/s: the most a hazard speeds up to make the meeting (bicycles: 8)
    towns = ("Town01", "Town06", "Town02", "Town05")
    turn = RIGHT
    hazard_side: float | None = 1.0
    aim_front = False  # the crossing car reaches the conflict point with the ego's centre
    release_margin_s = 0.3
    aim_delay_s = 0.0

    @classmethod
    def find_sites(cls, town):
        return priority_sites(town, cls.turn, cls.hazard_side)

    def hazard_count(self) -> int:
        return 1

    def spawn(self, world) -> None:
        town, rng, t = world.town, world.rng, world.table
        ix = town.index
        inc = self.site.lanes[0]
        hz, s_h = self.site.extra
        h_inc = hz[0]
        clear_near(world, town.junctions[ix.junction[self.site.lanes[1]]].center, 30.0)
        clear_lanes(world, [inc, h_inc, *hz[1:]])
        # truck parked at the kerb of the hazard's road, on the side facing the ego's approach
        side = side_of(town, h_inc, town.lanes[inc].points[-1])
        size = truck_size(rng)
        lat = side * (carriageway_edge(town, h_inc, side) + size[1] / 2 + 0.3)
        l_h = ix.length[h_inc]
        s_front = l_h - 2 * CROSSWALK_HALF - float(self.params["truck_gap"])
        park_vehicle(world, self.rows[0], h_inc, s_front, lat, size)
        self._line_s = self.conflict_s - self._dist_line_to_conflict(town)
        # the hazard(s), held upstream where the truck and buildings hide them from the ego
        plan = extend_plan(town, list(hz))
        n = self.hazard_count()
        p_t, h_t = lane_point(town, h_inc, s_front - size[0] / 2, lat)
        s0 = self._hidden_hold(world, h_inc, (p_t[0], p_t[1], size[0], size[1], h_t, size[2]))
        self.hazard_rows = []
        for k in range(n):
            row = int(self.rows[1 + k])
            s = (
                s0
                - k * float(self.params.get("spacing", 0.0))
                - (rng.uniform(0.0, 4.0) if k else 0.0)
            )
            if s < 1.0:
                break
            self._spawn_hazard(world, row, h_inc, s, plan)
            self.hazard_rows.append(row)
        self._speed = self.hazard_speed()
        self._time = (s_h - s0) / self._speed  # s_h: along the hazard's lanes from h_inc's start
        self._released = False
        t.hold[self.hazard_rows] = True

    def _hidden_hold(self, world, lane: int, truck: tuple) -> float:
        """Arc length on ``lane`` where the (first) hazard waits: the one nearest the junction
        (but at most ``distance`` m from it) hidden from the ego on its last 25 m to the stop
        line and seen by the conflict's roadside unit; the best compromise if none is."""
        town = world.town
        l_h = town.index.length[lane]
        far = max(l_h - float(self.params["distance"]), 2.0)
        eyes = route_eyes(
            world, self.route, self._line_s - 2.5 - np.array([0.0, 4.0, 10.0, 18.0, 25.0])
        )
        rsu = route_rsu_eye(world, self.route, self.conflict_s)[None]
        best, best_score = far, -1.0
        for s in np.arange(l_h - 2 * CROSSWALK_HALF - 6.0, far - 0.5, -1.0):
            p, h = lane_point(town, lane, s)
            pts = box_points(p, h, 4.5)
            score = sight_blocked(world, eyes, pts, [truck]) - 0.5 * sight_blocked(
                world, rsu, pts, [truck]
            )
            if score > best_score + 1e-6:
                best, best_score = float(s), score
            if score >= 0.999:
                break
        return best

    def _dist_line_to_conflict(self, town: Town) -> float:
        ix = town.index
        lanes = list(self.site.lanes)
        return float(
            STOP_LINE_SETBACK + sum(ix.length[lanes[1 : self.site.key]]) + self.site.s_on_key
        )

    def _spawn_hazard(self, world, row: int, lane: int, s: float, plan: list[int]) -> None:
        spawn_driver(world, row, lane, s, kind=CAR, hold=True, ignore_rules=True, plan=plan)

    def update(self, world) -> None:
        t = world.table
        if self._released:
            return
        if self.hazard_trigger_tick < 0:
            if self.ego_s(world) < self._line_s - self.line_trigger_m:
                return
            self.hazard_trigger_tick = world.tick  # fired: the timing is set once, here
            t_ego = eta(self.conflict_s - self.ego_s(world), float(t.speed[0]), v_max=self.ego_v_max)
            t_ego = max(t_ego + self.trigger_jitter - self.release_margin_s, 0.1)
            if self._time > t_ego:  # too far to make it at its drawn speed: faster, up to the cap
                cap = max(self.speed_cap, self._speed)
                self._speed = min(self._speed * self._time / t_ego, cap)
                self._time = self._time * float(self.hazard_speed()) / self._speed
            self.start_delay = max(t_ego - self._time, 0.0)
        if self.since_trigger(world) >= self.start_delay:
            self._released = True
            rows = np.array(self.hazard_rows, np.int64)
            limit = world.town.index.speed_limit[t.lane[rows]]
            t.hold[rows] = False
            t.speed[rows] = self._speed
            t.v0[rows] = np.where(
                t.kind[rows] == BICYCLE, self._speed, self._speed / np.maximum(limit, 1.0)
            )


# ---------------------------------------------------------------------------------------------
class _OccludedFlow(FlowScenario):
    """Shared logic of the non-signalized flow turns: an actor flow (:class:`~.flows.Flow`, as
    CARLA's ActorFlow) the ego must find a gap in, and a standing truck (row 0) that hides the flow
    from the ego. The flow runs from reset on, independent of the ego (its vehicles only brake,
    IDM, for what is in their lane, the ego included) and ignores its sign, as CARLA's flows do.

    Drawn per instance (world generator, at reset): the flow's speed (``speed`` times a factor in
    :data:`~.timed.SPEED_SCALE`), every gap between its vehicles (uniform in ``spacing_min`` ..
    ``spacing_max`` m, so where the flow stands when the ego arrives), and the truck's place
    (its parameter plus :data:`~.timed.POSITION_JITTER_M`)."""

    family = "junction"
    v2x = True
    max_actors = 12
    trigger_distance = 45.0
    towns = ("Town01", "Town05", "Town02")

    def setup(self, world, rows: np.ndarray) -> None:
        self.speed_scale = float(world.rng.uniform(*SPEED_SCALE))
        self.position_jitter = float(world.rng.uniform(*POSITION_JITTER_M))
        super().setup(world, rows)

    def flow_paths(self, town: Town) -> tuple:
        if len(self.site.extra) != 2:
            raise ValueError(f"scenario {self.name}: site.extra must be one (path, s) pair")
        return (self.site.extra,)

    def flow_rows(self) -> np.ndarray:
        return self.rows[1:]

    def flow_speed(self) -> float:
        return float(self.params["speed"]) * self.speed_scale

    def spawn(self, world) -> None:
        (path, _), = self.flow_paths(world.town)
        self.place_truck(world, int(path[0]), truck_size(world.rng))
        super().spawn(world)

    def place_truck(self, world, flow_lane: int, size: tuple[float, float, float]) -> None:
        """Put the occluding truck (row 0, of ``size``) in place (override)."""
        raise NotImplementedError


def oncoming_sites(town: Town) -> list[Site]:
    """Left turns from a lane that must yield (stop sign, or the minor road of a priority
    junction) across the oncoming approach's outer lane, next to an inner lane with a left turn of
    its own (where the truck waits). ``extra``: the flow's ``(path, conflict s on it)``."""
    sites = []
    for s in crossing_sites(town, (PRIORITY, STOP), (LEFT,), minor=True, sides=("opposite",)):
        for path, s_path in s.extra:
            inner = town.lanes[path[0]].left
            if inner < 0 or not connectors(town, inner, (LEFT,)):
                continue
            hit = lanes_conflict(town, s.lanes[1], path[1])
            if hit is not None:
                sites.append(Site(s.lanes, 1, hit[0], (tuple(path), s_path)))
                break
    return sites


@register_scenario
class NonSignalizedJunctionLeftTurn(_OccludedFlow):
    """CARLA LB2.0 NonSignalizedJunctionLeftTurn: at a junction without lights the ego makes an
    unprotected left turn across a flow of oncoming vehicles and must find a gap in it.

    Here the ego comes from a road that must yield (a stop sign, or the minor road of a priority
    junction) and the flow (:class:`_OccludedFlow`) drives straight through in the outer lane of
    the oncoming approach. **V2X addition**: a truck of the oncoming approach's inner lane stands
    just inside the junction waiting to turn left itself (its front ``into_junction`` m along its
    left-turn connector, clear of the ego's path) and hides the flow behind it from the ego at
    its stop line and while it pulls into the junction (the classic left-turn case for
    cooperation); the roadside units at the junction see the flow.

    Parameters: ``speed`` (m/s) of the flow; ``spacing_min`` / ``spacing_max`` (m, centre to
    centre) between its vehicles; ``into_junction`` (m) of the truck's front past its lane's end.
    """

    name = "NonSignalizedJunctionLeftTurn"
    towns = ("Town01", "Town05")
    defaults = {"speed": 10.0, "spacing_min": 25.0, "spacing_max": 70.0, "into_junction": 3.0}

    @classmethod
    def find_sites(cls, town):
        return oncoming_sites(town)

    @classmethod
    def actor_lanes(cls, town, site):
        lanes = super().actor_lanes(town, site)
        inner = town.lanes[site.extra[0][0]].left  # where the truck waits (``place_truck``)
        if inner >= 0:
            lanes |= {inner, *connectors(town, inner, (LEFT,))}
        return lanes - set(site.lanes)

    def place_truck(self, world, flow_lane, size):
        town = world.town
        inner = town.lanes[flow_lane].left
        turns = connectors(town, inner, (LEFT,)) if inner >= 0 else []
        if not turns:
            raise ValueError(
                f"scenario {self.name}: flow lane {flow_lane} has no inner lane turning left"
            )
        clear_lanes(world, [inner])
        # its centre on the inner lane / left connector, the front into_junction m past the lane end
        s = float(self.params["into_junction"]) + self.position_jitter - size[0] / 2
        lane = turns[0] if s >= 0.0 else inner
        p, h = lane_point(town, lane, s if s >= 0.0 else town.index.length[inner] + s)
        spawn_static(world, int(self.rows[0]), LARGE_VEHICLE, p, h, size, parked=True)


@register_scenario
class NonSignalizedJunctionRightTurn(_OccludedFlow):
    """CARLA LB2.0 NonSignalizedJunctionRightTurn: at a junction without lights the ego turns
    right and must merge into a flow of vehicles coming from its left on the crossing road.

    Here the ego comes from a road that must yield (the minor road of a priority junction, where
    the flow has priority; an all-way stop where the town has none) and the flow
    (:class:`_OccludedFlow`) drives straight through into the lane the ego turns into.
    **V2X addition**: a truck parked at the near kerb of the crossing road on the ego's left, its
    front just before the crosswalk, and the corner buildings hide the flow from the ego at its
    stop line; the roadside unit at the junction sees the flow.

    Parameters: ``speed`` (m/s) of the flow; ``spacing_min`` / ``spacing_max`` (m, centre to
    centre) between its vehicles; ``truck_gap`` (m) between the truck's front and the crosswalk.
    """

    name = "NonSignalizedJunctionRightTurn"
    towns = ("Town01", "Town06", "Town02", "Town05")
    defaults = {"speed": 10.0, "spacing_min": 25.0, "spacing_max": 70.0, "truck_gap": 0.3}

    @classmethod
    def find_sites(cls, town):
        sites = []
        for control in (PRIORITY, STOP):
            for s in merge_sites(town, RIGHT, (control,), minor=True, from_side="left"):
                sites.append(Site(s.lanes, s.key, s.s_on_key, s.extra[0]))
            if sites:  # priority junctions where the town has them
                break
        return sites

    def place_truck(self, world, flow_lane, size):
        # at the kerb of the flow's road on the side that faces the ego's approach
        town = world.town
        side = side_of(town, flow_lane, town.lanes[self.site.lanes[0]].points[-1])
        lat = side * (carriageway_edge(town, flow_lane, side) + 0.3 + size[1] / 2)
        s_front = town.index.length[flow_lane] - 2 * CROSSWALK_HALF - float(self.params["truck_gap"])
        park_vehicle(world, self.rows[0], flow_lane, s_front + self.position_jitter, lat, size)


@register_scenario
class CrossingBicycleFlow(_PriorityHazard):
    """The ego turns at an unsignalized junction across a flow of bicycles with priority.

    The ego, on a road that must yield, turns right (the flow comes from its left and rides on
    into the lane the ego turns into) or left (the flow comes from its right). The bicycles ride
    at the right edge of the crossing road (its bike lane); a truck parked at the near kerb and
    the corner buildings hide them. They wait ``distance`` m before the junction, ``spacing`` m
    (plus up to 4 m) apart, and ride off at ``speed`` once the ego leaves its stop line, the first
    timed to meet it (see :class:`_PriorityHazard`), ignoring the ego: the ego must find a gap.

    Parameters: ``count`` bicycles (1-5); ``speed`` (m/s); ``distance`` (m); ``spacing`` (m);
    ``truck_gap`` (m) between the truck's front and the crosswalk.
    """

    name = "CrossingBicycleFlow"
    max_actors = 6
    speed_cap = 8.0
    defaults = {"count": 4, "speed": 5.0, "distance": 25.0, "spacing": 7.0, "truck_gap": 0.3}

    @classmethod
    def find_sites(cls, town):
        return priority_sites(town, RIGHT, 1.0) + priority_sites(town, LEFT, -1.0)

    def hazard_count(self) -> int:
        return int(np.clip(self.params["count"], 1, self.max_actors - 1))

    def _spawn_hazard(self, world, row: int, lane: int, s: float, plan: list[int]) -> None:
        t = world.table
        spawn_driver(
            world,
            row,
            lane,
            s,
            kind=BICYCLE,
            hold=True,
            ignore_rules=True,
            plan=plan,
            size=draw_size(BICYCLE, world.rng),
        )
        t.behaviour[row] = RIDER
        t.v0[row] = float(self.params["speed"])
        edge = -(world.town.index.width[lane] / 2.0 - 0.6)
        t.lat[row] = edge
        p, h = lane_point(world.town, lane, s, edge)
        t.pos[row], t.yaw[row] = p, h
