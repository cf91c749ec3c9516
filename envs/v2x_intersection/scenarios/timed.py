"""The base of the hidden-hazard scenarios: a CARLA-style trigger, then a hazard on its own.

See :class:`TimedScenario`. Used by the crossing family (:mod:`.v2x`) and the turning and
junction families (:mod:`.v2x_junction`).
"""

from __future__ import annotations

import numpy as np

from ..traffic.pedestrians import ego_in_the_way
from .base import Scenario

WALKER_EGO_MARGIN = 0.4  # m around the ego's box in which a scenario walker stops for it
#: per-instance draws of :class:`TimedScenario` (uniform ranges)
SPEED_SCALE = (0.85, 1.15)  # factor on the hazard's nominal speed
START_DELAY_S = (0.0, 0.5)  # s from the trigger to the hazard's start
TRIGGER_JITTER_S = (-0.2, 0.2)  # s added to the trigger's time to arrival
POSITION_JITTER_M = (-0.4, 0.4)  # m along the road of the hazard's waiting spot
RETREAT_AFTER_S = 3.0  # s a walker stands before a car in its way before it steps back


class TimedScenario(Scenario):
    """Base for hazards started by a CARLA-style trigger and then independent of the ego.

    **Trigger** (checked every tick until it fires, then never again; :meth:`triggered_now`): the
    ego's time to arrival at the conflict point *at its current speed* drops to the instance's
    trigger time (CARLA's ``InTimeToArrivalToLocation``; the front bumper's arrival if
    :attr:`aim_front`), or the ego comes within :attr:`min_trigger_m` of the conflict point
    (``InTriggerDistanceToLocation``). A standing ego never reaches a time to arrival, so standing
    still and waiting does not start a hidden hazard, but coming close does, whatever the
    lights (pedestrians cross in front of a car waiting at a red light).

    **After the trigger** the hazard waits its start delay and moves at its own speed along its
    path, whatever the ego does or sees: no release after the ego waited, no pacing. A walker
    pauses only for a (nearly) standing car whose body blocks its next metre
    (:meth:`walkers_yield`): what the pedestrian itself can see.

    **Drawn per instance** (from the world's generator at reset, so each route and seed differ):
    the hazard's speed (``params["speed"]`` times a factor in :data:`SPEED_SCALE`), its start
    delay after the trigger (:data:`START_DELAY_S`), a jitter of the trigger time
    (:data:`TRIGGER_JITTER_S`) and a shift of its waiting spot along the road
    (:data:`POSITION_JITTER_M`, where the subclass uses :attr:`position_jitter`). The trigger
    time is set so that a hazard that starts and moves as drawn enters the ego's path
    :attr:`aim_delay_s` after the ego's centre gets there (negative: before) if the ego keeps the
    speed it had at the trigger: the conflict really happens unless the ego reacts, which an ego
    that cannot see the hazard can only do late.
    """

    #: m: CARLA's minimum trigger distance (InTriggerDistanceToLocation)
    min_trigger_m = 6.0
    #: m/s: below this ego speed the time to arrival counts as infinite
    min_tta_speed = 0.1
    #: m: a crossing walker or rider is in the ego's way once it is this close to the centre
    #: line of the ego's lane (half the ego's width plus a small margin)
    path_half_width = 1.2
    #: time the arrival to the ego's front bumper instead of its centre
    aim_front = False
    #: s: a hazard aims to enter the ego's path this long after the ego's timed point (its
    #: centre) reaches the conflict point; negative: before. A walker crossing the path is in
    #: the car's way from about 1.2 s before its centre arrives to L / 2v after, so -0.1 s hits
    #: a car that keeps its speed across the trigger jitter, at 5-14 m/s
    aim_delay_s = -0.1
    #: m/s: released walkers pause for an ego at most this fast that blocks their way
    yield_speed = 1.0

    def setup(self, world, rows: np.ndarray) -> None:
        rng = world.rng
        self.speed_scale = float(rng.uniform(*SPEED_SCALE))
        self.start_delay = float(rng.uniform(*START_DELAY_S))
        self.trigger_jitter = float(rng.uniform(*TRIGGER_JITTER_S))
        self.position_jitter = float(rng.uniform(*POSITION_JITTER_M))
        self.hazard_trigger_tick = -1  # tick the hazard's trigger fired (-1: not yet)
        self._walk_speed: dict[int, float] = {}  # walking speeds of held walkers
        self._walking: set[int] = set()  # walkers released
        self._yielding: set[int] = set()  # walkers paused for the ego in their way
        self._paused: dict[int, float] = {}  # s each walker has been paused for the ego
        self._home: dict[int, np.ndarray] = {}  # where each walker waited (it may step back there)
        self._retreating: set[int] = set()  # walkers stepping back for a car that waits for them
        super().setup(world, rows)

    def hazard_speed(self) -> float:
        """The hazard's speed for this instance: ``params["speed"]`` times the drawn factor."""
        return float(self.params["speed"]) * self.speed_scale

    def time_to_path(self, lateral: float, speed: float) -> float:
        """Time (s) a hazard ``lateral`` m from the ego lane's centre line, moving straight towards
        it at ``speed`` m/s, needs to enter the ego's path (:attr:`path_half_width`)."""
        return max(lateral - self.path_half_width, 0.0) / max(speed, 0.1)

    def trigger_time(self, hazard_time: float) -> float:
        """Time to arrival (s) at which the trigger fires for a hazard that needs ``hazard_time`` s
        after its start to reach the ego's path."""
        return max(hazard_time + self.start_delay - self.aim_delay_s + self.trigger_jitter, 0.0)

    def ego_tta(self, world) -> float:
        """The ego's time to arrival (s) at the conflict point at its current speed (its front
        bumper's if :attr:`aim_front`); ``inf`` for a (nearly) standing ego."""
        d = self.conflict_s - self.ego_s(world) - self._front(world)
        v = float(world.table.speed[0])
        return max(d, 0.0) / v if v >= self.min_tta_speed else float("inf")

    def triggered_now(self, world, hazard_time: float) -> bool:
        """Whether the hazard's trigger fires this tick (see the class docstring); once it has
        fired it stays fired, whatever the ego does."""
        if self.hazard_trigger_tick >= 0:
            return True
        d = self.conflict_s - self.ego_s(world)
        if d <= self.min_trigger_m or self.ego_tta(world) <= self.trigger_time(hazard_time):
            self.hazard_trigger_tick = world.tick
            return True
        return False

    def since_trigger(self, world) -> float:
        """Seconds since the hazard's trigger fired (negative before)."""
        if self.hazard_trigger_tick < 0:
            return -1.0
        return (world.tick - self.hazard_trigger_tick) * world.config.dt

    def started(self, world, hazard_time: float) -> bool:
        """Whether the hazard moves: its trigger fired and its start delay has passed."""
        fired = self.triggered_now(world, hazard_time)
        return fired and self.since_trigger(world) >= self.start_delay

    def _front(self, world) -> float:
        """Distance (m) from the ego's centre to the point whose arrival is timed."""
        return 0.5 * float(world.table.length[0]) if self.aim_front else 0.0

    def hold_walker(self, world, row: int, speed: float | None = None) -> None:
        """Make a freshly spawned walker wait, standing still; it walks at ``speed`` (default: its
        spawn speed) once released."""
        self._walk_speed[int(row)] = float(world.table.speed[row] if speed is None else speed)
        self._home[int(row)] = world.table.pos[row].copy()
        world.table.speed[row] = 0.0
        world.table.hold[row] = True

    def release_walker(self, world, row: int) -> None:
        """Let a walker held by :meth:`hold_walker` go at its walking speed."""
        world.table.hold[row] = False
        world.table.speed[row] = self._walk_speed.get(int(row), 1.4)
        self._walking.add(int(row))

    def step_one_walker(self, world, row: int, lateral: float) -> None:
        """The ``update`` of a scenario with one crossing walker ``row`` that waits ``lateral`` m
        from the ego lane's centre line: release it once :meth:`started`, then let it yield."""
        if row not in self._walking and self.started(
            world, self.time_to_path(lateral, self._walk_speed[row])
        ):
            self.release_walker(world, row)
        self.walkers_yield(world)

    @staticmethod
    def _clear_way(t, start: np.ndarray, end: np.ndarray) -> bool:
        """Whether the straight way from ``start`` to ``end`` misses the ego's box."""
        pts = start + np.linspace(0.0, 1.0, 12)[:, None] * (end - start)
        return not bool(ego_in_the_way(t, pts, 0.0).any())

    def walkers_yield(self, world) -> None:
        """Released walkers pause when a (nearly) standing ego's body blocks their next metre
        (they see the car in front of them) and, once paused, wait until the car's body has left
        their way (a pedestrian who stopped for a car does not walk into it as it pulls away); a
        walker paused :data:`RETREAT_AFTER_S` s steps back to where it waited (the car waits for
        it too: one of them has to give way). Otherwise they walk at their own speed: into a
        moving car's path (that is the hazard) but not into a car standing on it. Call every
        tick."""
        t = world.table
        ego_standing = float(t.speed[0]) <= self.yield_speed
        for row in self._walking:
            left = t.cross_to[row] - t.pos[row]
            dist = float(np.hypot(*left))
            if not t.active[row] or t.path[row] >= 0 or dist < 0.05:
                continue
            ahead = t.pos[row] + left / dist * min(1.0, dist)
            in_way = bool(ego_in_the_way(t, ahead[None], WALKER_EGO_MARGIN)[0])
            if row in self._retreating:  # stepping back along a way clear of the car's body
                in_way = bool(ego_in_the_way(t, ahead[None], 0.0)[0])
            blocked = in_way and (ego_standing or row in self._yielding)
            if blocked:
                self._yielding.add(row)
                self._paused[row] = self._paused.get(row, 0.0) + world.config.dt
                if self._paused[row] >= RETREAT_AFTER_S and row in self._home and self._clear_way(
                    t, t.pos[row], self._home[row]
                ):
                    # a car stands in the way and waits too: step back to the kerb it came from
                    # (past the car's bumper, not through it)
                    t.cross_from[row], t.cross_to[row] = t.cross_to[row].copy(), self._home.pop(row)
                    self._retreating.add(row)
                    blocked = False
            else:
                self._paused[row] = 0.0
            if not blocked:
                self._yielding.discard(row)
            t.hold[row] = blocked
            t.speed[row] = 0.0 if blocked else self._walk_speed[row]
