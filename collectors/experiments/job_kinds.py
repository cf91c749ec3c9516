"""What each kind of experiment job does: the existing Python functions behind the commands.

=================  ====================================================================  ========
kind               function (command)                                                    writes
=================  ====================================================================  ========
``collect``        ``dataset.collect.collect`` (``v2xbench collect``), ``chat.export.build``  data/
``dataset``        an existing data set folder (``qa: true``: builds its QA items there)  -
``aurora_train``   ``aurora.pipeline.run_pipeline`` (``v2xbench aurora pipeline``)        run/
``baseline_train`` ``BASELINES[m].train.train`` (``v2xbench baselines train M``)          run/
``shipped``        the weights the package ships for the method's agent (no training):      -
                   ``agents/aurora/weights/<agent>`` or ``agents/baselines/weights/<name>``
``perception``     ``aurora.eval_fused.evaluate_fused`` (a fusion run: its fused heads),    eval/
                   ``aurora.eval_perception.evaluate_run`` (No Fusion: its ego branch) or
                   ``evaluate_perception`` of a baseline (``aurora eval-perception
                   [--fused]`` / ``baselines eval-perception``)
``open_loop``      ``aurora.eval_planning.evaluate_planning`` (``aurora eval-planning``)   eval/
                   or ``evaluate_planning`` of a baseline (``baselines eval-planning``)
``closed_loop``    ``collectors.evaluate.evaluate`` (``v2xbench eval``)                   eval/
``vqa``            ``aurora.answer.answer_split`` + ``chat.scoring.score`` (``qa score``)  answers
=================  ====================================================================  ========

Each runner gets the job, its folder ``DIR/<job id>`` and the results of the jobs it names
(``data``, ``run``, ``from``), and returns ``{"outputs": {...}, "metrics": {...}}`` for the job's
``result.json``: ``outputs`` holds paths (absolute), ``metrics`` what the report tabulates.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

from .config import Config, Job, channel_overrides

Runner = Callable[[Job, Path, dict, Config, bool], dict]


class NotAvailable(Exception):
    """A job that cannot run in this checkout (a method's baseline is not registered, a
    training switch does not exist); the run skips it and says why."""


def baseline_module(name: str):
    """The ``train`` module of a registered baseline (``NotAvailable`` when unregistered)."""
    import importlib

    from v2xbench.agents.baselines import BASELINES

    if name not in BASELINES:
        raise NotAvailable(f"baseline {name!r} is not registered (agents/baselines/__init__.py "
                           f"BASELINES has {sorted(BASELINES)})")
    return importlib.import_module(BASELINES[name] + ".train")


def method_available(cfg: Config, method: str | None) -> str | None:
    """Why ``method`` cannot run here (its ``baseline`` is not registered), or ``None``."""
    base = cfg.methods.get(method or "", {}).get("baseline")
    if base is None:
        return None
    from v2xbench.agents.baselines import BASELINES

    if base in BASELINES:
        return None
    return (f"baseline {base!r} is not registered (agents/baselines/__init__.py "
            f"BASELINES has {sorted(BASELINES)})")


def _data(deps: dict, job: Job) -> Path:
    return Path(deps[job.get("data")]["outputs"]["data"])


def _run(deps: dict, job: Job) -> Path:
    return Path(deps[job.get("run")]["outputs"]["run"])


def _is_shipped(deps: dict, job: Job) -> bool:
    """Whether the job's ``run`` is a ``shipped`` job (exported weights, not a training run)."""
    return deps[job.get("run")]["spec"].get("kind") == "shipped"


def _fusion(deps: dict, job: Job) -> bool:
    """Whether the model of the job's ``run`` reads the roadside unit's messages."""
    dep = deps[job.get("run")]
    return bool(dep["metrics"].get("fusion", dep["spec"].get("fusion", True)))


def _collect(job: Job, d: Path, deps: dict, cfg: Config, progress: bool) -> dict:
    from v2xbench.collectors.dataset.collect import CollectConfig, collect

    kw = {k: job.get(k) for k in ("suite", "seeds", "max_routes", "max_ticks", "lidar_scale",
                                  "val_fraction", "env") if job.get(k) is not None}
    if job.get("camera_size") is not None:
        kw["camera_size"] = tuple(job.get("camera_size"))
    if job.get("sensors") is not None:
        kw["sensors"] = tuple(job.get("sensors"))
    root = d / "data"
    manifest = collect(CollectConfig(**kw), root, workers=job.get("workers", 1),
                       progress=progress)
    if not manifest.get("complete"):
        raise RuntimeError(f"collect into {root}: episodes failed: {manifest.get('failed')}")
    out = {"outputs": {"data": str(root.resolve())},
           "metrics": {"episodes": len(manifest["shards"])}}
    if job.get("qa", True):
        out["metrics"]["qa_pairs"] = _build_qa(root)
    return out


def _build_qa(root: Path) -> int:
    from v2xbench.collectors.chat.export import build

    return int(build(root)["stats"]["qa_pairs"])


def _dataset(job: Job, d: Path, deps: dict, cfg: Config, progress: bool) -> dict:
    root = Path(job.get("path")).expanduser()
    if not (root / "manifest.json").is_file():
        raise FileNotFoundError(f"job {job.id}: {root} is not a collected data set (no "
                                "manifest.json; `v2xbench collect --out DIR`)")
    out = {"outputs": {"data": str(root.resolve())}, "metrics": {}}
    if job.get("qa", False):
        out["metrics"]["qa_pairs"] = _build_qa(root)
    return out


def _copy_early_stages(src: Path, run: Path, planner: str | None) -> None:
    """Stages 0-2 of ``src`` into ``run`` (the pipeline then skips them); with ``planner``,
    the run files of stages 1-2 name that planner, which stages 3-5 then train."""
    from v2xbench.agents.aurora.config import AuroraConfig
    from v2xbench.agents.aurora.pipeline import stage_complete

    from v2xbench.files import atomic_write_json

    for s in (0, 1, 2):
        if stage_complete(run, s):
            continue
        if not stage_complete(src, s):
            raise FileNotFoundError(f"{src}/stage{s} is not a complete stage to start from")
        shutil.rmtree(run / f"stage{s}", ignore_errors=True)
        shutil.copytree(src / f"stage{s}", run / f"stage{s}")
        info_path = run / f"stage{s}" / "aurora.json"
        if planner is not None and s in (1, 2):
            import json

            info = json.loads(info_path.read_text())
            info["config"] = AuroraConfig.from_dict({**info["config"], "planner": planner}
                                                    ).to_dict()
            atomic_write_json(info_path, info, indent=1)


def _aurora_train(job: Job, d: Path, deps: dict, cfg: Config, progress: bool) -> dict:
    from v2xbench.agents.aurora.pipeline import run_pipeline

    run = d / "run"
    run.mkdir(parents=True, exist_ok=True)
    if job.get("from") is not None:
        _copy_early_stages(Path(deps[job.get("from")]["outputs"]["run"]), run,
                           job.get("planner"))
    lines: list[str] = []

    def say(msg: str) -> None:
        lines.append(msg)
        if progress:
            print(msg, flush=True)

    s = run_pipeline(_data(deps, job), run, scale=job.get("scale", "default"),
                     fusion=job.get("fusion", True), device=cfg.defaults["device"],
                     max_steps=job.get("max_steps"), stride=job.get("stride"),
                     seed=job.get("seed", 0), progress=progress, say=say,
                     qa=job.get("qa", True))
    if not s.get("complete"):
        raise RuntimeError(f"the pipeline stopped before stage 5 (max_steps={job.get('max_steps')}"
                           f"); its summary: {run}/pipeline_summary.md")
    return {"outputs": {"run": str(run.resolve())},
            "metrics": {"wall_s": s.get("wall_s"), "stages": [
                {"stage": r["stage"], "status": r["status"], "steps": r.get("steps"),
                 "wall_s": r.get("wall_s")} for r in s["stages"]]}}


def _baseline_train(job: Job, d: Path, deps: dict, cfg: Config, progress: bool) -> dict:
    m = baseline_module(cfg.methods[job.method]["baseline"])
    run = d / "run"
    s = m.train(_data(deps, job), run, scale=job.get("scale", "default"),
                device=cfg.defaults["device"], max_steps=job.get("max_steps"),
                stride=job.get("stride"), seed=job.get("seed", 0), progress=progress)
    return {"outputs": {"run": str(run.resolve())},
            "metrics": {"steps": s.get("steps"), "wall_s": s.get("wall_s")}}


def shipped_weights(cfg: Config, method: str) -> Path:
    """The folder of the weights the package ships for ``method``: AURORA's agents (``aurora``,
    ``no_fusion``) in ``agents/aurora/weights/``, a baseline's in ``agents/baselines/weights/``.

    Raises:
        NotAvailable: the package ships no weights for it (the message names where it looked).
    """
    spec = cfg.methods[method]
    agent, base = spec.get("agent", method), spec.get("baseline")
    if base is not None:
        from v2xbench.agents.baselines.common.export import SHIPPED
        folder = SHIPPED / base
    else:
        from v2xbench.agents.aurora.export import SHIPPED
        folder = SHIPPED / agent
    if not (folder / "manifest.json").is_file():
        raise NotAvailable(f"method {method!r}: no shipped weights ({folder}/manifest.json)")
    return folder


def _shipped(job: Job, d: Path, deps: dict, cfg: Config, progress: bool) -> dict:
    folder = shipped_weights(cfg, job.method)
    metrics: dict = {"manifest": json.loads((folder / "manifest.json").read_text())}
    if cfg.methods[job.method].get("baseline") is None:  # AURORA's: its config says fusion
        metrics["fusion"] = bool(json.loads((folder / "aurora.json").read_text()).get("fusion", True))
    return {"outputs": {"run": str(folder.resolve())}, "metrics": metrics}


def _message_bps(floats: int) -> float:
    """Bytes per second of one float16 message a tick (16-byte header, 10 Hz)."""
    return 10.0 * (16 + 2 * int(floats))


def _perception(job: Job, d: Path, deps: dict, cfg: Config, progress: bool) -> dict:
    run, data, out = _run(deps, job), _data(deps, job), d / "eval"
    kw = {"stride": job.get("stride", 1), "top_k": job.get("top_k", 50),
          "batch_size": job.get("batch_size", 4), "device": cfg.defaults["device"],
          "progress": progress}
    base = cfg.methods[job.method].get("baseline")
    split = job.get("split", "test")
    if base is not None:
        r = baseline_module(base).evaluate_perception(run, data, split, out=out, **kw)
        row, bps = r["table"], 10.0 * r["message_bytes"]
        how = {"evaluator": "fused detections", "ground_truth": "gt/fused"}
    elif _is_shipped(deps, job):
        raise NotAvailable(f"job {job.id}: AURORA's perception evaluation reads a training run's "
                           "stages; the shipped weights hold only the final model")
    elif _fusion(deps, job):
        from v2xbench.agents.aurora.config import AuroraConfig
        from v2xbench.agents.aurora.eval_fused import evaluate_fused
        from v2xbench.agents.aurora.rsu_agent import message_floats

        r = evaluate_fused(run, data, split, out, stage=job.get("stage"), **kw)
        row = r["table"]
        bps = _message_bps(message_floats(AuroraConfig.for_scale(r["scale"])))
        how = {"evaluator": f"fused heads (CQAF, stage {r['stage']})",
               "ground_truth": "gt/fused", "ego_gt": r["tables"]["fused@ego"],
               "ego_branch": r["tables"]["ego_branch@ego"]}
    else:  # No Fusion: no roadside input, its perception is the ego branch (stage 1)
        from v2xbench.agents.aurora.eval_perception import evaluate_run

        r = evaluate_run(run, data, split, out, pictures=0, **kw)
        row, bps = r["branches"]["ego"]["table"], 0.0
        how = {"evaluator": "ego branch (stage 1)", "ground_truth": "gt/ego"}
    return {"outputs": {"eval": str(out.resolve())},
            "metrics": {**{k: row.get(k) for k in ("avg_mAP", "NDS", "vehicle", "vru",
                                                  "traffic_light", "traffic_sign")},
                        "message_bps": bps, **how}}


def _open_loop(job: Job, d: Path, deps: dict, cfg: Config, progress: bool) -> dict:
    out = d / "eval"
    kw = {"split": job.get("split", "test"), "stride": job.get("stride", 50), "out": out,
          "device": cfg.defaults["device"], "progress": progress}
    base = cfg.methods[job.method].get("baseline")
    if base is not None:
        r = baseline_module(base).evaluate_planning(_run(deps, job), _data(deps, job),
                                                    batch_size=job.get("batch_size", 4), **kw)
    else:
        from v2xbench.agents.aurora.eval_planning import evaluate_planning

        model = {"weights" if _is_shipped(deps, job) else "run": _run(deps, job)}
        r = evaluate_planning(_data(deps, job), stage=job.get("stage"),
                              batch_size=job.get("batch_size", 8), **model, **kw)
    m = r["overall"]["model"]
    return {"outputs": {"eval": str(out.resolve())},
            "metrics": {**m, "frames": r["overall"]["frames"],
                        "l2_avg": sum(m[f"l2_{h}s"] for h in (1, 2, 3)) / 3.0,
                        "collision_avg": sum(m[f"collision_{h}s"] for h in (1, 2, 3)) / 3.0}}


def closed_loop_settings(job: Job, cfg: Config, deps: dict) -> dict:
    """The keyword arguments of ``evaluate`` for a closed-loop job (env overrides with the
    job's channel settings, the agent config naming the trained run)."""
    agent_cfg = dict(job.get("agent_config", {}))
    if job.get("run") is not None and not _is_shipped(deps, job):  # shipped: the agent's default
        agent_cfg["run"] = str(_run(deps, job))
    if job.get("stage") is not None:
        agent_cfg["stage"] = job.get("stage")
    env = {**job.get("set", {}), **channel_overrides(job.get("channel"))}
    return {"agent": cfg.methods[job.method].get("agent", job.method), "suite": job.get("suite"),
            "seeds": job.get("seeds", 1), "workers": job.get("workers", cfg.defaults["workers"]),
            "max_routes": job.get("max_routes"), "routes": job.get("routes"),
            "scenario": job.get("scenario"), "v2x_only": job.get("v2x_only", False),
            "config": env, "agent_config": agent_cfg or None,
            "agent_name": cfg.label(job.method)}


def _closed_loop(job: Job, d: Path, deps: dict, cfg: Config, progress: bool) -> dict:
    from v2xbench.collectors.evaluate import evaluate

    kw = closed_loop_settings(job, cfg, deps)
    for key in ("route_timeout", "backend", "address"):
        if job.get(key) is not None:
            kw[key] = job.get(key)
    out = d / "eval"
    s = evaluate(out=out, progress=progress, **kw)
    m = s["metrics"]
    keep = ("driving_score", "driving_score_ci_low", "driving_score_ci_high",
            "route_completion", "infraction_score", "efficiency", "comfortness", "bps")
    return {"outputs": {"eval": str(out.resolve())},
            "metrics": {**{k: m.get(k) for k in keep}, "n_jobs": s["n_jobs"],
                        "failed": sum(s["failed"].values()),
                        "channel": job.get("channel", {})}}


def _vqa(job: Job, d: Path, deps: dict, cfg: Config, progress: bool) -> dict:
    if cfg.methods[job.method].get("baseline") is not None:
        raise NotAvailable(f"baseline method {job.method!r} answers no Chat-V2XBench questions")
    from v2xbench.agents.aurora.answer import answer_split
    from v2xbench.collectors.chat.export import load_items, split_items
    from v2xbench.collectors.chat.scoring import load_predictions, score

    split = job.get("split", "test")
    out = d / "answers.jsonl"
    r = answer_split(_run(deps, job), _data(deps, job), split, out, stage=job.get("stage", 5),
                     stride=job.get("stride", 1), batch_size=job.get("batch_size", 32),
                     max_new_tokens=job.get("max_new_tokens", 192),
                     device=cfg.defaults["device"], progress=progress)
    s = score(split_items(load_items(r["qa"]), split, "vqa"), load_predictions(out))
    return {"outputs": {"answers": str(out.resolve())},
            "metrics": {"items": r["items"], "closed_accuracy": s["closed"]["accuracy"],
                        "descriptive_f1": s["descriptive"]["f1"],
                        "coordinate_error_m": s["coordinate"]["mean_error_m"], "score": s}}


RUNNERS: dict[str, Runner] = {
    "collect": _collect, "dataset": _dataset, "aurora_train": _aurora_train,
    "baseline_train": _baseline_train, "shipped": _shipped, "perception": _perception, "open_loop": _open_loop,
    "closed_loop": _closed_loop, "vqa": _vqa,
}

__all__ = ["RUNNERS", "NotAvailable", "baseline_module", "closed_loop_settings",
           "method_available", "shipped_weights"]
