"""CoDriving's training and evaluation samples: V2X-ViT's LiDAR samples
(:class:`~..v2x_vit.data.V2XViTFrames`: both agents' LiDAR, ``has_rsu``, ``age``,
``rsu_to_ego``, the ``gt/fused`` targets, the planning keys) plus the ego's route ahead, from
which the request is built (:mod:`.request`):

==============  ==========================================================================
key             content
==============  ==========================================================================
``route``       (R, 2) the observation's route rows (ego frame, m; ``R`` =
                ``request_route_points``, the rows ``request_route_step`` m apart)
==============  ==========================================================================

Message ages are drawn from ``msg_latency_ticks .. train_max_delay`` ticks in training (the
unit's LiDAR of that many ticks earlier; at the default both are 1), ``msg_latency_ticks`` in
evaluation, none before the unit's first message arrives, as V2X-ViT's.
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..v2x_vit.data import V2XViTFrames
from .config import CoDrivingConfig


class CoDrivingFrames(V2XViTFrames):
    """V2X-ViT's samples with the route rows (module docstring; same arguments and errors).

    Raises:
        ValueError: the data set's route has fewer rows than ``request_route_points``.
    """

    def __init__(self, root: str | Path, split: str, cfg: CoDrivingConfig, stride: int = 1,
                 delay: int | None = 0) -> None:
        super().__init__(root, split, cfg, stride=stride, delay=delay)
        rows = int(self.ds.shard(0)["route"].shape[1]) if len(self.ds.episodes) else 0
        if len(self.ds.episodes) and rows < cfg.request_route_points:
            raise ValueError(f"CoDrivingFrames: the data set {root} has {rows} route rows; "
                             f"request_route_points={cfg.request_route_points} needs as many")

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        out = super().__getitem__(index)
        e, t = self.ds.locate(int(self.frame_ids[index]))
        route = self.ds.shard(e)["route"][t][:self.cfg.request_route_points, :2]
        out["route"] = torch.as_tensor(route).float()
        return out


__all__ = ["CoDrivingFrames"]
