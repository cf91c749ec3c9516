"""UniMM-V2X's samples: UniV2X's (:class:`~..univ2x.data.UniV2XFrames`: both agents' cameras and
targets, ``gt/fused``, planning inputs and the expert's waypoints) plus **motion targets**.

The data set holds no trajectories, but every frame's ``gt/fused`` boxes carry the actor ``id``
and every frame the ego pose ``calib/T_world_ego`` (docs/dataset.md). The future of an agent of
``gt/fused`` at frame ``t`` is its box centre in the frames ``t + s * f`` (``f`` = ``motion_dt``
x 10 Hz = 5 frames, ``s = 1 .. motion_steps``) of the same episode where the same id is in
``gt/fused``, moved from that frame's ego frame into the ego frame of ``t``
(``T_world_ego(t)^-1 T_world_ego(t + s f)``). A step is missing (masked) after the episode's end
or where the agent is in neither agent's view (``gt/fused`` holds what the ego or the unit
sees). Extra keys, rows aligned with ``det_boxes`` (``gt/fused`` cut to the ego range):

=====================  ======================================================================
``motion_future``      (M, T, 2) future positions (m, the ego frame of this frame)
``motion_mask``        (M, T) bool: the step is known
=====================  ======================================================================
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from v2xbench.agents.aurora.data import in_range
from v2xbench.collectors.dataset.loader import V2XDataset

from ..univ2x.data import UniV2XFrames
from .config import UniMMV2XConfig

FRAME_HZ = 10.0  # the data set's rate: one row per simulation tick
FUTURE_KEYS = (("gt", "fused", "boxes"), ("gt", "fused", "id"), ("gt", "fused", "mask"),
               ("calib", "T_world_ego"))


class UniMMV2XFrames(UniV2XFrames):
    """UniV2X's samples plus motion targets (module docstring; arguments and errors as
    :class:`~..univ2x.data.UniV2XFrames`)."""

    def __init__(self, root: str | Path, split: str, cfg: UniMMV2XConfig,
                 stride: int = 1) -> None:
        super().__init__(root, split, cfg, stride)
        self.future = V2XDataset(root, split, keys=list(FUTURE_KEYS))
        self.step_frames = max(1, int(round(cfg.motion_dt * FRAME_HZ)))

    def _frame(self, e: int, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        td = self.future.shard(e)
        return (td["gt", "fused", "boxes"][t].numpy(), td["gt", "fused", "id"][t].numpy(),
                td["gt", "fused", "mask"][t].numpy().astype(bool),
                td["calib", "T_world_ego"][t].numpy())

    def motion_targets(self, fid: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``(motion_future (M, T, 2), motion_mask (M, T))`` of global frame ``fid``."""
        cfg = self.cfg
        e, t = self.future.locate(fid)
        boxes, ids, mask, pose = self._frame(e, t)
        keep = mask & in_range(boxes[:, :3], self.range)
        m, t_steps = len(mask), cfg.motion_steps
        fut = np.zeros((m, t_steps, 2), np.float32)
        known = np.zeros((m, t_steps), bool)
        own = ids[keep]
        n = len(own)
        inv = np.linalg.inv(pose)
        frames = int(self.future.meta[e]["frames"])
        for s in range(1, t_steps + 1):
            t2 = t + s * self.step_frames
            if t2 >= frames or not n:
                break
            b2, ids2, mask2, pose2 = self._frame(e, t2)
            where = {int(i): j for j, i in enumerate(ids2) if mask2[j]}
            rows = [r for r in range(n) if int(own[r]) in where]
            if not rows:
                continue
            cols = [where[int(own[r])] for r in rows]
            pts = np.c_[b2[cols, :3], np.ones(len(cols))] @ (inv @ pose2).T
            fut[rows, s - 1] = pts[:, :2]
            known[rows, s - 1] = True
        return torch.from_numpy(fut), torch.from_numpy(known)

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        out = super().__getitem__(index)
        fut, known = self.motion_targets(int(self.frame_ids[index]))
        out.update(motion_future=fut, motion_mask=known)
        return out


__all__ = ["FUTURE_KEYS", "UniMMV2XFrames"]
