"""The baselines' planning loss terms (AURORA's): ``plan_l1`` and ``plan_col``."""

from __future__ import annotations

from typing import Any

import torch
from v2xbench.agents.aurora.planner_losses import (
    collision_loss,
    constant_velocity_futures,
    start_weights,
)


def planning_terms(wps: torch.Tensor, batch: dict, boxes: torch.Tensor, mask: torch.Tensor,
                   cfg: Any) -> dict[str, torch.Tensor]:
    """The weighted planning terms of waypoints ``wps`` ``(B, T, 2)``:

    - ``plan_l1``: L1 (m) against ``expert_waypoints``, each sample weighted by AURORA's
      start-from-rest weight (:func:`~v2xbench.agents.aurora.planner_losses.start_weights`),
      times ``cfg.plan_l1_weight``;
    - ``plan_col``: AURORA's collision term against the agents ``boxes`` (valid ``mask``) moved
      at constant velocity (:func:`~v2xbench.agents.aurora.planner_losses.collision_loss`),
      times ``cfg.plan_col_weight``.
    """
    gt = batch["expert_waypoints"][:, :cfg.plan_waypoints].float()
    w = start_weights(batch, cfg).to(wps.device)
    l1 = cfg.plan_l1_weight * ((wps - gt).abs().mean((1, 2)) * w).sum() / w.sum()
    fut, fmask = constant_velocity_futures(boxes, mask, cfg.plan_waypoints, cfg.plan_dt)
    col = cfg.plan_col_weight * collision_loss(wps, fut, fmask, cfg.plan_col_radius).mean()
    return {"plan_l1": l1, "plan_col": col}


__all__ = ["planning_terms"]
