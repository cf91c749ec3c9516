"""How much AURORA's planned speed follows the speed its prompt says (the inertia probe).

Behaviour cloning with the ego's speed as an input learns a shortcut: the speed a moment from
now is mostly the speed now, so a planner can score well while reading little else, and in
closed loop a car that starts slowly keeps planning slowly (the "inertia" of Codevilla et al.,
ICCV 2019). This probe runs a trained planner over a split's planning frames several times,
each time with the prompt saying another speed (the frame's own, fixed values, or "unknown",
the speed-dropout form), and tabulates the planned speed (waypoints 0-1, as the agent's
controller reads it) by the frame's true speed and by what the expert does next. A planner
whose column barely changes between rows but follows the prompt across columns plans from the
speed, not from the scene (docs/aurora.md, "A sixth run").

``v2xbench aurora speed-probe --run RUN --data DIR`` writes ``metrics.json`` / ``metrics.md``
into ``RUN/speed_probe`` (or ``--out``).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from v2xbench.files import atomic_write_json, atomic_write_text
from v2xbench.locks import dir_lock

#: Prompt settings, in table order: ``"frame"`` (the frame's own speed), a speed (m/s), or
#: ``"unknown"``.
PROMPTS: tuple = ("frame", 0.0, 1.0, 3.0, "unknown")
#: Rows: the ego's true speed bins (m/s).
SPEED_BINS = ((0.0, 0.5), (0.5, 2.0), (2.0, 5.0), (5.0, float("inf")))
#: The expert "speeds up" / "slows" where its waypoint-0-1 speed is this far (m/s) above /
#: below the ego's speed.
TREND_MARGIN = 0.3
OUT_DIR = "speed_probe"


def _prompt_label(p) -> str:
    return "prompt: frame's speed" if p == "frame" else (
        "prompt: unknown" if p == "unknown" else f"prompt: {float(p):g} m/s")


def _planned_speeds(system, tok, data, split, items, prompt, batch_size) -> dict:
    """Waypoint-0-1 speeds of the model and the expert, and the ego speed, of ``items``."""
    import torch

    from .eval_planning import predict
    from .pairs import AuroraPairs, make_pair_loader
    from .policy import target_speed

    kw = {"speed_dropout": 1.0} if prompt == "unknown" else (
        {} if prompt == "frame" else {"prompt_speed": float(prompt)})
    ds = AuroraPairs(data, split, system.cfg, tok, items, fusion=system.fusion, **kw)
    t = system.cfg.plan_waypoints
    out = {"model": [], "expert": [], "speed": []}
    with torch.no_grad():
        for batch in make_pair_loader(ds, batch_size, shuffle=False):
            wps = torch.from_numpy(predict(system, batch))
            out["model"].append(target_speed(wps, system.cfg.plan_dt).numpy())
            out["expert"].append(target_speed(batch["expert_waypoints"][:, :t].double(),
                                              system.cfg.plan_dt).numpy())
            out["speed"].append(batch["ego_speed"].double().numpy())
    return {k: np.concatenate(v) for k, v in out.items()}


def probe_speed(data: str | Path, *, run: str | Path | None = None,
                weights: str | Path | None = None, stage: int | None = None,
                split: str = "val", stride: int = 3, prompts: tuple = PROMPTS,
                out: str | Path | None = None, batch_size: int = 8, device: str = "cpu",
                progress: bool = True) -> dict:
    """Run the probe (module docstring) and write ``metrics.json`` / ``metrics.md``.

    Args:
        data: data set folder. run / weights / stage: the model (as ``eval-planning``).
        split: the frames' split. stride: every ``stride``-th planning frame.
        prompts: what the prompt says, per pass (:data:`PROMPTS`).
        out: output folder (default ``RUN/speed_probe``). batch_size, device: inference.

    Returns:
        The result (``rows``: per speed bin and expert trend, the frame count, the expert's
        and, per prompt, the model's mean planned speed) plus ``out`` and ``table``.
    """
    from .data import AuroraFrames
    from .eval_planning import load_model, output_dir
    from .pairs import planning_items

    for p in prompts:
        if p not in ("frame", "unknown") and not (isinstance(p, (int, float))
                                                 and np.isfinite(p) and p >= 0):
            raise ValueError(f"speed probe: prompt {p!r} is not 'frame', 'unknown' or a speed")
    system, tok, info = load_model(run, weights, stage, device)
    frames = AuroraFrames(data, split, "ego", system.cfg, images=False)
    items = planning_items(frames, stride)
    out = output_dir(out, run, weights, OUT_DIR)
    t0 = time.perf_counter()
    passes = []
    with dir_lock(out, "aurora speed-probe"):
        for p in prompts:
            passes.append(_planned_speeds(system, tok, data, split, items, p, batch_size))
            if progress:
                print(f"speed probe: {_prompt_label(p)}: {len(items)} frames, "
                      f"{time.perf_counter() - t0:.0f} s", flush=True)
        v, ex = passes[0]["speed"], passes[0]["expert"]
        ok = np.isfinite(ex)
        trend = {"speeds up": ex > v + TREND_MARGIN, "slows": ex < v - TREND_MARGIN}
        trend["steady"] = ~trend["speeds up"] & ~trend["slows"]
        rows = []
        for lo, hi in SPEED_BINS:
            for name, m in trend.items():
                sel = ok & (v >= lo) & (v < hi) & m
                if not sel.any():
                    continue
                rows.append({"speed_bin": [lo, hi], "expert": name, "frames": int(sel.sum()),
                             "expert_speed": float(ex[sel].mean()),
                             "model_speed": [float(q["model"][sel].mean()) for q in passes]})
        result = {"format": "v2xbench-aurora-speed-probe/1",
                  "source": {"run": None if run is None else str(run),
                             "weights": None if weights is None else str(weights),
                             "stage": info.get("stage"), "fusion": bool(system.fusion),
                             "plan_speed_dropout": system.cfg.plan_speed_dropout},
                  "data": str(data), "split": split, "stride": stride,
                  "frames": int(ok.sum()), "prompts": [str(p) for p in prompts],
                  "trend_margin_mps": TREND_MARGIN,
                  "wall_s": round(time.perf_counter() - t0, 1), "rows": rows}
        table = markdown(result)
        atomic_write_json(out / "metrics.json", result, indent=1)
        atomic_write_text(out / "metrics.md", table)
    return dict(result, out=str(out), table=table)


def markdown(result: dict) -> str:
    """The probe's table: planned speed (m/s, waypoints 0-1) per row and prompt."""
    heads = [_prompt_label(p if p in ("frame", "unknown") else float(p))
             for p in result["prompts"]]
    lines = ["| ego speed (m/s) | expert | frames | expert's speed | " + " | ".join(heads) + " |",
             "|---" * (4 + len(heads)) + "|"]
    for r in result["rows"]:
        lo, hi = r["speed_bin"]
        bin_ = f"[{lo:g}, {hi:g})" if np.isfinite(hi) else f">= {lo:g}"
        lines.append(f"| {bin_} | {r['expert']} | {r['frames']} | {r['expert_speed']:.2f} | "
                     + " | ".join(f"{s:.2f}" for s in r["model_speed"]) + " |")
    return "\n".join(lines) + "\n"


__all__ = ["PROMPTS", "SPEED_BINS", "markdown", "probe_speed"]
