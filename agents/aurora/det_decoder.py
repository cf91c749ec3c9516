"""DETR-style 3D detection decoder with iterative box refinement, and the traffic-light head.

Queries: ``Q`` learnable content vectors and ``Q`` learnable 3D reference points in the range's
normalized ``[0, 1]^3``; a query's position embedding is an MLP of the sine embedding of its
reference point. Each layer is post-norm self-attention, cross-attention and FFN. Cross-
attention is dense (``nn.MultiheadAttention``) over all image tokens of all cameras, keyed by
``token + 3D position embedding`` (PETR); deformable attention is not used (the token count at
the CPU scales is small, and dense attention needs no camera projection of the queries).

Refinement (Deformable DETR, ``with_box_refine``): every layer has its own class and box heads;
the box head's centre output is an offset in inverse-sigmoid space from the layer's reference
points, the refined (detached) centre is the next layer's reference. Boxes are decoded to metres
in the branch frame: ``(x, y, z, l, w, h, sin yaw, cos yaw, vx, vy)``, sizes as ``exp``.
"""

from __future__ import annotations

import math

import torch
from torch import nn

LOG_SIZE_CLAMP = 6.0  # |log size| bound (m) before exp


def inverse_sigmoid(x: torch.Tensor, eps: float = 1e-5) -> torch.Tensor:
    """``log(x / (1 - x))`` with ``x`` clamped to ``[eps, 1 - eps]``."""
    x = x.clamp(eps, 1 - eps)
    return torch.log(x / (1 - x))


def sine_embed(coords: torch.Tensor, feats: int, temperature: float = 10000.0) -> torch.Tensor:
    """Sine/cosine embedding of normalized coordinates ``(..., k)`` -> ``(..., k * feats)``."""
    dim_t = torch.arange(feats // 2, dtype=torch.float32, device=coords.device)
    freq = temperature ** (2 * dim_t / feats)
    x = coords[..., None] * (2 * math.pi) / freq  # (..., k, feats/2)
    return torch.cat([x.sin(), x.cos()], -1).flatten(-2)


def mlp(dims: list[int]) -> nn.Sequential:
    """Linear layers of ``dims`` with ReLU between them."""
    layers: list[nn.Module] = []
    for i in range(len(dims) - 1):
        layers.append(nn.Linear(dims[i], dims[i + 1]))
        if i < len(dims) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def focal_bias(prior: float = 0.01) -> float:
    """Initial class-logit bias so that every query starts at probability ``prior``."""
    return -math.log((1 - prior) / prior)


class DecoderLayer(nn.Module):
    """Post-norm DETR decoder layer: self-attention, cross-attention to the image tokens, FFN."""

    def __init__(self, width: int, heads: int, ffn: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.self_attn = nn.MultiheadAttention(width, heads, dropout=dropout, batch_first=True)
        self.cross_attn = nn.MultiheadAttention(width, heads, dropout=dropout, batch_first=True)
        self.ffn = nn.Sequential(nn.Linear(width, ffn), nn.ReLU(), nn.Dropout(dropout),
                                 nn.Linear(ffn, width))
        self.norm1 = nn.LayerNorm(width)
        self.norm2 = nn.LayerNorm(width)
        self.norm3 = nn.LayerNorm(width)
        self.drop = nn.Dropout(dropout)

    def mix_queries(self, x: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        """Self-attention among the queries ``(B, Q, D)``; returns the new queries."""
        q = x + pos
        return self.norm1(x + self.drop(self.self_attn(q, q, x, need_weights=False)[0]))

    def forward(self, x: torch.Tensor, pos: torch.Tensor, memory: torch.Tensor,
                mem_pos: torch.Tensor) -> torch.Tensor:
        """Queries ``(B, Q, D)`` with position ``pos``; memory / mem_pos ``(B, S, D)``."""
        x = self.mix_queries(x, pos)
        y = self.cross_attn(x + pos, memory + mem_pos, memory, need_weights=False)[0]
        x = self.norm2(x + self.drop(y))
        return self.norm3(x + self.drop(self.ffn(x)))


class DetectionDecoder(nn.Module):
    """Detection decoder of one branch (module docstring).

    Args:
        width, heads, ffn, layers, dropout: transformer sizes.
        num_queries: detection queries ``Q``.
        num_classes: object classes (sigmoid logits, no background class).
        pc_range: the branch's ``(xmin, ymin, zmin, xmax, ymax, zmax)`` (m).
    """

    def __init__(self, width: int, heads: int, ffn: int, layers: int, num_queries: int,
                 num_classes: int, pc_range: tuple[float, ...], dropout: float = 0.0) -> None:
        super().__init__()
        self.register_buffer("lo", torch.tensor(pc_range[:3]), persistent=False)
        self.register_buffer("span", torch.tensor(pc_range[3:]) - self.lo, persistent=False)
        self.pos_feats = width // 2
        self.content = nn.Embedding(num_queries, width)
        self.ref_logit = nn.Parameter(inverse_sigmoid(torch.rand(num_queries, 3)))  # (Q, 3)
        self.query_pos = mlp([3 * self.pos_feats, width, width])
        self.layers = nn.ModuleList(DecoderLayer(width, heads, ffn, dropout) for _ in range(layers))
        self.cls_heads = nn.ModuleList(nn.Linear(width, num_classes) for _ in range(layers))
        self.reg_heads = nn.ModuleList(mlp([width, width, 10]) for _ in range(layers))
        for head in self.cls_heads:
            nn.init.constant_(head.bias, focal_bias())
        for head in self.reg_heads:  # start at the reference point, 1 m boxes, zero yaw vector
            nn.init.zeros_(head[-1].weight)
            nn.init.zeros_(head[-1].bias)

    def decode(self, reg: torch.Tensor, ref: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Head output ``(B, Q, 10)`` + reference ``(B, Q, 3)`` -> (metre boxes, new reference)."""
        centre = torch.sigmoid(reg[..., :3] + inverse_sigmoid(ref))  # normalized
        size = reg[..., 3:6].clamp(-LOG_SIZE_CLAMP, LOG_SIZE_CLAMP).exp()
        boxes = torch.cat([self.lo + centre * self.span, size, reg[..., 6:]], -1)
        return boxes, centre

    def forward(self, memory: torch.Tensor, mem_pos: torch.Tensor) -> dict[str, torch.Tensor]:
        """Decode image tokens ``memory`` ``(B, S, D)`` (position ``mem_pos``).

        Returns:
            ``logits`` ``(L, B, Q, C)``, ``boxes`` ``(L, B, Q, 10)`` (metres), ``ref``
            ``(B, Q, 3)`` final normalized reference points, ``queries`` ``(B, Q, D)``.
        """
        b = memory.shape[0]
        x = self.content.weight.expand(b, -1, -1)
        ref = self.ref_logit.sigmoid().expand(b, -1, -1)  # (B, Q, 3) normalized
        logits, boxes = [], []
        for layer, cls_head, reg_head in zip(self.layers, self.cls_heads, self.reg_heads):
            pos = self.query_pos(sine_embed(ref, self.pos_feats))
            x = layer(x, pos, memory, mem_pos)
            box, centre = self.decode(reg_head(x), ref)
            logits.append(cls_head(x))
            boxes.append(box)
            ref = centre.detach()
        return {"logits": torch.stack(logits), "boxes": torch.stack(boxes), "ref": ref,
                "queries": x}


class LightHead(nn.Module):
    """Traffic-light state of the ego branch: one learned query attends to all image tokens."""

    def __init__(self, width: int, heads: int, num_classes: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.query = nn.Parameter(torch.randn(1, 1, width) * 0.02)
        self.attn = nn.MultiheadAttention(width, heads, dropout=dropout, batch_first=True)
        self.norm = nn.LayerNorm(width)
        self.head = mlp([width, width, num_classes])

    def forward(self, memory: torch.Tensor, mem_pos: torch.Tensor) -> torch.Tensor:
        """``(B, S, D)`` tokens -> ``(B, num_classes)`` logits."""
        q = self.query.expand(memory.shape[0], -1, -1)
        y = self.attn(q, memory + mem_pos, memory, need_weights=False)[0]
        return self.head(self.norm(q + y))[:, 0]
