"""V2X-ViT's heads on the fused ego map: a centre-heatmap detection head and a waypoint head.

**Detection** (:class:`CenterHead`; the paper's PointPillars anchor head replaced by a
CenterPoint-style head, docs/baselines.md): per feature cell a heatmap logit per class and a
10-value regression ``ox, oy`` (the box centre's offset from the cell centre, in cells), ``z``,
``log l, log w, log h``, ``sin, cos`` of yaw, ``vx, vy``. :func:`decode_boxes` turns the
regression into AURORA's box layout ``x, y, z, l, w, h, sin, cos, vx, vy`` (metres, ego frame);
:meth:`CenterHead.forward` keeps a cell's class logits only where the cell is a 3x3 local
maximum of that class's heatmap (max-pool NMS) and sets them to -1e4 elsewhere, so the top-k of
AURORA's decoding (:func:`~v2xbench.agents.aurora.eval_perception.decode_detections`) picks
peaks. **Targets** (:func:`heatmap_targets`): a Gaussian per box (``sigma`` = ``hypot(l, w) /
4`` cells, at least ``min_sigma``) centred on the centre of the cell holding the box's centre
(that cell is exactly 1), the maximum over the boxes of each class.

**Waypoints** (:class:`WaypointHead`; V2X-ViT is perception only): two stride-2 convolutions
over the fused map, pooled to 4 x 4, with the command embedding, the speed and AURORA's route
points ahead, an MLP -> ``plan_waypoints`` steps, summed into waypoints (ego frame, 0.5 s apart)
for AURORA's waypoint controller.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from v2xbench.agents.aurora.det_decoder import focal_bias

from ..common.plan_frame import planner_speed, steps_to_waypoints
from ..univ2x.bev import cell_centres
from .config import V2XViTConfig


def _cell(cfg: V2XViTConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """``(lo (2,), cell size (2,))`` of the ego feature grid (metres)."""
    r, (nx, ny) = cfg.ego_range, cfg.feature_size("ego")
    lo = torch.tensor(r[:2], dtype=torch.float32)
    return lo, (torch.tensor(r[3:5], dtype=torch.float32) - lo) / torch.tensor([nx, ny]).float()


def box_cells(boxes: torch.Tensor, mask: torch.Tensor, cfg: V2XViTConfig
              ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(index (B, M), inside (B, M))``: the feature cell ``i * ny + j`` of each box centre and
    whether it is a valid box inside the grid."""
    lo, cell = (t.to(boxes.device) for t in _cell(cfg))
    nx, ny = cfg.feature_size("ego")
    ij = torch.floor((boxes[..., :2] - lo) / cell).long()
    inside = mask.bool() & (ij[..., 0] >= 0) & (ij[..., 0] < nx) & (ij[..., 1] >= 0) \
        & (ij[..., 1] < ny)
    return torch.where(inside, ij[..., 0] * ny + ij[..., 1], torch.zeros_like(ij[..., 0])), inside


def encode_boxes(boxes: torch.Tensor, index: torch.Tensor, cfg: V2XViTConfig) -> torch.Tensor:
    """Regression targets ``(B, M, 10)`` of boxes ``(B, M, 10)`` at their cells ``index``."""
    lo, cell = (t.to(boxes.device) for t in _cell(cfg))
    ny = cfg.feature_size("ego")[1]
    ij = torch.stack([index // ny, index % ny], -1).float()
    off = (boxes[..., :2] - (lo + (ij + 0.5) * cell)) / cell
    size = boxes[..., 3:6].abs().clamp_min(1e-2).log()
    return torch.cat([off, boxes[..., 2:3], size, boxes[..., 6:10]], -1)


def decode_boxes(reg: torch.Tensor, cfg: V2XViTConfig) -> torch.Tensor:
    """Regression maps ``(B, 10, nx, ny)`` -> boxes ``(B, nx * ny, 10)`` (AURORA's layout)."""
    lo, cell = (t.to(reg.device) for t in _cell(cfg))
    centres = cell_centres(cfg.ego_range, cfg.feature_size("ego")).to(reg.device).view(-1, 2)
    r = reg.flatten(2).transpose(1, 2)  # (B, P, 10)
    xy = centres + r[..., :2] * cell
    size = r[..., 3:6].clamp(-5.0, 5.0).exp()
    return torch.cat([xy, r[..., 2:3], size, r[..., 6:10]], -1)


def heatmap_targets(boxes: torch.Tensor, labels: torch.Tensor, mask: torch.Tensor,
                    cfg: V2XViTConfig) -> torch.Tensor:
    """``(B, K, nx, ny)`` class heatmaps of boxes ``(B, M, 10)`` (module docstring)."""
    nx, ny = cfg.feature_size("ego")
    lo, cell = (t.to(boxes.device) for t in _cell(cfg))
    index, inside = box_cells(boxes, mask, cfg)
    ij = torch.stack([index // ny, index % ny], -1).float()  # (B, M, 2)
    grid = torch.stack(torch.meshgrid(torch.arange(nx), torch.arange(ny), indexing="ij"),
                       -1).view(-1, 2).float().to(boxes.device)  # (P, 2)
    d2 = ((grid[None, None] - ij[:, :, None]) ** 2).sum(-1)  # (B, M, P) in cells^2
    extent = torch.hypot(boxes[..., 3], boxes[..., 4]) / (4.0 * cell.mean())
    sigma = extent.clamp_min(cfg.min_sigma)[..., None]
    g = torch.exp(-d2 / (2 * sigma ** 2)) * inside[..., None]
    onehot = F.one_hot(labels.clamp(0, cfg.num_classes - 1), cfg.num_classes).to(g.dtype)
    heat = (g[:, :, None, :] * onehot[..., None]).amax(1)  # (B, K, P)
    return heat.view(boxes.shape[0], cfg.num_classes, nx, ny)


class CenterHead(nn.Module):
    """Fused map ``(B, C, nx, ny)`` -> ``heat_logits (B, K, nx, ny)``, ``reg (B, 10, nx, ny)``,
    and the decoded ``det_logits (1, B, P, K)`` (non-peaks -1e4), ``det_boxes (1, B, P, 10)``
    (module docstring)."""

    def __init__(self, cfg: V2XViTConfig) -> None:
        super().__init__()
        self.cfg = cfg
        w = cfg.width
        self.shared = nn.Sequential(nn.Conv2d(w, w, 3, padding=1), nn.ReLU(inplace=True))
        self.heat = nn.Conv2d(w, cfg.num_classes, 1)
        self.reg = nn.Conv2d(w, 10, 1)
        nn.init.constant_(self.heat.bias, focal_bias())  # cells start at p = 0.01

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        h = self.shared(x)
        heat, reg = self.heat(h), self.reg(h)
        peak = F.max_pool2d(heat, 3, stride=1, padding=1) == heat
        logits = torch.where(peak, heat, torch.full_like(heat, -1e4))
        return {"heat_logits": heat, "reg": reg,
                "det_logits": logits.flatten(2).transpose(1, 2)[None],
                "det_boxes": decode_boxes(reg, self.cfg)[None]}


class WaypointHead(nn.Module):
    """Fused map, ``command (B,)``, ``ego_speed (B,)``, ``route_points (B, R, 2)`` ->
    waypoints ``(B, T, 2)`` (module docstring)."""

    def __init__(self, cfg: V2XViTConfig) -> None:
        super().__init__()
        self.cfg = cfg
        w, hdim = cfg.width, cfg.plan_hidden
        self.conv = nn.Sequential(nn.Conv2d(w, w, 3, stride=2, padding=1), nn.ReLU(inplace=True),
                                  nn.Conv2d(w, w, 3, stride=2, padding=1), nn.ReLU(inplace=True),
                                  nn.AdaptiveAvgPool2d(4))
        self.bev = nn.Linear(16 * w, hdim)
        self.command = nn.Embedding(cfg.num_commands, hdim)
        self.mlp = nn.Sequential(nn.Linear(2 * hdim + 1 + 2 * cfg.plan_route_points, hdim),
                                 nn.ReLU(inplace=True), nn.Linear(hdim, hdim),
                                 nn.ReLU(inplace=True), nn.Linear(hdim, 2 * cfg.plan_waypoints))

    def forward(self, bev: torch.Tensor, command: torch.Tensor, speed: torch.Tensor,
                route: torch.Tensor, path: torch.Tensor | None = None) -> torch.Tensor:
        b = bev.shape[0]
        speed = planner_speed(speed, self.cfg)  # 0 m/s with plan_ego_speed off
        feats = [F.relu(self.bev(self.conv(bev).flatten(1))),
                 self.command(command.long().clamp(0, self.cfg.num_commands - 1)),
                 speed.float().view(b, 1) / 10.0, route.float().reshape(b, -1) / 20.0]
        steps = self.mlp(torch.cat(feats, -1)).view(b, self.cfg.plan_waypoints, 2)
        return steps_to_waypoints(steps, self.cfg, path, "WaypointHead")


__all__ = ["CenterHead", "WaypointHead", "box_cells", "decode_boxes", "encode_boxes",
           "heatmap_targets"]
