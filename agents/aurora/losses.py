"""Set-prediction losses of one perception branch (DETR / PETR / MapTR).

Every decoder layer is matched to the ground truth on its own (Hungarian, :mod:`.matching`) and
contributes the same terms (auxiliary losses); the total is their sum plus the light term:

- ``det_cls``: sigmoid focal loss over all ``Q x C`` logits (matched queries have their GT class
  as target, every other query none), summed and divided by the batch's GT box count;
- ``det_box``: L1 between encoded matched boxes ``(x, y, z, log l, log w, log h, sin, cos, vx,
  vy)`` weighted per dimension by ``cfg.det_code_weights`` (yaw as sin / cos and velocity
  included), divided by the GT box count;
- ``map_cls``: focal loss of the map instances, divided by the GT polyline count;
- ``map_pts``: mean L1 of matched polylines' points normalized to the range, at the GT order
  that fits best (both directions of open lines; every start point and both directions of closed
  ones), divided by the GT polyline count;
- ``light`` (ego branch): cross-entropy of the traffic-light state.

Terms are weighted by the ``cfg.*_weight`` fields; ``parts`` reports each weighted term summed
over layers. The map's direction loss and one-to-many branch of MapTR and the detection
denoising queries are not used.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .config import AuroraConfig, check_branch
from .matching import (
    detection_cost,
    encode_boxes,
    hungarian,
    map_cost,
    polyline_distances,
)

DET_KEYS = ("det_boxes", "det_labels", "det_mask")
MAP_KEYS = ("map_points", "map_labels", "map_mask", "map_closed")


def sigmoid_focal_loss(logits: torch.Tensor, targets: torch.Tensor, alpha: float = 0.25,
                       gamma: float = 2.0) -> torch.Tensor:
    """Element-wise sigmoid focal loss (Lin et al.); ``targets`` in {0, 1}, same shape."""
    p = logits.sigmoid()
    ce = F.binary_cross_entropy_with_logits(logits, targets, reduction="none")
    p_t = p * targets + (1 - p) * (1 - targets)
    alpha_t = alpha * targets + (1 - alpha) * (1 - targets)
    return alpha_t * ce * (1 - p_t).pow(gamma)


class SetCriterion(nn.Module):
    """Loss of one branch's outputs against a batch (module docstring).

    ``SetCriterion(cfg, branch)(outputs, batch) -> (loss, parts)``; ``parts`` maps
    ``det_cls``, ``det_box``, ``map_cls``, ``map_pts`` (and ``light`` for the ego branch) to
    floats.
    """

    def __init__(self, cfg: AuroraConfig, branch: str = "ego") -> None:
        super().__init__()
        self.cfg, self.branch = cfg, check_branch(branch)
        rng = cfg.pc_range(branch)
        self.register_buffer("map_lo", torch.tensor(rng[:2]), persistent=False)
        self.register_buffer("map_span", torch.tensor(rng[3:5]) - self.map_lo, persistent=False)
        self.register_buffer("code_w", torch.tensor(cfg.det_code_weights), persistent=False)

    # ------------------------------------------------------------------ checks
    def check_batch(self, batch: dict) -> None:
        """Raise ``ValueError`` naming a missing or misshapen target key."""
        keys = DET_KEYS + MAP_KEYS + (("light",) if self.branch == "ego" else ())
        for k in keys:
            if k not in batch:
                raise ValueError(f"SetCriterion({self.branch}): batch has no {k!r}")
        b, m = batch["det_labels"].shape
        if tuple(batch["det_boxes"].shape) != (b, m, 10) or batch["det_mask"].shape != (b, m):
            raise ValueError(f"SetCriterion({self.branch}): det_boxes / det_mask shapes "
                             f"{tuple(batch['det_boxes'].shape)} / {tuple(batch['det_mask'].shape)}"
                             f" do not fit det_labels {(b, m)}")
        for key, n in (("det_labels", self.cfg.num_classes),
                       ("map_labels", self.cfg.num_map_classes)):
            mask = batch[key.replace("labels", "mask")].bool()
            lab = batch[key][mask]
            if lab.numel() and (int(lab.min()) < 0 or int(lab.max()) >= n):
                raise ValueError(f"SetCriterion({self.branch}): {key} outside [0, {n})")
        if self.branch == "ego":
            light = batch["light"]
            if tuple(light.shape) != (b,) or (light.numel() and (
                    int(light.min()) < 0 or int(light.max()) >= self.cfg.num_light_classes)):
                raise ValueError(f"SetCriterion(ego): light must be (B,) ints in "
                                 f"[0, {self.cfg.num_light_classes})")
        k = batch["map_labels"].shape[1]
        want = (b, k, self.cfg.map_points, 2)
        if tuple(batch["map_points"].shape) != want:
            raise ValueError(f"SetCriterion({self.branch}): map_points has shape "
                             f"{tuple(batch['map_points'].shape)}; expected {want}")

    def _clean(self, batch: dict) -> dict:
        """Targets with padded rows set to harmless values (class 0, 1 m boxes, zero points)."""
        out = dict(batch)
        dm, mm = batch["det_mask"].bool(), batch["map_mask"].bool()
        pad_box = torch.tensor([0, 0, 0, 1, 1, 1, 0, 1, 0, 0], dtype=batch["det_boxes"].dtype,
                               device=dm.device)
        out["det_mask"], out["map_mask"] = dm, mm
        out["det_labels"] = torch.where(dm, batch["det_labels"], 0)
        out["det_boxes"] = torch.where(dm[..., None], batch["det_boxes"], pad_box)
        out["map_labels"] = torch.where(mm, batch["map_labels"], 0)
        out["map_points"] = torch.where(mm[..., None, None], batch["map_points"], 0.0)
        out["map_closed"] = batch["map_closed"].bool() & mm
        return out

    # ------------------------------------------------------------------ terms
    def _det_layer(self, logits: torch.Tensor, boxes: torch.Tensor, batch: dict,
                   norm: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Focal and L1 terms of one layer: logits ``(B, Q, C)``, boxes ``(B, Q, 10)``."""
        cfg = self.cfg
        target = torch.zeros_like(logits)
        preds, gts = [], []
        with torch.no_grad():
            cost = detection_cost(logits, boxes, batch["det_labels"], batch["det_boxes"],
                                  cfg.det_cls_weight, cfg.det_box_weight, cfg.focal_alpha,
                                  cfg.focal_gamma)  # (B, Q, M)
        for i in range(logits.shape[0]):
            valid = batch["det_mask"][i].nonzero().squeeze(1)
            rows, cols = hungarian(cost[i][:, valid])
            gi = valid[cols.to(valid.device)]
            target[i, rows, batch["det_labels"][i, gi]] = 1.0
            preds.append(boxes[i, rows])
            gts.append(batch["det_boxes"][i, gi])
        cls = sigmoid_focal_loss(logits, target, cfg.focal_alpha, cfg.focal_gamma).sum() / norm
        diff = (encode_boxes(torch.cat(preds)) - encode_boxes(torch.cat(gts))).abs()
        return cfg.det_cls_weight * cls, cfg.det_box_weight * (diff * self.code_w).sum() / norm

    def _map_layer(self, logits: torch.Tensor, points: torch.Tensor, batch: dict,
                   norm: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Focal and polyline terms of one layer: logits ``(B, Qm, 3)``, points metres."""
        cfg = self.cfg
        pts = (points - self.map_lo) / self.map_span  # (B, Qm, P, 2) normalized
        gt = (batch["map_points"] - self.map_lo) / self.map_span
        target = torch.zeros_like(logits)
        dists = []
        with torch.no_grad():
            cost, _ = map_cost(logits, pts, batch["map_labels"], gt, batch["map_closed"],
                               cfg.map_cls_weight, cfg.map_pts_weight, cfg.focal_alpha,
                               cfg.focal_gamma)  # (B, Qm, K)
        for i in range(logits.shape[0]):
            valid = batch["map_mask"][i].nonzero().squeeze(1)
            rows, cols = hungarian(cost[i][:, valid])
            gi = valid[cols.to(valid.device)]
            target[i, rows, batch["map_labels"][i, gi]] = 1.0
            d = polyline_distances(pts[i, rows][:, None], gt[i, gi][:, None],
                                   batch["map_closed"][i, gi][:, None])  # (n, 1, 1, 2P)
            dists.append(d.flatten(1).min(1).values)
        cls = sigmoid_focal_loss(logits, target, cfg.focal_alpha, cfg.focal_gamma).sum() / norm
        return cfg.map_cls_weight * cls, cfg.map_pts_weight * torch.cat(dists).sum() / norm

    # ------------------------------------------------------------------ total
    def forward(self, outputs: dict, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        """Total loss (scalar tensor) and its weighted parts summed over decoder layers."""
        self.check_batch(batch)
        batch = self._clean(batch)
        det_norm = max(float(batch["det_mask"].sum()), 1.0)
        map_norm = max(float(batch["map_mask"].sum()), 1.0)
        terms: dict[str, torch.Tensor] = {}
        for logits, boxes in zip(outputs["det_logits"], outputs["det_boxes"]):
            cls, box = self._det_layer(logits, boxes, batch, det_norm)
            terms["det_cls"] = terms.get("det_cls", 0) + cls
            terms["det_box"] = terms.get("det_box", 0) + box
        for logits, points in zip(outputs["map_logits"], outputs["map_points"]):
            cls, pts = self._map_layer(logits, points, batch, map_norm)
            terms["map_cls"] = terms.get("map_cls", 0) + cls
            terms["map_pts"] = terms.get("map_pts", 0) + pts
        if self.branch == "ego":
            ce = F.cross_entropy(outputs["light_logits"], batch["light"])
            terms["light"] = self.cfg.light_weight * ce
        total = sum(terms.values())
        return total, {k: float(v.detach()) for k, v in terms.items()}
