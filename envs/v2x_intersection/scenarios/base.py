"""The scenario interface: a parameterized hazard placed on the ego's route.

A scenario is placed at a route arc length ``trigger_s`` (m). At reset it spawns its actors into
``max_actors`` reserved rows of the actor table (:meth:`Scenario.setup`); every tick the world
calls :meth:`Scenario.tick`, which fires :meth:`on_trigger` once when the ego comes within
``trigger_distance`` of the trigger point, then :meth:`update`. The ego *passes* the scenario
when its route progress reaches ``end_s``; if it has not passed ``timeout_s`` seconds after the
trigger, a ``SCENARIO_TIMEOUT`` event is emitted (CARLA's scenario timeout, IS factor 0.7). The
scenario clock stops while a red light holds the ego (``EventMonitor.held_by_red``): waiting
at a red light is obeying the rules, not failing to get through.

Subclasses set the class attributes, implement :meth:`find_sites` (where on a town it fits),
:meth:`spawn` and optionally :meth:`on_trigger` / :meth:`update`, and are registered with
:func:`~.registry.register_scenario`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..evaluation.infractions import SCENARIO_TIMEOUT
from ..town.model import Town
from ..town.routes import Route

REJOIN_M = 10.0  # m past a lanes-free scenario's end where driving outside the route lanes counts again


@dataclass(frozen=True)
class Site:
    """Where a scenario can happen: the lanes the ego drives through it, and the index in that
    lane sequence where the hazard is (its trigger lies ``lead_m`` before the lane's start)."""

    lanes: tuple[int, ...]
    key: int = 0  # index into ``lanes`` of the lane where the hazard happens
    s_on_key: float = 0.0  # arc length on that lane of the conflict point (m)
    extra: tuple = ()  # scenario-specific data (e.g. the crossing lane)


def completing_s(route: Route) -> float:
    """The route progress (m) that completes the route (``World.is_route_complete``: the third
    last route point); a scenario's end never lies beyond it, or it could never be passed."""
    return float(route.s[max(len(route.s) - 3, 0)])


class Scenario:
    """Base class; see the module docstring."""

    name: ClassVar[str] = ""
    family: ClassVar[str] = ""
    v2x: ClassVar[bool] = False
    max_actors: ClassVar[int] = 4
    towns: ClassVar[tuple[str, ...]] = ()  # preferred towns (empty: any)
    trigger_distance: ClassVar[float] = 35.0  # m before the conflict point
    timeout_s: ClassVar[float] = 60.0
    defaults: ClassVar[dict[str, Any]] = {}
    #: leaving the route's lanes is the manoeuvre here (around a blocked lane, making room for an
    #: emergency vehicle): the "outside the route's lanes" test is off from the trigger until the
    #: ego is ``REJOIN_M`` m past ``end_s`` (CARLA's SwitchWrongDirectionTest); off-road counts
    lanes_free: ClassVar[bool] = False
    #: the scenario rewrites the route to start at its site (the ego starts there, e.g. parked):
    #: it can only be a route's first scenario
    starts_route: ClassVar[bool] = False

    def __init__(self, route: Route, site: Site, conflict_s: float, params: dict | None = None) -> None:
        unknown = set(params or {}) - set(self.defaults)
        if unknown:
            raise ValueError(f"scenario {self.name}: unknown parameters {sorted(unknown)}; "
                             f"known: {sorted(self.defaults)}")
        self.params = {**self.defaults, **(params or {})}
        self.route, self.site = route, site
        self.conflict_s = float(conflict_s)  # route arc length of the conflict point (m)
        last = len(route.points) - 1
        k = min(max(int(np.searchsorted(route.s, conflict_s)), 0), last)  # np.clip on an int, cheaper
        self.conflict_point = route.points[k].copy()
        ts = max(conflict_s - self.trigger_distance, 0.0)
        self.trigger_s = ts
        self.trigger_point = route.points[min(max(int(np.searchsorted(route.s, ts)), 0), last)].copy()
        self.end_s = min(conflict_s + 15.0, completing_s(route))
        self.rows = np.zeros(0, np.int64)
        self.hazard_rows: list[int] = []
        self.triggered = False
        self.trigger_tick = -1
        self.elapsed_s = 0.0  # s since the trigger, not counting red-light waits
        self.passed = False
        self.timed_out = False
        self.lanes_off = False  # a lanes-free scenario that has the route-lanes test off now

    # ------------------------------------------------------------------ placement
    @classmethod
    def find_sites(cls, town: Town) -> list[Site]:
        """All places in ``town`` where this scenario fits (override)."""
        raise NotImplementedError

    @classmethod
    def actor_lanes(cls, town: Town, site: Site) -> set[int]:
        """Lanes outside ``site.lanes`` where this scenario's actors stand or drive: the lane ids
        in ``site.extra`` (flow paths) by default; subclasses add their own (a waiting truck's
        lane). A route must not pass through them elsewhere than at the site, where the
        scenario's standing actors would block it (the suite builder checks this)."""
        out: set[int] = set()

        def walk(x) -> None:
            if isinstance(x, (tuple, list)):
                for y in x:
                    walk(y)
            elif isinstance(x, (int, np.integer)) and not isinstance(x, bool):
                out.add(int(x))

        walk(site.extra)
        return out - set(site.lanes)

    # ------------------------------------------------------------------ runtime
    def setup(self, world, rows: np.ndarray) -> None:
        """Spawn the scenario's actors into ``rows`` (called by ``World.reset``)."""
        self.rows = rows
        self.spawn(world)

    def spawn(self, world) -> None:
        """Create actors (override). Use ``self.rows[i]`` as table rows."""
        raise NotImplementedError

    def on_trigger(self, world) -> None:
        """Called once when the ego reaches the trigger (override)."""

    def update(self, world) -> None:
        """Called every tick after the trigger (override)."""

    def ego_s(self, world) -> float:
        """Ego route progress (m)."""
        return float(world.route.s[world.monitor.progress])

    def check_passed(self, world, s: float | None = None) -> None:
        """Mark the scenario passed once the ego's route progress reaches ``end_s``. The world calls
        this again after its progress update, so that a scenario whose ``end_s`` is the route's end
        counts as passed on the tick the route is completed. ``s``: :meth:`ego_s`, where the
        caller has it already."""
        if self.triggered and not self.passed and (self.ego_s(world) if s is None else s) >= self.end_s:
            self.passed = True

    def tick(self, world) -> None:
        """Trigger, behaviour, pass / timeout bookkeeping (called by ``World.step``)."""
        s = self.ego_s(world)
        if not self.triggered:
            if s < self.trigger_s:
                return
            self.triggered, self.trigger_tick = True, world.tick
            self.on_trigger(world)
        self.update(world)
        self.check_passed(world, s)  # (the hooks do not move the route progress)
        if not world.monitor.held_by_red:
            self.elapsed_s += world.config.dt
        if not self.passed and not self.timed_out and self.elapsed_s > self.timeout_s:
            self.timed_out = True
            world.monitor.emit(SCENARIO_TIMEOUT, world.tick, -1, float(self.elapsed_s))
        if self.lanes_free:
            self.lanes_off = s < self.end_s + REJOIN_M
            # off while any lanes-free scenario of the route is (so overlapping ones do not fight)
            off = any(sc.lanes_off for sc in world.scenarios)
            if off == world.monitor.route_lanes_test:
                world.monitor.route_lanes_test = not off
