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

import math
import time
import warnings
from pathlib import Path
from typing import Any

import torch
from v2xbench.agents.aurora.eval_planning import (
    OUT_DIR,
    add_batch,
    check_settings,
    new_parts,
    write_result,
)

from v2xbench.locks import dir_lock

FORMAT = "v2xbench-baseline-eval-planning/1"


def evaluate_planning(brun: Any, run: str | Path, data: str | Path, split: str = "test", *,
                      stride: int = 50, out: str | Path | None = None, batch_size: int = 4,
                      device: str = "cpu", progress: bool = True,
                      command: str | None = None, ego_speed: float | None = None) -> dict:
    """Run baseline ``brun``'s (:class:`~.train.BaselineRun`) trained model of ``run`` over
    ``split`` of ``data``; write and return its open-loop metrics (module docstring).

    ``ego_speed``: a speed (m/s) the model is told on every frame instead of the frame's own
    (the ego-status probe: a planner that leans on the ego's speed, the shortcut of behaviour
    cloning, loses its open-loop L2 with it; the metrics' constant-velocity line and at-rest
    frames keep the true speed).

    Returns:
        the metrics dict (also in ``metrics.json``) plus ``out`` and ``table`` (Markdown).

    Raises:
        FileNotFoundError: a missing run or data folder. ValueError: a bad stride or batch
            size, an unknown split, or ``out`` locked by another process.
    """
    from tqdm import tqdm
    from v2xbench.agents.aurora.data import make_loader

    check_settings(f"{brun.method} eval-planning", stride, batch_size)
    if ego_speed is not None and not (math.isfinite(ego_speed) and ego_speed >= 0):
        raise ValueError(f"{brun.method} eval-planning: ego_speed={ego_speed!r} must be a "
                         "finite speed >= 0 (m/s)")
    if not Path(data).is_dir():
        raise FileNotFoundError(f"{brun.method} eval-planning: data directory {data} does not "
                                f"exist (collect one with {brun.collect_hint})")
    model, cfg, info = brun.load_run(run, device)
    if ego_speed is not None and not cfg.plan_ego_speed:
        warnings.warn(f"{brun.method} eval-planning: the run's planner is never told the ego's "
                      f"speed (plan_ego_speed=false): --ego-speed {ego_speed:g} changes nothing",
                      stacklevel=2)
    ds = brun.frames(data, split, cfg, stride, False)
    t_steps, dt = int(cfg.plan_waypoints), float(cfg.plan_dt)
    out = Path(out) if out is not None else Path(run) / OUT_DIR
    parts = new_parts()
    t0 = time.perf_counter()
    with dir_lock(out, f"{brun.method} eval-planning"), torch.no_grad():
        for batch in tqdm(make_loader(ds, batch_size, shuffle=False), desc="eval-planning",
                          unit="batch", disable=not progress):
            inputs = {k: v.to(device) for k, v in batch.items()}
            if ego_speed is not None:
                inputs["ego_speed"] = torch.full_like(inputs["ego_speed"], float(ego_speed))
            wps = model(inputs)["waypoints"]
            add_batch(parts, batch, wps.double().cpu().numpy(), t_steps, dt)
        head = {"format": FORMAT, "title": brun.title,
                "source": {"run": str(run), "weights": None, "stage": None,
                           "checkpoint": info.get("checkpoint"), "fusion": True,
                           "scale": info.get("scale"), "planner": f"{brun.title}'s"},
                "data": str(data), "split": split, "stride": stride, "command": command,
                "ego_speed_input": "frame" if ego_speed is None else float(ego_speed),
                "plan_ego_speed": bool(cfg.plan_ego_speed), "plan_frame": cfg.plan_frame}
        return write_result(out, parts, head, t_steps, dt, time.perf_counter() - t0, len(ds))


__all__ = ["FORMAT", "evaluate_planning"]
