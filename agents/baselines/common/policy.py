"""The baselines' closed loop shares the received payload's check and read
(:func:`received_message`) and the planning part of the ego's inputs and outputs
(:func:`planning_inputs`, :func:`waypoints_and_speed`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import torch
from v2xbench.agents.aurora.policy import target_speed
from v2xbench.agents.aurora.route_input import PATH_KEY, planner_route_path, route_points_ahead
from v2xbench.agents.aurora.rsu_agent import received_payload
from v2xbench.envs.v2x_intersection.api.observations import EGO_FEATURES

SPEED, COMMAND = 0, 2  # obs["ego"][SPEED]; obs["route"][:, COMMAND]
#: obs["ego"] columns of the light of the ego's lane and the distance to its stop line
LIGHT_STATE, STOP_DIST = EGO_FEATURES.index("light_state"), EGO_FEATURES.index("dist_to_stop_line")


def received_message(obs: Mapping, fusion: bool, need_floats: int, title: str,
                     read: Callable[[np.ndarray], Any]) -> Any:
    """``read(payload)`` of the message an observation received, ``None`` without one (or
    without ``fusion``).

    Raises:
        ValueError: the env's ``v2x_payload`` holds fewer than ``need_floats`` floats (naming the
            ``--set max_payload_floats`` to evaluate with).
    """
    payload = np.asarray(obs["v2x_payload"])
    if fusion and payload.shape[-1] < need_floats:
        raise ValueError(f"{title}: v2x_payload holds {payload.shape[-1]} floats; the roadside "
                         f"message needs {need_floats}: evaluate with --set "
                         f"max_payload_floats={need_floats}")
    raw = received_payload(obs) if fusion else None
    return None if raw is None else read(raw)


def planning_inputs(obs: Mapping, cfg: Any) -> dict[str, torch.Tensor]:
    """``command``, ``ego_speed`` and ``route_points`` (batch 1) of a sensors-mode observation;
    with ``cfg.plan_frame == "route"`` also ``route_path`` (as :func:`..data.planning_sample`)."""
    route = np.asarray(obs["route"], np.float32)
    out = {"command": torch.tensor([int(round(float(route[0, COMMAND])))]),
           "ego_speed": torch.tensor([float(obs["ego"][SPEED])]),
           "route_points": route_points_ahead(route, cfg.plan_route_points,
                                              cfg.plan_route_spacing)[None]}
    if cfg.plan_frame == "route":
        out[PATH_KEY] = planner_route_path(route, cfg)[None]
    return out


def waypoints_and_speed(wps: torch.Tensor, cfg: Any) -> tuple[np.ndarray, float]:
    """``(waypoints (T, 2) float64, target speed m/s)`` of a batch-1 plan (AURORA's rule)."""
    return wps[0].numpy().astype(np.float64), float(target_speed(wps, cfg.plan_dt)[0])


__all__ = ["COMMAND", "SPEED", "planning_inputs", "received_message", "waypoints_and_speed"]
