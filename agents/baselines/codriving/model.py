"""The CoDriving network: its roadside half (:class:`RoadsideNet`), its ego half
(:class:`EgoNet`) and both together for training (:class:`CoDriving`).

- **Roadside half** (the ``"rsu"`` agent's policy): V2X-ViT's PointPillars encoder on the unit's
  LiDAR in its ground frame (:class:`~..v2x_vit.pillars.LidarBEV`) -> BEV features; a
  confidence head (per cell a logit per class; the confidence is the largest class
  probability) and a 1x1 bottleneck to ``sent_channels()``; given the ego's request
  (:func:`~.request.request_map`) it chooses the cells to send (:func:`~.request.select_cells`).
- **Ego half**: the same encoder on the ego LiDAR (ego frame); the received cells through the 1x1
  decompressor, scattered into the ego grid by ``E_{r->e}`` (:func:`~.fusion.scatter_to_ego`),
  max fusion (:class:`~.fusion.MaxFusion`); V2X-ViT's centre head and waypoint head
  (:mod:`..v2x_vit.head`).
- **Training** (:class:`CoDriving`): end to end; the request comes from the sample's route rows
  and ``E_{r->e}``, the roadside half runs on the rows with an active unit, the chosen cells'
  features rounded to float16 as the channel delivers them (AURORA's
  :func:`~v2xbench.agents.aurora.rsu_agent.to_wire`); gradients reach the sent features, the
  choice itself is not differentiated (the confidence head learns from its own detection loss,
  :mod:`.losses`). In evaluation the model counts the cells it sent (:attr:`CoDriving.stats`).
"""

from __future__ import annotations

import torch
from torch import nn
from v2xbench.agents.aurora.det_decoder import focal_bias
from v2xbench.agents.aurora.route_input import PATH_KEY
from v2xbench.agents.aurora.rsu_agent import to_wire

from ..common.model import parameter_counts
from ..v2x_vit.head import CenterHead, WaypointHead
from ..v2x_vit.pillars import LidarBEV
from .config import CoDrivingConfig
from .fusion import MaxFusion, scatter_to_ego
from .request import request_map, select_cells


class RoadsideNet(nn.Module):
    """The roadside half (module docstring)."""

    branch = "rsu"

    def __init__(self, cfg: CoDrivingConfig) -> None:
        super().__init__()
        self.cfg = cfg
        w = cfg.width
        self.encoder = LidarBEV(cfg, "rsu")
        self.confidence = nn.Sequential(nn.Conv2d(w, w, 3, padding=1), nn.ReLU(inplace=True),
                                        nn.Conv2d(w, cfg.num_classes, 1))
        nn.init.constant_(self.confidence[-1].bias, focal_bias())
        self.compress = (nn.Conv2d(w, cfg.compress_channels, 1) if cfg.compress_channels
                         else nn.Identity())

    def forward(self, points: torch.Tensor, point_mask: torch.Tensor, request: torch.Tensor
                ) -> dict[str, torch.Tensor]:
        """Points ``(B, L, 4)`` and their mask in the unit's ground frame, the request ``(B, nx,
        ny)`` on its feature grid -> ``features (B, C, nx, ny)`` (every cell, before the
        choice), ``conf_logits (B, K, nx, ny)``, ``score (B, nx, ny)`` (confidence x request)
        and ``sent (B, nx, ny)`` bool (the chosen cells)."""
        bev = self.encoder(points, point_mask)
        logits = self.confidence(bev)
        score = logits.detach().sigmoid().amax(1) * request
        return {"features": self.compress(bev), "conf_logits": logits, "score": score,
                "sent": select_cells(score, self.cfg)}


class EgoNet(nn.Module):
    """The ego half (module docstring)."""

    def __init__(self, cfg: CoDrivingConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = LidarBEV(cfg, "ego")
        self.decompress = (nn.Conv2d(cfg.compress_channels, cfg.width, 1)
                           if cfg.compress_channels else nn.Identity())
        self.fusion = MaxFusion(cfg.width)
        self.head = CenterHead(cfg)
        self.planner = WaypointHead(cfg)

    def forward(self, batch: dict[str, torch.Tensor], received: torch.Tensor, sent: torch.Tensor,
                e_rsu_to_ego: torch.Tensor) -> dict[str, torch.Tensor]:
        """Ego inputs (``ego/points``, ``ego/point_mask``, ``command``, ``ego_speed``,
        ``route_points``), the received cells on the unit's grid ``(B, C', nx', ny')`` with
        ``sent`` ``(B, nx', ny')`` (none for rows without a message) and ``E_{r->e}``
        ``(B, 4, 4)`` -> the head's outputs (``heat_logits``, ``reg``, ``det_logits``,
        ``det_boxes``), ``waypoints`` ``(B, T, 2)`` and ``covered`` ``(B, nx, ny)``."""
        ego = self.encoder(batch["ego/points"], batch["ego/point_mask"])
        rsu, covered = scatter_to_ego(self.decompress(received), sent, e_rsu_to_ego, self.cfg)
        fused = self.fusion(ego, rsu, covered)
        out = self.head(fused)
        out["waypoints"] = self.planner(fused, batch["command"], batch["ego_speed"],
                                        batch["route_points"], batch.get(PATH_KEY))
        out["covered"] = covered
        return out


class CoDriving(nn.Module):
    """Both halves, trained end to end (module docstring)."""

    def __init__(self, cfg: CoDrivingConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.rsu = RoadsideNet(cfg)
        self.ego = EgoNet(cfg)
        #: In evaluation: messages (rows with a unit) and cells sent so far.
        self.stats = {"messages": 0, "cells": 0}

    def message(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The batch's messages as the channel delivers them: ``received`` (zeros without a
        unit), ``sent``, the request and the unit's ``conf_logits`` (zeros without a unit)."""
        cfg = self.cfg
        has = batch["has_rsu"].bool()
        b, dev = has.shape[0], has.device
        nx, ny = cfg.feature_size("rsu")
        request = request_map(batch["route"], batch["rsu_to_ego"], cfg) * has[:, None, None]
        out = {"received": torch.zeros(b, cfg.sent_channels(), nx, ny, device=dev),
               "sent": torch.zeros(b, nx, ny, dtype=torch.bool, device=dev),
               "conf_logits": torch.zeros(b, cfg.num_classes, nx, ny, device=dev),
               "request": request}
        rows = has.nonzero().squeeze(1)
        if len(rows):
            r = self.rsu(batch["rsu/points"][rows], batch["rsu/point_mask"][rows],
                         request[rows])
            wire = to_wire({"features": r["features"]})["features"]
            wire = wire * r["sent"][:, None].to(wire.dtype)
            out["received"] = out["received"].index_put((rows,), wire)
            out["sent"] = out["sent"].index_put((rows,), r["sent"])
            out["conf_logits"] = out["conf_logits"].index_put((rows,), r["conf_logits"])
        return out

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Training / evaluation pass over a batch of :class:`~.data.CoDrivingFrames`."""
        msg = self.message(batch)
        out = self.ego(batch, msg["received"], msg["sent"], batch["rsu_to_ego"])
        out["rsu_conf_logits"], out["sent"] = msg["conf_logits"], msg["sent"]
        if not self.training:
            self.stats["messages"] += int(batch["has_rsu"].sum())
            self.stats["cells"] += int(msg["sent"].sum())
        return out


__all__ = ["CoDriving", "EgoNet", "RoadsideNet", "parameter_counts"]
