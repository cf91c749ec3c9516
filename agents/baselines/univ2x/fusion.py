"""UniV2X's fusion on the ego side: cross-view agent-query association and fusion (sparse), and
occupancy fusion (dense).

**Agent fusion** (:class:`AgentFusion`, the paper's "agent fusion": spatial alignment,
association, feature fusion). The roadside reference points are moved into the ego frame by
``E_{r->e}`` (AURORA's :func:`~v2xbench.agents.aurora.cqaf.transform_points`); every roadside
query is aligned to the ego frame by an MLP of ``[query; vec(R); t / 50 m; score]``. Association
is a Hungarian matching (:func:`~v2xbench.agents.aurora.matching.hungarian`) on the bird's-eye
distance between the ego agents scoring at least ``cfg.ego_score`` and the roadside agents; a
pair farther apart than ``cfg.match_radius`` is not associated. An associated ego query takes
the gated residual ``q + g * MLP([q; a])`` (``g = sigmoid(Linear([q; a]))``), the others stay;
unassociated roadside agents inside the ego range are appended as new agents with their
ego-frame reference. Fixed sizes with masks: ``Q + K`` slots, the last ``K`` valid where a
roadside agent was appended.

**Occupancy fusion** (:class:`OccupancyFusion`): the roadside occupancy map is warped into the
ego BEV grid by ``E_{r->e}`` (:func:`~.bev.warp_bev`, with a channel marking the cells the unit's
range covers); a 1x1 convolution of both channels is added to the ego BEV, and the fused BEV's
occupancy head gives the fused occupancy. Without a message both channels are zero.
"""

from __future__ import annotations

import torch
from torch import nn
from v2xbench.agents.aurora.cqaf import transform_points
from v2xbench.agents.aurora.det_decoder import focal_bias, mlp
from v2xbench.agents.aurora.matching import hungarian

from .bev import warp_bev
from .config import UniV2XConfig

POSE_SCALE = 50.0  # m: the translation's scale in the alignment MLP's input


class AgentFusion(nn.Module):
    """Cross-view agent-query association and fusion (module docstring)."""

    def __init__(self, cfg: UniV2XConfig) -> None:
        super().__init__()
        d = cfg.width
        self.cfg = cfg
        self.align = mlp([d + 9 + 3 + 1, d, d])
        self.fuse = mlp([2 * d, d, d])
        self.gate = nn.Linear(2 * d, d)
        self.register_buffer("lo", torch.tensor(cfg.ego_range[:2]), persistent=False)
        self.register_buffer("hi", torch.tensor(cfg.ego_range[3:5]), persistent=False)

    @torch.no_grad()
    def associate(self, ego_ref: torch.Tensor, ego_scores: torch.Tensor, rsu_ref: torch.Tensor,
                  rsu_mask: torch.Tensor) -> torch.Tensor:
        """``(B, Q)`` int64: the roadside agent associated with each ego agent, ``-1`` for none.

        Args:
            ego_ref: ``(B, Q, 3)`` ego agents' positions (m, ego frame); ego_scores ``(B, Q)``.
            rsu_ref: ``(B, K, 3)`` roadside agents' positions in the ego frame; rsu_mask
                ``(B, K)`` bool, the agents received.
        """
        b, q = ego_scores.shape
        out = torch.full((b, q), -1, dtype=torch.long, device=ego_ref.device)
        dist = torch.cdist(ego_ref[..., :2].float(), rsu_ref[..., :2].float())  # (B, Q, K)
        for i in range(b):
            rows = (ego_scores[i] >= self.cfg.ego_score).nonzero().squeeze(1)
            cols = rsu_mask[i].nonzero().squeeze(1)
            if not len(rows) or not len(cols):
                continue
            sub = dist[i][rows][:, cols]
            r, c = hungarian(sub)
            ok = sub[r, c] < self.cfg.match_radius
            out[i, rows[r[ok]]] = cols[c[ok]]
        return out

    def forward(self, ego_q: torch.Tensor, ego_ref: torch.Tensor, ego_scores: torch.Tensor,
                msg: dict[str, torch.Tensor], e_rsu_to_ego: torch.Tensor
                ) -> dict[str, torch.Tensor]:
        """Fuse ego agents ``(B, Q, D)`` (positions ``(B, Q, 3)`` m, scores ``(B, Q)``) with the
        message's agents (:mod:`.message`, roadside frame) given ``E_{r->e}`` ``(B, 4, 4)``.

        Returns ``queries`` ``(B, Q + K, D)``, ``ref`` ``(B, Q + K, 3)`` (m, ego frame), ``mask``
        ``(B, Q + K)`` bool, ``match`` ``(B, Q)`` (:meth:`associate`) and ``rsu_ref`` ``(B, K,
        3)``: the roadside positions in the ego frame.
        """
        e = e_rsu_to_ego.to(ego_q.dtype)
        b, k = msg["mask"].shape
        rsu_ref = transform_points(e, msg["ref"].to(ego_q.dtype))  # (B, K, 3)
        pose = torch.cat([e[:, :3, :3].reshape(b, 9), e[:, :3, 3] / POSE_SCALE], -1)
        aligned = self.align(torch.cat([msg["queries"], pose[:, None].expand(-1, k, -1),
                                        msg["scores"][..., None]], -1))  # (B, K, D)
        match = self.associate(ego_ref, ego_scores, rsu_ref, msg["mask"])
        has = match >= 0
        partner = aligned.gather(1, match.clamp_min(0)[..., None].expand(-1, -1, aligned.shape[-1]))
        pair = torch.cat([ego_q, partner], -1)
        fused = ego_q + torch.sigmoid(self.gate(pair)) * self.fuse(pair)
        fused = torch.where(has[..., None], fused, ego_q)
        taken = torch.zeros(b, k, dtype=torch.bool, device=ego_q.device)
        rows, cols = has.nonzero(as_tuple=True)
        taken[rows, match[rows, cols]] = True
        inside = ((rsu_ref[..., :2] >= self.lo) & (rsu_ref[..., :2] <= self.hi)).all(-1)
        appended = msg["mask"] & ~taken & inside
        ones = torch.ones_like(ego_scores, dtype=torch.bool)
        return {"queries": torch.cat([fused, aligned], 1), "ref": torch.cat([ego_ref, rsu_ref], 1),
                "mask": torch.cat([ones, appended], 1), "match": match, "rsu_ref": rsu_ref}


class OccupancyFusion(nn.Module):
    """Roadside occupancy warped into the ego BEV and fused (module docstring)."""

    def __init__(self, cfg: UniV2XConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.mix = nn.Conv2d(2, cfg.width, 1)
        self.head = nn.Conv2d(cfg.width, 1, 1)
        nn.init.constant_(self.head.bias, focal_bias())  # cells start at p = 0.01

    def warp(self, occ: torch.Tensor, e_rsu_to_ego: torch.Tensor) -> torch.Tensor:
        """Roadside occupancy ``(B, Ox, Oy)`` -> ``(B, 2, nx, ny)`` on the ego grid: the warped
        probabilities and the cells inside the roadside range (:func:`~.bev.warp_bev`)."""
        cfg = self.cfg
        return warp_bev(occ[:, None], e_rsu_to_ego, cfg.rsu_range, cfg.ego_range, cfg.ego_bev)

    def forward(self, bev: torch.Tensor, occ: torch.Tensor, e_rsu_to_ego: torch.Tensor,
                has_rsu: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Ego BEV ``(B, W, nx, ny)``, roadside occupancy ``(B, Ox, Oy)``, ``E_{r->e}``, which
        rows received a message ``(B,)`` -> (fused BEV, fused occupancy logits ``(B, nx, ny)``)."""
        warped = self.warp(occ, e_rsu_to_ego) * has_rsu.view(-1, 1, 1, 1).to(bev.dtype)
        fused = bev + self.mix(warped)
        return fused, self.head(fused)[:, 0]


__all__ = ["AgentFusion", "OccupancyFusion"]
