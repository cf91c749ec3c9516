"""The expert and the two restricted oracles: one planner, three object lists.

=====================  =====================================================================
agent                  objects the planner gets
=====================  =====================================================================
:class:`Expert`        every active actor except the ego (privileged ground truth)
:class:`EgoOnlyOracle` actors the ego sees now (``world.ego_vis >= VISIBLE_THRESHOLD``) plus a
                       ``memory_s`` memory of what it saw, moved at constant velocity
:class:`V2XOracle`     the above plus the objects received from the RSU over the channel
                       (``obs["v2x_objects"]``, with the channel's latency and losses), with
                       the same ``memory_s`` memory
=====================  =====================================================================

All three are privileged (the harness calls :meth:`bind` with the :class:`World` after every
reset): they read the ego state, the route, the town and the signal states from it. After each
:meth:`act`, ``last_waypoints`` holds the planned ``(8, 2)`` ego-frame waypoints (every 0.5 s)
and ``last_plan`` the full :class:`~.planner.Plan`.
"""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.perception.visibility import VISIBLE_THRESHOLD

from .objects import (
    AnonymousMemory,
    ObjectMemory,
    Objects,
    dedupe,
    from_observation_rows,
    from_table,
)
from .planner import N_WAYPOINTS, Plan, Planner, PlannerParams


def emergency_rows(world) -> list[int]:
    """Actor rows of the world's emergency vehicles (``World.emergency_rows``, set at reset)."""
    return world.emergency_rows.tolist()


class Expert:
    """Privileged rule-based expert (PDM-Lite-like) over all actors.

    Args:
        params: planner constants.
    """

    obs_mode = "objects"
    privileged = True
    rsu_policy = "share_objects"

    def __init__(self, params: PlannerParams | None = None) -> None:
        self.planner = Planner(params)
        self.world = None
        self.last_waypoints = np.zeros((N_WAYPOINTS, 2), np.float32)
        self.last_plan: Plan | None = None

    def bind(self, world) -> None:
        """Attach the world of the episode that was just reset."""
        self.world = world
        self._start()

    def reset(self, route_info: dict | None = None) -> None:
        """Start an episode (the planner restarts on the bound world's route)."""
        if self.world is not None:
            self._start()

    def _start(self) -> None:
        w = self.world
        self.planner.reset(w.town, w.route)
        self.last_waypoints = np.zeros((N_WAYPOINTS, 2), np.float32)
        self._on_start()

    def _on_start(self) -> None:
        pass

    def objects(self, obs: dict | None) -> Objects:
        """All active actors but the ego."""
        t = self.world.table
        rows = t.active.nonzero()[0]
        return from_table(t, rows[rows > 0], emergency_rows(self.world))

    def act(self, obs: dict | None = None) -> np.ndarray:
        """``(3,)`` control for the bound world's current state."""
        if self.world is None:
            raise RuntimeError(
                f"{type(self).__name__} is privileged: call bind(world) after each reset"
            )
        w = self.world
        if w.route is not self.planner.track.route:
            self._start()
        t = w.table
        plan = self.planner.step(
            t.pos[0], float(t.yaw[0]), float(t.speed[0]), self.objects(obs), w.lane_signal
        )
        self.last_plan = plan
        self.last_waypoints = plan.waypoints
        return plan.control


class EgoOnlyOracle(Expert):
    """The expert's planner restricted to what the ego sees, with a short memory.

    Args:
        memory_s: how long unseen objects are remembered (s).
    """

    def __init__(self, params: PlannerParams | None = None, memory_s: float = 2.0) -> None:
        super().__init__(params)
        self.memory = ObjectMemory(memory_s)

    def _on_start(self) -> None:
        self.memory.reset()

    def seen(self) -> tuple[Objects, Objects]:
        """``(objects the ego sees now, remembered objects it no longer sees)``."""
        w = self.world
        t = w.table
        rows = (w.ego_vis >= VISIBLE_THRESHOLD).nonzero()[0]
        now = from_table(t, rows[rows > 0], emergency_rows(w))
        return self.memory.update_split(now, w.tick * w.config.dt)

    def objects(self, obs: dict | None) -> Objects:
        return Objects.concat(list(self.seen()))


class V2XOracle(EgoOnlyOracle):
    """The ego-only oracle plus the objects the RSU sent over the channel (``obs["v2x_objects"]``),
    remembered as long as what the ego saw (``memory_s``, matched by position: they carry no ids).

    Precedence where two sources report the same object (within 2 m): what the ego sees now, then
    what the RSU sent (fresh, then remembered), then the ego's memory (a remembered object moves
    at its last velocity, so an RSU track of it is better)."""

    def __init__(self, params: PlannerParams | None = None, memory_s: float = 2.0) -> None:
        super().__init__(params, memory_s)
        self.v2x_memory = AnonymousMemory(memory_s)

    def _on_start(self) -> None:
        super()._on_start()
        self.v2x_memory.reset()

    def objects(self, obs: dict | None) -> Objects:
        now, remembered = self.seen()
        if obs is None or "v2x_objects" not in obs:
            return Objects.concat([now, remembered])
        w = self.world
        t = w.table
        v2x = from_observation_rows(obs["v2x_objects"], t.pos[0], float(t.yaw[0]))
        v2x = self.v2x_memory.update(v2x, w.tick * w.config.dt)
        return dedupe(dedupe(now, v2x), remembered)
