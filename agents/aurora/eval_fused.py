"""Perception evaluation of AURORA's fused heads: what CQAF makes of the roadside unit's queries.

For every ``stride``-th frame of a split (the frames ``eval-perception`` scores the ego branch
on), the trained system of a fusion run (stage 3, 4 or 5; default the latest) runs as in closed
loop, on the recorded data:

1. the ego branch on the six ego cameras;
2. where a roadside unit serves the ego (``calib/rsu_unit >= 0``), the roadside branch on the
   unit's recorded camera and calibration; its message (:func:`~.cqaf.rsu_message`, the unit's
   ground frame) goes through the wire format of closed loop, :func:`~.rsu_agent.
   serialize_message` -> float16 -> :func:`~.rsu_agent.deserialize_message`, and ``E_{r->e}``
   comes from the frame's calibration (:func:`~.cqaf.rsu_to_ego`, the matrix the channel's pose
   gives at run time: :func:`~.rsu_agent.received_pose`); the message is the same frame's (age
   0, as the baselines' perception evaluation; closed loop's channel adds at least one tick);
   frames without a unit get the empty message, as when nothing is received;
3. CQAF fuses; the fused detection head's ``top_k`` slots by score become the predictions
   (padding slots score ~2e-9, :data:`~.fused_heads.MASKED_LOGIT`).

Ground truth. The fused heads learn ``gt/fused`` (every actor the ego's or the unit's sensors
see, in the ego frame) cut to the ego range, so that is what they are scored against first:
the **main table**, the ground of the baselines' fused detections (``baselines
eval-perception``) in the experiments' perception table. They are also scored against ``gt/ego``
(what the ego's own sensors see, the ground of the ego-branch evaluation, :mod:`.eval_perception`)
and, on the same frames, the system's own ego branch (its weights in the stage's checkpoint) is
scored against both, so one file holds the 2 x 2 comparison of fused heads and ego branch. The
metric code is the ego branch's (:func:`~.eval_perception.decode_detections`,
:func:`~v2xbench.envs.v2x_intersection.evaluation.metrics_perception.detection_metrics`).

A No Fusion run (``fusion=False``) has nothing to fuse: :func:`evaluate_fused` refuses it.
Files: ``perception.json`` and ``perception.md`` in ``out`` (default ``RUN/eval_fused_<split>``).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from v2xbench.files import atomic_write_json, atomic_write_text, json_safe

from .eval_perception import _concat, decode_detections, table_row, to_det_boxes

#: Rows of the result: ``(predictions, ground truth)``; the first is the main table.
ROWS = (("fused", "fused"), ("fused", "ego"), ("ego_branch", "ego"), ("ego_branch", "fused"))
ROW_TITLES = {"fused": "fused heads (CQAF)", "ego_branch": "ego branch"}


def fused_message(system, rsu_in: dict, e_rsu_to_ego: torch.Tensor, rows: torch.Tensor,
                  batch: int) -> dict[str, torch.Tensor]:
    """The roadside messages of a batch as the ego receives them in closed loop.

    Args:
        system: the :class:`~.system.AuroraSystem`. rsu_in: the roadside branch's inputs of the
            rows with a unit. e_rsu_to_ego: ``(B, 4, 4)`` of every row. rows: ``(R,)`` indices
            of the rows with a unit (``R >= 1``). batch: ``B``.

    Returns:
        :data:`~.cqaf.MESSAGE_KEYS` with ``B`` rows (rows without a unit: zeros, masks off,
        identity pose), each unit's message serialized to float16 and read back.
    """
    from .cqaf import rsu_message
    from .rsu_agent import deserialize_message, serialize_message

    eye = torch.eye(4, device=e_rsu_to_ego.device)
    # each unit's message in its own ground frame, as AuroraRoadside sends it
    sent = rsu_message(system.rsu(rsu_in), system.cfg, eye.expand(len(rows), 4, 4))
    got = [deserialize_message(serialize_message({k: v[i:i + 1] for k, v in sent.items()}),
                               system.cfg) for i in range(len(rows))]
    dev = e_rsu_to_ego.device
    msg = {}
    for k in got[0]:
        sub = torch.cat([g[k] for g in got]).to(dev)
        msg[k] = sub.new_zeros((batch, *sub.shape[1:])).index_copy(0, rows, sub)
    has = torch.zeros(batch, dtype=torch.bool, device=dev)
    has[rows] = True
    msg["rsu_to_ego"] = torch.where(has[:, None, None], e_rsu_to_ego.float(),
                                    eye.expand(batch, 4, 4))
    return msg


def _boxes(fid: np.ndarray, mask: torch.Tensor, labels: torch.Tensor, boxes: torch.Tensor):
    m = mask.cpu().numpy().astype(bool)
    return to_det_boxes(np.repeat(fid, m.sum(1)), labels.cpu().numpy()[m],
                        boxes.cpu().numpy()[m])


def _preds(fid: np.ndarray, logits: torch.Tensor, boxes: torch.Tensor, top_k: int):
    score, cls, b = decode_detections(logits, boxes, top_k)
    k = score.shape[1]
    return to_det_boxes(np.repeat(fid, k), cls.cpu().numpy().reshape(-1),
                        b.cpu().numpy().reshape(-1, 10), score.cpu().numpy().reshape(-1))


@torch.no_grad()
def predict_fused(system, dataset, *, top_k: int = 50, batch_size: int = 4,
                  device: str = "cpu", progress: bool = False) -> dict:
    """Run the system's perception and CQAF over ``dataset`` (:class:`~.pairs.AuroraPairs`).

    Returns:
        ``preds`` (``{"fused", "ego_branch"}`` -> :class:`DetBoxes`), ``gts`` (``{"fused",
        "ego"}``), ``frames`` and ``frames_with_unit``.
    """
    from .cqaf import empty_message
    from .pairs import make_pair_loader
    from .system import _prefixed, ego_features, ego_outputs

    preds: dict[str, list] = {"fused": [], "ego_branch": []}
    gts: dict[str, list] = {"fused": [], "ego": []}
    with_unit = 0
    loader = make_pair_loader(dataset, batch_size, shuffle=False)
    t0, every = time.perf_counter(), max(1, 500 // batch_size)
    for n, batch in enumerate(loader, 1):
        if progress and n % every == 0:
            print(f"fused perception: {n * batch_size}/{len(dataset)} frames, "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
        dev = {k: v.to(device) for k, v in batch.items()}
        b = dev["frame_id"].shape[0]
        ego_out = system.ego(_prefixed(dev, "ego/"))
        has = dev["has_rsu"].bool()
        rows = has.nonzero()[:, 0]
        if len(rows):
            rsu_in = {k: v[rows] for k, v in _prefixed(dev, "rsu/").items()}
            msg = fused_message(system, rsu_in, dev["rsu_to_ego"], rows, b)
        else:
            msg = empty_message(system.cfg, b, device)
        fused = system.cqaf(ego_outputs(ego_features(ego_out)), msg)
        fid = batch["frame_id"].numpy()
        with_unit += len(rows)
        preds["fused"].append(_preds(fid, fused["det_logits"][-1], fused["det_boxes"][-1],
                                     top_k))
        preds["ego_branch"].append(_preds(fid, ego_out["det_logits"][-1],
                                          ego_out["det_boxes"][-1], top_k))
        gts["fused"].append(_boxes(fid, batch["det_mask"], batch["det_labels"],
                                   batch["det_boxes"]))
        gts["ego"].append(_boxes(fid, batch["ego/det_mask"], batch["ego/det_labels"],
                                 batch["ego/det_boxes"]))
    return {"preds": {k: _concat(v) for k, v in preds.items()},
            "gts": {k: _concat(v) for k, v in gts.items()}, "frames": len(dataset),
            "frames_with_unit": with_unit}


def markdown_rows(tables: dict[str, dict[str, float]]) -> str:
    """``| predictions | ground truth | avg mAP | NDS | vehicle | VRU | light | sign |``."""
    import math

    from .eval_perception import TABLE_COLUMNS

    def fmt(v: float | None) -> str:
        return "n/a" if v is None or not math.isfinite(v) else f"{v:.3f}"

    head = ("| predictions | ground truth | avg mAP | NDS | vehicle | VRU | traffic light | "
            "traffic sign |\n|---|---|---|---|---|---|---|---|\n")
    lines = []
    for key, row in tables.items():
        pred, gt = key.split("@")
        lines.append(f"| {ROW_TITLES[pred]} | gt/{gt} | "
                     + " | ".join(fmt(row[c]) for c, _ in TABLE_COLUMNS) + " |\n")
    return head + "".join(lines)


def evaluate_fused(run: str | Path, data: str | Path, split: str = "test",
                   out: str | Path | None = None, *, stage: int | None = None,
                   device: str = "cpu", top_k: int = 50, batch_size: int = 4, stride: int = 1,
                   progress: bool = True) -> dict:
    """Evaluate the fused heads of a fusion run on ``split`` of ``data`` (module docstring).

    Args:
        run: a run folder with stage 3, 4 or 5 (``aurora train`` / ``pipeline``).
        data: data set folder. split: ``train``, ``val``, ``test`` or ``all``.
        out: output folder (default ``RUN/eval_fused_<split>``).
        stage: the stage whose checkpoint is evaluated (default: the run's latest).
        device, top_k, batch_size: inference settings. stride: every ``stride``-th frame of
            each episode (the frames of ``eval-perception --stride``).

    Returns:
        ``table`` (fused heads vs ``gt/fused``: the paper's columns), ``tables`` (every row of
        :data:`ROWS`, keyed ``"<predictions>@<gt>"``), ``metrics`` (every metric of each),
        ``predictions`` (per predictor: boxes kept, their mean score), ``frames``,
        ``frames_with_unit``, ``stage``, ``scale``, ``markdown``, ``out``.

    Raises:
        FileNotFoundError: no run, no stage 3-5, no data folder. ValueError: a No Fusion run
            (nothing to fuse), a bad stride, a split without frames.
    """
    from v2xbench.envs.v2x_intersection.evaluation.metrics_perception import detection_metrics

    from .data import AuroraFrames
    from .pairs import AuroraPairs, planning_items
    from .system import load_system

    run, data = Path(run), Path(data)
    if not data.is_dir():
        raise FileNotFoundError(f"eval-perception --fused: data directory {data} does not exist")
    system, tok, info = load_system(run, stage, device)  # the run and its stage (default: latest)
    stage = int(info["stage"])
    if not bool(info.get("fusion", True)):
        raise ValueError(f"eval-perception --fused: {run}/stage{stage} is a No Fusion model "
                         "(trained with fusion=False, --no-fusion): it never receives the "
                         "roadside queries, so it has no fused perception; evaluate its ego "
                         "branch with `v2xbench aurora eval-perception` without --fused")
    frames = AuroraFrames(data, split, "ego", system.cfg, stride=stride, images=False)
    ds = AuroraPairs(data, split, system.cfg, tok, planning_items(frames, stride),
                     fusion=True, plan=False)
    if progress:
        print(f"eval-perception --fused: stage {stage} of {run} on {len(ds)} frames of {data} "
              f"({split})")
    t0 = time.perf_counter()
    res = predict_fused(system, ds, top_k=top_k, batch_size=batch_size, device=device,
                        progress=progress)
    wall = time.perf_counter() - t0
    metrics, tables = {}, {}
    for pred, gt in ROWS:
        key = f"{pred}@{gt}"
        metrics[key] = detection_metrics(res["preds"][pred], res["gts"][gt])
        tables[key] = table_row(metrics[key])
    md = markdown_rows(tables)
    out = Path(out) if out is not None else run / f"eval_fused_{split}"
    out.mkdir(parents=True, exist_ok=True)
    result = {"run": str(run), "stage": stage, "scale": system.cfg.scale, "data": str(data),
              "split": split, "stride": stride, "top_k": top_k, "device": device,
              "frames": res["frames"], "frames_with_unit": res["frames_with_unit"],
              "gt_boxes": {k: len(v.frame) for k, v in res["gts"].items()},
              "predictions": {k: {"boxes": len(v.frame), "mean_score": float(v.score.mean())
                                  if len(v.frame) else None} for k, v in res["preds"].items()},
              "table": tables["fused@fused"], "tables": tables, "metrics": metrics,
              "ms_per_frame": 1e3 * wall / max(res["frames"], 1)}
    atomic_write_json(out / "perception.json", json_safe(result), indent=1)
    atomic_write_text(out / "perception.md", f"# AURORA fused perception: {data} ({split})\n\n"
                      f"Run `{run}`, stage {stage}; {res['frames']} frames (every {stride}th), "
                      f"{res['frames_with_unit']} with a roadside unit (its message serialized "
                      f"to float16 as in closed loop); top-{top_k} slots per frame; the fused "
                      "heads' target is gt/fused, the ego branch's gt/ego "
                      "(agents/aurora/eval_fused.py).\n\n" + md)
    result.update(markdown=md, out=str(out))
    return result


__all__ = ["ROWS", "evaluate_fused", "fused_message", "markdown_rows", "predict_fused"]
