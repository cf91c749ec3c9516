"""``v2xbench aurora pipeline``: stages 0-5 of AURORA in order, each resumed or skipped.

=====  ==========================  ============================================================
stage  what                        function (the same as ``v2xbench aurora train --stage N``)
=====  ==========================  ============================================================
0      language-model pre-training :func:`~.stage0.train_stage0` (not run with ``--lm PATH``)
1      ego branch                  :func:`~.cli.train_stage`
2      roadside branch             :func:`~.cli.train_stage`
3      fusion + QA                 :func:`~.stages.train_late_stage`
4      planning                    :func:`~.stages.train_late_stage`
5      joint QA + planning         :func:`~.stages.train_late_stage`
=====  ==========================  ============================================================

A stage is **complete** when its trainer state says done (``state.json``) and the files later
stages read are there (stage 0: the ``save_pretrained`` model; 3-5: the peft adapter). A complete
stage is skipped (its recorded scale, and for 3-5 its fusion and qa, must match the call,
else ``ValueError``); an incomplete one is resumed by its function (which refuses other settings).
With ``max_steps`` a stage stops early and the pipeline stops after it (later stages need it
complete); the same command goes on. One progress line per stage, then a summary of each
stage's final losses (the mean of the last :data:`FINAL_STEPS` logged steps, ``log.jsonl``), steps
and time, written atomically to ``RUN/pipeline_summary.json`` and ``RUN/pipeline_summary.md``.

No Fusion: ``fusion=False`` trains stages 3-5 without the roadside message; stages 0-2 are the
same as AURORA's, so copying ``RUN/stage0..2`` of an AURORA run into the No Fusion run folder
first makes the pipeline skip them. The VQA ablation: ``qa=False`` (``--no-qa``) trains stages
3-5 without the Chat-V2XBench loss (:mod:`.stages`); stages 0-2 are again AURORA's.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

from v2xbench.files import atomic_write_json, atomic_write_text
from v2xbench.locks import dir_lock

from .config import SCALES

STAGES = (0, 1, 2, 3, 4, 5)
NAMES = {0: "language model", 1: "ego branch", 2: "roadside branch", 3: "fusion + QA",
         4: "planning", 5: "joint QA + planning"}
SUMMARY = "pipeline_summary"
FINAL_STEPS = 20  # final losses: mean over the last steps of log.jsonl
_NOT_LOSSES = {"step", "epoch", "lr", "grad_norm", "data_s", "compute_s"}


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, ValueError):
        return None


def stage_complete(run: str | Path, stage: int) -> bool:
    """Whether ``RUN/stage<N>`` is complete (module docstring)."""
    d = Path(run) / f"stage{stage}"
    state = _read_json(d / "state.json")
    if not state or not state.get("done"):
        return False
    need = {0: ["config.json"], 1: ["checkpoint.safetensors"], 2: ["checkpoint.safetensors"]}
    files = need.get(stage, ["checkpoint.safetensors", "adapter/adapter_config.json"])
    return all((d / f).is_file() for f in files) and (d / "aurora.json").is_file()


def _check_skipped(run: Path, stage: int, scale: str, fusion: bool, qa: bool = True) -> None:
    info = _read_json(run / f"stage{stage}" / "aurora.json") or {}
    if info.get("scale") != scale:
        raise ValueError(f"aurora pipeline: {run}/stage{stage} was trained at scale "
                         f"{info.get('scale')!r}, not {scale!r}; use --scale "
                         f"{info.get('scale')} or another --out")
    if stage >= 3 and bool(info.get("fusion", True)) != fusion:
        raise ValueError(f"aurora pipeline: {run}/stage{stage} was trained with fusion="
                         f"{info.get('fusion')}; this call has fusion={fusion} (--no-fusion): "
                         "use another --out")
    if stage >= 3 and bool(info.get("qa", True)) != qa:  # a file without the key: QA loss on
        raise ValueError(f"aurora pipeline: {run}/stage{stage} was trained with qa="
                         f"{bool(info.get('qa', True))}; this call has qa={qa} (--no-qa): use "
                         "another --out")


def stage_record(run: str | Path, stage: int) -> dict:
    """What the summary says about a stage folder: ``steps``, ``total_steps``, ``done``,
    ``final`` (each logged loss averaged over the last :data:`FINAL_STEPS` steps), ``final_steps``
    and ``train_s`` (data + compute seconds of every logged step, over all calls)."""
    d = Path(run) / f"stage{stage}"
    state = _read_json(d / "state.json") or {}
    rows = []
    if (d / "log.jsonl").is_file():
        rows = [json.loads(x) for x in (d / "log.jsonl").read_text().splitlines() if x.strip()]
    last = rows[-FINAL_STEPS:]
    keys = [k for k in (last[0] if last else {}) if k not in _NOT_LOSSES]
    final = {k: sum(float(r[k]) for r in last) / len(last) for k in keys
             if all(isinstance(r.get(k), (int, float)) for r in last)}
    return {"steps": state.get("step", 0), "total_steps": state.get("total_steps"),
            "done": bool(state.get("done", False)), "final": final, "final_steps": len(last),
            "train_s": sum(float(r.get("data_s", 0)) + float(r.get("compute_s", 0))
                           for r in rows)}


def _train(stage: int, data: Path, run: Path, *, scale: str, fusion: bool, lm, device: str,
           max_steps: int | None, stride: int | None, seed: int, progress: bool,
           qa: bool = True) -> tuple[dict, str]:
    """One stage through its own function: ``(summary, its summary line)``."""
    common = dict(device=device, max_steps=max_steps, stride=stride, seed=seed,
                  progress=progress)
    if stage == 0:
        from .stage0 import format_stage0_summary, train_stage0

        s = train_stage0(data, run, scale=scale, **common)
        return s, format_stage0_summary(s)
    if stage in (1, 2):
        from .cli import format_summary, train_stage

        s = train_stage(data, run, stage, scale=scale, **common)
        return s, format_summary(s)
    from .stages import format_late_summary, train_late_stage

    s = train_late_stage(data, run, stage, scale=scale, lm=lm if stage == 3 else None,
                         fusion=fusion, qa=qa, **common)
    return s, format_late_summary(s)


def run_pipeline(data: str | Path, out: str | Path, *, scale: str = "default",
                 fusion: bool = True, lm: str | Path | None = None, device: str = "cpu",
                 max_steps: int | None = None, stride: int | None = None, seed: int = 0,
                 progress: bool = True, say: Callable[[str], None] = print,
                 qa: bool = True) -> dict:
    """Stages 0-5 into ``out`` (module docstring).

    Args:
        data: data set folder with Chat-V2XBench items (``v2xbench qa build``).
        out: the run folder RUN. scale: ``tiny``, ``default`` or ``paper``.
        fusion: ``False``: the No Fusion model (stages 3-5). lm: a local Hugging Face causal LM
            as the base LM (stage 0 is then not run). qa: ``False``: stages 3-5 without the
            Chat-V2XBench loss (the VQA ablation, :mod:`.stages`).
        device, seed, progress: as ``aurora train``. max_steps: per stage (the pipeline stops
            after a stage that it leaves incomplete). stride: every k-th frame / QA item in every
            stage (default: each stage's ``frame_stride``).
        say: where the progress lines go.

    Returns:
        The summary written to ``RUN/pipeline_summary.json``: ``stages`` (one row per stage:
        ``stage``, ``name``, ``status`` trained / skipped / not run, ``wall_s`` of this call and
        :func:`stage_record`), ``complete``, ``wall_s``, the settings.

    Raises:
        FileNotFoundError: no data folder or no QA items. ValueError: unknown scale, a complete
            stage of other settings, or what a stage's function refuses.
    """
    from .pairs import QA_FILE

    if scale not in SCALES:
        raise ValueError(f"aurora pipeline: unknown scale {scale!r}; known: {', '.join(SCALES)}")
    data, run = Path(data), Path(out)
    if not data.is_dir():
        raise FileNotFoundError(f"aurora pipeline: data directory {data} does not exist")
    if not (data / QA_FILE).is_file():
        raise FileNotFoundError(f"aurora pipeline: {data / QA_FILE} does not exist (stages 0, 3 "
                                f"and 5 train on it: `v2xbench qa build {data}`)")
    run.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows: list[dict] = []
    with dir_lock(run, "aurora pipeline"):
        for stage in STAGES:
            head = f"[pipeline] stage {stage}/5 ({NAMES[stage]})"
            t = time.perf_counter()
            if stage == 0 and lm is not None:
                say(f"{head}: not run (--lm {lm} is the base LM)")
                rows.append({"stage": 0, "name": NAMES[0], "status": "not run (--lm)",
                             "wall_s": 0.0, **stage_record(run, 0)})
                continue
            if stage_complete(run, stage):
                _check_skipped(run, stage, scale, fusion, qa)
                rec = stage_record(run, stage)
                say(f"{head}: complete ({rec['steps']}/{rec['total_steps']} steps), skipped")
                rows.append({"stage": stage, "name": NAMES[stage], "status": "skipped",
                             "wall_s": 0.0, **rec})
                continue
            say(f"{head}: training -> {run / f'stage{stage}'}")
            _, line = _train(stage, data, run, scale=scale, fusion=fusion, lm=lm,
                             device=device, max_steps=max_steps, stride=stride, seed=seed,
                             progress=progress, qa=qa)
            say(line)
            rec = stage_record(run, stage)
            rows.append({"stage": stage, "name": NAMES[stage], "status": "trained",
                         "wall_s": time.perf_counter() - t, **rec})
            if not stage_complete(run, stage):
                say(f"[pipeline] stopped after stage {stage} at step {rec['steps']}/"
                    f"{rec['total_steps']} (--max-steps); the same command goes on")
                break
        summary = {"format": "v2xbench-aurora-pipeline/1", "run": str(run),
                   "data": str(data.resolve()), "scale": scale, "fusion": bool(fusion),
                   "qa": bool(qa), "lm": None if lm is None else str(lm), "seed": seed,
                   "stride": stride,
                   "max_steps": max_steps, "stages": rows,
                   "complete": all(stage_complete(run, s) for s in STAGES
                                   if not (s == 0 and lm is not None)),
                   "wall_s": time.perf_counter() - t0}
        atomic_write_json(run / f"{SUMMARY}.json", summary, indent=1)
        atomic_write_text(run / f"{SUMMARY}.md", format_pipeline_summary(summary))
    return summary


def format_pipeline_summary(s: dict) -> str:
    """The summary as a Markdown table (one row per stage)."""
    lines = [f"AURORA pipeline {s['run']} (scale {s['scale']}, fusion {s['fusion']}, "
             f"QA loss {s.get('qa', True)}): "
             f"{'complete' if s['complete'] else 'incomplete'}, {s['wall_s']:.0f} s this call",
             "", "| stage | name | status | steps | final losses (mean of last steps) | "
             "train s (all calls) | wall s (this call) |", "|---|---|---|---|---|---|---|"]
    for r in s["stages"]:
        losses = ", ".join(f"{k} {v:.4g}" for k, v in r["final"].items()) or "-"
        total = "?" if r["total_steps"] is None else r["total_steps"]
        lines.append(f"| {r['stage']} | {r['name']} | {r['status']} | {r['steps']}/{total} | "
                     f"{losses} | {r['train_s']:.0f} | {r['wall_s']:.0f} |")
    return "\n".join(lines) + "\n"


__all__ = ["FINAL_STEPS", "NAMES", "STAGES", "format_pipeline_summary", "run_pipeline",
           "stage_complete", "stage_record"]
