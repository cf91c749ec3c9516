"""MapTR-style vectorized map decoder (Liao et al., ICLR 2023; decoupled attention of MapTRv2).

Hierarchical queries: ``Qm`` instance embeddings + ``P`` point embeddings give ``Qm x P`` point
queries (instance ``i``, point ``j``: ``inst_i + point_j``). Each point query has a 2D reference
point ``(x, y)`` in the range's normalized ``[0, 1]^2`` (initially a learned linear map of its
query, then refined layer by layer as offsets in inverse-sigmoid space); its position embedding
is an MLP of the reference point's sine embedding.

A layer is: self-attention among instances (for each point index), self-attention among the
points of each instance (MapTRv2's decoupled self-attention, cheaper than attention over all
``Qm P`` queries), dense cross-attention to all image tokens of the branch (keyed by token + 3D
position embedding; MapTR attends to BEV features instead, which this model does not build),
FFN. Per layer: class logits of an instance from the mean of its point features, and each point's
offset. Points are decoded to metres ``(x, y)`` in the branch frame.
"""

from __future__ import annotations

import torch
from torch import nn

from .det_decoder import DecoderLayer, focal_bias, inverse_sigmoid, mlp, sine_embed


class MapDecoderLayer(DecoderLayer):
    """:class:`DecoderLayer` whose self-attention is decoupled (inter-instance, intra-instance)."""

    def __init__(self, width: int, heads: int, ffn: int, instances: int, points: int,
                 dropout: float = 0.0) -> None:
        super().__init__(width, heads, ffn, dropout)
        self.instances, self.points = instances, points
        self.point_attn = nn.MultiheadAttention(width, heads, dropout=dropout, batch_first=True)
        self.norm0 = nn.LayerNorm(width)

    def mix_queries(self, x: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        """``(B, Qm*P, D)``: attention across instances per point index, then within instances."""
        b, _, d = x.shape
        qm, p = self.instances, self.points

        def per_point(t: torch.Tensor) -> torch.Tensor:  # (B, Qm*P, D) -> (B*P, Qm, D)
            return t.view(b, qm, p, d).transpose(1, 2).reshape(b * p, qm, d)

        xi, q = per_point(x), per_point(x + pos)
        xi = self.norm0(xi + self.drop(self.self_attn(q, q, xi, need_weights=False)[0]))
        x = xi.view(b, p, qm, d).transpose(1, 2).reshape(b * qm, p, d)  # (B*Qm, P, D)
        q = x + pos.reshape(b * qm, p, d)
        x = self.norm1(x + self.drop(self.point_attn(q, q, x, need_weights=False)[0]))
        return x.view(b, qm * p, d)


class MapDecoder(nn.Module):
    """Map decoder of one branch (module docstring).

    Args:
        width, heads, ffn, layers, dropout: transformer sizes.
        num_instances: instance queries ``Qm``.
        num_points: points per polyline ``P``.
        num_classes: map classes (divider, boundary, crosswalk).
        pc_range: the branch's ``(xmin, ymin, zmin, xmax, ymax, zmax)`` (m); x, y are used.
    """

    def __init__(self, width: int, heads: int, ffn: int, layers: int, num_instances: int,
                 num_points: int, num_classes: int, pc_range: tuple[float, ...],
                 dropout: float = 0.0) -> None:
        super().__init__()
        self.qm, self.p = num_instances, num_points
        self.register_buffer("lo", torch.tensor(pc_range[:2]), persistent=False)
        self.register_buffer("span", torch.tensor(pc_range[3:5]) - self.lo, persistent=False)
        self.pos_feats = width // 2
        self.instance = nn.Embedding(num_instances, width)
        self.point = nn.Embedding(num_points, width)
        self.ref_init = nn.Linear(width, 2)
        self.query_pos = mlp([2 * self.pos_feats, width, width])
        self.layers = nn.ModuleList(
            MapDecoderLayer(width, heads, ffn, num_instances, num_points, dropout)
            for _ in range(layers))
        self.cls_heads = nn.ModuleList(nn.Linear(width, num_classes) for _ in range(layers))
        self.reg_heads = nn.ModuleList(mlp([width, width, 2]) for _ in range(layers))
        for head in self.cls_heads:
            nn.init.constant_(head.bias, focal_bias())
        for head in self.reg_heads:
            nn.init.zeros_(head[-1].weight)
            nn.init.zeros_(head[-1].bias)

    def forward(self, memory: torch.Tensor, mem_pos: torch.Tensor) -> dict[str, torch.Tensor]:
        """Decode image tokens ``memory`` ``(B, S, D)`` (position ``mem_pos``).

        Returns:
            ``logits`` ``(L, B, Qm, C)``, ``points`` ``(L, B, Qm, P, 2)`` (metres),
            ``queries`` ``(B, Qm, D)`` (mean of each instance's point features).
        """
        b, d = memory.shape[0], memory.shape[-1]
        content = (self.instance.weight[:, None] + self.point.weight[None]).view(-1, d)
        x = content.expand(b, -1, -1)  # (B, Qm*P, D)
        ref = self.ref_init(content).sigmoid().expand(b, -1, -1)  # (B, Qm*P, 2)
        logits, points = [], []
        for layer, cls_head, reg_head in zip(self.layers, self.cls_heads, self.reg_heads):
            pos = self.query_pos(sine_embed(ref, self.pos_feats))
            x = layer(x, pos, memory, mem_pos)
            ref_new = torch.sigmoid(reg_head(x) + inverse_sigmoid(ref))
            logits.append(cls_head(x.view(b, self.qm, self.p, d).mean(2)))
            points.append((self.lo + ref_new * self.span).view(b, self.qm, self.p, 2))
            ref = ref_new.detach()
        return {"logits": torch.stack(logits), "points": torch.stack(points),
                "queries": x.view(b, self.qm, self.p, d).mean(2)}
