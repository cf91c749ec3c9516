"""UniV2X's training and evaluation samples: one frame of a collected data set, both agents.

Built from AURORA's samples (:class:`~v2xbench.agents.aurora.data.AuroraFrames`: images resized
to the model's size, intrinsics and ``cam_to_frame`` from the recorded calibration, targets cut
to each agent's range) plus the frame's planning data. Keys (shapes without the leading ``B``):

=====================================  ===================================================
key                                    content
=====================================  ===================================================
``ego/images``, ``ego/intrinsics``,    the ego's six cameras and ``gt/ego`` targets (ego
``ego/cam_to_frame``, ``ego/det_*``    frame, ego range)
``rsu/images``, ..., ``rsu/det_*``     the active unit's camera and ``gt/rsu`` in its ground
                                       frame (zeros, identity calibration without a unit)
``has_rsu``                            () bool: a unit serves the ego in this frame
``rsu_to_ego``                         (4, 4) ``E_{r->e}`` (AURORA's ``cqaf.rsu_to_ego``;
                                       identity without a unit)
``det_boxes``, ``det_labels``,         ``gt/fused`` in the ego frame, cut to the ego range
``det_mask``                           (the fused detection and occupancy targets)
``command``, ``ego_speed``             () navigation command, speed (m/s)
``route_points``                       (R, 2) the route points ahead (AURORA's planner input)
``expert_waypoints``                   (8, 2) the expert's future positions, 0.5 s apart
``frame_id``                           () global frame index
=====================================  ===================================================

Frames: every ``stride``-th frame of each episode of the split. The roadside half's inputs and
targets (``rsu/*``, ``has_rsu``, the unit's pose in ``rsu_to_ego``) are those of the frame
``cfg.msg_latency_ticks`` earlier in the same episode (the channel's latency: closed loop reads
at tick t the message the unit sent at t - 1, from its pose then, and none at a route's first
tick); the ego's inputs and every other target are the frame's own.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch.utils.data import Dataset
from v2xbench.agents.aurora.cqaf import rsu_to_ego
from v2xbench.agents.aurora.data import CALIB_KEYS, AuroraFrames, fused_targets
from v2xbench.collectors.dataset.loader import V2XDataset

from ..common.data import planning_sample
from .config import UniV2XConfig

EXTRA_KEYS = ("ego_speed", "command", "route", "expert_waypoints", ("gt", "fused", "boxes"),
              ("gt", "fused", "class"), ("gt", "fused", "mask"))
_DROP = ("map_points", "map_labels", "map_mask", "map_closed", "light", "frame_id")


class UniV2XFrames(Dataset):
    """Samples of both agents over one split (module docstring).

    Args:
        root: data set folder (``v2xbench collect --out``). split: ``train``, ``val``, ``test``
            or ``all``. cfg: the model configuration. stride: every ``stride``-th frame.

    Raises:
        FileNotFoundError: no data set at ``root``. ValueError: a data set without camera
            images, an unknown split, a bad stride (AURORA's messages name the problem).
    """

    def __init__(self, root: str | Path, split: str, cfg: UniV2XConfig, stride: int = 1) -> None:
        self.cfg, self.dcfg = cfg, cfg.data_config()
        self.ego = AuroraFrames(root, split, "ego", self.dcfg, stride=stride)
        try:
            self.rsu: AuroraFrames | None = AuroraFrames(root, split, "rsu", self.dcfg)
        except ValueError:  # no frame of the split has an active unit
            self.rsu = None
        self.extra = V2XDataset(root, split, keys=list(EXTRA_KEYS))
        self.frame_ids = self.ego.frame_ids
        self.range = tuple(float(v) for v in cfg.ego_range)
        self._blank: dict[str, torch.Tensor] | None = None

    def __len__(self) -> int:
        return len(self.frame_ids)

    @property
    def recorded_size(self) -> tuple[int, int]:
        """``(width, height)`` of the recorded camera images."""
        return self.ego.recorded_size

    def _blank_rsu(self, like: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        if self._blank is None:
            w, h = self.cfg.image_size
            m = like["det_boxes"].shape[0]
            boxes = torch.zeros(m, 10)
            boxes[:, 3:6], boxes[:, 7] = 1.0, 1.0  # padding rows: 1 m boxes, yaw 0
            self._blank = {"images": torch.zeros(1, 3, h, w), "intrinsics": torch.eye(3)[None],
                           "cam_to_frame": torch.eye(4)[None], "det_boxes": boxes,
                           "det_labels": torch.zeros(m, dtype=torch.long),
                           "det_mask": torch.zeros(m, dtype=torch.bool)}
        return {k: v.clone() for k, v in self._blank.items()}

    def _sent_calib(self, fid: int, calib: dict) -> tuple[int, dict | None]:
        """``(global frame, calibration arrays)`` of the frame whose roadside message the ego
        reads at frame ``fid`` (``cfg.msg_latency_ticks`` earlier; ``None``: before the
        episode's first tick). Reads only the calibration of that frame."""
        lag = self.cfg.msg_latency_ticks
        if lag == 0:
            return fid, calib
        e, t = self.ego.ds.locate(fid)
        if t < lag:
            return fid, None
        shard = self.ego.ds.shard(e)
        return fid - lag, {k: shard["calib", k][t - lag].numpy() for k in CALIB_KEYS}

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        fid = int(self.frame_ids[index])
        td = self.ego.ds[fid]
        calib = {k: td["calib", k].numpy() for k in CALIB_KEYS}
        ego = self.ego.sample(td, calib, fid)
        sent, sent_calib = self._sent_calib(fid, calib)
        has = (self.rsu is not None and sent_calib is not None
               and int(sent_calib["rsu_unit"]) >= 0)
        rsu = (self.rsu.sample(self.rsu.ds[sent], sent_calib, sent) if has
               else self._blank_rsu(ego))
        x = self.extra[fid]
        out = {f"ego/{k}": v for k, v in ego.items() if k not in _DROP}
        out.update({f"rsu/{k}": v for k, v in rsu.items() if k not in _DROP})
        out.update(fused_targets(x, self.range))
        e = (rsu_to_ego(calib["T_world_ego"], sent_calib["T_world_rsu"]) if has
             else torch.eye(4))
        out.update(has_rsu=torch.tensor(has), rsu_to_ego=e.float())
        out.update(planning_sample(x, self.cfg, fid))
        return out


__all__ = ["EXTRA_KEYS", "UniV2XFrames"]
