"""The baselines' planner switches in one place (configuration fields ``plan_ego_speed`` and
``plan_frame``, checked by :func:`~.config.check_planning`):

- :func:`planner_speed`: the speed a planner is told (0 m/s with ``plan_ego_speed`` off, in
  training and closed loop alike: UniAD's planner reads no ego status);
- :func:`steps_to_waypoints`: a planner head's ``(B, T, 2)`` steps -> ego-frame waypoints; in the
  ``"route"`` frame (AURORA's route-relative output) per waypoint a step along the observed
  route, never backwards (``relu`` with a straight-through gradient), and one across it, turned
  into x, y on the route polyline (batch key ``route_path``) by
  :func:`~v2xbench.agents.aurora.route_input.route_to_ego`.
"""

from __future__ import annotations

from typing import Any

import torch
from v2xbench.agents.aurora.route_input import PATH_KEY, PATH_SPACING, route_to_ego

PLAN_FRAMES = ("ego", "route")


def planner_speed(speed: torch.Tensor, cfg: Any) -> torch.Tensor:
    """``speed`` ``(B,)``, or zeros where ``cfg.plan_ego_speed`` is off."""
    return speed if cfg.plan_ego_speed else torch.zeros_like(speed)


def steps_to_waypoints(steps: torch.Tensor, cfg: Any, path: torch.Tensor | None,
                       who: str) -> torch.Tensor:
    """``(B, T, 2)`` per-waypoint steps -> ego-frame waypoints (m) in ``cfg.plan_frame``.

    Raises:
        ValueError: a route-frame planner without a ``(B, N, 2)`` route polyline ``path``.
    """
    if cfg.plan_frame == "ego":
        return steps.cumsum(1)
    b = steps.shape[0]
    if path is None or path.dim() != 3 or path.shape[0] != b or path.shape[2] != 2:
        raise ValueError(f"{who}: plan_frame='route' needs the route polyline {PATH_KEY!r} of "
                         f"shape ({b}, N, 2) (route_input.route_path); got "
                         f"{None if path is None else tuple(path.shape)}")
    u = steps[..., :1]
    along = u + (u.clamp_min(0.0) - u).detach()  # relu forward, gradient 1 (AURORA's)
    return route_to_ego(torch.cat([along, steps[..., 1:]], -1).cumsum(1), path, PATH_SPACING)


def check_switches(cfg: Any, who: str) -> None:
    """``plan_frame`` one of :data:`PLAN_FRAMES`, ``plan_ego_speed`` a bool."""
    if cfg.plan_frame not in PLAN_FRAMES:
        raise ValueError(f"{who}: plan_frame={cfg.plan_frame!r} must be 'ego' or 'route'")
    if not isinstance(cfg.plan_ego_speed, bool):
        raise ValueError(f"{who}: plan_ego_speed={cfg.plan_ego_speed!r} must be a bool")


__all__ = ["PLAN_FRAMES", "check_switches", "planner_speed", "steps_to_waypoints"]
