"""V2X-ViT's LiDAR encoder: PointPillars (Lang et al., CVPR 2019) on each agent's points.

**Pillarization** (:func:`pillarize`): a point at ``(x, y)`` of the agent's frame falls into the
pillar ``i = floor((x - xmin) / dx)``, ``j = floor((y - ymin) / dy)`` of the grid over its range
(layout of :mod:`.config`); points outside the range (any of ``x, y, z``) or padding rows are
dropped. **Pillar feature net** (:class:`PillarEncoder`): each point gets PointPillars' 9
features (``x, y, z``, intensity, the offsets from the mean of its pillar's points and the
offsets ``x, y`` from the pillar's centre), a linear layer, LayerNorm and ReLU, and a max over
the pillar's points gives the pillar's feature; empty pillars are zero (the pseudo-image
``(B, C, nx, ny)``). **Backbone** (:class:`BEVBackbone`): PointPillars' 2D CNN, two stages: 3x3
convolutions at the pillar resolution, then a stride-``bev_stride`` stage; the first stage,
pooled to the coarse grid, joins the second by a 1x1 convolution (the paper's multi-scale
concatenation, with downsampling instead of upsampling).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .config import POINT_FEATURES, V2XViTConfig


def pillarize(points: torch.Tensor, mask: torch.Tensor, pc_range: tuple[float, ...],
              size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """The pillar of each point.

    Args:
        points: ``(B, L, >= 3)`` points (``x, y, z`` first; metres, the grid's frame).
        mask: ``(B, L)`` bool, the valid rows. pc_range: the grid's range. size: ``(nx, ny)``.

    Returns:
        ``index (B, L)`` int64: ``i * ny + j`` of the point's pillar (0 where not kept), and
        ``keep (B, L)`` bool: a valid point inside the range.
    """
    nx, ny = size
    lo = torch.tensor(pc_range[:3], dtype=points.dtype, device=points.device)
    hi = torch.tensor(pc_range[3:], dtype=points.dtype, device=points.device)
    xyz = points[..., :3]
    cell = (hi[:2] - lo[:2]) / torch.tensor([nx, ny], dtype=points.dtype, device=points.device)
    ij = torch.floor((xyz[..., :2] - lo[:2]) / cell).long()
    keep = mask.bool() & ((xyz >= lo) & (xyz < hi)).all(-1)
    keep &= (ij[..., 0] >= 0) & (ij[..., 0] < nx) & (ij[..., 1] >= 0) & (ij[..., 1] < ny)
    index = torch.where(keep, ij[..., 0] * ny + ij[..., 1], torch.zeros_like(ij[..., 0]))
    return index, keep


class PillarEncoder(nn.Module):
    """Points ``(B, L, 4)`` (``x, y, z``, intensity) + mask -> pseudo-image ``(B, C, nx, ny)``
    (module docstring)."""

    def __init__(self, cfg: V2XViTConfig, branch: str) -> None:
        super().__init__()
        self.range = tuple(float(v) for v in cfg.pc_range(branch))
        self.size = tuple(cfg.pillar_size(branch))
        self.linear = nn.Linear(POINT_FEATURES + 5, cfg.pillar_channels)
        self.norm = nn.LayerNorm(cfg.pillar_channels)

    def forward(self, points: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        if points.dim() != 3 or points.shape[-1] < POINT_FEATURES:
            raise ValueError(f"PillarEncoder: points have shape {tuple(points.shape)}; expected "
                             f"(B, L, {POINT_FEATURES}) (x, y, z, intensity)")
        b, n = points.shape[:2]
        nx, ny = self.size
        pts = points[..., :POINT_FEATURES].float()
        index, keep = pillarize(pts, mask, self.range, self.size)
        flat = (torch.arange(b, device=pts.device)[:, None] * (nx * ny) + index)[keep]
        p = pts[keep]  # (K, 4)
        count = pts.new_zeros(b * nx * ny).index_add_(0, flat, torch.ones_like(p[:, 0]))
        mean = pts.new_zeros(b * nx * ny, 3).index_add_(0, flat, p[:, :3])
        mean = mean / count.clamp_min(1.0)[:, None]
        lo = torch.tensor(self.range[:2], device=pts.device)
        cell = (torch.tensor(self.range[3:5], device=pts.device) - lo) / torch.tensor(
            [nx, ny], device=pts.device, dtype=torch.float32)
        ij = torch.stack([flat % (nx * ny) // ny, flat % ny], -1).float()
        centre = lo + (ij + 0.5) * cell
        feats = torch.cat([p, p[:, :3] - mean[flat], p[:, :2] - centre], -1)  # (K, 9)
        h = F.relu(self.norm(self.linear(feats)))
        out = h.new_zeros(b * nx * ny, h.shape[-1])
        out = out.scatter_reduce(0, flat[:, None].expand_as(h), h, "amax", include_self=True)
        return out.view(b, nx, ny, -1).permute(0, 3, 1, 2).contiguous()


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False),
                         nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class BEVBackbone(nn.Module):
    """Pseudo-image ``(B, pillar_channels, nx, ny)`` -> BEV features ``(B, width, nx / s,
    ny / s)`` (module docstring)."""

    def __init__(self, cfg: V2XViTConfig) -> None:
        super().__init__()
        c1, w, s = max(cfg.width // 2, cfg.pillar_channels), cfg.width, cfg.bev_stride
        self.stage1 = nn.Sequential(_conv(cfg.pillar_channels, c1), _conv(c1, c1))
        self.stage2 = nn.Sequential(_conv(c1, w, stride=s), _conv(w, w), _conv(w, w))
        self.pool = nn.AvgPool2d(s) if s > 1 else nn.Identity()
        self.join = nn.Conv2d(c1 + w, w, 1)

    def forward(self, pseudo: torch.Tensor) -> torch.Tensor:
        a = self.stage1(pseudo)
        b = self.stage2(a)
        return self.join(torch.cat([self.pool(a), b], 1))


class LidarBEV(nn.Module):
    """One agent's points -> BEV features in its frame (pillar encoder + backbone)."""

    def __init__(self, cfg: V2XViTConfig, branch: str) -> None:
        super().__init__()
        self.pillars = PillarEncoder(cfg, branch)
        self.backbone = BEVBackbone(cfg)

    def forward(self, points: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.backbone(self.pillars(points, mask))


__all__ = ["BEVBackbone", "LidarBEV", "PillarEncoder", "pillarize"]
