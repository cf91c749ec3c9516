"""Hungarian matching of predictions to ground truth (DETR), with the costs it uses.

- Classification: the sigmoid-focal cost of Deformable DETR, ``pos - neg`` at the GT class.
- Boxes: L1 between encoded boxes (:func:`encode_boxes`) over ``(x, y, z, log l, log w,
  log h, sin, cos)`` (PETR's ``BBox3DL1Cost``; velocity is left out of the cost).
- Polylines: the mean L1 distance between points normalized to the range, minimized over the
  equivalent point orders of the ground truth (:func:`polyline_orders`: both directions of an
  open polyline; every start point in both directions of a closed one, whose ``P`` points are
  distinct and whose last point connects back to the first).

The assignment itself is ``scipy.optimize.linear_sum_assignment`` on the CPU.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

EPS = 1e-8


def encode_boxes(boxes: torch.Tensor) -> torch.Tensor:
    """``(..., 10)`` metre boxes -> ``(x, y, z, log l, log w, log h, sin, cos, vx, vy)``."""
    return torch.cat([boxes[..., :3], boxes[..., 3:6].clamp_min(1e-3).log(), boxes[..., 6:]], -1)


def focal_cost(logits: torch.Tensor, labels: torch.Tensor, alpha: float = 0.25,
               gamma: float = 2.0) -> torch.Tensor:
    """``(..., Q, C)`` logits, ``(..., M)`` labels -> ``(..., Q, M)`` classification cost."""
    p = logits.sigmoid()
    neg = (1 - alpha) * p.pow(gamma) * -(1 - p + EPS).log()
    pos = alpha * (1 - p).pow(gamma) * -(p + EPS).log()
    idx = labels.unsqueeze(-2).expand(*p.shape[:-1], labels.shape[-1])
    return torch.gather(pos - neg, -1, idx)


def box_cost(pred: torch.Tensor, gt: torch.Tensor, dims: int = 8) -> torch.Tensor:
    """``(..., Q, 10)`` and ``(..., M, 10)`` encoded boxes -> ``(..., Q, M)`` L1 distance."""
    return (pred[..., :, None, :dims] - gt[..., None, :, :dims]).abs().sum(-1)


def polyline_orders(points: int, closed: bool) -> torch.Tensor:
    """``(S, P)`` index orders under which a polyline of ``P`` points is the same line."""
    i = torch.arange(points)
    if not closed:
        return torch.stack([i, i.flip(0)])
    shifts = torch.stack([(i + s) % points for s in range(points)])
    return torch.cat([shifts, shifts.flip(1)])


def polyline_distances(pred: torch.Tensor, gt: torch.Tensor,
                       closed: torch.Tensor) -> torch.Tensor:
    """Distances of every prediction to every equivalent order of every GT polyline.

    Args:
        pred: ``(..., Q, P, 2)`` points; gt: ``(..., M, P, 2)``; closed: ``(..., M)`` bool.

    Returns:
        ``(..., Q, M, 2P)`` mean absolute coordinate difference; orders that do not apply (an
        open line has 2) are ``inf``. Order ``s`` is row ``s`` of ``polyline_orders(P, True)``;
        rows 0 and ``P`` are the identity and the reversal, the two orders of an open line.
    """
    p = pred.shape[-2]
    orders = polyline_orders(p, True).to(pred.device)  # (2P, P)
    gt_perm = gt[..., orders, :]  # (..., M, 2P, P, 2)
    d = (pred[..., :, None, None, :, :] - gt_perm[..., None, :, :, :, :]).abs().mean((-1, -2))
    valid = torch.zeros(2 * p, dtype=torch.bool, device=pred.device)
    valid[[0, p]] = True
    ok = closed[..., None] | valid  # (..., M, 2P)
    return d.masked_fill(~ok.unsqueeze(-3), float("inf"))


def hungarian(cost: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Minimum-cost assignment of a ``(Q, M)`` cost -> (prediction indices, GT indices), on
    the cost's device (so that masks computed from the cost index them on a GPU too)."""
    c = cost.detach().cpu().double().numpy()
    if c.size == 0:
        empty = torch.zeros(0, dtype=torch.int64, device=cost.device)
        return empty, empty
    if not np.isfinite(c).all():
        raise ValueError("hungarian: the cost matrix has NaN or inf entries")
    rows, cols = linear_sum_assignment(c)
    return (torch.as_tensor(rows, dtype=torch.int64, device=cost.device),
            torch.as_tensor(cols, dtype=torch.int64, device=cost.device))


def detection_cost(logits: torch.Tensor, boxes: torch.Tensor, gt_labels: torch.Tensor,
                   gt_boxes: torch.Tensor, cls_weight: float, box_weight: float,
                   alpha: float = 0.25, gamma: float = 2.0) -> torch.Tensor:
    """``(Q, C)`` logits, ``(Q, 10)`` metre boxes vs ``(M,)``, ``(M, 10)`` GT -> ``(Q, M)``."""
    cls = focal_cost(logits, gt_labels, alpha, gamma)
    return cls_weight * cls + box_weight * box_cost(encode_boxes(boxes), encode_boxes(gt_boxes))


def map_cost(logits: torch.Tensor, points: torch.Tensor, gt_labels: torch.Tensor,
             gt_points: torch.Tensor, gt_closed: torch.Tensor, cls_weight: float,
             pts_weight: float, alpha: float = 0.25,
             gamma: float = 2.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Map matching cost ``(Qm, K)`` and the best GT order per pair ``(Qm, K)``.

    ``points`` / ``gt_points`` are normalized to the range (``(Qm, P, 2)`` / ``(K, P, 2)``).
    """
    dist, order = polyline_distances(points, gt_points, gt_closed).min(-1)
    return cls_weight * focal_cost(logits, gt_labels, alpha, gamma) + pts_weight * dist, order
