"""Rewards, termination and info: shared by the PettingZoo, Gymnasium and TorchRL adapters.

Reward = weighted sum of named terms (each visible as ``info["reward_<term>"]``):

==============  =======  ====================================================
term            weight   value per tick
==============  =======  ====================================================
progress        1.0      metres the ego advanced along the route this tick / 10
                         (continuous: :func:`route_progress`, not 1 m route points)
collision       -10.0    collisions this tick (pedestrian, vehicle, static)
infraction      -2.0     red light, stop sign, off-road, wrong way this tick
comfort         -0.01    ``abs(accel) / 4``, a mild smoothness penalty
==============  =======  ====================================================

An episode is *terminated* when the route is complete, the ego deviates more than 30 m from it,
is blocked for 180 s, or (``terminate_on_collision``) collides; it is *truncated* at the time
budget (``max_steps``, default ``route length / 2.5 m/s + 30 s``).
"""

from __future__ import annotations

import numpy as np

from . import infractions as inf
from .jit_route import PROGRESS_RADIUS_M, PROGRESS_WINDOW, route_progress_kernel

REWARD_WEIGHTS = {"progress": 1.0, "collision": -10.0, "infraction": -2.0, "comfort": -0.01}
COLLISIONS = (inf.COLLISION_PEDESTRIAN, inf.COLLISION_VEHICLE, inf.COLLISION_STATIC)
INFRACTIONS = (inf.RED_LIGHT, inf.STOP_SIGN, inf.OFF_ROAD, inf.WRONG_WAY)


def time_budget_steps(world) -> int:
    """The episode's tick budget (config ``max_steps`` or from the route length)."""
    if world.config.max_steps is not None:
        return world.config.max_steps
    return int(np.ceil((world.route.length / 2.5 + 30.0) / world.config.dt))


def v2x_bps(world) -> float:
    """Bytes counted by the channel / simulated seconds of this episode (the channel's own ``bps``
    also counts the interval of the tick in progress); 0 before the first tick."""
    return world.channel.bytes_sent_total / (world.tick * world.config.dt) if world.tick else 0.0


def route_progress(world) -> float:
    """The ego's continuous route progress (m): the furthest position on the route polyline within
    ``jit_route.PROGRESS_RADIUS_M`` of the ego, from the monitor's progress point on (the
    continuous version of ``infractions.EventMonitor.progress``; ``jit_route``)."""
    r = world.route
    x, y = world.table.pos[0].tolist()
    return float(route_progress_kernel(r.points, r.s, int(world.monitor.progress), x, y,
                                       PROGRESS_RADIUS_M, PROGRESS_WINDOW))


class EpisodeTracker:
    """Turns a world's events into reward, termination flags and a numeric info dict."""

    def __init__(self, world) -> None:
        self.world = world
        self.max_steps = time_budget_steps(world)
        self.prev_s = route_progress(world)  # never decreases (as the monitor's progress)
        self.route_length = world.route.length
        self.done = False

    def after_step(self, events: list, with_info: bool = True) -> tuple[float, bool, bool, dict | None]:
        """Reward, terminated, truncated, info for the tick just simulated (info ``None`` when
        ``with_info`` is false: callers that never read it skip building it)."""
        w = self.world
        mon = w.monitor
        s = max(route_progress(w), self.prev_s)
        if events:
            collision = float(sum(e[0] in COLLISIONS for e in events))
            infraction = float(sum(e[0] in INFRACTIONS for e in events))
        else:
            collision = infraction = 0.0
        progress = (s - self.prev_s) / 10.0
        comfort = abs(float(w.table.accel[0])) / 4.0
        self.prev_s = s
        wt = REWARD_WEIGHTS  # the weighted terms summed in their order from 0 (the same float as sum())
        reward = float(0 + wt["progress"] * progress + wt["collision"] * collision + wt["infraction"] * infraction
                       + wt["comfort"] * comfort)
        counts = mon.counts
        terminated = bool(
            w.is_route_complete() or counts[inf.ROUTE_DEVIATION] > 0 or counts[inf.BLOCKED] > 0
            or (w.config.terminate_on_collision and collision > 0)
        )
        truncated = bool(not terminated and w.tick >= self.max_steps)
        self.done = terminated or truncated
        if not with_info:
            return reward, terminated, truncated, None
        return reward, terminated, truncated, self.info((progress, collision, infraction, comfort))

    def info(self, terms: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)) -> dict:
        """Flat numeric info: tick, route completion, event counts (``events``, indexed by
        ``infractions.EVENT_NAMES``), channel statistics and reward terms (``reward_<term>``;
        ``terms`` in the order of ``REWARD_WEIGHTS``)."""
        w = self.world
        ch = w.channel
        mon = w.monitor
        return {
            "tick": w.tick,
            "route_completion": mon.route_completion,
            "route_length": self.route_length,
            "speed": float(w.table.speed[0]),
            "events": mon.counts.copy(),
            "outside_lanes_m": mon.outside_m,
            "driven_m": mon.driven_m,
            "active_rsu": int(w.active_rsu[0]),
            "v2x_bytes_total": int(ch.bytes_sent_total),
            "v2x_bps": v2x_bps(w),
            "v2x_peak_bps": float(ch.peak_bps),
            "v2x_messages_lost": int(ch.messages_lost),
            "v2x_messages_dropped": int(ch.messages_dropped_bandwidth),
            "reward_progress": terms[0],
            "reward_collision": terms[1],
            "reward_infraction": terms[2],
            "reward_comfort": terms[3],
        }


