"""A baseline's ``v2xbench baselines train NAME`` / ``eval-perception NAME`` and its run folder.

Run folder (``--out RUN``)::

    RUN/<method>.json          scale, model config, data, stride, seed, the sensors' settings
    RUN/checkpoint.safetensors, optimizer.pt, state.json, log.jsonl, loss.png  (AURORA's fit)
    RUN/train_summary.json     the last call's summary
    RUN/eval_<split>/perception.json, perception.md   (:meth:`BaselineRun.evaluate_perception`)
    RUN/eval_planning/metrics.json, metrics.md        (:meth:`BaselineRun.evaluate_planning`)

Each method's ``train`` module subclasses :class:`BaselineRun` (its names, data set, model,
criterion) and exposes the bound methods as ``train``, ``format_summary``, ``load_run``,
``evaluate_perception`` and ``evaluate_planning`` (what :mod:`v2xbench.cli.baselines` calls).
"""

from __future__ import annotations

import dataclasses
import importlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from v2xbench.files import atomic_write_json, atomic_write_text, json_safe

CHECKPOINT = "checkpoint.safetensors"
#: Run settings that must match to resume a run folder.
SAME_RUN_KEYS = ("scale", "config", "data", "frame_stride", "frame_balance", "seed")


def check_same_run(path: Path, info: dict, config_cls: Any = None) -> None:
    """Refuse (``ValueError`` naming what differs) a run file at ``path`` whose settings
    (:data:`SAME_RUN_KEYS`) are not ``info``'s; no file: nothing to check. With ``config_cls``
    the stored configuration is read by its ``from_dict`` first (a run written before a field
    existed has the field's legacy value) and the differing fields are named."""
    if not path.is_file():
        return
    old = json.loads(path.read_text())
    if config_cls is not None and isinstance(old.get("config"), dict):
        old["config"] = config_cls.from_dict(old["config"]).to_dict()
    old, new = json.loads(json.dumps(old)), json.loads(json.dumps(info))
    diff = [k for k in SAME_RUN_KEYS if old.get(k) != new.get(k)]
    if diff:
        show = [(k, old.get(k), new.get(k)) for k in diff if k != "config"]
        if "config" in diff and isinstance(old.get("config"), dict):
            show += [(f"config.{k}", old["config"].get(k), v) for k, v in new["config"].items()
                     if old["config"].get(k) != v]
        raise ValueError(f"{info['method']} train: {path.parent} holds a run with other settings ("
                         f"{', '.join(diff)} differ{': ' + str(show) if show else ''}); use the "
                         "same settings to resume, or another --out")


class BaselineRun:
    """One baseline's training, loading and perception evaluation (module docstring).

    Subclasses set the class attributes (the data set, model and criterion classes by
    ``"module:Class"`` within the subclass's package, imported on use: torch loads only then)
    and implement :meth:`sensor_info`.
    """

    #: ``"module:Class"`` of the data set, the model and the loss in the subclass's package.
    frames_cls: str = ""
    model_cls: str = ""
    criterion_cls: str = ""

    #: The registered name (``univ2x``); also the run file's stem and the messages' prefix.
    method: str = ""
    #: The paper's name (``UniV2X``), in messages and the perception report's title.
    title: str = ""
    #: The run file's ``format`` value.
    run_format: str = ""
    #: The configuration class (``for_scale``, ``to_dict``, ``from_dict``).
    config_cls: Any = None
    #: The collect command a missing data folder's message suggests.
    collect_hint: str = "`v2xbench collect --suite train --out DIR`"
    #: What the perception report counts per frame (``fused agents``, ``heatmap peaks``).
    detections: str = "fused agents"

    @property
    def run_file(self) -> str:
        """The run folder's settings file (``<method>.json``)."""
        return f"{self.method}.json"

    # ------------------------------------------------------------------ the method's parts
    def part(self, ref: str) -> Any:
        """The class ``"module:Class"`` of the subclass's package (imported now)."""
        module, name = ref.split(":")
        package = type(self).__module__.rsplit(".", 1)[0]
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    def frames(self, data: str | Path, split: str, cfg: Any, stride: int, train: bool):
        """The method's data set over ``split`` (``train``: the training samples)."""
        return self.part(self.frames_cls)(data, split, cfg, stride=stride)

    def sensor_info(self, ds: Any) -> dict:
        """The run file's sensor settings of the training data set (what the agent declares)."""
        raise NotImplementedError

    def model(self, cfg: Any):
        """A new model of ``cfg``."""
        return self.part(self.model_cls)(cfg)

    def criterion(self, cfg: Any):
        """The training loss of ``cfg``."""
        return self.part(self.criterion_cls)(cfg)

    def commands(self) -> tuple:
        """``(train, format_summary, load_run, evaluate_perception, evaluate_planning)``: the
        names a baseline's ``train`` module exposes (what :mod:`v2xbench.cli.baselines`, the
        experiments and the agent call)."""
        return (self.train, self.format_summary, self.load_run, self.evaluate_perception,
                self.evaluate_planning)

    # ------------------------------------------------------------------ the commands
    def train(self, data: str | Path, out: str | Path, *, scale: str = "default",
              device: str = "cpu", max_steps: int | None = None, stride: int | None = None,
              seed: int = 0, progress: bool = True, num_workers: int | None = None,
              overrides: dict | None = None, rest_stride: int | None = None,
              start_stride: int | None = None) -> dict:
        """Train the method on the ``train`` split of ``data`` into the run folder ``out``.

        Args:
            data: data set folder. out: run folder (resumed when it holds this run).
            scale: ``tiny``, ``default`` or ``paper``. device: torch device.
            max_steps: stop after this many optimizer steps in total (run again to go on).
            stride: frame stride (default: the scale's). seed: the run's seed.
            num_workers: data-loader workers (default: the scale's).
            overrides: configuration fields over the scale's (``{"plan_frame": "ego"}``);
                part of the run's settings (a run resumes only with the same).
            rest_stride, start_stride: keep every k-th frame where the ego stands and the
                expert stays / sets off (default: the scale's; 0: ``stride``;
                :mod:`~v2xbench.agents.aurora.frame_balance`).

        Returns:
            :func:`~v2xbench.agents.aurora.trainer.fit`'s summary plus ``scale``, ``frames``,
            ``parameters``.

        Raises:
            FileNotFoundError: no data folder. ValueError: unknown scale, bad stride, a data set
                without the method's sensors, or a run folder of other settings.
        """
        import torch
        from v2xbench.agents.aurora.data import make_loader
        from v2xbench.agents.aurora.trainer import fit

        from .model import parameter_counts

        cfg = self.config_cls.for_scale(scale, **(overrides or {}))
        if not Path(data).is_dir():
            raise FileNotFoundError(f"{self.method} train: data directory {data} does not exist "
                                    f"(collect one with {self.collect_hint})")
        hp = cfg.train
        if stride is not None:
            hp = dataclasses.replace(hp, frame_stride=stride)
        if num_workers is not None:
            hp = dataclasses.replace(hp, num_workers=num_workers)
        if rest_stride is not None:
            hp = dataclasses.replace(hp, rest_stride=rest_stride)
        if start_stride is not None:
            hp = dataclasses.replace(hp, start_stride=start_stride)
        balance = {k: getattr(hp, k) for k in ("rest_stride", "start_stride") if getattr(hp, k)}
        ds = self.frames(data, "train", cfg, 1 if balance else hp.frame_stride, True)
        if balance:
            from v2xbench.agents.aurora import frame_balance as fb

            offsets, classes = fb.split_classes(data, "train")
            keep = fb.balanced_frame_ids(offsets, classes, hp.frame_stride, hp.rest_stride,
                                         hp.start_stride)
            ds.frame_ids = np.intersect1d(ds.frame_ids, keep)
            balance["classes"] = fb.class_counts(classes, ds.frame_ids)
        out = Path(out)
        info = {"format": self.run_format, "method": self.method, "scale": scale,
                "config": cfg.to_dict(), "data": str(Path(data).resolve()), "split": "train",
                "frame_stride": hp.frame_stride, "frames": len(ds), "seed": seed,
                **({"frame_balance": balance} if balance else {}), **self.sensor_info(ds)}
        check_same_run(out / self.run_file, info, self.config_cls)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / self.run_file, info, indent=1)
        loader = make_loader(ds, hp.batch_size, shuffle=True, seed=seed,
                             num_workers=hp.num_workers)
        torch.manual_seed(seed)  # the initial weights are part of the run
        model = self.model(cfg)
        summary = fit(model, self.criterion(cfg), loader, out, hp, device=device, seed=seed,
                      progress=progress, max_steps=max_steps)
        summary.update(scale=scale, frames=len(ds), parameters=parameter_counts(model))
        atomic_write_json(out / "train_summary.json", summary, indent=1)
        return summary

    def format_summary(self, s: dict) -> str:
        """One line about a training call."""
        from v2xbench.agents.aurora.trainer import loss_text, progress_text, speed_text

        return (f"{self.method} ({s['scale']}, {s['parameters']['total']:,d} parameters): "
                f"{progress_text(s)}, {s['frames']} frames, loss {loss_text(s)}, {speed_text(s)}")

    def load_run(self, run: str | Path, device: str = "cpu"):
        """``(model, cfg, info)``: the trained model of a run folder (eval mode).

        Raises:
            FileNotFoundError: no ``<method>.json`` or checkpoint in ``run``.
        """
        from v2xbench.agents.aurora.trainer import load_weights

        run = Path(run)
        if not (run / self.run_file).is_file() or not (run / CHECKPOINT).is_file():
            raise FileNotFoundError(f"{self.method}: {run} is not a trained {self.title} run (no "
                                    f"{self.run_file} or {CHECKPOINT}; train one with `v2xbench "
                                    f"baselines train {self.method} --data DIR --out {run}`)")
        info = json.loads((run / self.run_file).read_text())
        cfg = self.config_cls.from_dict(info["config"])
        model = self.model(cfg)
        load_weights(model, run / CHECKPOINT, device)
        info["checkpoint"] = str(run / CHECKPOINT)
        return model.to(device).eval(), cfg, info

    def evaluate_perception(self, run: str | Path, data: str | Path, split: str = "test", *,
                            out: str | Path | None = None, stride: int = 1, top_k: int = 50,
                            batch_size: int = 4, device: str = "cpu",
                            progress: bool = True) -> dict:
        """The fused detections of a run on a split, with AURORA's metrics code.

        Per frame the ``top_k`` detections by score (AURORA's
        :func:`~v2xbench.agents.aurora.eval_perception.predict` and ``decode_detections``: the
        model's outputs and the samples have the keys it reads) against ``gt/fused`` in the ego
        range (frames without a unit get the empty message, as in closed loop), matched by
        :func:`~v2xbench.envs.v2x_intersection.evaluation.metrics_perception.detection_metrics`;
        the table has AURORA's (the seed paper's) columns. Also the bytes of one message on air
        (float16, the channel's 16-byte header). Writes ``perception.json`` and
        ``perception.md`` in ``out`` (default ``RUN/eval_<split>``).
        """
        from v2xbench.agents.aurora.eval_perception import (
            markdown_table,
            predict,
            table_row,
        )
        from v2xbench.envs.v2x_intersection.evaluation.metrics_perception import (
            detection_metrics,
        )

        model, cfg, _ = self.load_run(run, device)
        ds = self.frames(data, split, cfg, stride, False)
        if progress:
            print(f"{self.method} eval-perception: {len(ds)} frames of {data} ({split})")
        res = predict(model, ds, top_k=top_k, batch_size=batch_size, device=device)
        metrics = detection_metrics(res["preds"], res["gts"])
        row = table_row(metrics)
        msg_bytes = 16 + 2 * cfg.message_floats()
        table = markdown_table({f"{self.method} (fused, ego frame)": row})
        res = {"run": str(run), "data": str(data), "split": split, "stride": stride,
               "top_k": top_k, "frames": len(ds), "table": row, "metrics": metrics,
               "message_floats": cfg.message_floats(), "message_bytes": msg_bytes,
               "bps_per_unit_frame": 10 * msg_bytes}
        out = Path(out) if out is not None else Path(run) / f"eval_{split}"
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "perception.json", json_safe(res), indent=1)
        atomic_write_text(out / "perception.md", f"# {self.title} perception: {data} ({split})\n\n"
                          f"Run `{run}`, top-{top_k} {self.detections} per frame, nuScenes-style "
                          "metrics (envs/v2x_intersection/evaluation/metrics_perception.py); "
                          f"message {msg_bytes:,d} bytes on air ({10 * msg_bytes:,d} B/s at 10 Hz "
                          "while a unit serves).\n\n" + table)
        res["out"], res["markdown"] = str(out), table
        return res

    def evaluate_planning(self, run: str | Path, data: str | Path, split: str = "test", *,
                          stride: int = 50, out: str | Path | None = None, batch_size: int = 4,
                          device: str = "cpu", progress: bool = True,
                          command: str | None = None, ego_speed: float | None = None) -> dict:
        """The run's planner open loop on a split, with AURORA's metrics
        (:func:`~.eval_planning.evaluate_planning`: L2 at 1 / 2 / 3 s, collision rate; writes
        ``metrics.json`` and ``metrics.md`` in ``out``, default ``RUN/eval_planning``;
        ``ego_speed``: a speed told on every frame instead of the frame's own)."""
        from .eval_planning import evaluate_planning

        return evaluate_planning(self, run, data, split, stride=stride, out=out,
                                 batch_size=batch_size, device=device, progress=progress,
                                 command=command, ego_speed=ego_speed)


__all__ = ["CHECKPOINT", "SAME_RUN_KEYS", "BaselineRun", "check_same_run"]
