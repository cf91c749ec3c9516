"""UniV2X's training loss: detection (AURORA's set criterion), occupancy, planning.

Parts (each already weighted; ``loss`` is their sum):

- ``det_cls``, ``det_box``: the fused detections against ``gt/fused`` (ego frame): AURORA's
  Hungarian matching and terms (:class:`~v2xbench.agents.aurora.losses.SetCriterion`'s
  detection layer: focal classification + code-weighted L1 of encoded boxes);
- ``ego_cls``, ``ego_box``: the ego's own agent queries (every decoder layer) against ``gt/ego``,
  times ``cfg.ego_aux_weight`` (the ego half's perception before fusion);
- ``rsu_cls``, ``rsu_box``, ``rsu_occ``: the roadside half on the rows with an active unit,
  against ``gt/rsu`` in its ground frame, times ``cfg.rsu_weight``;
- ``occ``: the fused occupancy against the occupancy of ``gt/fused``
  (:func:`~.bev.box_occupancy`); occupancy terms are sigmoid focal losses summed over the cells
  and divided by the occupied cells (at least 1), times ``cfg.occ_weight``;
- ``plan_l1``: L1 (m) of the 6 waypoints against ``expert_waypoints``, each sample weighted by
  AURORA's start-from-rest weight (:func:`~v2xbench.agents.aurora.planner_losses.start_weights`);
- ``plan_col``: AURORA's collision term against the ``gt/fused`` agents moved at constant
  velocity (:func:`~v2xbench.agents.aurora.planner_losses.collision_loss`).
"""

from __future__ import annotations

import torch
from torch import nn
from v2xbench.agents.aurora.losses import SetCriterion, sigmoid_focal_loss

from ..common.losses import planning_terms
from .bev import box_occupancy
from .config import UniV2XConfig

_PAD_BOX = (0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0, 0.0, 0.0)


class DetectionCriterion(SetCriterion):
    """AURORA's set criterion, detection only: ``det_terms(logits, boxes, targets)`` sums the
    matched focal and L1 terms over decoder layers (``(L, B, Q, C)``, ``(L, B, Q, 10)``)."""

    def det_terms(self, logits: torch.Tensor, boxes: torch.Tensor, boxes_gt: torch.Tensor,
                  labels: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(classification, box) terms against ``(B, M, 10)`` boxes, ``(B, M)`` labels, mask."""
        dm = mask.bool()
        pad = torch.tensor(_PAD_BOX, dtype=boxes_gt.dtype, device=dm.device)
        tgt = {"det_mask": dm, "det_labels": torch.where(dm, labels, 0),
               "det_boxes": torch.where(dm[..., None], boxes_gt, pad)}
        norm = max(float(dm.sum()), 1.0)
        cls = box = logits.new_zeros(())
        for lg, bx in zip(logits, boxes):
            c, b = self._det_layer(lg, bx, tgt, norm)
            cls, box = cls + c, box + b
        return cls, box


def occupancy_loss(logits: torch.Tensor, target: torch.Tensor, cfg: UniV2XConfig) -> torch.Tensor:
    """Sigmoid focal loss of occupancy logits ``(B, nx, ny)`` over the cells, divided by the
    occupied cells (at least one)."""
    loss = sigmoid_focal_loss(logits, target, cfg.focal_alpha, cfg.focal_gamma).sum()
    return loss / target.sum().clamp_min(1.0)


class UniV2XCriterion(nn.Module):
    """``UniV2XCriterion(cfg)(outputs, batch) -> (loss, parts)`` (module docstring)."""

    def __init__(self, cfg: UniV2XConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.det = DetectionCriterion(cfg.data_config(), "ego")

    def forward(self, out: dict, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        cfg = self.cfg
        terms: dict[str, torch.Tensor] = {}
        terms["det_cls"], terms["det_box"] = self.det.det_terms(
            out["det_logits"], out["det_boxes"], batch["det_boxes"], batch["det_labels"],
            batch["det_mask"])
        c, b = self.det.det_terms(out["ego_det_logits"], out["ego_det_boxes"],
                                  batch["ego/det_boxes"], batch["ego/det_labels"],
                                  batch["ego/det_mask"])
        terms["ego_cls"], terms["ego_box"] = cfg.ego_aux_weight * c, cfg.ego_aux_weight * b
        occ_gt = box_occupancy(batch["det_boxes"], batch["det_labels"], batch["det_mask"],
                               cfg.ego_range, cfg.ego_bev)
        terms["occ"] = cfg.occ_weight * occupancy_loss(out["occ_logits"], occ_gt, cfg)
        rsu, rows = out.get("rsu"), out.get("rsu_rows")
        if rsu is not None and len(rows):
            g = {k: batch[f"rsu/{k}"][rows] for k in ("det_boxes", "det_labels", "det_mask")}
            c, b = self.det.det_terms(rsu["det_logits"], rsu["det_boxes"], g["det_boxes"],
                                      g["det_labels"], g["det_mask"])
            occ_r = box_occupancy(g["det_boxes"], g["det_labels"], g["det_mask"],
                                  cfg.rsu_range, cfg.rsu_bev)
            terms["rsu_cls"], terms["rsu_box"] = cfg.rsu_weight * c, cfg.rsu_weight * b
            terms["rsu_occ"] = cfg.rsu_weight * cfg.occ_weight * occupancy_loss(
                rsu["occ_logits"], occ_r, cfg)
        else:  # no unit in this batch: the parts stay in the log as zeros
            for k in ("rsu_cls", "rsu_box", "rsu_occ"):
                terms[k] = out["det_logits"].new_zeros(())
        terms.update(planning_terms(out["waypoints"], batch, batch["det_boxes"],
                                    batch["det_mask"], cfg))
        total = sum(terms.values())
        return total, {k: float(v.detach()) for k, v in terms.items()}


__all__ = ["DetectionCriterion", "UniV2XCriterion", "occupancy_loss"]
