"""V2X-ViT's training and evaluation samples: one frame of a collected data set with both agents'
LiDAR (``v2xbench collect --sensors lidar``).

Keys (shapes without the leading ``B``; ``L`` / ``L'`` the LiDARs' padded rows):

=====================================  ===================================================
key                                    content
=====================================  ===================================================
``ego/points``, ``ego/point_mask``     (L, 4) ``x, y, z``, intensity in the ego frame
                                       (``calib/T_ego_lidar[0]``), (L,) valid rows
``rsu/points``, ``rsu/point_mask``     (L', 4) the unit's LiDAR in its ground frame
                                       (``T_ego_lidar[1]`` and AURORA's
                                       :func:`~v2xbench.agents.aurora.calib.ego_frame_pose`),
                                       of ``age`` ticks earlier; zeros without a unit
``has_rsu``, ``age``                   () a unit serves the ego; () the message's age (ticks)
``rsu_to_ego``                         (4, 4) ``E_{r->e}`` of the current frame (AURORA's
                                       ``cqaf.rsu_to_ego``; identity without a unit)
``det_boxes``, ``det_labels``,         ``gt/fused`` in the ego frame, cut to the ego range
``det_mask``                           (AURORA's :func:`~v2xbench.agents.aurora.data.
                                       fused_targets`)
``command``, ``ego_speed``,            () command, speed (m/s); (R, 2) AURORA's route points
``route_points``, ``expert_waypoints`` ahead; (8, 2) the expert's positions, 0.5 s apart
``frame_id``                           () global frame index
=====================================  ===================================================

**Delay** (the paper's asynchronous messages): ``delay=None`` draws the age from
``cfg.msg_latency_ticks .. max(cfg.msg_latency_ticks, cfg.train_max_delay)`` ticks per sample,
an int fixes it (taken as is when below ``msg_latency_ticks``); the roadside points are then
those of that many ticks earlier in the same episode (fewer when the episode or the unit's
service started later, but never fewer than ``msg_latency_ticks``, the channel's latency: closed
loop has no message before the unit's first one arrives, so such a frame has none, ``has_rsu``
false). ``msg_latency_ticks`` = 0 (runs trained before the third stop of 2026-11-28) gives a
message of age 0 at every frame with a unit. One difference remains: at a handover between
units (or for a few ticks after the ego leaves a unit's range) closed loop still delivers the
previous unit's last message, with that unit's pose; here such a frame has no message. The unit
stands still, so its map needs no motion compensation; the objects in it moved, which is what
the delay encoding is for. ``E_{r->e}`` is the current one, as in closed
loop (``v2x_info`` gives the unit's pose when the message is read).

Frames: every ``stride``-th frame of each episode of the split.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset
from v2xbench.agents.aurora.calib import ego_frame_pose
from v2xbench.agents.aurora.cqaf import rsu_to_ego
from v2xbench.agents.aurora.data import fused_targets
from v2xbench.collectors.dataset.loader import V2XDataset
from v2xbench.collectors.dataset.shards import load_manifest
from v2xbench.envs.v2x_intersection.core.geometry import invert_transform

from ..common.data import planning_sample
from .config import POINT_FEATURES, V2XViTConfig

CALIB = ("T_world_ego", "T_world_rsu", "T_ego_rsu", "rsu_unit", "T_ego_lidar")
KEYS = [("lidar", g, k) for g in ("ego", "rsu") for k in ("points", "count")] + \
    [("calib", k) for k in CALIB] + \
    ["ego_speed", "command", "route", "expert_waypoints", ("gt", "fused", "boxes"),
     ("gt", "fused", "class"), ("gt", "fused", "mask")]


def lidar_points(padded: np.ndarray, count: int, t_frame_lidar: np.ndarray
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(points (L, 4), mask (L,))``: a LiDAR's padded sensor-frame rows ``(L, >= 4)`` moved into
    a frame by ``t_frame_lidar`` ``(4, 4)`` (``x, y, z``, intensity; padding rows zero).

    Raises:
        ValueError: the rows are not ``(L, >= 4)`` or ``count`` is outside ``0..L``.
    """
    p = np.asarray(padded, np.float64)
    if p.ndim != 2 or p.shape[1] < POINT_FEATURES:
        raise ValueError(f"V2X-ViT lidar_points: points have shape {p.shape}; expected (L, 6) "
                         "(x, y, z, intensity, semantic, instance; the sensor frame)")
    n = int(count)
    if not 0 <= n <= len(p):
        raise ValueError(f"V2X-ViT lidar_points: count={n} outside 0..{len(p)} (the rows)")
    t = np.asarray(t_frame_lidar, np.float64)
    out = np.zeros((len(p), POINT_FEATURES), np.float32)
    out[:n, :3] = p[:n, :3] @ t[:3, :3].T + t[:3, 3]
    out[:n, 3] = p[:n, 3]
    return torch.from_numpy(out), torch.arange(len(p)) < n


def rsu_ground_from_lidar(calib: dict) -> np.ndarray:
    """``(4, 4)``: the unit's LiDAR frame -> its ground frame, from a frame's ``calib``."""
    t_ego_ground = ego_frame_pose(calib, "rsu")
    return invert_transform(t_ego_ground) @ np.asarray(calib["T_ego_lidar"][1], np.float64)


class V2XViTFrames(Dataset):
    """Samples of both agents' LiDAR over one split (module docstring).

    Args:
        root: data set folder. split: ``train``, ``val``, ``test`` or ``all``.
        cfg: the model configuration. stride: every ``stride``-th frame.
        delay: the message's age in ticks (``None``: drawn per sample, training).

    Raises:
        FileNotFoundError: no data set at ``root``. ValueError: a data set without LiDAR points,
            an unknown split, a bad stride or delay.
    """

    def __init__(self, root: str | Path, split: str, cfg: V2XViTConfig, stride: int = 1,
                 delay: int | None = 0) -> None:
        if not isinstance(stride, int) or isinstance(stride, bool) or stride < 1:
            raise ValueError(f"V2XViTFrames: stride={stride!r} must be an int >= 1")
        if delay is not None and (not isinstance(delay, int) or delay < 0):
            raise ValueError(f"V2XViTFrames: delay={delay!r} must be None or an int >= 0")
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"V2XViTFrames: data directory {root} does not exist "
                                    "(collect one with `v2xbench collect --sensors lidar`)")
        self.cfg, self.delay = cfg, delay
        self.ds = V2XDataset(root, split, keys=KEYS)
        if ("lidar", "ego", "points") not in self.ds.schema:
            raise ValueError(f"V2XViTFrames: the data set {root} has no LiDAR points "
                             "(lidar/ego/points); collect it with `v2xbench collect --sensors "
                             "lidar` (or rgb,lidar)")
        self.lidar_scale = float(load_manifest(root)["sensor_config"]["lidar_scale"])
        self.range = tuple(float(v) for v in cfg.ego_range)
        frames = []
        for e in range(len(self.ds.episodes)):
            t = np.arange(int(self.ds.offsets[e + 1] - self.ds.offsets[e]))
            frames.append(self.ds.offsets[e] + t[t % stride == 0])
        self.frame_ids = np.concatenate(frames).astype(np.int64)

    def __len__(self) -> int:
        return len(self.frame_ids)

    def _age(self, e: int, t: int, unit: int) -> int | None:
        """The age (ticks) of the message ``unit`` delivers at tick ``t`` of episode ``e``;
        ``None``: no message has arrived yet (module docstring, "Delay")."""
        lag = self.cfg.msg_latency_ticks
        if self.delay is None:
            top = max(lag, self.cfg.train_max_delay)
            want = int(torch.randint(lag, top + 1, ()))
        else:
            want = self.delay
        lo = min(lag, want)
        units = self.ds.shard(e)["calib", "rsu_unit"]
        d = min(want, t)
        while d > lo and int(units[t - d]) != unit:
            d -= 1
        return d if d >= lo and int(units[t - d]) == unit else None

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        fid = int(self.frame_ids[index])
        x = self.ds[fid]
        calib = {k: x["calib", k].numpy() for k in CALIB}
        ego, ego_mask = lidar_points(x["lidar", "ego", "points"].numpy(),
                                     int(x["lidar", "ego", "count"]), calib["T_ego_lidar"][0])
        unit = int(calib["rsu_unit"])
        age = self._age(*self.ds.locate(fid), unit) if unit >= 0 else None
        has = age is not None
        if has:
            old = self.ds[fid - age] if age else x
            old_calib = {k: old["calib", k].numpy() for k in CALIB}
            rsu, rsu_mask = lidar_points(old["lidar", "rsu", "points"].numpy(),
                                         int(old["lidar", "rsu", "count"]),
                                         rsu_ground_from_lidar(old_calib))
            e_re = rsu_to_ego(calib["T_world_ego"], calib["T_world_rsu"])
        else:
            n = x["lidar", "rsu", "points"].shape[0]
            rsu, rsu_mask = torch.zeros(n, POINT_FEATURES), torch.zeros(n, dtype=torch.bool)
            e_re = torch.eye(4)
        out = {"ego/points": ego, "ego/point_mask": ego_mask, "rsu/points": rsu,
               "rsu/point_mask": rsu_mask, "has_rsu": torch.tensor(has),
               "age": torch.tensor(age or 0, dtype=torch.long), "rsu_to_ego": e_re.float()}
        out.update(fused_targets(x, self.range))
        out.update(planning_sample(x, self.cfg, fid))
        return out


__all__ = ["KEYS", "V2XViTFrames", "lidar_points", "rsu_ground_from_lidar"]
