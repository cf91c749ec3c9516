"""The V2X-ViT network: its roadside half (:class:`RoadsideNet`), its ego half (:class:`EgoNet`)
and both together for training (:class:`V2XViT`).

- **Roadside half** (the ``"rsu"`` agent's policy): PointPillars on the unit's LiDAR in its
  ground frame (:class:`~.pillars.LidarBEV`) -> BEV features -> the learned 1x1 bottleneck
  (``compress_channels``; identity when 0): the map it sends (:mod:`.message`).
- **Ego half**: PointPillars on the ego LiDAR (ego frame); the received map through the 1x1
  decompressor, warped into the ego grid by ``E_{r->e}`` (:func:`~.fusion.warp_to_ego`); the
  V2X-ViT encoder with the message's age (:class:`~.fusion.V2XViTEncoder`); the centre head
  (:class:`~.head.CenterHead`) and the waypoint head (:class:`~.head.WaypointHead`).
- **Training** (:class:`V2XViT`): end to end; the roadside half runs on the batch's rows with an
  active unit, its map rounded to float16 as the channel delivers it (AURORA's
  :func:`~v2xbench.agents.aurora.rsu_agent.to_wire`; the cast passes gradients); the other rows
  get the empty map (zeros, uncovered).
"""

from __future__ import annotations

import torch
from torch import nn
from v2xbench.agents.aurora.route_input import PATH_KEY
from v2xbench.agents.aurora.rsu_agent import to_wire

from ..common.model import parameter_counts
from .config import V2XViTConfig
from .fusion import V2XViTEncoder, warp_to_ego
from .head import CenterHead, WaypointHead
from .message import empty_features
from .pillars import LidarBEV


class RoadsideNet(nn.Module):
    """The roadside half (module docstring): ``points (B, L, 4)``, ``point_mask (B, L)`` in the
    unit's ground frame -> the sent map ``(B, sent_channels, nx, ny)``."""

    branch = "rsu"

    def __init__(self, cfg: V2XViTConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = LidarBEV(cfg, "rsu")
        self.compress = (nn.Conv2d(cfg.width, cfg.compress_channels, 1)
                         if cfg.compress_channels else nn.Identity())

    def forward(self, points: torch.Tensor, point_mask: torch.Tensor) -> torch.Tensor:
        return self.compress(self.encoder(points, point_mask))


class EgoNet(nn.Module):
    """The ego half (module docstring)."""

    def __init__(self, cfg: V2XViTConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = LidarBEV(cfg, "ego")
        self.decompress = (nn.Conv2d(cfg.compress_channels, cfg.width, 1)
                           if cfg.compress_channels else nn.Identity())
        self.fusion = V2XViTEncoder(cfg)
        self.head = CenterHead(cfg)
        self.planner = WaypointHead(cfg)

    def forward(self, batch: dict[str, torch.Tensor], received: torch.Tensor,
                e_rsu_to_ego: torch.Tensor, has_rsu: torch.Tensor, age: torch.Tensor
                ) -> dict[str, torch.Tensor]:
        """Ego inputs (``ego/points``, ``ego/point_mask``, ``command``, ``ego_speed``,
        ``route_points``), the received map ``(B, C', nx', ny')`` (zeros for rows without
        one), ``E_{r->e}`` ``(B, 4, 4)``, ``has_rsu`` ``(B,)`` and the message's ``age`` ``(B,)``
        (ticks) -> the head's outputs (``heat_logits``, ``reg``, ``det_logits``, ``det_boxes``),
        ``waypoints`` ``(B, T, 2)`` and ``covered`` ``(B, nx, ny)``."""
        ego = self.encoder(batch["ego/points"], batch["ego/point_mask"])
        rsu, covered = warp_to_ego(self.decompress(received), e_rsu_to_ego, has_rsu, self.cfg)
        fused = self.fusion(ego, rsu, covered, age)
        out = self.head(fused)
        out["waypoints"] = self.planner(fused, batch["command"], batch["ego_speed"],
                                        batch["route_points"], batch.get(PATH_KEY))
        out["covered"] = covered
        return out


class V2XViT(nn.Module):
    """Both halves, trained end to end (module docstring)."""

    def __init__(self, cfg: V2XViTConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.rsu = RoadsideNet(cfg)
        self.ego = EgoNet(cfg)

    def message(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """The batch's received maps as the channel delivers them (zeros without a unit)."""
        has = batch["has_rsu"].bool()
        sent = empty_features(self.cfg, has.shape[0], has.device)
        rows = has.nonzero().squeeze(1)
        if len(rows):
            out = self.rsu(batch["rsu/points"][rows], batch["rsu/point_mask"][rows])
            wire = to_wire({"features": out})["features"]
            sent = sent.index_put((rows,), wire.to(sent.dtype))
        return sent

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Training / evaluation pass over a batch of :class:`~.data.V2XViTFrames`."""
        return self.ego(batch, self.message(batch), batch["rsu_to_ego"], batch["has_rsu"],
                        batch["age"])


__all__ = ["EgoNet", "RoadsideNet", "V2XViT", "parameter_counts"]
