"""UniMM-V2X's prediction level: the MotionMoE decoder and the fusion of the roadside motion
queries into the ego's (the paper's prediction-level fusion).

**MotionMoE decoder** (:class:`MotionDecoder`; UniAD's MotionFormer with its FFNs replaced by
MoE blocks, :class:`~.moe.MoEFFN`): one motion query per agent, initialized from the agent's
query plus a position embedding of its reference point (sine embedding of the position
normalized to the agent's range, AURORA's :func:`~v2xbench.agents.aurora.det_decoder.
sine_embed`). Each of ``cfg.motion_layers`` post-norm layers: agent-agent self-attention
(padding masked), attention to the BEV tokens, MoE FFN. Heads: ``M`` modes of ``T`` future
positions (cumulative displacement steps from the agent's reference, metres, the agent's frame,
``cfg.motion_dt`` apart) and a score per mode.

**Prediction-level fusion** (:class:`MotionFusion`): a roadside motion query is aligned to the
ego frame by an MLP of ``[query; vec(R); t / 50 m; score]`` (as UniV2X's agent alignment,
:class:`~..univ2x.fusion.AgentFusion`) and fused into the ego motion query of the *same* agent:
the ego agent associated with it by the perception-level association (``match``), or the slot
where the roadside agent was appended. Fusion is the gated residual ``m + g * MLP([m; a])``,
``g = sigmoid(Linear([m; a]))``; agents without a roadside partner keep their motion query.
"""

from __future__ import annotations

import torch
from torch import nn
from v2xbench.agents.aurora.det_decoder import mlp, sine_embed

from ..univ2x.fusion import POSE_SCALE
from .config import UniMMV2XConfig
from .moe import MoEFFN


class MotionLayer(nn.Module):
    """Post-norm: agent self-attention, attention to the BEV, MoE FFN."""

    def __init__(self, cfg: UniMMV2XConfig) -> None:
        super().__init__()
        d = cfg.width
        self.agents = nn.MultiheadAttention(d, cfg.heads, dropout=cfg.dropout, batch_first=True)
        self.bev = nn.MultiheadAttention(d, cfg.heads, dropout=cfg.dropout, batch_first=True)
        self.moe = MoEFFN(d, cfg.moe_hidden, cfg.num_experts, cfg.moe_topk)
        self.norms = nn.ModuleList(nn.LayerNorm(d) for _ in range(3))

    def forward(self, x: torch.Tensor, pos: torch.Tensor, mask: torch.Tensor, bev: torch.Tensor,
                bev_pos: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x`` / ``pos`` ``(B, N, D)``, ``mask`` ``(B, N)`` True = valid, BEV ``(B, S, D)``
        -> (``x``, balance loss)."""
        q = x + pos
        x = self.norms[0](x + self.agents(q, q, x, key_padding_mask=~mask, need_weights=False)[0])
        x = self.norms[1](x + self.bev(x + pos, bev + bev_pos, bev, need_weights=False)[0])
        y, bal = self.moe(x, mask)
        return self.norms[2](x + y), bal


class MotionDecoder(nn.Module):
    """Agent queries -> motion queries, ``M`` trajectories and mode scores (module docstring).

    Args:
        cfg: the configuration. pc_range: the agents' range (for the position embedding).
    """

    def __init__(self, cfg: UniMMV2XConfig, pc_range: tuple[float, ...]) -> None:
        super().__init__()
        d = cfg.width
        self.cfg = cfg
        self.register_buffer("lo", torch.tensor(pc_range[:2], dtype=torch.float32),
                             persistent=False)
        self.register_buffer("span", torch.tensor(pc_range[3:5], dtype=torch.float32)
                             - torch.tensor(pc_range[:2], dtype=torch.float32), persistent=False)
        self.feats = d // 2
        self.pos = mlp([2 * self.feats, d, d])
        self.layers = nn.ModuleList(MotionLayer(cfg) for _ in range(cfg.motion_layers))
        self.traj = mlp([d, d, cfg.motion_modes * cfg.motion_steps * 2])
        self.mode = nn.Linear(d, cfg.motion_modes)

    def decode(self, agents: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor,
               bev: torch.Tensor, bev_pos: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``agents`` ``(B, N, D)``, ``ref`` ``(B, N, 3)`` (m), ``mask`` ``(B, N)``, BEV tokens
        ``(B, S, D)`` and positions -> (motion queries ``(B, N, D)``, balance loss summed over
        the layers)."""
        b = agents.shape[0]
        norm = ((ref[..., :2].detach() - self.lo) / self.span).clamp(0.0, 1.0)
        pos = self.pos(sine_embed(norm, self.feats))
        x, bal = agents, agents.new_zeros(())
        bev_pos = bev_pos.expand(b, -1, -1)
        for layer in self.layers:
            x, bl = layer(x, pos, mask, bev, bev_pos)
            bal = bal + bl
        return x, bal

    def heads(self, motion_q: torch.Tensor, ref: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """Motion queries ``(B, N, D)`` and references -> (``traj`` ``(B, N, M, T, 2)``, m, the
        agents' frame; ``mode_logits`` ``(B, N, M)``)."""
        cfg = self.cfg
        b, n = motion_q.shape[:2]
        steps = self.traj(motion_q).view(b, n, cfg.motion_modes, cfg.motion_steps, 2)
        return steps.cumsum(3) + ref[..., None, None, :2].detach(), self.mode(motion_q)

    def forward(self, agents: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor,
                bev: torch.Tensor, bev_pos: torch.Tensor) -> dict[str, torch.Tensor]:
        """:meth:`decode` then :meth:`heads`: ``motion_q``, ``traj``, ``mode_logits``,
        ``balance``."""
        x, bal = self.decode(agents, ref, mask, bev, bev_pos)
        traj, modes = self.heads(x, ref)
        return {"motion_q": x, "traj": traj, "mode_logits": modes, "balance": bal}


class MotionFusion(nn.Module):
    """Roadside motion queries fused into the ego's (module docstring)."""

    def __init__(self, cfg: UniMMV2XConfig) -> None:
        super().__init__()
        d = cfg.width
        self.align = mlp([d + 9 + 3 + 1, d, d])
        self.fuse = mlp([2 * d, d, d])
        self.gate = nn.Linear(2 * d, d)

    def partners(self, match: torch.Tensor, appended: torch.Tensor) -> torch.Tensor:
        """``(B, Q + K)`` int64: the roadside agent of each fused slot (``-1``: none), from the
        association ``match`` ``(B, Q)`` and the appended slots ``appended`` ``(B, K)``."""
        k = appended.shape[1]
        own = torch.arange(k, device=match.device).expand(match.shape[0], -1)
        return torch.cat([match, torch.where(appended, own, torch.full_like(own, -1))], 1)

    def forward(self, motion_q: torch.Tensor, rsu_motion: torch.Tensor, rsu_scores: torch.Tensor,
                partner: torch.Tensor, e_rsu_to_ego: torch.Tensor) -> torch.Tensor:
        """Ego motion queries ``(B, Q + K, D)``, roadside motion queries ``(B, K, D)`` with
        scores ``(B, K)``, ``partner`` (:meth:`partners`), ``E_{r->e}`` -> fused ``(B, Q + K,
        D)``."""
        e = e_rsu_to_ego.to(motion_q.dtype)
        b, k = rsu_scores.shape
        pose = torch.cat([e[:, :3, :3].reshape(b, 9), e[:, :3, 3] / POSE_SCALE], -1)
        aligned = self.align(torch.cat([rsu_motion, pose[:, None].expand(-1, k, -1),
                                        rsu_scores[..., None]], -1))
        idx = partner.clamp_min(0)[..., None].expand(-1, -1, aligned.shape[-1])
        pair = torch.cat([motion_q, aligned.gather(1, idx)], -1)
        fused = motion_q + torch.sigmoid(self.gate(pair)) * self.fuse(pair)
        return torch.where((partner >= 0)[..., None], fused, motion_q)


__all__ = ["MotionDecoder", "MotionFusion", "MotionLayer"]
