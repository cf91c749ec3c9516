"""Per-tick infraction and route-progress events for the ego (structured, numeric).

Event codes are stable integers (``EVENT_NAMES``); :class:`EventMonitor` turns world state into a
list of ``(code, tick, other_actor_id, value)`` rows and running counters. Metrics (RC, IS, DS)
are computed from these events in ``metrics.py`` - this module only detects. The rules follow
CARLA Leaderboard 2.0's criteria:

- collisions (``CollisionTest``): a contact with the same party as the last registered collision
  within :data:`COLLISION_SAME_ACTOR_S` of it is ignored, and so is any contact while the ego is
  within :data:`COLLISION_NEAR_M` of where it was at a registered collision; such a place is
  forgotten once the ego is more than :data:`COLLISION_FORGET_M` from it. Bicycles are vehicles.
  A collision's ``value`` is where on the ego the other party was (``SIDE_*``, :func:`contact_side`:
  front, left, right, rear; 0 for statics), so "the ego drove into the car ahead" and "a car
  drove into the ego" can be told apart.
- outside the route's lanes (``OutsideRouteLanesTest``): off the drivable lanes, or (outside
  junctions) on a lane that is not one of the route's, the opposite lane included. Scenarios that
  need the ego to leave its lanes may switch the second part off (``route_lanes_test``, CARLA's
  ``SwitchWrongDirectionTest``).
- held by a red light: standing in a lane that ends at a red light with the ego's front at most
  :data:`HELD_BY_RED_M` before the stop line; it stops the blocked clock and scenario clocks.

A pedestrian or cyclist the ego has hit leaves the world :data:`HIT_VRU_LEAVES_S` after the
collision (:meth:`EventMonitor.leaving`, applied by ``World.check_events``): walkers do not walk
into a standing car, so one standing in the ego's way after a collision would otherwise wait for
the ego while the ego waits for it.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.actors import ActorTable
from ..core.classes import BICYCLE, CAR, LARGE_VEHICLE, PEDESTRIAN
from ..core.geometry import row_norms
from ..core.jit import HAVE_JIT
from ..core.jit_args import PackedArgs
from ..core.jit_grid import point_grid
from ..town.model import CONNECTOR, PARKING, Town
from ..town.routes import Route
from ..traffic.signals import RED
from ..traffic.vehicles import STOP_LINE_SETBACK, stop_sign_lanes
from .jit_events import (
    MAX_LANE_EVENTS,
    STATE_DRIVEN_M,
    STATE_HELD_BY_RED,
    STATE_LANE,
    STATE_MIN_SPEED_NEAR_LINE,
    STATE_OFF_ROAD,
    STATE_OUTSIDE,
    STATE_OUTSIDE_M,
    STATE_ROUTE_LANES_TEST,
    STATE_S_ON_LANE,
    STATE_SIZE,
    STATE_STILL_S,
    STATE_WRONG_WAY,
    monitor_kernel,
)
from .physics import CollisionWorld

(COLLISION_PEDESTRIAN, COLLISION_VEHICLE, COLLISION_STATIC, RED_LIGHT, STOP_SIGN, OUTSIDE_LANES,
 OFF_ROAD, WRONG_WAY, ROUTE_DEVIATION, BLOCKED, SCENARIO_TIMEOUT, YIELD_EMERGENCY) = range(12)
EVENT_NAMES = ("collision_pedestrian", "collision_vehicle", "collision_static", "red_light",
               "stop_sign", "outside_lanes", "off_road", "wrong_way", "route_deviation", "blocked",
               "scenario_timeout", "yield_emergency")
NUM_EVENTS = len(EVENT_NAMES)

COLLISION_SAME_ACTOR_S = 5.0  # s: the last registered collision's party is ignored this long after it
COLLISION_NEAR_M = 3.0  # m: contacts while the ego is this close to a registered collision's place are ignored
COLLISION_FORGET_M = 5.0  # m: a registered collision's place is forgotten once the ego is further from it
# A collision event's ``value`` says where on the ego the other party was (its centre's bearing in
# the ego's frame): ahead within 45 degrees of the heading, behind within 45, else left or right.
# 0 is a static party (and every collision of records written before the sides were recorded).
SIDE_UNKNOWN, SIDE_FRONT, SIDE_LEFT, SIDE_RIGHT, SIDE_REAR = range(5)
HIT_VRU_LEAVES_S = 2.0  # s after its collision with the ego, a pedestrian or cyclist leaves the world
ROUTE_DEVIATION_M = 30.0  # m
BLOCKED_S = 180.0  # s without moving (no red light ahead) ends the route
STOP_SPEED = 0.5  # m/s: below this near the line counts as having stopped at a stop sign
STOP_CHECK_M = 6.0  # m before the stop line where the stop must happen
HELD_SPEED = 1.0  # m/s: slower than this in a lane ending at a red light, the ego is held by it...
HELD_BY_RED_M = 15.0  # m: ...when its front is at most this far before the stop line (two cars queued)

_NO_CONTACTS = np.zeros(0, np.int64)
_NO_FLOATS = np.zeros(0)


def _state_slot(index: int, doc: str) -> property:
    """A float attribute of :class:`EventMonitor` kept in slot ``index`` of its state array."""

    def get(self) -> float:
        return float(self._state[index])

    def set(self, value: float) -> None:
        self._state[index] = value

    return property(get, set, doc=doc)


class EventMonitor:
    """Detects the ego's infractions and route progress, tick by tick.

    Attributes:
        counts: ``(NUM_EVENTS,)`` occurrences so far.
        events: list of ``(code, tick, other_id, value)``.
        progress: index of the last route point passed. outside_m / driven_m: distance driven
            outside the route's lanes / in total (m). still_s: the blocked clock (s).
            held_by_red: the ego waits at a red light near its stop line. route_lanes_test:
            whether lanes not on the route count as outside.
    """

    def __init__(self, town: Town, route: Route, dt: float) -> None:
        self.town, self.route, self.dt = town, route, dt
        self._length = max(route.length, 1e-9)  # the route is fixed for the episode
        self.counts = np.zeros(NUM_EVENTS, np.int64)
        self.events: list[tuple[int, int, int, float]] = []
        self.progress = 0
        # the running state of both paths (jit_events.STATE_* slots)
        self._state = np.zeros(STATE_SIZE)
        self._state[STATE_LANE] = int(route.lane_ids[0])
        self._state[STATE_MIN_SPEED_NEAR_LINE] = np.inf
        self._state[STATE_ROUTE_LANES_TEST] = 1.0
        # the collision filter: the last registered party and tick, the ego's places at registered
        # collisions; pedestrians and cyclists hit, with the tick they leave the world
        self._last_party: int | None = None
        self._last_hit_tick = 0
        self._hit_places: list[tuple[float, float]] = []
        self._leave_at: dict[int, int] = {}
        self._on_route = np.zeros(len(town.lanes), np.bool_)
        self._on_route[np.asarray(route.lanes, np.int64)] = True
        self._on_route_list = self._on_route.tolist()
        self._driving_pts = _driving_point_ids(town)
        self._driving_grid = _driving_grid(town)
        self._lanes = _lane_lists(town)  # Python numbers: the same values, cheaper scalar tests
        self._args = PackedArgs()
        self._contacts = _NO_CONTACTS
        self._codes = np.zeros(MAX_LANE_EVENTS, np.int64)
        self._values = np.zeros(MAX_LANE_EVENTS)

    outside_m = _state_slot(STATE_OUTSIDE_M, "m driven outside the lanes")
    driven_m = _state_slot(STATE_DRIVEN_M, "m driven in all")
    still_s = _state_slot(STATE_STILL_S, "s the ego has stood still (< 0.1 m/s) while not held by a red light "
                                         "(the blocked clock)")

    @property
    def held_by_red(self) -> bool:
        """The ego stands (< ``HELD_SPEED``) in a lane that ends at a red light, its front at most
        ``HELD_BY_RED_M`` before the stop line (or past it)."""
        return bool(self._state[STATE_HELD_BY_RED])

    @property
    def route_lanes_test(self) -> bool:
        """Whether distance on lanes that are not the route's counts as outside the route lanes
        (on by default; a scenario that makes the ego go around an obstacle may switch it off
        meanwhile, as CARLA's ``SwitchWrongDirectionTest``). Leaving the drivable lanes always
        counts."""
        return bool(self._state[STATE_ROUTE_LANES_TEST])

    @route_lanes_test.setter
    def route_lanes_test(self, on: bool) -> None:
        self._state[STATE_ROUTE_LANES_TEST] = 1.0 if on else 0.0

    def leaving(self, tick: int) -> list[int]:
        """Rows of the pedestrians and cyclists hit by the ego whose time to leave the world
        (``HIT_VRU_LEAVES_S`` after the collision) has come by ``tick``; each is returned once."""
        due = [row for row, at in self._leave_at.items() if at <= tick]
        for row in due:
            del self._leave_at[row]
        return due

    def emit(self, code: int, tick: int, other: int = -1, value: float = 0.0) -> None:
        """Record an event (scenarios emit ``SCENARIO_TIMEOUT`` and ``YIELD_EMERGENCY`` here)."""
        self.counts[code] += 1
        self.events.append((code, tick, other, value))

    @property
    def route_completion(self) -> float:
        """Percent of the route length passed (0-100)."""
        return 100.0 * float(self.route.s[self.progress]) / self._length

    def update_world(self, tick: int, t: ActorTable, collisions: CollisionWorld, lane_signal: np.ndarray,
                     old_xy: list[float]) -> list[tuple[int, int, int, float]]:
        """:meth:`update` for the tick a world just moved: the ego's contacts from ``collisions``
        and the distance it moved from ``old_xy`` (its ``(x, y)`` before the move). With numba
        all of it is one kernel call (``jit_events.monitor_kernel``)."""
        if not HAVE_JIT:
            contacts = collisions.ego_contacts(t)
            x, y = t.pos[0].tolist()  # (np.linalg.norm takes BLAS's dot, which may fuse the multiply-adds)
            dx, dy = x - old_xy[0], y - old_xy[1]
            return self.update(tick, t, contacts, lane_signal, math.sqrt(dx * dx + dy * dy))
        n0 = len(self.events)
        nc, self.progress, ne = monitor_kernel(self._kernel_args(t, collisions), lane_signal, self.progress, 0.0,
                                               old_xy[0], old_xy[1], True)
        if nc or self._hit_places:
            self._collisions(tick, t, self._contacts[:nc])
        if ne:
            self._lane_events(tick, ne)
        return self.events[n0:]

    def update(self, tick: int, t: ActorTable, contacts: np.ndarray, lane_signal: np.ndarray,
               moved: float) -> list[tuple[int, int, int, float]]:
        """Process one tick: ``contacts`` are the ego's (``physics.CollisionWorld.ego_contacts``),
        ``moved`` the metres it moved; returns the events emitted in it."""
        n0 = len(self.events)
        if HAVE_JIT:
            ex, ey = t.pos[0].tolist()
            _, self.progress, ne = monitor_kernel(self._kernel_args(t, None), lane_signal, self.progress, moved, ex,
                                                  ey, False)
            if len(contacts) or self._hit_places:
                self._collisions(tick, t, contacts)
            if ne:
                self._lane_events(tick, ne)
            return self.events[n0:]
        st = self._state
        yaw, v = float(t.yaw[0]), float(t.speed[0])
        st[STATE_DRIVEN_M] += moved
        if len(contacts) or self._hit_places:
            self._collisions(tick, t, contacts)
        # route progress: furthest route point within 3 m ahead in a window
        r = self.route
        ix = self.town.index
        ego = t.pos[0]
        hi = min(self.progress + 40, len(r.points))
        d = row_norms(r.points[self.progress:hi] - ego)
        close = np.flatnonzero(d < 3.0)
        if len(close):
            self.progress += int(close[-1])
        dev = float(np.min(row_norms(r.points[max(self.progress - 20, 0): self.progress + 40] - ego)))
        # lane-relative checks: nearest lane among drivable lanes
        lane, s, dist = ix.project_near(ego, self._driving_pts)
        lane, s, dist = int(lane[0]), float(s[0]), float(dist[0])
        heading = float(ix.pose_at(np.array([lane]), np.array([s]))[1][0])
        if dev > ROUTE_DEVIATION_M and not self.counts[ROUTE_DEVIATION]:
            self.emit(ROUTE_DEVIATION, tick, -1, dev)
        lanes = self._lanes
        half = lanes["width"][lane] / 2.0
        off_lanes = dist > half + 0.3
        # on a lane that is not the route's (junctions excepted: their connectors overlap)
        other_lane = (bool(st[STATE_ROUTE_LANES_TEST]) and lanes["kind"][lane] != CONNECTOR
                      and not self._on_route_list[lane])
        outside = off_lanes or other_lane
        if outside:
            st[STATE_OUTSIDE_M] += moved
        if outside and not st[STATE_OUTSIDE]:
            self.emit(OUTSIDE_LANES, tick, -1, dist)
        off_road = dist > half + 2.0
        if off_road and not st[STATE_OFF_ROAD]:
            self.emit(OFF_ROAD, tick, -1, dist)
        st[STATE_OUTSIDE], st[STATE_OFF_ROAD] = outside, off_road
        wrong = v > 1.0 and not off_lanes and abs(((yaw - heading + np.pi) % (2 * np.pi)) - np.pi) > 2.1
        wrong = wrong and lanes["kind"][lane] != CONNECTOR
        if wrong and not st[STATE_WRONG_WAY]:
            self.emit(WRONG_WAY, tick, -1, float(lane))
        st[STATE_WRONG_WAY] = wrong
        # stop lines: red lights and stop signs, when crossing the line of the current lane
        stop_at_end = lanes["stop_at_end"][lane]
        line = lanes["length"][lane] - STOP_LINE_SETBACK
        if lane == int(st[STATE_LANE]):
            if stop_at_end and line - STOP_CHECK_M < s:
                st[STATE_MIN_SPEED_NEAR_LINE] = min(float(st[STATE_MIN_SPEED_NEAR_LINE]), v)
            if stop_at_end and float(st[STATE_S_ON_LANE]) < line <= s:
                if lane_signal[lane] == RED:
                    self.emit(RED_LIGHT, tick, -1, float(lane))
                elif (lane_signal[lane] == -1 and self._is_stop_lane(lane)
                      and st[STATE_MIN_SPEED_NEAR_LINE] > STOP_SPEED):
                    self.emit(STOP_SIGN, tick, -1, float(lane))
        else:
            st[STATE_MIN_SPEED_NEAR_LINE] = np.inf
        st[STATE_LANE], st[STATE_S_ON_LANE] = lane, s
        # held by a red light near its stop line (it stops the blocked clock), blocked
        gap = line - s - 0.5 * float(t.length[0])  # the ego's front to the stop line
        held = stop_at_end and lane_signal[lane] == RED and v < HELD_SPEED and gap <= HELD_BY_RED_M
        st[STATE_HELD_BY_RED] = held
        still = float(st[STATE_STILL_S])
        if v >= 0.1:
            still = 0.0
        elif not held:
            still = still + self.dt
        if still >= BLOCKED_S:
            self.emit(BLOCKED, tick, -1, still)
            still = 0.0
        st[STATE_STILL_S] = still
        return self.events[n0:]

    def _collisions(self, tick: int, t: ActorTable, contacts: np.ndarray) -> None:
        """Collision events by class of the other party (statics are encoded as negative ids),
        through CARLA's filter: the places of registered collisions the ego is now more than
        ``COLLISION_FORGET_M`` from are forgotten, and the last party ``COLLISION_SAME_ACTOR_S``
        after its collision; then a contact with the last party, or while the ego is within
        ``COLLISION_NEAR_M`` of a remembered place, is ignored. Contacts are taken in the given
        order, so of two in one tick only the first registers. Called on every tick with contacts
        or remembered places (the places are forgotten as the ego moves)."""
        ex, ey = t.pos[0].tolist()
        if self._hit_places:
            self._hit_places = [p for p in self._hit_places
                                if math.hypot(ex - p[0], ey - p[1]) <= COLLISION_FORGET_M]
        if self._last_party is not None and (tick - self._last_hit_tick) * self.dt > COLLISION_SAME_ACTOR_S + 1e-9:
            self._last_party = None
        for c in contacts:
            key = int(c)
            if key == self._last_party or any(math.hypot(ex - p[0], ey - p[1]) <= COLLISION_NEAR_M
                                              for p in self._hit_places):
                continue
            self._last_party, self._last_hit_tick = key, tick
            self._hit_places.append((ex, ey))
            if c < 0:
                self.emit(COLLISION_STATIC, tick, key)
                continue
            kind = int(t.kind[c])
            code = (COLLISION_PEDESTRIAN if kind == PEDESTRIAN else
                    COLLISION_VEHICLE if kind in (CAR, LARGE_VEHICLE, BICYCLE) else COLLISION_STATIC)
            if kind in (PEDESTRIAN, BICYCLE):
                self._leave_at.setdefault(key, tick + int(round(HIT_VRU_LEAVES_S / self.dt)))
            ox, oy = t.pos[c].tolist()
            self.emit(code, tick, int(t.actor_id[c]), float(contact_side(ox - ex, oy - ey, float(t.yaw[0]))))

    def _lane_events(self, tick: int, ne: int) -> None:
        """Emit the ``ne`` lane events the kernel wrote."""
        for code, value in zip(self._codes[:ne].tolist(), self._values[:ne].tolist()):
            self.emit(code, tick, -1, value)

    def _kernel_args(self, t: ActorTable, collisions: CollisionWorld | None):
        """``jit_events.monitor_kernel``'s typed list of the episode's arguments, kept while the
        table and the collision world are the same objects (``None``: no static boxes)."""
        return self._args.get((t, collisions), lambda: self._build_args(t, collisions))

    def _build_args(self, t: ActorTable, collisions: CollisionWorld | None) -> tuple:
        ix = self.town.index
        if collisions is None:
            statics, cos, sin, radius = np.zeros((0, 5)), _NO_FLOATS, _NO_FLOATS, _NO_FLOATS
        else:
            statics, cos, sin, radius = collisions.kernel_args()
        self._contacts = np.zeros(len(t) + len(statics), np.int64)
        return (t.pos, t.yaw, t.length, t.width, t.active, t.speed, statics, cos, sin, radius, self.route.points,
                ix.points, self._driving_pts, ix.owner, ix.offset, ix.n_points, ix.gs, ix.base, ix.heading,
                ix.length, *self._driving_grid, ix.width, ix.kind, ix.stop_at_end, stop_sign_lanes(self.town),
                STOP_LINE_SETBACK, float(self.dt), self.counts, self._state, self._contacts, self._codes,
                self._values, self._on_route)

    def _is_stop_lane(self, lane: int) -> bool:
        j = self.town.index.junction_ahead[lane]
        return j >= 0 and lane in self.town.junctions[j].stop_lanes


def contact_side(dx: float, dy: float, ego_yaw: float) -> int:
    """``SIDE_*`` code of a party whose centre is ``(dx, dy)`` (world frame) from the ego's centre:
    front / rear within 45 degrees of the ego's heading / its reverse, else left or right."""
    bearing = math.degrees(math.atan2(dy, dx) - ego_yaw)
    bearing = (bearing + 180.0) % 360.0 - 180.0
    if abs(bearing) <= 45.0:
        return SIDE_FRONT
    if abs(bearing) >= 135.0:
        return SIDE_REAR
    return SIDE_LEFT if bearing > 0 else SIDE_RIGHT


def _lane_lists(town: Town) -> dict[str, list]:
    """Per-lane ``width``, ``length``, ``kind`` and ``stop_at_end`` as Python lists (cached on the
    town): the monitor's scalar tests on them cost a fraction of NumPy scalar operations."""
    store = town.cache("lanes")
    lists = store.get("lists")
    if lists is None:
        ix = town.index
        lists = {k: getattr(ix, k).tolist() for k in ("width", "length", "kind", "stop_at_end")}
        store["lists"] = lists
    return lists


def _driving_grid(town: Town) -> tuple:
    """``jit_grid.point_grid`` of :func:`_driving_point_ids` (cached on the town)."""
    store = town.cache("lanes")
    if "driving_grid" not in store:
        store["driving_grid"] = point_grid(town.index.points, _driving_point_ids(town))
    return store["driving_grid"]


def _driving_point_ids(town: Town) -> np.ndarray:
    """Point ids of all non-parking lanes (cached on the town)."""
    store = town.cache("lanes")
    if "driving_point_ids" not in store:
        pid = town.index.point_ids(np.array([ln.id for ln in town.lanes if ln.kind != PARKING]))
        pid.setflags(write=False)
        store["driving_point_ids"] = pid
    return store["driving_point_ids"]
