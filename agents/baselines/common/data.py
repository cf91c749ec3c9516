"""The planning part of a baseline's sample (:func:`planning_sample`)."""

from __future__ import annotations

from typing import Any

import torch
from v2xbench.agents.aurora.route_input import PATH_KEY, planner_route_path, route_points_ahead


def planning_sample(x: Any, cfg: Any, fid: int) -> dict[str, torch.Tensor]:
    """``command``, ``ego_speed``, ``route_points`` (AURORA's route points ahead),
    ``expert_waypoints`` and ``frame_id`` of a data-set row ``x`` (global frame ``fid``); with
    ``cfg.plan_frame == "route"`` also ``route_path`` (the route-frame planner's polyline)."""
    out = dict(
        command=torch.tensor(int(x["command"]), dtype=torch.long),
        ego_speed=torch.tensor(float(x["ego_speed"]), dtype=torch.float32),
        route_points=route_points_ahead(x["route"], cfg.plan_route_points,
                                        cfg.plan_route_spacing),
        expert_waypoints=x["expert_waypoints"].float(), frame_id=torch.tensor(fid))
    if cfg.plan_frame == "route":
        out[PATH_KEY] = planner_route_path(x["route"], cfg)
    return out


__all__ = ["planning_sample"]
