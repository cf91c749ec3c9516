"""Perception evaluation of trained AURORA branches: nuScenes-style detection metrics and pictures.

For each branch a run holds (``RUN/stage1`` ego, ``RUN/stage2`` roadside), the branch runs over
a split of a data set (:class:`~.data.AuroraFrames`); per frame the ``top_k`` queries with the
highest score (``sigmoid`` of the last decoder layer's logits, maximum over classes; the class
is that maximum's) become predictions, and
:func:`v2xbench.envs.v2x_intersection.evaluation.metrics_perception.detection_metrics` matches them with
the frame's ground truth (already cut to the branch's range; the ego branch in the ego frame,
the roadside branch in its own ground frame). The table has the seed paper's columns (its
Table 2): average mAP over the four class groups, NDS, and mAP for vehicle, VRU, traffic light
and traffic sign. VRU is the project's metric group (pedestrians and bicycles matched as one
group, ``classes.GROUPS``), where the paper averages the two classes' mAPs. The ego branch also
reports its traffic-light classification accuracy.

Files (:func:`evaluate_run`, written atomically): ``perception.json`` (every metric per branch),
``perception.md`` (the table), ``pictures/<branch>_<frame>.png`` (:mod:`.perception_pictures`).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn
from v2xbench.envs.v2x_intersection.evaluation.metrics_perception import DetBoxes, detection_metrics

from v2xbench.files import atomic_write_json, atomic_write_text, json_safe

from .config import AuroraConfig
from .data import AuroraFrames, make_loader

STAGE_BRANCH = {1: "ego", 2: "rsu"}
BRANCH_STAGE = {b: s for s, b in STAGE_BRANCH.items()}
RUN_CONFIG = "aurora.json"  # written by `v2xbench aurora train` beside the trainer's files
CHECKPOINT = "checkpoint.safetensors"
TABLE_COLUMNS = (("avg_mAP", "mAP"), ("NDS", "NDS"), ("vehicle", "vehicle/AP"),
                 ("vru", "vru/AP"), ("traffic_light", "traffic_light/AP"),
                 ("traffic_sign", "traffic_sign/AP"))
LAST_LAYER_KEYS = ("det_logits", "det_boxes", "map_logits", "map_points")
BRANCH_TITLES = {"ego": "ego branch (ego frame)", "rsu": "roadside branch (its ground frame)"}


# ------------------------------------------------------------------------------ decoding
def decode_detections(logits: torch.Tensor, boxes: torch.Tensor, top_k: int
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Top-``k`` queries per frame of one decoder layer's output.

    Args:
        logits: ``(B, Q, C)`` class logits. boxes: ``(B, Q, 10)`` metres.
        top_k: queries kept per frame (at most ``Q``).

    Returns:
        ``scores (B, k)``, ``classes (B, k)`` int64 and ``boxes (B, k, 10)``, by falling score.
    """
    if top_k < 1:
        raise ValueError(f"decode_detections: top_k={top_k} must be >= 1")
    prob = logits.detach().float().sigmoid()
    score, cls = prob.max(-1)  # (B, Q)
    k = min(int(top_k), score.shape[1])
    top, idx = score.topk(k, dim=1)
    return top, cls.gather(1, idx), boxes.detach().float().gather(
        1, idx[..., None].expand(-1, -1, boxes.shape[-1]))


def to_det_boxes(frame: np.ndarray, cls: np.ndarray, boxes10: np.ndarray,
                 score: np.ndarray | None = None) -> DetBoxes:
    """:class:`DetBoxes` from ``(N, 10)`` boxes ``x, y, z, l, w, h, sin, cos, vx, vy``."""
    b = np.asarray(boxes10, np.float64).reshape(-1, 10)
    return DetBoxes(frame=frame, cls=cls, center=b[:, :2], size=np.abs(b[:, 3:6]),
                    yaw=np.arctan2(b[:, 6], b[:, 7]), velocity=b[:, 8:10], score=score)


def _concat(parts: list[DetBoxes]) -> DetBoxes:
    if not parts:
        return DetBoxes(np.zeros(0), np.zeros(0), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0))
    return DetBoxes(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                      ("frame", "cls", "center", "size", "yaw", "velocity", "score")))


@torch.no_grad()
def predict(model: nn.Module, dataset: AuroraFrames, *, top_k: int = 50, batch_size: int = 4,
            device: str = "cpu", keep: set[int] | None = None, min_score: float = 0.0) -> dict:
    """Run ``model`` over ``dataset`` (in order) and collect predictions and ground truth
    (the ``top_k`` queries of each frame, less those scoring below ``min_score``).

    Returns:
        ``preds``, ``gts`` (:class:`DetBoxes` over all frames), ``light`` (correct, total) for
        the ego branch, ``frames`` (count) and ``kept``: for each frame id in ``keep``, its
        sample and the last decoder layer's outputs (:data:`LAST_LAYER_KEYS`, for pictures).
    """
    model.eval().to(device)
    keep = keep or set()
    preds, gts, kept = [], [], {}
    light_ok = light_n = 0
    for batch in make_loader(dataset, batch_size, shuffle=False):
        dev = {k: v.to(device) for k, v in batch.items()}
        out = model(dev)
        score, cls, boxes = decode_detections(out["det_logits"][-1], out["det_boxes"][-1], top_k)
        fid = batch["frame_id"].numpy()
        ok = (score >= min_score).cpu().numpy()
        preds.append(to_det_boxes(np.repeat(fid, ok.sum(1)), cls.cpu().numpy()[ok],
                                  boxes.cpu().numpy()[ok], score.cpu().numpy()[ok]))
        m = batch["det_mask"].numpy()
        gts.append(to_det_boxes(np.repeat(fid, m.sum(1)), batch["det_labels"].numpy()[m],
                                batch["det_boxes"].numpy()[m]))
        if "light_logits" in out and "light" in batch:
            light_ok += int((out["light_logits"].argmax(-1).cpu() == batch["light"]).sum())
            light_n += len(fid)
        for i, f in enumerate(fid):
            if int(f) in keep:
                kept[int(f)] = ({k: v[i] for k, v in batch.items()},
                                {k: out[k][-1, i].cpu() for k in LAST_LAYER_KEYS})
    return {"preds": _concat(preds), "gts": _concat(gts), "light": (light_ok, light_n),
            "frames": len(dataset), "kept": kept}


def table_row(metrics: dict) -> dict[str, float]:
    """The paper's columns from :func:`detection_metrics`' output."""
    return {col: float(metrics[key]) for col, key in TABLE_COLUMNS}


def markdown_table(rows: dict[str, dict[str, float]]) -> str:
    """``| branch | avg mAP | NDS | vehicle | VRU | traffic light | traffic sign |``."""
    head = ("| branch | avg mAP | NDS | vehicle | VRU | traffic light | traffic sign |\n"
            "|---|---|---|---|---|---|---|\n")

    def fmt(v: float) -> str:
        return "n/a" if v is None or not math.isfinite(v) else f"{v:.3f}"

    return head + "".join(
        f"| {BRANCH_TITLES.get(b, b)} | " + " | ".join(fmt(r[c]) for c, _ in TABLE_COLUMNS)
        + " |\n" for b, r in rows.items())


# ------------------------------------------------------------------------------ a run
def run_branches(run: str | Path) -> dict[str, Path]:
    """``{branch: stage folder}`` of the trained stages of a run (``RUN/stage1``, ``stage2``).

    Raises:
        FileNotFoundError: ``run`` is not a folder or holds no trained stage.
    """
    run = Path(run)
    if not run.is_dir():
        raise FileNotFoundError(f"eval-perception: run folder {run} does not exist")
    out = {STAGE_BRANCH[s]: run / f"stage{s}" for s in STAGE_BRANCH
           if (run / f"stage{s}" / CHECKPOINT).is_file()}
    if not out:
        raise FileNotFoundError(f"eval-perception: {run} has no trained stage (no "
                                f"stage1/{CHECKPOINT} or stage2/{CHECKPOINT}; run "
                                "`v2xbench aurora train` first)")
    return out


def load_branch(stage_dir: str | Path, device: str = "cpu") -> tuple[nn.Module, AuroraConfig]:
    """The trained :class:`~.branch.PerceptionBranch` of a stage folder and its config."""
    from .branch import PerceptionBranch
    from .trainer import load_weights

    stage_dir = Path(stage_dir)
    info_path = stage_dir / RUN_CONFIG
    if not info_path.is_file():
        raise FileNotFoundError(f"eval-perception: {info_path} is missing (the run was not made "
                                "by `v2xbench aurora train`)")
    info = json.loads(info_path.read_text())
    cfg = AuroraConfig.from_dict(info["config"])
    model = PerceptionBranch(cfg, info["branch"])
    load_weights(model, stage_dir / CHECKPOINT, device)
    return model.to(device).eval(), cfg


def evaluate_branch(model: nn.Module, dataset: AuroraFrames, *, top_k: int = 50,
                    batch_size: int = 4, device: str = "cpu", pictures: int = 4,
                    picture_dir: str | Path | None = None) -> dict:
    """Metrics (and pictures of ``pictures`` evenly spread frames) of one branch."""
    n = len(dataset)
    chosen = dataset.frame_ids[np.linspace(0, n - 1, min(pictures, n)).round().astype(int)] \
        if pictures > 0 and picture_dir is not None else []
    t0 = time.perf_counter()
    res = predict(model, dataset, top_k=top_k, batch_size=batch_size, device=device,
                  keep={int(f) for f in chosen})
    wall = time.perf_counter() - t0
    metrics = detection_metrics(res["preds"], res["gts"])
    out = {"branch": dataset.branch, "frames": res["frames"], "gt_boxes": len(res["gts"].frame),
           "top_k": top_k, "table": table_row(metrics), "metrics": metrics,
           "ms_per_frame": 1e3 * wall / max(n, 1)}
    ok, tot = res["light"]
    if tot:
        out["light_accuracy"] = ok / tot
    if picture_dir is not None:
        from .perception_pictures import frame_picture

        paths = []
        for fid, (sample, outputs) in sorted(res["kept"].items()):
            path = Path(picture_dir) / f"{dataset.branch}_{fid:07d}.png"
            frame_picture(sample, outputs, dataset.cfg, dataset.branch, path, top_k=top_k)
            paths.append(str(path))
        out["pictures"] = paths
    return out


def evaluate_run(run: str | Path, data: str | Path, split: str = "test",
                 out: str | Path | None = None, *, device: str = "cpu", top_k: int = 50,
                 batch_size: int = 4, stride: int = 1, pictures: int = 4,
                 progress: bool = True) -> dict:
    """Evaluate every trained branch of ``run`` on ``split`` of ``data``; write the files.

    Args:
        run: the training run folder (``v2xbench aurora train --out RUN``).
        data: data set folder; split: its split to evaluate (``test`` for the test50 data).
        out: output folder (default ``RUN/eval_<split>``).
        device, top_k, batch_size: inference settings. stride: every ``stride``-th frame.
        pictures: pictures per branch (0: none).

    Returns:
        ``{"branches": {branch: evaluate_branch result}, "table": markdown, ...}``.
    """
    stages = run_branches(run)
    data = Path(data)
    if not data.is_dir():
        raise FileNotFoundError(f"eval-perception: data directory {data} does not exist")
    out = Path(out) if out is not None else Path(run) / f"eval_{split}"
    out.mkdir(parents=True, exist_ok=True)
    result: dict = {"run": str(run), "data": str(data), "split": split, "stride": stride,
                    "device": device, "branches": {}}
    for branch, stage_dir in stages.items():
        model, cfg = load_branch(stage_dir, device)
        ds = AuroraFrames(data, split, branch, cfg, stride=stride)
        if progress:
            print(f"eval-perception: {branch} branch on {len(ds)} frames of {data} ({split})")
        result["branches"][branch] = evaluate_branch(
            model, ds, top_k=top_k, batch_size=batch_size, device=device, pictures=pictures,
            picture_dir=out / "pictures")
        result["branches"][branch]["scale"] = cfg.scale
    table = markdown_table({b: r["table"] for b, r in result["branches"].items()})
    result["table"] = table
    atomic_write_json(out / "perception.json", json_safe(result), indent=1)
    atomic_write_text(out / "perception.md", f"# AURORA perception: {data} ({split})\n\n"
                      f"Run `{run}`, top-{top_k} queries per frame, nuScenes-style metrics "
                      "(envs/v2x_intersection/evaluation/metrics_perception.py).\n\n" + table)
    result["out"] = str(out)
    return result


__all__ = ["BRANCH_STAGE", "RUN_CONFIG", "STAGE_BRANCH", "TABLE_COLUMNS", "decode_detections",
           "evaluate_branch", "evaluate_run", "load_branch", "markdown_table", "predict",
           "run_branches", "table_row", "to_det_boxes"]
