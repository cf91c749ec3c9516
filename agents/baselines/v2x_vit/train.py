"""``v2xbench baselines train v2x_vit`` and ``eval-perception v2x_vit``: what the commands do.

Run folder (``--out RUN``): :mod:`..common.train`'s, with ``RUN/v2x_vit.json`` (scale, model
config, data, stride, seed, LiDAR scale).

Training, loading and perception metrics are the baselines' shared
:class:`~..common.train.BaselineRun`: AURORA's loop (:func:`v2xbench.agents.aurora.trainer.fit`:
AdamW, warm-up + cosine, checkpoints every epoch and when stopped, exact resume, ``log.jsonl``,
``loss.png``) over the ``train`` split (:class:`~.data.V2XViTFrames`, message ages drawn per
sample), both halves end to end (:class:`~.model.V2XViT`, :class:`~.losses.V2XViTCriterion`). The
same command on the same ``RUN`` resumes; other settings on it are refused, naming what differs.
"""

from __future__ import annotations

from pathlib import Path

from ..common.train import CHECKPOINT, BaselineRun
from .config import V2XViTConfig

RUN_FILE = "v2x_vit.json"
FORMAT = "v2xbench-v2x_vit-run/1"


class V2XViTRun(BaselineRun):
    """V2X-ViT's data set (both agents' LiDAR; message ages drawn per training sample, the
    channel's latency ``msg_latency_ticks`` in evaluation), model and loss."""

    method, title, run_format, config_cls = "v2x_vit", "V2X-ViT", FORMAT, V2XViTConfig
    frames_cls, model_cls = "data:V2XViTFrames", "model:V2XViT"
    criterion_cls = "losses:V2XViTCriterion"
    collect_hint = "`v2xbench collect --suite train --sensors lidar --out DIR`"
    detections = "heatmap peaks"

    def frames(self, data: str | Path, split: str, cfg: V2XViTConfig, stride: int, train: bool):
        """:class:`~.data.V2XViTFrames` of ``split`` (``delay=None`` when training, else the
        channel's latency ``cfg.msg_latency_ticks``, the age closed loop delivers)."""
        return self.part(self.frames_cls)(data, split, cfg, stride=stride,
                                          delay=None if train else cfg.msg_latency_ticks)

    def sensor_info(self, ds) -> dict:
        """The data set's ``lidar_scale`` (the agent declares it)."""
        return {"lidar_scale": ds.lidar_scale}


RUN = V2XViTRun()
train, format_summary, load_run, evaluate_perception, evaluate_planning = RUN.commands()
train_v2x_vit = train

__all__ = ["CHECKPOINT", "FORMAT", "RUN", "RUN_FILE", "V2XViTRun", "evaluate_perception",
           "evaluate_planning", "format_summary", "load_run", "train", "train_v2x_vit"]
