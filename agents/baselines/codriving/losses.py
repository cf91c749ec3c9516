"""CoDriving's training loss: V2X-ViT's terms on the fused map and the unit's confidence map.

Parts (each already weighted; ``loss`` is their sum):

- ``heat``, ``box``, ``plan_l1``, ``plan_col``: V2X-ViT's (:class:`~..v2x_vit.losses.
  V2XViTCriterion`): CenterNet focal loss of the fused class heatmaps and L1 of the boxes against
  ``gt/fused``; waypoint L1 (AURORA's start weighting) and AURORA's collision term;
- ``conf``: the unit's confidence map (the score it chooses cells by) against the heatmap of the
  same ``gt/fused`` boxes moved into its ground frame (``E_{r->e}^-1``) on its feature grid
  (:meth:`~.config.CoDrivingConfig.rsu_grid`), CenterNet's focal loss over the rows with a unit,
  times ``conf_weight``.
"""

from __future__ import annotations

import torch
from torch import nn

from ..v2x_vit.head import heatmap_targets
from ..v2x_vit.losses import V2XViTCriterion, heatmap_focal_loss
from .config import CoDrivingConfig


def boxes_to_rsu(boxes: torch.Tensor, e_rsu_to_ego: torch.Tensor) -> torch.Tensor:
    """Boxes ``(B, M, 10)`` (AURORA's layout, ego frame) with their centres moved into the
    unit's ground frame by ``E_{r->e}^-1`` (the rest unchanged: the heatmap reads centre and
    size only)."""
    e = e_rsu_to_ego.float()
    xy = (boxes[..., :2] - e[:, None, :2, 3]) @ e[:, :2, :2]
    return torch.cat([xy, boxes[..., 2:]], -1)


class CoDrivingCriterion(nn.Module):
    """``CoDrivingCriterion(cfg)(outputs, batch) -> (loss, parts)`` (module docstring)."""

    def __init__(self, cfg: CoDrivingConfig) -> None:
        super().__init__()
        self.cfg, self.rsu_cfg = cfg, cfg.rsu_grid()
        self.fused = V2XViTCriterion(cfg)

    def forward(self, out: dict, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        cfg = self.cfg
        total, parts = self.fused(out, batch)
        has = batch["has_rsu"].bool()
        conf = out["rsu_conf_logits"].new_zeros(())
        if bool(has.any()):
            boxes = boxes_to_rsu(batch["det_boxes"][has], batch["rsu_to_ego"][has])
            target = heatmap_targets(boxes, batch["det_labels"][has], batch["det_mask"][has],
                                     self.rsu_cfg)
            conf = cfg.conf_weight * heatmap_focal_loss(out["rsu_conf_logits"][has], target,
                                                        cfg.heat_alpha, cfg.heat_beta)
        parts["conf"] = float(conf.detach())
        return total + conf, parts


__all__ = ["CoDrivingCriterion", "boxes_to_rsu"]
