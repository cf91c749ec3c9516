"""Open-loop planning evaluation of a trained baseline on recorded frames.

``v2xbench baselines eval-planning NAME --run RUN --data DIR`` runs a baseline's whole model
(both halves: the roadside half on the frame's recorded roadside sensors makes the message the
ego half fuses, as in :meth:`~.train.BaselineRun.evaluate_perception`; a frame without a unit
gets the empty message) over every ``stride``-th frame of each episode of a split and scores its
``waypoints`` against the expert's with AURORA's open-loop metrics
(:mod:`v2xbench.agents.aurora.eval_planning`: L2 at 1 / 2 / 3 s beside the constant-velocity
line, collision rate against ``gt/fused`` actors moved at constant velocity, speeds at rest;
overall and per navigation command). The frames are the ones AURORA's ``eval-planning`` scores
with the same ``--split`` and ``--stride`` on the same data set, so the methods' rows compare.

Files (written atomically): ``metrics.json`` and ``metrics.md`` in ``--out`` (default
``RUN/eval_planning``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from v2xbench.agents.aurora.eval_planning import (
    ACTOR_CLASSES,
    HEADING_MIN_STEP,
    HORIZONS,
    OUT_DIR,
    PLANS,
    _finite,
    actor_futures,
    collisions,
    constant_velocity_plan,
    markdown,
    summarize,
)
from v2xbench.envs.v2x_intersection.core.classes import CLASS_NAMES

from v2xbench.files import atomic_write_json, atomic_write_text
from v2xbench.locks import dir_lock

FORMAT = "v2xbench-baseline-eval-planning/1"


def evaluate_planning(brun: Any, run: str | Path, data: str | Path, split: str = "test", *,
                      stride: int = 50, out: str | Path | None = None, batch_size: int = 4,
                      device: str = "cpu", progress: bool = True,
                      command: str | None = None) -> dict:
    """Run baseline ``brun``'s (:class:`~.train.BaselineRun`) trained model of ``run`` over
    ``split`` of ``data``; write and return its open-loop metrics (module docstring).

    Returns:
        the metrics dict (also in ``metrics.json``) plus ``out`` and ``table`` (Markdown).

    Raises:
        FileNotFoundError: a missing run or data folder. ValueError: a bad stride or batch
            size, an unknown split, or ``out`` locked by another process.
    """
    from tqdm import tqdm
    from v2xbench.agents.aurora.data import make_loader

    for name, v in (("stride", stride), ("batch_size", batch_size)):
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise ValueError(f"{brun.method} eval-planning: {name}={v!r} must be an int >= 1")
    if not Path(data).is_dir():
        raise FileNotFoundError(f"{brun.method} eval-planning: data directory {data} does not "
                                f"exist (collect one with {brun.collect_hint})")
    model, cfg, info = brun.load_run(run, device)
    ds = brun.frames(data, split, cfg, stride, False)
    t_steps, dt = int(cfg.plan_waypoints), float(cfg.plan_dt)
    out = Path(out) if out is not None else Path(run) / OUT_DIR
    parts: dict[str, list] = {k: [] for k in ("frame_id", "command", "speed", "expert", "model",
                                              "has_rsu", "futures")}
    t0 = time.perf_counter()
    with dir_lock(out, f"{brun.method} eval-planning"), torch.no_grad():
        for batch in tqdm(make_loader(ds, batch_size, shuffle=False), desc="eval-planning",
                          unit="batch", disable=not progress):
            res = model({k: v.to(device) for k, v in batch.items()})
            parts["model"].append(res["waypoints"][:, :t_steps].double().cpu().numpy())
            parts["expert"].append(batch["expert_waypoints"][:, :t_steps].double().numpy())
            parts["speed"].append(batch["ego_speed"].double().numpy())
            parts["command"].append(batch["command"].numpy())
            parts["frame_id"].append(batch["frame_id"].numpy())
            parts["has_rsu"].append(batch["has_rsu"].numpy())
            parts["futures"].append(actor_futures(batch["det_boxes"].numpy(),
                                                  batch["det_labels"].numpy(),
                                                  batch["det_mask"].numpy(), t_steps, dt))
        wall = time.perf_counter() - t0
        rec = {k: np.concatenate(v) for k, v in parts.items()}
        bad = ~np.isfinite(rec["expert"]).all((1, 2))
        if bad.any():  # no expert future recorded: nothing to compare with
            rec = {k: v[~bad] for k, v in rec.items()}
        rec["constant_velocity"] = constant_velocity_plan(rec["speed"], t_steps, dt)
        for plan in PLANS:
            rec[f"col_{plan}"] = collisions(rec[plan], rec["futures"])
        result = {
            "format": FORMAT, "title": brun.title,
            "source": {"run": str(run), "weights": None, "stage": None,
                       "checkpoint": info.get("checkpoint"), "fusion": True,
                       "scale": info.get("scale"), "planner": f"{brun.title}'s"},
            "data": str(data), "split": split, "stride": stride, "command": command,
            "frames": int(len(rec["speed"])), "frames_without_expert_future": int(bad.sum()),
            "frames_with_roadside_unit": int(rec["has_rsu"].sum()),
            "horizons_s": list(HORIZONS), "dt_s": dt,
            "collision_actors": [CLASS_NAMES[c] for c in ACTOR_CLASSES],
            "actor_futures": "constant velocity from each gt/fused box's recorded velocity",
            "heading_min_step_m": HEADING_MIN_STEP,
            "wall_s": round(wall, 1), "ms_per_frame": round(1e3 * wall / max(len(ds), 1), 1),
            **summarize(rec, dt)}
        result = _finite(result)
        table = markdown(result)
        atomic_write_json(out / "metrics.json", result, indent=1)
        atomic_write_text(out / "metrics.md", table)
    return dict(result, out=str(out), table=table)


__all__ = ["FORMAT", "evaluate_planning"]
