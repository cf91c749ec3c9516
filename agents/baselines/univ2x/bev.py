"""UniV2X's bird's-eye view: the camera BEV encoder (Lift-Splat), the BEV warp between agents and
box occupancy targets.

**Lift-Splat** (Philion and Fidler, ECCV 2020; the paper's BEVFormer encoder is replaced by it,
docs/baselines.md). AURORA's ViT (:class:`~v2xbench.agents.aurora.vit.ViTEncoder`, conv stem)
turns each camera image into one token per ``stride x stride`` pixels; a linear head gives per
token a distribution over ``D`` depth bins (softmax) and ``C`` context channels. *Lift*: the
outer product puts ``p_d * c`` at the ``D`` points along the token's pixel ray
(:func:`~v2xbench.agents.aurora.position.ray_points` with the cameras' ``intrinsics`` and
``cam_to_frame``, depths :func:`~v2xbench.agents.aurora.position.lid_depths`). *Splat*: every
point inside the agent's range is sum-pooled into its BEV cell (:func:`splat`; layout
``(B, C, nx, ny)``, config module docstring). A small conv net refines the BEV.

**Warp** (:func:`warp_bev`): a grid in one agent's frame resampled at the cell centres of
another's, given ``E`` (source frame -> target frame), bilinear, zero outside the source range;
the roadside occupancy reaches the ego grid this way (:mod:`.fusion`).

**Occupancy targets** (:func:`box_occupancy`): a cell is occupied when its centre lies in the
footprint of a box of :data:`~.config.OCC_CLASSES`, or holds the box's centre (small agents).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from v2xbench.agents.aurora.position import lid_depths, patch_centres, ray_points
from v2xbench.agents.aurora.vit import ViTEncoder

from .config import OCC_CLASSES, UniV2XConfig


def cell_centres(pc_range: tuple[float, ...], size: tuple[int, int]) -> torch.Tensor:
    """``(nx, ny, 2)`` metre ``x, y`` of the cell centres of a grid over ``pc_range``."""
    (x0, y0), (x1, y1) = pc_range[:2], pc_range[3:5]
    nx, ny = size
    xs = x0 + (torch.arange(nx, dtype=torch.float32) + 0.5) * (x1 - x0) / nx
    ys = y0 + (torch.arange(ny, dtype=torch.float32) + 0.5) * (y1 - y0) / ny
    return torch.stack(torch.meshgrid(xs, ys, indexing="ij"), -1)


def splat(features: torch.Tensor, points: torch.Tensor, pc_range: tuple[float, ...],
          size: tuple[int, int]) -> torch.Tensor:
    """Sum-pool lifted features into a BEV grid.

    Args:
        features: ``(B, P, C)`` features of ``P`` points.
        points: ``(B, P, 3)`` their positions (m) in the grid's frame.
        pc_range: ``(xmin, ymin, zmin, xmax, ymax, zmax)``; points outside are dropped.
        size: ``(nx, ny)`` cells.

    Returns:
        ``(B, C, nx, ny)``: cell ``(i, j)`` holds the sum of the features of the points in it.
    """
    b, p, c = features.shape
    nx, ny = size
    lo = torch.tensor(pc_range[:3], dtype=points.dtype, device=points.device)
    hi = torch.tensor(pc_range[3:], dtype=points.dtype, device=points.device)
    cell = (hi[:2] - lo[:2]) / torch.tensor([nx, ny], dtype=points.dtype, device=points.device)
    ij = torch.floor((points[..., :2] - lo[:2]) / cell).long()  # (B, P, 2)
    inside = ((points >= lo) & (points < hi)).all(-1)
    inside &= (ij[..., 0] >= 0) & (ij[..., 0] < nx) & (ij[..., 1] >= 0) & (ij[..., 1] < ny)
    flat = torch.arange(b, device=points.device)[:, None] * (nx * ny) + ij[..., 0] * ny + ij[..., 1]
    out = features.new_zeros(b * nx * ny, c)
    out.index_add_(0, flat[inside], features[inside])
    return out.view(b, nx, ny, c).permute(0, 3, 1, 2)


class LiftSplatEncoder(nn.Module):
    """Cameras of one agent -> BEV features ``(B, width, nx, ny)`` (module docstring).

    Args:
        cfg: the configuration. branch: ``"ego"`` (6 cameras) or ``"rsu"`` (1 camera).
    """

    def __init__(self, cfg: UniV2XConfig, branch: str) -> None:
        super().__init__()
        self.cfg, self.branch = cfg, branch
        self.range = tuple(float(v) for v in cfg.pc_range(branch))
        self.size = tuple(cfg.bev_size(branch))
        cams = 6 if branch == "ego" else 1
        self.vit = ViTEncoder(cfg.image_size_of(branch), cfg.stride, cfg.vit_width,
                              cfg.vit_depth, cfg.vit_heads, cfg.mlp_ratio, cams, cfg.dropout,
                              stem="conv")
        self.depth_bins, self.channels = cfg.depth_bins, cfg.bev_channels
        self.head = nn.Linear(cfg.vit_width, cfg.depth_bins + cfg.bev_channels)
        self.register_buffer("pixels", patch_centres(cfg.image_size_of(branch), cfg.stride),
                             persistent=False)
        self.register_buffer("depths", lid_depths(cfg.depth_bins, cfg.depth_near,
                                                  cfg.depth_far(branch)), persistent=False)
        c, w = cfg.bev_channels, cfg.width
        self.bev_net = nn.Sequential(
            nn.Conv2d(c, w, 3, padding=1), nn.BatchNorm2d(w), nn.ReLU(inplace=True),
            nn.Conv2d(w, w, 3, padding=1), nn.BatchNorm2d(w), nn.ReLU(inplace=True))

    def lift_splat(self, depth: torch.Tensor, context: torch.Tensor, intrinsics: torch.Tensor,
                   cam_to_frame: torch.Tensor) -> torch.Tensor:
        """Lift per-token depth distributions ``(B, N, T, D)`` and context ``(B, N, T, C)`` along
        the pixel rays and splat them: ``(B, C, nx, ny)`` (:func:`splat`)."""
        pts = ray_points(intrinsics.float(), cam_to_frame.float(), self.pixels, self.depths)
        feats = depth[..., :, None] * context[..., None, :]  # (B, N, T, D, C)
        b = depth.shape[0]
        return splat(feats.reshape(b, -1, feats.shape[-1]), pts.reshape(b, -1, 3), self.range,
                     self.size)

    def forward(self, images: torch.Tensor, intrinsics: torch.Tensor,
                cam_to_frame: torch.Tensor) -> dict[str, torch.Tensor]:
        """``images`` ``(B, N, 3, H, W)`` in [0, 1] with their calibration -> ``bev`` ``(B, width,
        nx, ny)`` and ``depth`` ``(B, N, T, D)`` (the depth distributions)."""
        tokens = self.head(self.vit(images))  # (B, N, T, D + C)
        depth = tokens[..., :self.depth_bins].softmax(-1)
        context = tokens[..., self.depth_bins:]
        raw = self.lift_splat(depth, context, intrinsics, cam_to_frame)
        return {"bev": self.bev_net(raw), "depth": depth}


def warp_bev(grid: torch.Tensor, e_src_to_dst: torch.Tensor, src_range: tuple[float, ...],
             dst_range: tuple[float, ...], dst_size: tuple[int, int]) -> torch.Tensor:
    """Resample a source-frame grid at the cell centres of a destination grid.

    Args:
        grid: ``(B, C, nx, ny)`` over ``src_range`` (source frame).
        e_src_to_dst: ``(B, 4, 4)`` source frame -> destination frame (e.g. ``E_{r->e}``).
        src_range, dst_range: the grids' ranges; dst_size: ``(nx, ny)`` of the destination.

    Returns:
        ``(B, C + 1, nx', ny')``: the resampled channels (bilinear, zero outside the source
        range) and a last channel, 1 where the destination cell centre lies in the source range.
    """
    b = grid.shape[0]
    centres = cell_centres(dst_range, dst_size).to(grid.device)  # (nx', ny', 2)
    inv = torch.linalg.inv(e_src_to_dst.float())  # destination -> source
    src = torch.einsum("pk,bjk->bpj", centres.reshape(-1, 2), inv[:, :2, :2]) \
        + inv[:, None, :2, 3]  # (B, P, 2), ground points (z = 0)
    lo = torch.tensor(src_range[:2], device=grid.device)
    span = torch.tensor(src_range[3:5], device=grid.device) - lo
    norm = 2.0 * (src - lo) / span - 1.0  # (B, P, 2): x -> grid dim 2 (H), y -> dim 3 (W)
    sample_at = norm.flip(-1).view(b, *dst_size, 2)  # grid_sample: [..., 0] indexes W (= y)
    out = F.grid_sample(grid.float(), sample_at, mode="bilinear", padding_mode="zeros",
                        align_corners=False)
    valid = (norm.abs() <= 1.0).all(-1).view(b, 1, *dst_size).to(out.dtype)
    return torch.cat([out, valid], 1)


def box_occupancy(boxes: torch.Tensor, labels: torch.Tensor, mask: torch.Tensor,
                  pc_range: tuple[float, ...], size: tuple[int, int]) -> torch.Tensor:
    """``(B, nx, ny)`` float occupancy of boxes ``(B, M, 10)`` (AURORA's target layout: ``x, y,
    z, l, w, h, sin, cos, vx, vy``), labels ``(B, M)``, valid ``mask`` ``(B, M)`` (module
    docstring; classes :data:`~.config.OCC_CLASSES`)."""
    centres = cell_centres(pc_range, size).to(boxes.device).view(1, 1, -1, 2)  # (1, 1, P, 2)
    keep = mask.bool() & torch.isin(labels, torch.tensor(OCC_CLASSES, device=labels.device))
    d = centres - boxes[..., None, :2]  # (B, M, P, 2)
    s, c = boxes[..., 6:7], boxes[..., 7:8]
    yaw_norm = torch.sqrt(s * s + c * c).clamp_min(1e-6)
    s, c = s / yaw_norm, c / yaw_norm
    lx = d[..., 0] * c + d[..., 1] * s  # the box's own axes
    ly = -d[..., 0] * s + d[..., 1] * c
    inside = (lx.abs() <= boxes[..., 3:4] / 2) & (ly.abs() <= boxes[..., 4:5] / 2)
    nx, ny = size
    lo = torch.tensor(pc_range[:2], device=boxes.device)
    cell = (torch.tensor(pc_range[3:5], device=boxes.device) - lo) / torch.tensor(
        [nx, ny], device=boxes.device)
    ij = torch.floor((boxes[..., :2] - lo) / cell).long()  # (B, M, 2)
    own = ij[..., 0:1] * ny + ij[..., 1:2] == torch.arange(nx * ny, device=boxes.device)
    occ = ((inside | own) & keep[..., None]).any(1)
    return occ.view(-1, nx, ny).float()


__all__ = ["LiftSplatEncoder", "box_occupancy", "cell_centres", "splat", "warp_bev"]
