"""Static obstacles in the ego lane: accidents, road works, a parked vehicle and an opening car
door, on multi-lane roads and on two-way roads with oncoming traffic (ControlLoss, which used to
be debris here, perturbs the ego's control instead: :mod:`.control_loss`).

None of these is V2X-specific. The route always runs straight through the blocked lane (as in
CARLA): the driver must leave it (change lane, or invade the opposite lane of a two-way road when
the oncoming flow leaves a gap). Shared pieces used by :mod:`.parking` too: :func:`lane_sites`,
:class:`LaneFlow` (a recycled stream of vehicles along one lane) and :func:`plan_from`.

Every class here registers itself with ``@register_scenario``.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, NamedTuple

import numpy as np

from ..core.actors import draw_size
from ..core.classes import CAR, LARGE_VEHICLE, STATIC_OBSTACLE, TRAFFIC_CONE, TRAFFIC_SIGN
from ..town.model import DRIVING, PARKING, Town
from ..traffic.vehicles import occupied
from .base import Scenario, Site, completing_s
from .placement import (
    clear_lanes,
    clear_near,
    lane_point,
    spawn_driver,
    spawn_scripted,
    spawn_static,
)
from .registry import register_scenario

CONE = (0.4, 0.4, 0.7)  # m, traffic cone (length, width, height)
FLOW_ROWS = 5  # actor rows reserved for an oncoming flow
ENTRY_HIDDEN_M = 90.0  # a lane flow re-enters vehicles only while the ego is farther from its entry
#: oncoming flow: mean spacing (m) and desired speed (factor of the speed limit)
FLOW_DEFAULTS: dict[str, float] = {"flow_gap": 55.0, "flow_speed": 0.8}
MULTI_TOWNS = ("Town03", "Town04", "Town01", "Town05")
TWO_WAY_TOWNS = ("Town06", "Town02", "Town05", "Town01", "Town03")


# ---------------------------------------------------------------------------------------- helpers
def lane_sites(
    town: Town,
    span: float,
    frac: float = 0.45,
    min_lead: float = 15.0,
    pred=None,
    back: float = 0.0,
) -> list[Site]:
    """One site per plain driving lane where ``span`` m fit after the conflict point.

    The conflict point sits at ``frac`` of the lane (as late as possible on lanes entering the map,
    which have no run-up before them), moved so that ``[s, s + span]`` ends 10 m before the lane's
    end (12 m on lanes leaving the map, where the route ends), starts at least ``min_lead`` m into
    the lane and keeps ``[s - back, s + span]`` clear of mid-block crosswalks; ``pred(lane) ->
    bool`` filters.
    """
    sites = []
    mid = [c.corners.mean(0) for c in town.crosswalks if c.junction == -1]
    for ln in town.lanes:
        if ln.kind != DRIVING or (pred is not None and not pred(ln)):
            continue
        hi = ln.length - span - (10.0 if ln.successors else 12.0)
        s = min(max(frac * ln.length if ln.predecessors else hi, min_lead), hi)
        if mid:  # keep mid-block crosswalks (4 m wide) out of [s - 4, s + span + 4]
            _, cs, d = town.index.project(np.array(mid), np.array([ln.id]))
            for c in np.sort(cs[d < 12.0]):
                if s - back - 6.0 < c < s + span + 6.0:
                    s = c + back + 6.0 if c + back + 6.0 <= hi else c - 6.0 - span
        if min_lead <= s <= hi:
            sites.append(Site((ln.id,), 0, float(s)))
    return sites


def is_multi_lane(ln) -> bool:
    """A lane with a same-direction neighbour."""
    return ln.left >= 0 or ln.right >= 0


def is_two_way_single(ln) -> bool:
    """A lane of a two-way road with one lane per direction."""
    return ln.opposite >= 0 and ln.left < 0 and ln.right < 0


def free_side(town: Town, lane: int) -> float:
    """+1 when the ego gets around an obstacle on the left (a left neighbour, else the opposite
    lane of a one-lane-per-direction road), -1 on the right (only a right neighbour)."""
    ln = town.lanes[lane]
    return -1.0 if (ln.left < 0 and ln.right >= 0) else 1.0


def plan_from(route, lane: int) -> list[int]:
    """The route's lane sequence from ``lane`` on (a fixed plan for scenario vehicles)."""
    return list(route.lanes[route.lanes.index(lane) :])


class LaneFlow:
    """A stream of vehicles along one lane, recycled in a fixed set of table rows.

    At spawn, vehicles are spread over ``[s_lo, s_hi]`` of the lane; every tick a free row (one
    whose vehicle reached the end of its plan) re-enters at ``s_lo`` (only while the ego is more
    than ``ENTRY_HIDDEN_M`` from there: vehicles never pop up in view) once the previous vehicle is
    ``gap`` m (times a uniform factor in [0.5, 2.5], so that the flow leaves gaps long enough to
    overtake through now and then) down the lane and the entry is clear. Rows
    keep their size.
    """

    def __init__(
        self,
        rows: np.ndarray,
        lane: int,
        gap: float,
        speed: float,
        s_lo: float = 1.0,
        s_hi: float | None = None,
        plan: list[int] | None = None,
        ignore_rules: bool = True,
    ) -> None:
        self.rows, self.lane, self.gap, self.speed = [int(r) for r in rows], lane, gap, speed
        self._row_index = np.array(self.rows, np.int64)
        self.s_lo, self.s_hi, self.plan, self.ignore_rules = (
            s_lo,
            s_hi,
            plan or [lane],
            ignore_rules,
        )
        self.last, self.next_gap, self.plan_id = -1, gap, -1
        self._entry: np.ndarray | None = None  # lane point at s_lo, computed on first use

    def _draw_gap(self, rng: np.random.Generator) -> float:
        return float(self.gap * rng.uniform(0.5, 2.5))

    def _put(self, world, row: int, s: float) -> None:
        t = world.table
        v = self.speed * float(world.town.index.speed_limit[self.lane])
        spawn_driver(
            world,
            row,
            self.lane,
            s,
            int(t.kind[row]),
            speed=v,
            v0=self.speed,
            ignore_rules=self.ignore_rules,
            size=(t.length[row], t.width[row], t.height[row]),
        )
        t.plan[row], t.plan_pos[row] = self.plan_id, 0
        self.last = row

    def spawn(self, world) -> None:
        """Size every row, spread the first vehicles over the lane, leave the rest inactive."""
        t, rng = world.table, world.rng
        world.plans.append(list(self.plan))
        self.plan_id = len(world.plans) - 1
        hi = self.s_hi if self.s_hi is not None else world.town.index.length[self.lane] - 10.0
        s = self.s_lo + rng.uniform(0.0, self.gap)
        for row in self.rows:
            t.kind[row] = LARGE_VEHICLE if rng.random() < 0.15 else CAR
            t.length[row], t.width[row], t.height[row] = draw_size(int(t.kind[row]), rng)
        for row in self.rows:
            self._put(world, row, min(s, hi))
            if s > hi:
                t.active[row] = False
            s += self._draw_gap(rng)
        self.next_gap = self._draw_gap(rng)
        self.last = next((r for r in self.rows if t.active[r]), -1)
        if self.last >= 0:  # the vehicle nearest the entry spaces the next one
            self.last = min((r for r in self.rows if t.active[r]), key=lambda r: t.s[r])

    def update(self, world) -> None:
        """Re-enter one vehicle at the lane start when there is room."""
        t = world.table
        active = t.active[self._row_index].tolist()  # a short list: Python's all() beats ndarray.all()
        if all(active):
            return
        free = self.rows[active.index(False)]  # the first inactive row
        lead = self.last
        if (
            lead >= 0
            and t.active[lead]
            and t.lane[lead] == self.lane
            and t.s[lead] - self.s_lo < self.next_gap
        ):
            return
        if self._entry is None:
            self._entry = lane_point(world.town, self.lane, self.s_lo)[0]
        p = self._entry
        if _ego_within(t, p, ENTRY_HIDDEN_M) or occupied(t, p, 7.0):
            return  # no vehicle appears out of nowhere within sight of the ego
        self._put(world, free, self.s_lo)
        self.next_gap = self._draw_gap(world.rng)


def _ego_within(t, p: np.ndarray, radius: float) -> bool:
    """``np.linalg.norm(t.pos[0] - p) < radius`` without building arrays: the distance in Python
    floats decides where it is more than ``1e-9`` m from ``radius``; closer, ``np.linalg.norm``
    itself does (its BLAS dot may round differently in the last bit)."""
    ex, ey = t.pos[0].tolist()
    px, py = p.tolist()
    dx, dy = ex - px, ey - py
    d = math.sqrt(dx * dx + dy * dy)
    if abs(d - radius) > 1e-9:
        return d < radius
    return bool(np.linalg.norm(t.pos[0] - p) < radius)


class Item(NamedTuple):
    """One static box of a lane-obstacle layout.

    ``ds``: m after the conflict point along the lane; ``q``: m from the lane centre toward the
    kerb side (negative: toward the side the ego passes on); ``dyaw``: rad, nose toward the pass side.
    """

    kind: int
    ds: float
    q: float
    size: tuple[float, float, float]
    dyaw: float = 0.0
    parked: bool = False


class _LaneBlock(Scenario):
    """Base of the lane-obstacle scenarios: ``layout()`` boxes from the conflict point on, on a
    multi-lane road (the ego changes lane) or, with ``two_way``, on a one-lane-per-direction road
    with an oncoming :class:`LaneFlow` in the opposite lane (the ego invades it when clear)."""

    two_way: ClassVar[bool] = False
    lanes_free = True  # driving around the block in another lane is the manoeuvre
    n_items: ClassVar[int] = 1  # boxes returned by layout()
    n_extra: ClassVar[int] = 0  # rows after the items used by subclasses
    span: ClassVar[float] = 20.0  # m of lane the layout covers after the conflict point

    @classmethod
    def find_sites(cls, town):
        return lane_sites(town, cls.span, pred=is_two_way_single if cls.two_way else is_multi_lane)

    def __init__(self, route, site, conflict_s, params=None) -> None:
        super().__init__(route, site, conflict_s, params)
        # (``route.length - 1`` can lie beyond the completing progress: the route's last points
        # are not always 0.5 m apart)
        self.end_s = min(self.conflict_s + self.span + 10.0, completing_s(route))
        self.flow: LaneFlow | None = None

    def layout(self, width: float, rng: np.random.Generator) -> list[Item]:
        """The boxes (override); exactly ``n_items`` of them."""
        raise NotImplementedError

    def spawn(self, world) -> None:
        town = world.town
        lane = self.site.lanes[self.site.key]
        s0 = self.site.s_on_key
        self.free = free_side(town, lane)
        mid, _ = lane_point(town, lane, s0 + self.span / 2)
        clear_near(world, mid, self.span / 2 + 20.0)
        clear_lanes(world, [lane])
        items = self.layout(float(town.index.width[lane]), world.rng)
        for row, it in zip(self.rows, items):
            p, h = lane_point(town, lane, s0 + it.ds, -self.free * it.q)
            spawn_static(
                world, int(row), it.kind, p, h + self.free * it.dyaw, it.size, parked=it.parked
            )
        self.hazard_rows = [int(r) for r in self.rows[: self.n_items]]
        if self.two_way:
            opp = town.lanes[lane].opposite
            self.flow = LaneFlow(
                self.rows[self.n_items + self.n_extra :],
                opp,
                float(self.params["flow_gap"]),
                float(self.params["flow_speed"]),
            )
            self.flow.spawn(world)

    def tick(self, world) -> None:
        if self.flow is not None:
            self.flow.update(world)
        super().tick(world)


def _car(rng: np.random.Generator) -> tuple[float, float, float]:
    return draw_size(CAR, rng)


# -------------------------------------------------------------------------------------- accidents
class _AccidentBase(_LaneBlock):
    """Warning cones, a police car and two crashed cars (turned across the lane) in the ego lane."""

    family = "obstacle"
    n_items = 5
    span = 24.0
    trigger_distance = 40.0
    defaults = {"offset": 0.75}

    def layout(self, width, rng):
        half = width / 2
        police_q = float(self.params["offset"]) * half
        return [
            Item(TRAFFIC_CONE, 0.0, -0.2, CONE),
            Item(TRAFFIC_CONE, 2.0, 0.6, CONE),
            Item(CAR, 7.0, police_q, _car(rng), 0.0, True),
            Item(CAR, 15.0, 0.35 * half, _car(rng), 0.45, True),
            Item(CAR, 20.5, 0.3 * half, _car(rng), -0.55, True),
        ]


@register_scenario
class Accident(_AccidentBase):
    """An accident blocks the ego lane of a multi-lane road: two warning cones, a police car
    (``offset`` x half the lane width toward the kerb) and two crashed cars turned across the lane
    over ~24 m. The ego must change to the free neighbour lane and come back.

    Parameters: ``offset`` lateral offset of the police car as a fraction of the half lane width.
    """

    name = "Accident"
    max_actors = 5
    towns = MULTI_TOWNS


@register_scenario
class AccidentTwoWays(_AccidentBase):
    """:class:`Accident` on a two-way road with one lane per direction: the ego must invade the
    opposite lane when the oncoming flow leaves a gap.

    Parameters: ``offset`` as :class:`Accident`; ``flow_gap`` (m) mean spacing and ``flow_speed``
    (factor of the speed limit) of the oncoming vehicles.
    """

    name = "AccidentTwoWays"
    two_way = True
    max_actors = 5 + FLOW_ROWS
    towns = TWO_WAY_TOWNS
    defaults = {**_AccidentBase.defaults, **FLOW_DEFAULTS}


# ----------------------------------------------------------------------------------- construction
class _ConstructionBase(_LaneBlock):
    """A construction warning sign, a taper of five cones across the lane, a barrier and a line
    of cones along the lane edge: the ego lane is closed for ~24 m."""

    family = "obstacle"
    n_items = 9
    span = 24.0
    trigger_distance = 40.0
    defaults: ClassVar[dict[str, Any]] = {}

    def layout(self, width, rng):
        edge = width / 2 - 0.35
        taper = [Item(TRAFFIC_CONE, 4.0 + 2.5 * k, edge - k * 2 * edge / 4, CONE) for k in range(5)]
        return [
            Item(TRAFFIC_SIGN, 0.0, 0.3, (0.3, 1.0, 1.6)),
            *taper,
            Item(STATIC_OBSTACLE, 16.0, 0.0, (0.5, width - 0.8, 1.0)),
            Item(TRAFFIC_CONE, 20.0, -edge, CONE),
            Item(TRAFFIC_CONE, 24.0, -edge, CONE),
        ]


@register_scenario
class ConstructionObstacle(_ConstructionBase):
    """Road works close the ego lane of a multi-lane road (sign, cone taper, barrier, cone line);
    the ego must change to the free neighbour lane.

    Parameters: none.
    """

    name = "ConstructionObstacle"
    max_actors = 9
    towns = MULTI_TOWNS


@register_scenario
class ConstructionObstacleTwoWays(_ConstructionBase):
    """:class:`ConstructionObstacle` on a two-way road with one lane per direction and oncoming
    traffic: the ego must invade the opposite lane when clear.

    Parameters: ``flow_gap`` (m), ``flow_speed`` (factor of the speed limit) of the oncoming flow.
    """

    name = "ConstructionObstacleTwoWays"
    two_way = True
    max_actors = 9 + FLOW_ROWS
    towns = TWO_WAY_TOWNS
    defaults = dict(FLOW_DEFAULTS)


# --------------------------------------------------------------------------------- parked vehicle
class _ParkedBase(_LaneBlock):
    """A car (30%: a van) stands partially in the ego lane, pushed ``offset`` x half the lane
    width toward the kerb."""

    family = "obstacle"
    n_items = 1
    span = 6.0
    trigger_distance = 40.0
    defaults = {"offset": 0.7}

    def layout(self, width, rng):
        size = draw_size(LARGE_VEHICLE, rng) if rng.random() < 0.3 else _car(rng)
        size = (min(size[0], 7.0), size[1], size[2])
        return [
            Item(
                LARGE_VEHICLE if size[0] > 5.5 else CAR,
                size[0] / 2,
                float(self.params["offset"]) * width / 2,
                size,
                0.0,
                True,
            )
        ]


@register_scenario
class ParkedObstacle(_ParkedBase):
    """A vehicle parked partially in the ego lane of a multi-lane road blocks it; the ego must
    change to the neighbour lane to pass.

    Parameters: ``offset`` lateral offset toward the kerb as a fraction of the half lane width.
    """

    name = "ParkedObstacle"
    max_actors = 1
    towns = ("Town03", "Town01", "Town05", "Town04")


@register_scenario
class ParkedObstacleTwoWays(_ParkedBase):
    """:class:`ParkedObstacle` on a two-way road with oncoming traffic: the ego must invade the
    opposite lane when clear.

    Parameters: ``offset`` as :class:`ParkedObstacle`; ``flow_gap``, ``flow_speed`` of the flow.
    """

    name = "ParkedObstacleTwoWays"
    two_way = True
    max_actors = 1 + FLOW_ROWS
    towns = TWO_WAY_TOWNS
    defaults = {**_ParkedBase.defaults, **FLOW_DEFAULTS}


# ------------------------------------------------------------------------------------ opening door
@register_scenario
class VehicleOpensDoorTwoWays(_LaneBlock):
    """A car parked at the kerb of a two-way road (in the parking lane where there is one, its side
    ``intrude`` m inside the ego lane) opens its traffic-side door when the ego's time to reach it
    drops below ``reaction_time`` s (or it is within 10 m). The door is a thin scripted box (1.2 x
    0.2 x 1.2 m) swinging to ``door_angle`` within ``open_time`` s, so it reaches ~1.1 m into the ego
    lane; the ego must move into the opposite lane when the oncoming flow leaves a gap.

    Parameters: ``intrude`` (m), ``door_angle`` (rad), ``open_time`` (s), ``reaction_time`` (s),
    ``flow_gap``, ``flow_speed`` of the oncoming flow.
    """

    name = "VehicleOpensDoorTwoWays"
    family = "obstacle"
    two_way = True
    n_items = 1
    n_extra = 1
    max_actors = 2 + FLOW_ROWS
    span = 5.0
    trigger_distance = 40.0
    towns = ("Town06", "Town03", "Town02", "Town05", "Town01")
    defaults = {
        "intrude": 0.3,
        "door_angle": 1.2,
        "open_time": 1.0,
        "reaction_time": 3.0,
        **FLOW_DEFAULTS,
    }
    DOOR = (1.2, 0.2, 1.2)

    @classmethod
    def find_sites(cls, town):
        parked = {ln.road for ln in town.lanes if ln.kind == PARKING}
        both = lane_sites(
            town, cls.span, pred=lambda ln: is_two_way_single(ln) and ln.road in parked
        )
        return both or lane_sites(town, cls.span, pred=is_two_way_single)

    def layout(self, width, rng):
        size = _car(rng)
        return [
            Item(CAR, 0.0, width / 2 + size[1] / 2 - float(self.params["intrude"]), size, 0.0, True)
        ]

    def spawn(self, world) -> None:
        super().spawn(world)
        t = world.table
        car, door = self.hazard_rows[0], int(self.rows[1])
        spawn_scripted(world, door, STATIC_OBSTACLE, t.pos[car], float(t.yaw[car]), self.DOOR)
        t.active[door] = False
        self.hazard_rows = [car, door]
        self._open_tick = -1

    def _place_door(self, t, frac: float) -> None:
        car, door = self.hazard_rows
        theta = float(self.params["door_angle"]) * frac
        hinge = np.array([0.35, self.free * t.width[car] / 2])  # front hinge on the traffic side
        dirn = np.array([-np.cos(theta), self.free * np.sin(theta)])
        local = hinge + 0.5 * self.DOOR[0] * dirn
        c, s = np.cos(t.yaw[car]), np.sin(t.yaw[car])
        t.pos[door] = t.pos[car] + np.array(
            [c * local[0] - s * local[1], s * local[0] + c * local[1]]
        )
        t.yaw[door] = t.yaw[car] + np.arctan2(dirn[1], dirn[0])

    def update(self, world) -> None:
        t = world.table
        door = self.hazard_rows[1]
        if self._open_tick < 0:
            dist = self.conflict_s - self.ego_s(world)
            if dist <= 10.0 or dist / max(float(t.speed[0]), 0.5) <= float(
                self.params["reaction_time"]
            ):
                self._open_tick = world.tick
                t.active[door] = True
            else:
                return
        frac = min(
            (world.tick - self._open_tick + 1) * world.config.dt / float(self.params["open_time"]),
            1.0,
        )
        self._place_door(t, frac)
