"""``v2xbench baselines train univ2x`` and ``eval-perception univ2x``: what the commands do.

Run folder (``--out RUN``): :mod:`..common.train`'s, with ``RUN/univ2x.json`` (scale, model
config, data, stride, seed, camera size).

Training, loading and perception metrics are the baselines' shared
:class:`~..common.train.BaselineRun`: AURORA's loop (:func:`v2xbench.agents.aurora.trainer.fit`:
AdamW, warm-up + cosine, checkpoints every epoch and when stopped, exact resume, ``log.jsonl``,
``loss.png``) over the ``train`` split (:class:`~.data.UniV2XFrames`), both halves end to end
(:class:`~.model.UniV2X`, :class:`~.losses.UniV2XCriterion`). The same command on the same ``RUN``
resumes; other settings on it are refused, naming what differs.
"""

from __future__ import annotations

from ..common.train import CHECKPOINT, BaselineRun
from .config import UniV2XConfig

RUN_FILE = "univ2x.json"
FORMAT = "v2xbench-univ2x-run/1"


class UniV2XRun(BaselineRun):
    """UniV2X's data set (camera images of both agents), model and loss."""

    method, title, run_format, config_cls = "univ2x", "UniV2X", FORMAT, UniV2XConfig
    frames_cls, model_cls = "data:UniV2XFrames", "model:UniV2X"
    criterion_cls = "losses:UniV2XCriterion"

    def sensor_info(self, ds) -> dict:
        """The recorded camera size (the agent declares it)."""
        return {"camera_size": list(ds.recorded_size)}


RUN = UniV2XRun()
train, format_summary, load_run, evaluate_perception, evaluate_planning = RUN.commands()
train_univ2x = train

__all__ = ["CHECKPOINT", "FORMAT", "RUN", "RUN_FILE", "UniV2XRun", "evaluate_perception",
           "evaluate_planning", "format_summary", "load_run", "train", "train_univ2x"]
