"""CoDriving's fusion at the ego: the received sparse cells scattered into the ego grid by
``E_{r->e}``, then max fusion.

- **Scatter** (:func:`scatter_to_ego`): each sent roadside cell's centre (the unit's ground
  frame) is moved into the ego frame by ``E_{r->e}``; its features land in the ego feature cell
  holding that point (the maximum where several land in one cell). Ego cells that received
  nothing are not covered. Only sent cells travel: this is the sparse counterpart of V2X-ViT's
  dense resampling (:func:`~..v2x_vit.fusion.warp_to_ego`).
- **Max fusion** (:class:`MaxFusion`, Where2comm's and CoDriving's perception fusion): per cell
  and channel the maximum of the ego's and the received (decompressed) features where the cell
  is covered, the ego's elsewhere, then a residual 3x3 convolution block.
"""

from __future__ import annotations

import torch
from torch import nn

from ..univ2x.bev import cell_centres
from .config import CoDrivingConfig


def scatter_to_ego(features: torch.Tensor, sent: torch.Tensor, e_rsu_to_ego: torch.Tensor,
                   cfg: CoDrivingConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """``(map (B, C, nx, ny), covered (B, nx, ny) bool)`` on the ego feature grid.

    Args:
        features: ``(B, C, nx', ny')`` roadside features on its grid.
        sent: ``(B, nx', ny')`` bool, the cells sent (rows without a unit: none).
        e_rsu_to_ego: ``(B, 4, 4)`` ``E_{r->e}``. cfg: the grids.
    """
    b, c = features.shape[:2]
    nx, ny = cfg.feature_size("ego")
    centres = cell_centres(cfg.rsu_range, cfg.feature_size("rsu")).to(features.device)
    centres = centres.view(1, -1, 2)  # (1, P', 2)
    e = e_rsu_to_ego.float()
    p = centres @ e[:, :2, :2].transpose(1, 2) + e[:, None, :2, 3]  # (B, P', 2) ego frame
    r = cfg.ego_range
    lo = torch.tensor(r[:2], device=p.device)
    size = (torch.tensor(r[3:5], device=p.device) - lo) / torch.tensor([nx, ny], device=p.device)
    ij = torch.floor((p - lo) / size).long()
    ok = sent.reshape(b, -1).bool() & (ij[..., 0] >= 0) & (ij[..., 0] < nx) \
        & (ij[..., 1] >= 0) & (ij[..., 1] < ny)
    target = (torch.arange(b, device=p.device)[:, None] * (nx * ny) + ij[..., 0] * ny
              + ij[..., 1])[ok]
    src = features.permute(0, 2, 3, 1).reshape(b, -1, c)[ok]  # (N, C)
    out = features.new_zeros(b * nx * ny, c)
    if len(target):
        out = out.scatter_reduce(0, target[:, None].expand(-1, c), src, "amax",
                                 include_self=False)
    covered = torch.zeros(b * nx * ny, dtype=torch.bool, device=p.device)
    covered[target] = True
    return (out.view(b, nx, ny, c).permute(0, 3, 1, 2).contiguous(),
            covered.view(b, nx, ny))


class MaxFusion(nn.Module):
    """Ego map ``(B, C, H, W)``, received map in the ego grid and its coverage ``(B, H, W)`` ->
    the fused map (module docstring)."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.refine = nn.Sequential(nn.Conv2d(width, width, 3, padding=1, bias=False),
                                    nn.BatchNorm2d(width), nn.ReLU(inplace=True),
                                    nn.Conv2d(width, width, 3, padding=1))

    def forward(self, ego: torch.Tensor, rsu: torch.Tensor, covered: torch.Tensor
                ) -> torch.Tensor:
        fused = torch.where(covered[:, None], torch.maximum(ego, rsu), ego)
        return fused + self.refine(fused)


__all__ = ["MaxFusion", "scatter_to_ego"]
