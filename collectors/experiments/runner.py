"""``v2xbench experiments run``: the jobs of a config in dependency order, resumable.

Every job works in ``DIR/<job id>/`` and ends with one file written atomically:
``result.json`` (:data:`RESULT`: the job's spec, outputs, metrics, elapsed time) when it
succeeded, ``failed.json`` (:data:`FAILED`: error and traceback) when it raised. A job whose
``result.json`` exists is skipped (its spec must be the one in the config: a changed job is
refused, naming it, so that no table mixes settings); a failed job runs again on the next call.
A failing job does not stop the run: the jobs that need it are ``blocked``, the others go on. A
job of a method whose baseline is not registered, or one that needs a switch this checkout lacks,
is ``not available`` (said with the reason, not an error). ``DIR/experiments.json`` holds every
job's status after each job, ``DIR/config.json`` the config the report reads; the run holds
``dir_lock(DIR)``.
"""

from __future__ import annotations

import json
import sys
import time
import traceback
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

from v2xbench.files import atomic_write_json, check_output_dir, remove_stale_tmp
from v2xbench.locks import dir_lock

from .config import Config, Job, load_config, parse_config
from .job_kinds import RUNNERS, NotAvailable, method_available

RESULT = "result.json"
FAILED = "failed.json"
STATE = "experiments.json"
CONFIG_COPY = "config.json"
FORMAT = "v2xbench-experiment-job/1"


def _now() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def read_result(out: Path, job_id: str) -> dict | None:
    """The ``result.json`` of a job in ``out`` (``None`` when there is none)."""
    p = Path(out) / job_id / RESULT
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except ValueError:
        return None  # a file that does not read back: the job runs again


def load_config_copy(out: str | Path, who: str = "experiments") -> Config:
    """The config a run wrote into its folder (:data:`CONFIG_COPY`), parsed.

    Raises:
        FileNotFoundError: ``out`` holds no config copy (no run yet; the message, led by ``who``,
            names it).
    """
    copy = Path(out) / CONFIG_COPY
    if not copy.is_file():
        raise FileNotFoundError(f"{who}: {out} holds no experiment ({copy} is missing; `v2xbench "
                                "experiments run --config FILE --out DIR`)")
    saved = json.loads(copy.read_text())
    return parse_config(saved["config"], saved.get("source", str(copy)))


def _same_spec(old: dict, job: Job) -> bool:
    return json.loads(json.dumps(old.get("spec"))) == json.loads(json.dumps(job.spec))


def run_experiments(config: str | Path | Config, out: str | Path, *, progress: bool = False,
                    say: Callable[[str], None] | None = None) -> dict:
    """Run (or resume) every job of ``config`` into ``out`` (module docstring).

    Args:
        config: a config file or a parsed :class:`~.config.Config`.
        out: the experiment folder DIR.
        progress: show each job's own progress bars and lines (else one line per job).
        say: where the per-job lines go (default: stderr).

    Returns:
        The state written to ``DIR/experiments.json``: ``jobs`` (id -> status, elapsed_s,
        reason), ``counts`` per status, ``wall_s``.

    Raises:
        ConfigError: a bad config. ValueError: ``out`` is locked or not a folder, or a job's
            result was made with another spec than the config's.
    """
    import torch

    cfg = config if isinstance(config, Config) else load_config(config)
    out = check_output_dir(out, "experiment folder")
    say = say or (lambda m: print(m, file=sys.stderr, flush=True))
    torch.set_num_threads(int(cfg.defaults["threads"]))
    with dir_lock(out, "experiments run"):
        for j in cfg.jobs:  # refuse before any job runs
            old = read_result(out, j.id)
            if old is not None and not _same_spec(old, j):
                raise ValueError(f"job {j.id!r}: {out / j.id / RESULT} was made with another "
                                 f"spec ({json.dumps(old.get('spec'), sort_keys=True)}) than "
                                 f"the config's ({json.dumps(j.spec, sort_keys=True)}); delete "
                                 f"{out / j.id} to run it again, or use another folder")
        atomic_write_json(out / CONFIG_COPY, {"source": cfg.source, "config": cfg.raw}, indent=1)
        return _run_all(cfg, out, progress, say)


def _run_all(cfg: Config, out: Path, progress: bool, say: Callable[[str], None]) -> dict:
    t0 = time.perf_counter()
    from v2xbench.benchmarks.suite import machine

    state: dict = {"config": cfg.name, "source": cfg.source, "started": _now(),
                   "machine": machine(), "jobs": {}}
    results: dict[str, dict] = {}
    n = len(cfg.jobs)
    for k, job in enumerate(cfg.jobs, 1):
        head = f"[experiments {k}/{n}] {job.id} ({job.kind})"
        rec = _one(cfg, job, out, results, state["jobs"], progress,
                   lambda h=head: say(f"{h}: running ..."))
        state["jobs"][job.id] = rec
        st = rec["status"]
        if st == "done":
            say(f"{head}: done in {rec['elapsed_s']:.1f} s")
        elif st == "skipped":
            say(f"{head}: skipped, result exists ({out / job.id / RESULT})")
        elif st == "failed":
            say(f"{head}: FAILED after {rec['elapsed_s']:.1f} s: {rec['reason']} (details: "
                f"{out / job.id / FAILED})")
        else:
            say(f"{head}: {st}: {rec['reason']}")
        state["counts"] = {s: sum(r["status"] == s for r in state["jobs"].values())
                           for s in ("done", "skipped", "failed", "blocked", "not available")}
        state["wall_s"] = round(time.perf_counter() - t0, 1)
        atomic_write_json(out / STATE, state, indent=1)
    state["finished"] = _now()
    atomic_write_json(out / STATE, state, indent=1)
    c = state["counts"]
    say(f"[experiments] {c['done']} done, {c['skipped']} skipped (results existed), "
        f"{c['failed']} failed, {c['blocked']} blocked, {c['not available']} not available in "
        f"{state['wall_s']:.0f} s; results in {out}")
    return state


def _one(cfg: Config, job: Job, out: Path, results: dict, done: dict, progress: bool,
         starting: Callable[[], None]) -> dict:
    """Run or skip one job (``results``: those of the jobs before it; ``done``: their state
    records; ``starting`` is called when it is about to run); returns its state record."""
    d = out / job.id
    old = read_result(out, job.id)
    if old is not None:
        results[job.id] = old
        return {"status": "skipped", "elapsed_s": old.get("elapsed_s"), "reason": None}
    why = method_available(cfg, job.method)
    if why is not None:
        return {"status": "not available", "elapsed_s": 0.0, "reason": why}
    for dep in job.deps:
        if dep not in results:
            rec = done.get(dep, {})
            if rec.get("status") == "not available":
                return {"status": "not available", "elapsed_s": 0.0,
                        "reason": f"needs job {dep!r}, not available: {rec.get('reason')}"}
            return {"status": "blocked", "elapsed_s": 0.0,
                    "reason": f"needs job {dep!r}, which has no result ({rec.get('status')})"}
    starting()
    d.mkdir(parents=True, exist_ok=True)
    remove_stale_tmp(d)
    (d / FAILED).unlink(missing_ok=True)
    t = time.perf_counter()
    try:
        r = RUNNERS[job.kind](job, d, {x: results[x] for x in job.deps}, cfg, progress)
    except NotAvailable as e:
        return {"status": "not available", "elapsed_s": 0.0, "reason": str(e)}
    except Exception as e:  # noqa: BLE001  (recorded; the run goes on without it)
        elapsed = time.perf_counter() - t
        reason = f"{type(e).__name__}: {e}"
        atomic_write_json(d / FAILED, {"id": job.id, "kind": job.kind, "spec": job.spec,
                                       "error": reason, "elapsed_s": round(elapsed, 2),
                                       "finished": _now(), "traceback": traceback.format_exc()},
                          indent=1)
        return {"status": "failed", "elapsed_s": round(elapsed, 2), "reason": reason}
    elapsed = time.perf_counter() - t
    result = {"format": FORMAT, "id": job.id, "kind": job.kind, "method": job.method,
              "spec": job.spec, "status": "done", "elapsed_s": round(elapsed, 2),
              "finished": _now(), **r}
    atomic_write_json(d / RESULT, result, indent=1, default=_json_default)
    results[job.id] = json.loads((d / RESULT).read_text())
    return {"status": "done", "elapsed_s": round(elapsed, 2), "reason": None}


def _json_default(x):
    import numpy as np

    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"{type(x).__name__} is not JSON serializable")


__all__ = ["CONFIG_COPY", "FAILED", "RESULT", "STATE", "load_config_copy", "read_result",
           "run_experiments"]
