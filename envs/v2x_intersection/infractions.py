"""Per-tick infraction and route-progress events for the ego (structured, numeric).

Event codes are stable integers (``EVENT_NAMES``); :class:`EventMonitor` turns world state into a
list of ``(code, tick, other_actor_id, value)`` rows and running counters. Metrics (RC, IS, DS)
are computed from these events in ``metrics.py`` (later) - this module only detects.
"""

from __future__ import annotations

import numpy as np

from .actors import ActorTable
from .classes import BICYCLE, CAR, LARGE_VEHICLE, PEDESTRIAN
from .geometry import row_norms
from .jit import HAVE_JIT
from .jit_grid import point_grid
from .jit_perception import route_monitor_kernel
from .routes import Route
from .signals import RED
from .town.model import CONNECTOR, PARKING, Town
from .traffic import STOP_LINE_SETBACK

(COLLISION_PEDESTRIAN, COLLISION_VEHICLE, COLLISION_STATIC, RED_LIGHT, STOP_SIGN, OUTSIDE_LANES,
 OFF_ROAD, WRONG_WAY, ROUTE_DEVIATION, BLOCKED, SCENARIO_TIMEOUT, YIELD_EMERGENCY) = range(12)
EVENT_NAMES = ("collision_pedestrian", "collision_vehicle", "collision_static", "red_light",
               "stop_sign", "outside_lanes", "off_road", "wrong_way", "route_deviation", "blocked",
               "scenario_timeout", "yield_emergency")
NUM_EVENTS = len(EVENT_NAMES)

REPEAT_COLLISION_S = 3.0  # s: repeated contacts with the same actor inside this window count once
ROUTE_DEVIATION_M = 30.0  # m
BLOCKED_S = 180.0  # s without moving (no red light ahead) ends the route
STOP_SPEED = 0.5  # m/s: below this near the line counts as having stopped at a stop sign
STOP_CHECK_M = 6.0  # m before the stop line where the stop must happen
HELD_SPEED = 1.0  # m/s: slower than this in a lane ending at a red light, the ego is held by it


class EventMonitor:
    """Detects the ego's infractions and route progress, tick by tick.

    Attributes:
        counts: ``(NUM_EVENTS,)`` occurrences so far.
        events: list of ``(code, tick, other_id, value)``.
        progress: index of the last route point passed. outside_m / driven_m: distance driven
            outside the lanes / in total (m).
    """

    def __init__(self, town: Town, route: Route, dt: float) -> None:
        self.town, self.route, self.dt = town, route, dt
        self._length = max(route.length, 1e-9)  # the route is fixed for the episode
        self.counts = np.zeros(NUM_EVENTS, np.int64)
        self.events: list[tuple[int, int, int, float]] = []
        self.progress = 0
        self.outside_m = 0.0
        self.driven_m = 0.0
        self.still_s = 0.0
        self.held_by_red = False  # the ego stands (< 1 m/s) in a lane that ends at a red light
        self._last_hit: dict[int, int] = {}
        self._lane = int(route.lane_ids[0])
        self._s_on_lane = 0.0
        self._min_speed_near_line = np.inf
        self._wrong_way_active = False
        self._outside_active = False
        self._off_road_active = False
        self._driving_pts = _driving_point_ids(town)
        self._driving_grid = _driving_grid(town)
        self._lanes = _lane_lists(town)  # Python numbers: the same values, cheaper scalar tests

    def emit(self, code: int, tick: int, other: int = -1, value: float = 0.0) -> None:
        """Record an event (scenarios emit ``SCENARIO_TIMEOUT`` and ``YIELD_EMERGENCY`` here)."""
        self.counts[code] += 1
        self.events.append((code, tick, other, value))

    @property
    def route_completion(self) -> float:
        """Percent of the route length passed (0-100)."""
        return 100.0 * float(self.route.s[self.progress]) / self._length

    def update(self, tick: int, t: ActorTable, contacts: np.ndarray, lane_signal: np.ndarray,
               moved: float) -> list[tuple[int, int, int, float]]:
        """Process one tick; returns the events emitted in it."""
        n0 = len(self.events)
        yaw, v = float(t.yaw[0]), float(t.speed[0])
        self.driven_m += moved
        # collisions (by class of the other party); statics are encoded as negative ids
        for c in contacts:
            key = int(c)
            last = self._last_hit.get(key)
            self._last_hit[key] = tick
            if last is not None and (tick - last) * self.dt < REPEAT_COLLISION_S:
                continue
            if c < 0:
                self.emit(COLLISION_STATIC, tick, key)
                continue
            kind = int(t.kind[c])
            code = (COLLISION_PEDESTRIAN if kind in (PEDESTRIAN, BICYCLE) else
                    COLLISION_VEHICLE if kind in (CAR, LARGE_VEHICLE) else COLLISION_STATIC)
            self.emit(code, tick, int(t.actor_id[c]))
        # route progress: furthest route point within 3 m ahead in a window
        r = self.route
        ix = self.town.index
        if HAVE_JIT:
            ex, ey = t.pos[0].tolist()
            self.progress, dev, lane, s, dist, heading = route_monitor_kernel(
                r.points, self.progress, ex, ey, ix.points, self._driving_pts, ix.owner,
                ix.offset, ix.n_points, ix.gs, ix.base, ix.heading, ix.length, *self._driving_grid)
        else:
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
        outside = dist > half + 0.3
        if outside:
            self.outside_m += moved
        if outside and not self._outside_active:
            self.emit(OUTSIDE_LANES, tick, -1, dist)
        off_road = dist > half + 2.0
        if off_road and not self._off_road_active:
            self.emit(OFF_ROAD, tick, -1, dist)
        self._outside_active, self._off_road_active = outside, off_road
        wrong = v > 1.0 and not outside and abs(((yaw - heading + np.pi) % (2 * np.pi)) - np.pi) > 2.1
        wrong = wrong and lanes["kind"][lane] != CONNECTOR
        if wrong and not self._wrong_way_active:
            self.emit(WRONG_WAY, tick, -1, float(lane))
        self._wrong_way_active = wrong
        # stop lines: red lights and stop signs, when crossing the line of the current lane
        stop_at_end = lanes["stop_at_end"][lane]
        if lane == self._lane:
            line = lanes["length"][lane] - STOP_LINE_SETBACK
            if stop_at_end and line - STOP_CHECK_M < s:
                self._min_speed_near_line = min(self._min_speed_near_line, v)
            if stop_at_end and self._s_on_lane < line <= s:
                if lane_signal[lane] == RED:
                    self.emit(RED_LIGHT, tick, -1, float(lane))
                elif lane_signal[lane] == -1 and self._is_stop_lane(lane) and self._min_speed_near_line > STOP_SPEED:
                    self.emit(STOP_SIGN, tick, -1, float(lane))
        else:
            self._min_speed_near_line = np.inf
        self._lane, self._s_on_lane = lane, s
        # blocked
        self.still_s = self.still_s + self.dt if v < 0.1 else 0.0
        red_ahead = stop_at_end and lane_signal[lane] == RED
        self.held_by_red = bool(red_ahead and v < HELD_SPEED)
        if self.still_s >= BLOCKED_S and not red_ahead:
            self.emit(BLOCKED, tick, -1, self.still_s)
            self.still_s = 0.0
        return self.events[n0:]

    def _is_stop_lane(self, lane: int) -> bool:
        j = self.town.index.junction_ahead[lane]
        return j >= 0 and lane in self.town.junctions[j].stop_lanes


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
