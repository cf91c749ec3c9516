"""``v2xbench baselines train codriving`` and ``eval-perception codriving``: what the commands
do.

Run folder (``--out RUN``): :mod:`..common.train`'s, with ``RUN/codriving.json`` (scale, model
config, data, stride, seed, LiDAR scale).

Training, loading and perception metrics are the baselines' shared
:class:`~..common.train.BaselineRun`: AURORA's loop over the ``train`` split
(:class:`~.data.CoDrivingFrames`, message ages drawn per sample), both halves end to end
(:class:`~.model.CoDriving`, :class:`~.losses.CoDrivingCriterion`). The perception report adds
what the messages held: the mean number of cells sent per message and the mean bytes on air
(the shared report's ``message_bytes`` is the largest message, the budget's).
"""

from __future__ import annotations

import json
from pathlib import Path

from v2xbench.files import atomic_write_json

from ..common.train import CHECKPOINT, BaselineRun
from .config import CoDrivingConfig

RUN_FILE = "codriving.json"
FORMAT = "v2xbench-codriving-run/1"


class CoDrivingRun(BaselineRun):
    """CoDriving's data set (both agents' LiDAR and the route rows), model and loss."""

    method, title, run_format, config_cls = "codriving", "CoDriving", FORMAT, CoDrivingConfig
    frames_cls, model_cls = "data:CoDrivingFrames", "model:CoDriving"
    criterion_cls = "losses:CoDrivingCriterion"
    collect_hint = "`v2xbench collect --suite train --sensors lidar --out DIR`"
    detections = "heatmap peaks"

    def frames(self, data: str | Path, split: str, cfg: CoDrivingConfig, stride: int,
               train: bool):
        """:class:`~.data.CoDrivingFrames` of ``split`` (``delay=None`` when training, else the
        channel's latency ``cfg.msg_latency_ticks``, the age closed loop delivers)."""
        return self.part(self.frames_cls)(data, split, cfg, stride=stride,
                                          delay=None if train else cfg.msg_latency_ticks)

    def sensor_info(self, ds) -> dict:
        """The data set's ``lidar_scale`` (the agent declares it)."""
        return {"lidar_scale": ds.lidar_scale}

    def load_run(self, run: str | Path, device: str = "cpu"):
        """:meth:`BaselineRun.load_run`; the model is kept for the message statistics of
        :meth:`evaluate_perception`."""
        model, cfg, info = super().load_run(run, device)
        self._last_model = model
        return model, cfg, info

    def evaluate_perception(self, run: str | Path, data: str | Path, split: str = "test",
                            **kw) -> dict:
        """:meth:`BaselineRun.evaluate_perception` plus ``mean_cells`` (cells per message with a
        unit) and ``mean_message_bytes`` (``16 + 2 (6 + cells (2 + C))``) in
        ``perception.json``."""
        res = super().evaluate_perception(run, data, split, **kw)
        stats, cfg = self._last_model.stats, self._last_model.cfg
        cells = stats["cells"] / max(stats["messages"], 1)
        res.update(messages=stats["messages"], mean_cells=cells,
                   mean_message_bytes=16 + 2 * (cfg.message_floats(0) + cells * cfg.cell_floats()))
        path = Path(res["out"]) / "perception.json"
        saved = json.loads(path.read_text())
        saved.update({k: res[k] for k in ("messages", "mean_cells", "mean_message_bytes")})
        atomic_write_json(path, saved, indent=1)
        return res


RUN = CoDrivingRun()
train, format_summary, load_run, evaluate_perception, evaluate_planning = RUN.commands()

__all__ = ["CHECKPOINT", "FORMAT", "RUN", "RUN_FILE", "CoDrivingRun", "evaluate_perception",
           "evaluate_planning", "format_summary", "load_run", "train"]
