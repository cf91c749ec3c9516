"""V2X-ViT's training loss: the fused detections and the waypoints.

Parts (each already weighted; ``loss`` is their sum):

- ``heat``: CenterNet's penalty-reduced focal loss of the class heatmaps against
  :func:`~.head.heatmap_targets` of ``gt/fused`` (``-(1 - p)^a log p`` at the centre cells,
  ``-(1 - y)^b p^a log(1 - p)`` elsewhere, divided by the number of boxes), times
  ``heat_weight``;
- ``box``: code-weighted L1 of the regression at each box's centre cell against
  :func:`~.head.encode_boxes`, averaged over the boxes, times ``box_weight``;
- ``plan_l1``: L1 (m) of the waypoints against ``expert_waypoints``, each sample weighted by
  AURORA's start-from-rest weight (:func:`~v2xbench.agents.aurora.planner_losses.start_weights`);
- ``plan_col``: AURORA's collision term against the ``gt/fused`` agents moved at constant
  velocity (:func:`~v2xbench.agents.aurora.planner_losses.collision_loss`).
"""

from __future__ import annotations

import torch
from torch import nn

from ..common.losses import planning_terms
from .config import V2XViTConfig
from .head import box_cells, encode_boxes, heatmap_targets


def heatmap_focal_loss(logits: torch.Tensor, target: torch.Tensor, alpha: float, beta: float
                       ) -> torch.Tensor:
    """CenterNet's focal loss of heatmap ``logits`` against Gaussian ``target`` (same shape),
    divided by the number of centre cells (``target == 1``; at least one)."""
    p = logits.float().sigmoid().clamp(1e-4, 1 - 1e-4)
    pos = target >= 1.0 - 1e-6
    pos_loss = torch.log(p) * (1 - p).pow(alpha) * pos
    neg_loss = torch.log(1 - p) * p.pow(alpha) * (1 - target).pow(beta) * ~pos
    return -(pos_loss.sum() + neg_loss.sum()) / pos.sum().clamp_min(1)


class V2XViTCriterion(nn.Module):
    """``V2XViTCriterion(cfg)(outputs, batch) -> (loss, parts)`` (module docstring)."""

    def __init__(self, cfg: V2XViTConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.register_buffer("code", torch.tensor(cfg.box_code_weights, dtype=torch.float32),
                             persistent=False)

    def forward(self, out: dict, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        cfg = self.cfg
        boxes, labels, mask = batch["det_boxes"], batch["det_labels"], batch["det_mask"]
        terms: dict[str, torch.Tensor] = {}
        heat = heatmap_targets(boxes, labels, mask, cfg)
        terms["heat"] = cfg.heat_weight * heatmap_focal_loss(out["heat_logits"], heat,
                                                             cfg.heat_alpha, cfg.heat_beta)
        index, inside = box_cells(boxes, mask, cfg)
        reg = out["reg"].flatten(2).transpose(1, 2)  # (B, P, 10)
        pred = reg.gather(1, index[..., None].expand(-1, -1, 10))
        l1 = ((pred - encode_boxes(boxes, index, cfg)).abs() * self.code).sum(-1)
        terms["box"] = cfg.box_weight * (l1 * inside).sum() / inside.sum().clamp_min(1)
        terms.update(planning_terms(out["waypoints"], batch, boxes, mask, cfg))
        total = sum(terms.values())
        return total, {k: float(v.detach()) for k, v in terms.items()}


__all__ = ["V2XViTCriterion", "heatmap_focal_loss"]
