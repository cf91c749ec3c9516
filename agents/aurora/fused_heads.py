"""Fused detection and map heads of CQAF (seed paper, section 4.2) and their criterion.

After DET-CQAF and MAP-CQAF (:mod:`.cqaf`) the fused query sets mix ego queries and appended
roadside queries, each with a reference in the ego frame (a 3D point for detection, a polyline
for the map) and a validity mask (appended slots that were not appended are padding). A head is
one self-attention + FFN layer over the valid fused queries (keyed by the position embedding of
their references, padding excluded), then part 1's prediction parametrization:

- detection (:class:`FusedDetHead`): class logits and a box whose centre is an offset from the
  reference in inverse-sigmoid space of the ego range, sizes as ``exp``, ``sin / cos`` yaw and
  velocity (:meth:`.det_decoder.DetectionDecoder.decode`);
- map (:class:`FusedMapHead`): class logits and per-point offsets of the reference polyline.

Outputs use part 1's layout with one "decoder layer" (``L = 1``), so part 1's set criterion
scores them: :class:`FusedCriterion` is :class:`~.losses.SetCriterion` in the ego range
without the traffic-light term, for the ``gt/fused`` targets (ego frame). Padding slots get the
class logit :data:`MASKED_LOGIT` (probability ~2e-9), which the focal loss and the matching cost
treat as "no object".
"""

from __future__ import annotations

import torch
from torch import nn

from .config import AuroraConfig
from .det_decoder import DetectionDecoder, focal_bias, inverse_sigmoid, mlp, sine_embed
from .losses import SetCriterion

MASKED_LOGIT = -20.0
MAP_POS_FEATS = 16  # sine features per polyline coordinate


class FusionLayer(nn.Module):
    """Post-norm self-attention (position on queries and keys, padding masked) + FFN."""

    def __init__(self, width: int, heads: int, ffn: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.attn = nn.MultiheadAttention(width, heads, dropout=dropout, batch_first=True)
        self.ffn = nn.Sequential(nn.Linear(width, ffn), nn.ReLU(), nn.Dropout(dropout),
                                 nn.Linear(ffn, width))
        self.norm1, self.norm2 = nn.LayerNorm(width), nn.LayerNorm(width)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, pos: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """``x``, ``pos`` ``(B, N, D)``; ``mask`` ``(B, N)`` bool, True = valid (one per row)."""
        q = x + pos
        y = self.attn(q, q, x, key_padding_mask=~mask, need_weights=False)[0]
        x = self.norm1(x + self.drop(y))
        return self.norm2(x + self.drop(self.ffn(x)))


def _range(cfg: AuroraConfig, dims: int) -> tuple[torch.Tensor, torch.Tensor]:
    r = cfg.pc_range("ego")
    lo = torch.tensor(r[:dims])
    return lo, torch.tensor(r[3:3 + dims]) - lo


class FusedDetHead(nn.Module):
    """Detection head over the fused detection queries (module docstring)."""

    decode = DetectionDecoder.decode  # part 1's box parametrization (uses self.lo / self.span)

    def __init__(self, cfg: AuroraConfig) -> None:
        super().__init__()
        d = cfg.dec_width
        lo, span = _range(cfg, 3)
        self.register_buffer("lo", lo, persistent=False)
        self.register_buffer("span", span, persistent=False)
        self.pos_feats = d // 2
        self.query_pos = mlp([3 * self.pos_feats, d, d])
        self.layer = FusionLayer(d, cfg.dec_heads, cfg.dec_ffn, cfg.dropout)
        self.cls = nn.Linear(d, cfg.num_classes)
        self.reg = mlp([d, d, 10])
        nn.init.constant_(self.cls.bias, focal_bias())
        nn.init.zeros_(self.reg[-1].weight)
        nn.init.zeros_(self.reg[-1].bias)

    def position(self, ref: torch.Tensor) -> torch.Tensor:
        """Position embedding ``(B, N, D)`` of ego-frame reference points ``(B, N, 3)`` (m)."""
        return self.query_pos(sine_embed(self.normalize(ref), self.pos_feats))

    def normalize(self, ref: torch.Tensor) -> torch.Tensor:
        """Metres -> the ego range's ``[0, 1]^3`` (clamped)."""
        return ((ref - self.lo) / self.span).clamp(0.0, 1.0)

    def forward(self, queries: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor
                ) -> dict[str, torch.Tensor]:
        """Fused queries ``(B, N, D)``, references ``(B, N, 3)`` (m, ego frame), mask ``(B, N)``.

        Returns ``det_logits`` ``(1, B, N, C)`` (padding: :data:`MASKED_LOGIT`), ``det_boxes``
        ``(1, B, N, 10)`` metres, ``q_det`` ``(B, N, D)`` refined queries and ``det_pos``
        ``(B, N, D)`` their position embedding.
        """
        pos = self.position(ref)
        x = self.layer(queries, pos, mask)
        boxes, _ = self.decode(self.reg(x), self.normalize(ref))
        logits = self.cls(x).masked_fill(~mask[..., None], MASKED_LOGIT)
        return {"det_logits": logits[None], "det_boxes": boxes[None], "q_det": x, "det_pos": pos}


class FusedMapHead(nn.Module):
    """Map head over the fused map queries (module docstring)."""

    def __init__(self, cfg: AuroraConfig) -> None:
        super().__init__()
        d, p = cfg.dec_width, cfg.map_points
        lo, span = _range(cfg, 2)
        self.register_buffer("lo", lo, persistent=False)
        self.register_buffer("span", span, persistent=False)
        self.points = p
        self.query_pos = mlp([2 * p * MAP_POS_FEATS, d, d])
        self.layer = FusionLayer(d, cfg.dec_heads, cfg.dec_ffn, cfg.dropout)
        self.cls = nn.Linear(d, cfg.num_map_classes)
        self.reg = mlp([d, d, 2 * p])
        nn.init.constant_(self.cls.bias, focal_bias())
        nn.init.zeros_(self.reg[-1].weight)
        nn.init.zeros_(self.reg[-1].bias)

    def normalize(self, points: torch.Tensor) -> torch.Tensor:
        """Metres -> the ego range's ``[0, 1]^2`` (clamped)."""
        return ((points - self.lo) / self.span).clamp(0.0, 1.0)

    def position(self, points: torch.Tensor) -> torch.Tensor:
        """Position embedding ``(B, N, D)`` of reference polylines ``(B, N, P, 2)`` (m)."""
        return self.query_pos(sine_embed(self.normalize(points).flatten(-2), MAP_POS_FEATS))

    def forward(self, queries: torch.Tensor, ref_points: torch.Tensor, mask: torch.Tensor
                ) -> dict[str, torch.Tensor]:
        """Fused map queries ``(B, N, D)``, reference polylines ``(B, N, P, 2)`` (m, ego frame),
        mask ``(B, N)``.

        Returns ``map_logits`` ``(1, B, N, 3)`` (padding: :data:`MASKED_LOGIT`), ``map_points``
        ``(1, B, N, P, 2)`` metres, ``q_map`` ``(B, N, D)`` and ``map_pos`` ``(B, N, D)``.
        """
        pos = self.position(ref_points)
        x = self.layer(queries, pos, mask)
        off = self.reg(x).unflatten(-1, (self.points, 2))
        pts = torch.sigmoid(off + inverse_sigmoid(self.normalize(ref_points)))
        logits = self.cls(x).masked_fill(~mask[..., None], MASKED_LOGIT)
        return {"map_logits": logits[None], "map_points": (self.lo + pts * self.span)[None],
                "q_map": x, "map_pos": pos}


class FusedCriterion(SetCriterion):
    """Part 1's set-prediction loss of the fused heads' outputs against ``gt/fused`` targets in
    the ego frame (ego range; no traffic-light term): ``(loss, parts)`` with ``det_cls``,
    ``det_box``, ``map_cls``, ``map_pts``."""

    def __init__(self, cfg: AuroraConfig) -> None:
        super().__init__(cfg, "ego")  # the ego range's normalization of map points
        self.branch = "fused"  # not "ego": SetCriterion then neither needs nor scores `light`


__all__ = ["MASKED_LOGIT", "FusedCriterion", "FusedDetHead", "FusedMapHead", "FusionLayer"]
