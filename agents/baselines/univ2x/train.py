"""``v2xbench baselines train univ2x`` and ``eval-perception univ2x``: what the commands do.

Run folder (``--out RUN``)::

    RUN/univ2x.json            scale, model config, data, stride, seed, camera size (this module)
    RUN/checkpoint.safetensors, optimizer.pt, state.json, log.jsonl, loss.png  (AURORA's fit)
    RUN/train_summary.json     the last call's summary
    RUN/eval_<split>/perception.json, perception.md   (:func:`evaluate_perception`)

Training is AURORA's loop (:func:`v2xbench.agents.aurora.trainer.fit`: AdamW, warm-up + cosine,
checkpoints every epoch and when stopped, exact resume, ``log.jsonl``, ``loss.png``) over the
``train`` split (:class:`~.data.UniV2XFrames`), both halves end to end
(:class:`~.model.UniV2X`, :class:`~.losses.UniV2XCriterion`). The same command on the same
``RUN`` resumes; other settings on it are refused, naming what differs.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from v2xbench.files import atomic_write_json, atomic_write_text

from .config import UniV2XConfig

RUN_FILE = "univ2x.json"
FORMAT = "v2xbench-univ2x-run/1"
CHECKPOINT = "checkpoint.safetensors"
_SAME = ("scale", "config", "data", "frame_stride", "seed")


def _check_same_run(path: Path, info: dict) -> None:
    if not path.is_file():
        return
    old = json.loads(path.read_text())
    diff = [k for k in _SAME if old.get(k) != json.loads(json.dumps(info[k]))]
    if diff:
        show = [(k, old.get(k), info[k]) for k in diff if k != "config"]
        raise ValueError(f"{info['method']} train: {path.parent} holds a run with other settings ("
                         f"{', '.join(diff)} differ{': ' + str(show) if show else ''}); use the "
                         "same settings to resume, or another --out")


def train_univ2x(data: str | Path, out: str | Path, *, scale: str = "default",
                 device: str = "cpu", max_steps: int | None = None, stride: int | None = None,
                 seed: int = 0, progress: bool = True, num_workers: int | None = None) -> dict:
    """Train UniV2X on the ``train`` split of ``data`` into the run folder ``out``.

    Args:
        data: data set folder. out: run folder (resumed when it holds this run).
        scale: ``tiny``, ``default`` or ``paper``. device: torch device.
        max_steps: stop after this many optimizer steps in total (run again to go on).
        stride: frame stride (default: the scale's). seed: the run's seed.
        num_workers: data-loader workers (default: the scale's).

    Returns:
        :func:`~v2xbench.agents.aurora.trainer.fit`'s summary plus ``scale``, ``frames``,
        ``parameters``.

    Raises:
        FileNotFoundError: no data folder. ValueError: unknown scale, bad stride, a data set
            without camera images, or a run folder of other settings.
    """
    import torch
    from v2xbench.agents.aurora.data import make_loader
    from v2xbench.agents.aurora.trainer import fit

    from .data import UniV2XFrames
    from .losses import UniV2XCriterion
    from .model import UniV2X, parameter_counts

    cfg = UniV2XConfig.for_scale(scale)
    if not Path(data).is_dir():
        raise FileNotFoundError(f"univ2x train: data directory {data} does not exist (collect "
                                "one with `v2xbench collect --suite train --out DIR`)")
    hp = cfg.train
    if stride is not None:
        hp = dataclasses.replace(hp, frame_stride=stride)
    if num_workers is not None:
        hp = dataclasses.replace(hp, num_workers=num_workers)
    ds = UniV2XFrames(data, "train", cfg, stride=hp.frame_stride)
    out = Path(out)
    info = {"format": FORMAT, "method": "univ2x", "scale": scale, "config": cfg.to_dict(),
            "data": str(Path(data).resolve()), "split": "train", "frame_stride": hp.frame_stride,
            "frames": len(ds), "seed": seed, "camera_size": list(ds.recorded_size)}
    _check_same_run(out / RUN_FILE, info)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / RUN_FILE, info, indent=1)
    loader = make_loader(ds, hp.batch_size, shuffle=True, seed=seed, num_workers=hp.num_workers)
    torch.manual_seed(seed)  # the initial weights are part of the run
    model = UniV2X(cfg)
    summary = fit(model, UniV2XCriterion(cfg), loader, out, hp, device=device, seed=seed,
                  progress=progress, max_steps=max_steps)
    summary.update(scale=scale, frames=len(ds), parameters=parameter_counts(model))
    atomic_write_json(out / "train_summary.json", summary, indent=1)
    return summary


#: The name ``v2xbench baselines train`` calls (every baseline's ``train`` module has one).
train = train_univ2x


def format_summary(s: dict) -> str:
    """One line about a training call."""
    from v2xbench.agents.aurora.trainer import loss_text, progress_text, speed_text

    return (f"univ2x ({s['scale']}, {s['parameters']['total']:,d} parameters): "
            f"{progress_text(s)}, {s['frames']} frames, loss {loss_text(s)}, {speed_text(s)}")


def load_run(run: str | Path, device: str = "cpu"):
    """``(model, cfg, info)``: the trained :class:`~.model.UniV2X` of a run folder (eval mode).

    Raises:
        FileNotFoundError: no ``univ2x.json`` or checkpoint in ``run``.
    """
    from v2xbench.agents.aurora.trainer import load_weights

    from .model import UniV2X

    run = Path(run)
    if not (run / RUN_FILE).is_file() or not (run / CHECKPOINT).is_file():
        raise FileNotFoundError(f"univ2x: {run} is not a trained UniV2X run (no {RUN_FILE} or "
                                f"{CHECKPOINT}; train one with `v2xbench baselines train univ2x "
                                f"--data DIR --out {run}`)")
    info = json.loads((run / RUN_FILE).read_text())
    cfg = UniV2XConfig.from_dict(info["config"])
    model = UniV2X(cfg)
    load_weights(model, run / CHECKPOINT, device)
    info["checkpoint"] = str(run / CHECKPOINT)
    return model.to(device).eval(), cfg, info


def evaluate_perception(run: str | Path, data: str | Path, split: str = "test", *,
                        out: str | Path | None = None, stride: int = 1, top_k: int = 50,
                        batch_size: int = 4, device: str = "cpu", progress: bool = True) -> dict:
    """The fused detections of a run on a split, with AURORA's metrics code.

    Per frame the ``top_k`` fused agents by score
    (:func:`~v2xbench.agents.aurora.eval_perception.decode_detections`) against ``gt/fused`` in
    the ego range (frames without a unit get the empty message, as in closed loop), matched by
    :func:`~v2xbench.envs.v2x_intersection.evaluation.metrics_perception.detection_metrics`; the table has
    AURORA's (the seed paper's) columns (AURORA's :func:`~v2xbench.agents.aurora.eval_perception.
    predict` runs the model: its outputs and the samples have the keys it reads). Also the bytes
    of one message on air (float16, the channel's 16-byte header). Writes ``perception.json``
    and ``perception.md`` in ``out`` (default ``RUN/eval_<split>``).
    """
    from v2xbench.agents.aurora.eval_perception import _finite, markdown_table, predict, table_row
    from v2xbench.envs.v2x_intersection.evaluation.metrics_perception import detection_metrics

    from .data import UniV2XFrames

    model, cfg, _ = load_run(run, device)
    ds = UniV2XFrames(data, split, cfg, stride=stride)
    if progress:
        print(f"univ2x eval-perception: {len(ds)} frames of {data} ({split})")
    res = predict(model, ds, top_k=top_k, batch_size=batch_size, device=device)
    metrics = detection_metrics(res["preds"], res["gts"])
    row = table_row(metrics)
    msg_bytes = 16 + 2 * cfg.message_floats()
    table = markdown_table({"univ2x (fused, ego frame)": row})
    res = {"run": str(run), "data": str(data), "split": split, "stride": stride, "top_k": top_k,
           "frames": len(ds), "table": row, "metrics": metrics,
           "message_floats": cfg.message_floats(), "message_bytes": msg_bytes,
           "bps_per_unit_frame": 10 * msg_bytes}
    out = Path(out) if out is not None else Path(run) / f"eval_{split}"
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "perception.json", _finite(res), indent=1)
    atomic_write_text(out / "perception.md", f"# UniV2X perception: {data} ({split})\n\n"
                      f"Run `{run}`, top-{top_k} fused agents per frame, nuScenes-style metrics "
                      f"(envs/v2x_intersection/evaluation/metrics_perception.py); message {msg_bytes:,d} "
                      f"bytes on air ({10 * msg_bytes:,d} B/s at 10 Hz while a unit serves).\n\n"
                      + table)
    res["out"], res["markdown"] = str(out), table
    return res


__all__ = ["RUN_FILE", "evaluate_perception", "format_summary", "load_run", "train_univ2x"]
