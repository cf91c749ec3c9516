"""V2X-ViT's fusion at the ego: the received map in the ego grid, the delay-aware positional
encoding, and the V2X-ViT encoder (heterogeneous multi-agent self-attention + multi-scale window
attention).

- **Warp** (:func:`warp_to_ego`): the decompressed roadside map (its ground frame) resampled at
  the ego grid's cell centres with ``E_{r->e}`` (UniV2X's :func:`~..univ2x.bev.warp_bev`:
  bilinear, zero outside the unit's range, plus a coverage channel); cells the unit does not
  cover, and every cell of a row without a message, are masked for the attention.
- **Delay-aware positional encoding** (:class:`DelayEncoding`, the paper's DPE): the message's
  age ``dt`` (ticks of 0.1 s, clipped to ``max_age``) as sinusoids ``p(dt)_{2k} = sin(dt /
  10000^{2k/C})``, ``p(dt)_{2k+1} = cos(...)``, through a linear layer, added to every cell of
  the agent's map (the ego's age is 0).
- **Heterogeneous multi-agent self-attention** (:class:`HeteroAgentAttention`, HMSA): per BEV
  cell, attention over the agents. Node types ``ego`` (vehicle, 0) and ``rsu``
  (infrastructure, 1) have their own query / key / value and output projections; the edge type
  ``(type_i, type_j)`` has its own attention matrix ``W_att`` and message matrix ``W_msg`` per
  head: ``score_ij = (K_j W_att) . Q_i / sqrt(d)``, ``out_i = A_{type_i}(sum_j softmax_j(score)
  W_msg V_j)``; masked agents get no weight.
- **Multi-scale window attention** (:class:`MultiScaleWindowAttention`, MSwin): per agent, one
  branch per window size (``windows``, cells) of self-attention inside non-overlapping windows
  with a learned relative position bias (Swin), fewer heads for larger windows
  (``window_heads``, as the paper's 16 / 8 / 4); the branches are fused by split attention (a
  softmax over the branches per channel from the pooled sum).
- **Encoder** (:class:`V2XViTEncoder`): ``vit_blocks`` blocks of pre-norm HMSA, MSwin and an MLP,
  each residual; the output is the ego's map.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ..univ2x.bev import warp_bev
from .config import V2XViTConfig

EGO, RSU = 0, 1  # node types


def warp_to_ego(features: torch.Tensor, e_rsu_to_ego: torch.Tensor, has_rsu: torch.Tensor,
                cfg: V2XViTConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """``(warped (B, C, nx, ny), covered (B, nx, ny) bool)``: roadside features ``(B, C, nx',
    ny')`` over its range moved into the ego feature grid by ``E_{r->e}`` ``(B, 4, 4)``; rows
    with ``has_rsu`` false are zero and uncovered."""
    out = warp_bev(features, e_rsu_to_ego, cfg.rsu_range, cfg.ego_range, cfg.feature_size("ego"))
    covered = (out[:, -1] > 0.5) & has_rsu.bool()[:, None, None]
    return out[:, :-1] * covered[:, None].to(out.dtype), covered


class DelayEncoding(nn.Module):
    """Ages ``(B, N)`` in ticks -> ``(B, N, C)`` (module docstring)."""

    def __init__(self, width: int, max_age: int) -> None:
        super().__init__()
        self.max_age = float(max_age)
        k = torch.arange(0, width, 2, dtype=torch.float32)
        self.register_buffer("freq", 1.0 / (10000.0 ** (k / width)), persistent=False)
        self.width = width
        self.proj = nn.Linear(width, width)

    def sinusoid(self, age: torch.Tensor) -> torch.Tensor:
        """The fixed part ``p(dt)`` ``(..., C)`` (before the linear layer)."""
        a = age.float().clamp(0.0, self.max_age)[..., None] * self.freq
        return torch.stack([a.sin(), a.cos()], -1).flatten(-2)[..., :self.width]

    def forward(self, age: torch.Tensor) -> torch.Tensor:
        return self.proj(self.sinusoid(age))


class HeteroAgentAttention(nn.Module):
    """HMSA over ``x`` ``(B, N, H, W, C)`` with node ``types`` ``(N,)`` and ``mask`` ``(B, N, H,
    W)`` (module docstring)."""

    def __init__(self, width: int, heads: int, types: int = 2) -> None:
        super().__init__()
        self.h, self.d = heads, width // heads
        self.q = nn.ModuleList(nn.Linear(width, width) for _ in range(types))
        self.k = nn.ModuleList(nn.Linear(width, width) for _ in range(types))
        self.v = nn.ModuleList(nn.Linear(width, width) for _ in range(types))
        self.out = nn.ModuleList(nn.Linear(width, width) for _ in range(types))
        eye = torch.eye(self.d).expand(types * types, heads, -1, -1).clone()
        self.w_att = nn.Parameter(eye + 0.02 * torch.randn_like(eye))
        self.w_msg = nn.Parameter(eye.clone() + 0.02 * torch.randn_like(eye))
        self.types = types

    def forward(self, x: torch.Tensor, types: list[int], mask: torch.Tensor) -> torch.Tensor:
        b, n, hh, ww, c = x.shape
        split = (b, hh, ww, self.h, self.d)
        q = [self.q[t](x[:, a]).view(split) for a, t in enumerate(types)]
        k = [self.k[t](x[:, a]).view(split) for a, t in enumerate(types)]
        v = [self.v[t](x[:, a]).view(split) for a, t in enumerate(types)]
        out = []
        for i, ti in enumerate(types):
            scores, msgs = [], []
            for j, tj in enumerate(types):
                e = ti * self.types + tj
                s = torch.einsum("bxyhd,hde,bxyhe->bxyh", k[j], self.w_att[e], q[i])
                s = s / math.sqrt(self.d)
                scores.append(s.masked_fill(~mask[:, j, ..., None], float("-inf")))
                msgs.append(torch.einsum("hde,bxyhe->bxyhd", self.w_msg[e], v[j]))
            att = torch.stack(scores, -1).softmax(-1)  # (B, H, W, heads, N)
            att = torch.nan_to_num(att)  # a cell where every agent is masked: no message
            agg = (att[..., None, :] * torch.stack(msgs, -1)).sum(-1)  # (B, H, W, heads, d)
            out.append(self.out[ti](agg.reshape(b, hh, ww, c)))
        return torch.stack(out, 1)


class WindowAttention(nn.Module):
    """Self-attention inside ``ws x ws`` windows with a relative position bias (one branch)."""

    def __init__(self, width: int, heads: int, ws: int) -> None:
        super().__init__()
        self.h, self.d, self.ws = heads, width // heads, ws
        self.qkv = nn.Linear(width, 3 * width)
        self.bias = nn.Parameter(torch.zeros((2 * ws - 1) ** 2, heads))
        nn.init.trunc_normal_(self.bias, std=0.02)
        yy, xx = torch.meshgrid(torch.arange(ws), torch.arange(ws), indexing="ij")
        pos = torch.stack([yy.flatten(), xx.flatten()], -1)  # (ws^2, 2)
        rel = pos[:, None] - pos[None] + ws - 1
        self.register_buffer("index", rel[..., 0] * (2 * ws - 1) + rel[..., 1], persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(M, H, W, C)`` -> ``(M, H, W, C)`` (``H``, ``W`` multiples of the window)."""
        m, hh, ww, c = x.shape
        s = self.ws
        win = x.view(m, hh // s, s, ww // s, s, c).permute(0, 1, 3, 2, 4, 5).reshape(-1, s * s, c)
        q, k, v = self.qkv(win).view(win.shape[0], s * s, 3, self.h, self.d).permute(
            2, 0, 3, 1, 4)
        bias = self.bias[self.index].permute(2, 0, 1)  # (heads, s^2, s^2)
        out = F.scaled_dot_product_attention(q, k, v, attn_mask=bias)
        out = out.transpose(1, 2).reshape(m, hh // s, ww // s, s, s, c)
        return out.permute(0, 1, 3, 2, 4, 5).reshape(m, hh, ww, c)


class MultiScaleWindowAttention(nn.Module):
    """MSwin over ``x`` ``(B, N, H, W, C)``, each agent on its own (module docstring)."""

    def __init__(self, width: int, heads: tuple[int, ...], windows: tuple[int, ...]) -> None:
        super().__init__()
        self.branches = nn.ModuleList(WindowAttention(width, h, w) for h, w in zip(heads, windows))
        k = len(windows)
        self.split = nn.Sequential(nn.Linear(width, max(width // 2, 4)), nn.ReLU(inplace=True),
                                   nn.Linear(max(width // 2, 4), k * width))
        self.proj = nn.Linear(width, width)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, n, hh, ww, c = x.shape
        flat = x.reshape(b * n, hh, ww, c)
        outs = torch.stack([br(flat) for br in self.branches])  # (K, BN, H, W, C)
        pooled = outs.sum(0).mean((1, 2))  # (BN, C)
        w = self.split(pooled).view(b * n, len(self.branches), c).softmax(1)
        fused = (outs * w.transpose(0, 1)[:, :, None, None]).sum(0)
        return self.proj(fused).view(b, n, hh, ww, c)


class V2XViTBlock(nn.Module):
    """Pre-norm HMSA, MSwin and MLP, each residual."""

    def __init__(self, cfg: V2XViTConfig) -> None:
        super().__init__()
        w = cfg.width
        self.n1, self.n2, self.n3 = nn.LayerNorm(w), nn.LayerNorm(w), nn.LayerNorm(w)
        self.hmsa = HeteroAgentAttention(w, cfg.heads)
        self.mswin = MultiScaleWindowAttention(w, tuple(cfg.window_heads), tuple(cfg.windows))
        hidden = int(round(w * cfg.mlp_ratio))
        self.mlp = nn.Sequential(nn.Linear(w, hidden), nn.GELU(), nn.Dropout(cfg.dropout),
                                 nn.Linear(hidden, w), nn.Dropout(cfg.dropout))

    def forward(self, x: torch.Tensor, types: list[int], mask: torch.Tensor) -> torch.Tensor:
        x = x + self.hmsa(self.n1(x), types, mask)
        x = x + self.mswin(self.n2(x))
        return x + self.mlp(self.n3(x))


class V2XViTEncoder(nn.Module):
    """Ego map ``(B, C, H, W)``, warped roadside map and its coverage ``(B, H, W)``, the
    message's age ``(B,)`` (ticks) -> the fused ego map ``(B, C, H, W)`` (module docstring)."""

    def __init__(self, cfg: V2XViTConfig) -> None:
        super().__init__()
        self.delay = DelayEncoding(cfg.width, cfg.max_age)
        self.blocks = nn.ModuleList(V2XViTBlock(cfg) for _ in range(cfg.vit_blocks))
        self.norm = nn.LayerNorm(cfg.width)

    def forward(self, ego: torch.Tensor, rsu: torch.Tensor, covered: torch.Tensor,
                age: torch.Tensor) -> torch.Tensor:
        x = torch.stack([ego, rsu], 1).permute(0, 1, 3, 4, 2)  # (B, 2, H, W, C)
        ages = torch.stack([torch.zeros_like(age), age], 1).float()  # the ego's age is 0
        x = x + self.delay(ages)[:, :, None, None]
        mask = torch.stack([torch.ones_like(covered), covered], 1)
        x = x * mask[..., None].to(x.dtype)
        for blk in self.blocks:
            x = blk(x, [EGO, RSU], mask)
        return self.norm(x[:, 0]).permute(0, 3, 1, 2).contiguous()


__all__ = ["DelayEncoding", "HeteroAgentAttention", "MultiScaleWindowAttention",
           "V2XViTBlock", "V2XViTEncoder", "WindowAttention", "warp_to_ego"]
