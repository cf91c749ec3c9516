"""Junction conflicts: signalized turns across or into flows, vehicles running red lights or taking
priority, yielding to an ego with priority, and oncoming vehicles invading the ego's lane before a
turn (CARLA Leaderboard 2.0 names). Built on the helpers of ``flows.py``.

V2XBench signals use split phasing (one approach green at a time), so no two signal-green flows
ever cross. Where CARLA freezes the lights so that the ego *and* a crossing flow both have green
(SignalizedJunctionLeftTurn / RightTurn), the flow here ignores its light instead: its vehicles
behave as if they had the permissive green CARLA gives them.

Every class here registers itself with ``@register_scenario``.
"""

from __future__ import annotations

import numpy as np

from ..core.classes import CAR, TRAFFIC_CONE
from ..town.model import LEFT, PRIORITY, RIGHT, SIGNAL, STOP, STRAIGHT
from ..traffic.signals import RED
from ..traffic.vehicles import STOP_LINE_SETBACK
from .base import Scenario, Site
from .flows import (
    Flow,
    FlowScenario,
    connectors,
    crossing_sites,
    ego_eta,
    green_for,
    merge_sites,
    park,
    resolve_extra,
    set_speed,
    side_of,
)
from .placement import clear_lanes, clear_near, lane_point, spawn_scripted, spawn_static
from .registry import register_scenario


# ---------------------------------------------------------------------------- signalized turns
@register_scenario
class SignalizedJunctionLeftTurn(FlowScenario):
    """The ego turns left at a signalized junction while a dense flow of oncoming vehicles goes
    straight through; it must wait for a gap. The oncoming flow behaves as if it had a
    permissive green at the same time as the ego (it ignores its own light; see module docstring).

    Parameters: ``speed`` (m/s) of the oncoming flow; ``spacing_min`` / ``spacing_max`` (m).
    """

    name = "SignalizedJunctionLeftTurn"
    family = "junction"
    towns = ("Town01", "Town03", "Town05", "Town02")
    defaults = {"speed": 10.0, "spacing_min": 25.0, "spacing_max": 70.0}

    @classmethod
    def find_sites(cls, town):
        return crossing_sites(town, (SIGNAL,), (LEFT,), minor=None, sides=("opposite",))


@register_scenario
class SignalizedJunctionRightTurn(FlowScenario):
    """The ego turns right at a signalized junction into a road carrying a dense flow that comes
    straight through from the ego's left (with a permissive green, see module docstring); it
    must merge into a gap.

    Parameters: ``speed`` (m/s) of the flow; ``spacing_min`` / ``spacing_max`` (m).
    """

    name = "SignalizedJunctionRightTurn"
    family = "junction"
    towns = ("Town01", "Town03", "Town05", "Town02")
    defaults = {"speed": 10.0, "spacing_min": 25.0, "spacing_max": 70.0}

    @classmethod
    def find_sites(cls, town):
        return merge_sites(town, RIGHT, controls=(SIGNAL,), minor=False, from_side="left")


# ---------------------------------------------------------------------------- crossing adversaries
class CrossingAdversary(Scenario):
    """Base: one vehicle waits ``source_dist`` m before its stop line on a crossing approach and
    crosses straight through the junction at ``speed`` m/s without braking for anyone, released
    (as CARLA's adversaries) when the ego's time to the conflict point equals its own, or when the
    ego moves off within 12 m of it.
    ``direction``: side it comes from (``"right"``, ``"left"``, ``"any"``)."""

    family = "junction"
    max_actors = 1
    trigger_distance = 45.0
    timeout_s = 60.0
    defaults = {"speed": 12.0, "source_dist": 25.0, "direction": "right"}

    def spawn(self, world) -> None:
        town, t = world.town, world.table
        paths = resolve_extra(self, town)
        e = self.site.lanes[0]
        side = self.params["direction"]
        pick = [p for p in paths if side in ("any", side_of(town, e, p[0][0]))] or list(paths)
        path, s_conf = pick[int(world.rng.integers(len(pick)))]
        row = int(self.rows[0])
        v = float(self.params["speed"])
        self.flow = Flow(world, path, [row], v, (1e3, 1e3), 0.0, None, True, large_fraction=0.0)
        self.lane_in = int(path[0])
        self.line_s = float(town.index.length[self.lane_in] - STOP_LINE_SETBACK)
        self.s_conf = float(s_conf)
        # where the chosen path crosses the ego's route (the site's conflict point is the first
        # crossing on the ego's connector, possibly with another lane of the same approach)
        self.cross_xy = self.flow.point(town, s_conf)[0]
        r = self.route
        near = np.flatnonzero(np.abs(r.s - self.conflict_s) < 30.0)
        k = near[np.argmin(np.linalg.norm(r.points[near] - self.cross_xy, axis=1))]
        self.cross_s = float(r.s[k])
        s0 = max(self.line_s - float(self.params["source_dist"]), 2.0)
        clear_lanes(world, list(path))
        clear_near(world, self.conflict_point, 12.0)
        self.flow.place(world, row, s0, 0.0)
        t.hold[row] = True
        self.released = False
        self.hazard_rows = [row]

    def may_release(self, world) -> bool:
        """Extra release condition (override)."""
        return True

    def update(self, world) -> None:
        t, row = world.table, int(self.rows[0])
        if not t.active[row]:
            return
        v = float(self.params["speed"])
        if not self.released:
            s = float(self.flow.path_s(t)[0])
            t_adv = (self.s_conf - s) / v
            near = self.cross_s - self.ego_s(world) < 12.0 and t.speed[0] > 1.0
            if (ego_eta(self, world, self.cross_s) <= t_adv or near) and self.may_release(world):
                self.released = True
                t.hold[row] = False
                set_speed(world, row, v)
            return
        if float(self.flow.path_s(t)[0]) < self.s_conf + 10.0:
            # as CARLA's adversary it ignores other vehicles (the ego too) until past the crossing
            set_speed(world, row, v)
        else:
            t.v0[row] = v / world.town.index.speed_limit[t.lane[row]]


def adversary_sites(town, controls, ego_minor, adv_minor) -> list[Site]:
    """Ego going straight (or left) across a straight crossing from the left or the right."""
    return crossing_sites(
        town,
        controls,
        (STRAIGHT, LEFT),
        minor=ego_minor,
        sides=("left", "right"),
        flow_minor=adv_minor,
    )


@register_scenario
class OppositeVehicleRunningRedLight(CrossingAdversary):
    """At a signalized junction a vehicle from a crossing approach runs its red light while the
    ego crosses on green. It ignores all rules and is released only while the ego's light is
    green and stays green until it reaches its own stop line, so it always enters on red.

    Parameters: ``speed`` (m/s); ``source_dist`` (m) before its stop line where it waits;
    ``direction`` it comes from (``"right"``, ``"left"``, ``"any"``).
    """

    name = "OppositeVehicleRunningRedLight"
    towns = ("Town01", "Town03", "Town05", "Town02")

    @classmethod
    def find_sites(cls, town):
        return adversary_sites(town, (SIGNAL,), None, None)

    def may_release(self, world) -> bool:
        t_line = (self.line_s - float(self.flow.path_s(world.table)[0])) / float(
            self.params["speed"]
        )
        return (
            green_for(world, self.site.lanes[0], t_line + 0.5)
            and world.lane_signal[self.lane_in] == RED
        )


@register_scenario
class OppositeVehicleTakingPriority(CrossingAdversary):
    """At an unsignalized junction a vehicle from a road that must give way (stop sign or minor
    road) drives straight through without stopping, just as the ego, which has priority (or
    stopped first at an all-way stop), crosses.

    Parameters: ``speed`` (m/s); ``source_dist`` (m) before its stop line where it waits;
    ``direction`` it comes from (``"right"``, ``"left"``, ``"any"``).
    """

    name = "OppositeVehicleTakingPriority"
    towns = ("Town01", "Town05", "Town02")

    @classmethod
    def find_sites(cls, town):
        return adversary_sites(town, (PRIORITY,), False, True) + adversary_sites(
            town, (STOP,), True, True
        )


@register_scenario
class PriorityAtJunction(Scenario):
    """CARLA's PriorityAtJunction: at a signalized junction the ego goes straight on and its light
    is set green (the conflicting approaches red) as it comes within ``trigger_distance`` m of
    the junction, so it can cross at speed; vehicles on the crossing roads (one per side where
    available) arrive fast, timed to the ego's arrival (CARLA's time-to-arrival trigger), and must
    stop at their red light. The ego must keep its green instead of freezing.

    The override goes through :meth:`~..signals.SignalPlan.force_green` (approaches that were
    green turn yellow for the junction's yellow time first) and ends once the ego has passed
    (or with the episode). As in CARLA this is not a V2X type: nothing is hidden.

    Parameters: ``speed`` (m/s) of the crossing vehicles; ``source_dist`` (m) before their stop
    line where they start.
    """

    name = "PriorityAtJunction"
    family = "junction"
    max_actors = 2
    towns = ("Town01", "Town05")
    trigger_distance = 60.0
    defaults = {"speed": 10.0, "source_dist": 45.0}

    @classmethod
    def find_sites(cls, town):
        return crossing_sites(town, (SIGNAL,), (STRAIGHT,), minor=None, sides=("left", "right"))

    def spawn(self, world) -> None:
        town = world.town
        e = self.site.lanes[0]
        by_side: dict[str, tuple] = {}
        for p in resolve_extra(self, town):
            by_side.setdefault(side_of(town, e, p[0][0]), p)
        self.cars = []
        v = float(self.params["speed"])
        for row, (path, _) in zip(self.rows, by_side.values()):
            # obeys its light (ignore_rules=False): the forced red stops it at its line
            f = Flow(world, path, [int(row)], v, (1e3, 1e3), 0.0, None, False, large_fraction=0.0)
            line = float(town.index.length[path[0]] - STOP_LINE_SETBACK)
            f.place(world, int(row), max(line - float(self.params["source_dist"]), 2.0), 0.0)
            world.table.hold[row] = True
            clear_lanes(world, list(path))
            self.cars.append((int(row), f, line))
        for row in self.rows[len(self.cars) :]:
            park(world.table, int(row))
        clear_near(world, self.conflict_point, 12.0)
        self.state = {r: "waiting" for r, _, _ in self.cars}
        self.hazard_rows = [r for r, _, _ in self.cars]
        self.forced = False

    def green_lanes(self, town) -> list[int]:
        """The ego's approach's phase group: the lanes that go green with it."""
        e = self.site.lanes[0]
        j = town.junctions[int(town.index.junction[self.site.lanes[1]])]
        return next(list(g) for g in j.phase_groups if e in g)

    def on_trigger(self, world) -> None:
        world.signals.force_green(self.green_lanes(world.town), world.tick * world.config.dt)
        self.forced = True  # (World.update_signals applies it this tick)

    def update(self, world) -> None:
        t, v = world.table, float(self.params["speed"])
        for row, f, line in self.cars:
            if self.state[row] != "waiting":
                continue
            s = float(f.path_s(t)[0])
            t_cross = (line - s) / v + 4.5  # time to reach and stop at the line (IDM brakes early)
            if ego_eta(self, world, self.conflict_s) <= t_cross:
                t.hold[row] = False
                set_speed(world, row, v)
                self.state[row] = "approaching"
        if self.forced and self.ego_s(world) > self.conflict_s + 6.0:
            world.signals.release()
            self.forced = False
            for row, _, _ in self.cars:
                t.hold[row] = False


# ---------------------------------------------------------------------------- invading turn
@register_scenario
class InvadingTurn(Scenario):
    """As the ego approaches a junction where it turns right, oncoming vehicles leaving that
    junction invade its lane by ``invasion`` m (cones narrow their own lane); the ego must keep to
    the right of its lane to avoid them.

    The invading vehicles are scripted: they drive at ``speed`` m/s along the opposite lane,
    shifted towards the ego, and do not brake. The first one is released so that it meets the ego
    at the conflict point; the others follow ``spacing`` m apart.

    Parameters: ``invasion`` (m) of their near side over the centre line; ``speed`` (m/s);
    ``count`` of vehicles (at most 3); ``spacing`` (m).
    """

    name = "InvadingTurn"
    family = "junction"
    max_actors = 8
    towns = ("Town06", "Town01", "Town05")
    trigger_distance = 60.0
    defaults = {"invasion": 1.0, "speed": 8.0, "count": 3, "spacing": 25.0}

    @classmethod
    def find_sites(cls, town):
        sites = []
        for ln in town.lanes:
            o = ln.opposite
            if o < 0 or ln.length < 60 or ln.left >= 0 or not connectors(town, ln.id, (RIGHT,)):
                continue
            if np.linalg.norm(town.lanes[o].points[0] - ln.points[-1]) > 8.0:
                continue
            sites.append(Site((ln.id, connectors(town, ln.id, (RIGHT,))[0]), 0, 0.6 * ln.length))
        return sites

    def spawn(self, world) -> None:
        town, t = world.town, world.table
        e = self.site.lanes[0]
        self.o = o = int(town.lanes[e].opposite)
        # they appear where the opposite lane leaves the junction (as CARLA's invading flow source)
        _, s_meet, _ = town.index.project(self.conflict_point[None], np.array([o]))
        self.s_meet = float(s_meet[0])
        w = float(town.index.width[o])
        n = int(np.clip(self.params["count"], 1, 3))
        self.cars = [int(r) for r in self.rows[:n]]
        for row in self.cars:
            spawn_scripted(world, row, CAR, lane_point(town, o, 2.0)[0], 0.0)
            park(t, row)
        for k, row in enumerate(self.rows[3:]):
            p, h = lane_point(town, o, self.s_meet - 12.0 + 6.0 * k, -(w / 2 - 0.45))
            spawn_static(world, int(row), TRAFFIC_CONE, p, h, (0.4, 0.4, 0.7))
        clear_lanes(world, [o, e])
        self.s_car: dict[int, float] = {}
        self.hazard_rows = list(self.cars)

    def pose(self, world, row: int, s: float) -> tuple[np.ndarray, float]:
        """Pose at arc length ``s`` on the opposite lane, shifted towards the ego so that the near
        side is ``invasion`` m over the centre line."""
        town, t = world.town, world.table
        shift = float(self.params["invasion"]) + town.index.width[self.o] / 2 - t.width[row] / 2
        return lane_point(town, self.o, s, shift)

    def update(self, world) -> None:
        t, dt = world.table, world.config.dt
        v = float(self.params["speed"])
        waiting = [r for r in self.cars if r not in self.s_car]
        if waiting:
            last = min(self.s_car.values()) if self.s_car else None  # the latest released
            first_go = (
                last is None and ego_eta(self, world, self.conflict_s) <= (self.s_meet - 2.0) / v
            )
            if first_go or (last is not None and last > 2.0 + float(self.params["spacing"])):
                self.s_car[waiting[0]] = 2.0
        end = float(world.town.index.length[self.o]) - 12.0
        for row, s in list(self.s_car.items()):
            if s > end:
                if t.active[row]:
                    park(t, row)
                continue
            p, h = self.pose(world, row, s)
            t.active[row], t.pos[row], t.yaw[row], t.speed[row] = True, p, h, v
            self.s_car[row] = s + v * dt
