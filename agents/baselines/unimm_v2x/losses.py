"""UniMM-V2X's training loss: UniV2X's parts (:class:`~..univ2x.losses.UniV2XCriterion`:
fused, ego and roadside detection, occupancy, planning L1 and collision) plus

- ``motion``: the motion head on the fused agents against the agents' futures
  (:mod:`.data`): each ``gt/fused`` agent with a known future is assigned one fused agent by a
  Hungarian matching (AURORA's :func:`~v2xbench.agents.aurora.matching.hungarian`) on the
  bird's-eye distance between its box centre and the fused boxes' centres (pairs farther than
  ``cfg.motion_match_radius`` dropped); the predicted displacements from the fused agent's
  centre against the agent's displacements from its own centre (so that a detection's position
  error is not the motion head's); winner-takes-all over the modes: the L1 (m) of the
  closest mode over the known steps (``cfg.motion_weight``), plus the cross-entropy of the mode
  scores towards that mode (``cfg.motion_cls_weight``);
- ``moe``: the MoE balance losses of both halves (:func:`~.moe.balance_loss`, summed over the
  MoE layers), times ``cfg.moe_weight``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from v2xbench.agents.aurora.matching import hungarian

from ..univ2x.losses import UniV2XCriterion
from .config import UniMMV2XConfig


def motion_loss(traj: torch.Tensor, mode_logits: torch.Tensor, pred_ref: torch.Tensor,
                pred_mask: torch.Tensor, gt_xy: torch.Tensor, gt_mask: torch.Tensor,
                future: torch.Tensor, known: torch.Tensor, cfg: UniMMV2XConfig
                ) -> tuple[torch.Tensor, torch.Tensor, int]:
    """(L1 term, mode term, matched agents) of predictions ``traj`` ``(B, N, M, T, 2)``,
    ``mode_logits`` ``(B, N, M)`` at ``pred_ref`` ``(B, N, 2)`` (valid ``pred_mask``) against
    agents at ``gt_xy`` ``(B, G, 2)`` (valid ``gt_mask``) with ``future`` ``(B, G, T, 2)``,
    ``known`` ``(B, G, T)`` (module docstring)."""
    l1 = cls = traj.new_zeros(())
    matched = 0
    for i in range(traj.shape[0]):
        rows = pred_mask[i].nonzero().squeeze(1)
        cols = (gt_mask[i] & known[i].any(-1)).nonzero().squeeze(1)
        if not len(rows) or not len(cols):
            continue
        dist = torch.cdist(pred_ref[i, rows].detach().float(), gt_xy[i, cols].float())
        r, c = hungarian(dist)
        ok = dist[r, c] < cfg.motion_match_radius
        p, g = rows[r[ok]], cols[c[ok]]
        if not len(p):
            continue
        w = known[i, g].float()[:, None, :]  # (n, 1, T)
        disp = traj[i, p] - pred_ref[i, p, None, None].detach()  # (n, M, T, 2) from the agent
        gt_disp = future[i, g] - gt_xy[i, g, None]  # (n, T, 2)
        err = (disp - gt_disp[:, None]).abs().sum(-1)  # (n, M, T)
        ade = (err * w).sum(-1) / w.sum(-1).clamp_min(1.0)  # (n, M)
        best = ade.detach().argmin(-1)
        l1 = l1 + ade.gather(1, best[:, None]).sum()
        cls = cls + F.cross_entropy(mode_logits[i, p], best, reduction="sum")
        matched += len(p)
    n = max(matched, 1)
    return l1 / n, cls / n, matched


class UniMMV2XCriterion(UniV2XCriterion):
    """``UniMMV2XCriterion(cfg)(outputs, batch) -> (loss, parts)`` (module docstring)."""

    def forward(self, out: dict, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        cfg = self.cfg
        loss, parts = super().forward(out, batch)
        mot, mcls, _ = motion_loss(out["traj"], out["mode_logits"],
                                   out["det_boxes"][-1][..., :2], out["det_mask"],
                                   batch["det_boxes"][..., :2], batch["det_mask"].bool(),
                                   batch["motion_future"], batch["motion_mask"].bool(), cfg)
        bal = out["balance"]
        if out.get("rsu") is not None:
            bal = bal + out["rsu"]["balance"]
        terms = {"motion": cfg.motion_weight * mot, "motion_cls": cfg.motion_cls_weight * mcls,
                 "moe": cfg.moe_weight * bal}
        parts.update({k: float(v.detach()) for k, v in terms.items()})
        return loss + sum(terms.values()), parts


__all__ = ["UniMMV2XCriterion", "motion_loss"]
