"""``v2xbench baselines train unimm_v2x`` and ``eval-perception unimm_v2x``.

Run folder (``--out RUN``), as UniV2X's (:mod:`..univ2x.train`)::

    RUN/unimm_v2x.json         scale, model config, data, stride, seed, camera size
    RUN/checkpoint.safetensors, optimizer.pt, state.json, log.jsonl, loss.png  (AURORA's fit)
    RUN/train_summary.json     the last call's summary
    RUN/eval_<split>/perception.json, perception.md   (:func:`evaluate_perception`)

Training is AURORA's loop (:func:`v2xbench.agents.aurora.trainer.fit`) over the ``train`` split
(:class:`~.data.UniMMV2XFrames`), both halves end to end (:class:`~.model.UniMMV2X`,
:class:`~.losses.UniMMV2XCriterion`). The same command on the same ``RUN`` resumes; other
settings on it are refused, naming what differs.
"""

from __future__ import annotations

from ..common.train import CHECKPOINT
from ..univ2x.train import UniV2XRun
from .config import UniMMV2XConfig

METHOD = "unimm_v2x"
RUN_FILE = "unimm_v2x.json"
FORMAT = "v2xbench-unimm-v2x-run/1"


class UniMMV2XRun(UniV2XRun):
    """UniV2X's run with UniMM-V2X's data set (motion targets), model and loss."""

    method, title, run_format, config_cls = METHOD, "UniMM-V2X", FORMAT, UniMMV2XConfig
    frames_cls, model_cls = "data:UniMMV2XFrames", "model:UniMMV2X"
    criterion_cls = "losses:UniMMV2XCriterion"


RUN = UniMMV2XRun()
train, format_summary, load_run, evaluate_perception, evaluate_planning = RUN.commands()
train_unimm_v2x = train

__all__ = ["CHECKPOINT", "METHOD", "RUN", "RUN_FILE", "UniMMV2XRun", "evaluate_perception",
           "evaluate_planning", "format_summary", "load_run", "train", "train_unimm_v2x"]
