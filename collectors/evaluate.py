"""Closed-loop evaluation of an agent on a route suite through TorchRL collectors.

::

    from v2xbench.collectors.evaluate import evaluate

    if __name__ == "__main__":          # needed: the routes run in worker processes
        summary = evaluate("route_follower", suite="test50", seeds=3, workers=2, out="results/rf")

or ``v2xbench eval --agent route_follower --suite test50 --seeds 3 --workers 2 --out results/rf``.

The jobs are the suite's routes x ``seeds`` seed indices (``jobs.py``: job ``{route_id}_s{k}``,
world seed ``route seed + 1000 k``). ``workers`` worker processes each run a
``torchrl.collectors.Collector`` over one :class:`~.eval_env.EvalEnv` that claims jobs from the
shared queue in ``<out>/claims`` and writes ``<out>/routes/<job>.json``. The harness supervises
them (``eval_workers.py``): a job that runs longer than ``route_timeout`` seconds of wall clock,
or whose worker dies (``os._exit`` in the agent, a crash), is recorded as that job's failure
(result ``failure = "timeout"`` / ``"error"``, ``ended_by = "error"``, DS 0) and a new worker
takes the remaining jobs. When every job has a result it writes ``<out>/summary.json`` and
``<out>/summary.md`` (:func:`summarize`).

The run holds ``v2xbench.locks.dir_lock(out)`` from start to end: a second evaluation on the same
``out`` is refused (``DirectoryLocked`` names the holder). Running again on the same ``out``
resumes: finished jobs are skipped; claims and temporary files left by an interrupted run are
removed, and a result file that does not read back (empty, truncated) is removed with a warning
naming it, so its job runs again.

``agent`` is a registered agent name, ``path/to/file.py:ClassName``, a picklable zero-argument
factory, or a TorchRL policy (a ``TensorDictModule`` reading the observation keys of
:class:`~.eval_env.EvalEnv` and writing ``action``); factories and policies must be picklable
(they are sent to the worker processes).

Trust: ``path/to/file.py:ClassName`` executes that file: in this process (the agent is built
once to fail early) and in every worker, or only in the agent's own process with
``isolate_agent`` (docs/evaluation.md, "Trust"). Only the built-in expert and oracles are
privileged (``interface.PRIVILEGED_AGENTS``;
results and summary record the harness's decision, not the agent's claim). With
``isolate_agent=True`` (``--isolate-agent``) a protocol agent runs in a process of its own and
sees only ``route_info`` and its observations (``agent_process.py``); privileged agents and
TorchRL policies cannot be isolated (``ValueError``). Every result and the summary record
``agent_process`` (``"isolated"`` or ``"in_process"``), and a directory holds one or the other:
resuming with the other setting is refused like resuming with another agent.

Summary (``metrics.aggregate`` over routes x seeds, bootstrap 95% CI of DS): DS, RC, IS,
Efficiency, Comfortness, BPS, infractions per km; the same restricted to routes that contain a
V2X scenario type (``v2x``); per scenario type: instances, success rate (passed with no collision
in the scenario window and no timeout), collision and timeout rates, mean DS of the runs whose
route contains the type (failed or missing runs count 0).
"""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from v2xbench.envs.v2x_intersection.metrics import ENDED_BY_NAMES, ENDED_ERROR, aggregate
from v2xbench.envs.v2x_intersection.route_files import load_suite_cached
from v2xbench.envs.v2x_intersection.scenarios import get_scenario

from v2xbench.files import atomic_write_text, check_output_dir, remove_stale_tmp
from v2xbench.locks import dir_lock

from . import jobs as J
from .eval_env import agent_label, copy_policy, instantiate_agent, make_env_factory
from .eval_workers import DEFAULT_ROUTE_TIMEOUT_S, check_route_timeout, run_jobs
from .route_log import FAILURE_KINDS, build_result

FRAMES_PER_WORKER = 64  # collector frames per worker between two looks for more work


def _is_policy(agent: Any) -> bool:
    return isinstance(agent, torch.nn.Module)


def _suite_key(suite: str) -> str:
    p = Path(suite)
    return str(p.resolve()) if p.suffix else str(suite)


def _check_manifest(out: Path, manifest: dict) -> None:
    """Refuse to mix results of another agent, suite or config in one directory."""
    path = out / "run.json"
    if path.is_file():
        try:
            old = json.loads(path.read_text())
            if not isinstance(old, dict):
                raise ValueError(f"a JSON {type(old).__name__}, not an object")
        except ValueError as e:
            raise ValueError(f"{path} is unreadable ({e}); it says what this directory holds, so "
                             "fix or delete it (or use another --out)") from None
        old.setdefault("agent_process", "in_process")  # directories written before isolation existed
        for key in ("agent", "suite_key", "config_overrides", "agent_process"):
            if old.get(key) != manifest[key]:
                raise ValueError(f"{out} holds results with {key}={old.get(key)!r}, not {manifest[key]!r}; "
                                 "use another --out (or delete it) to start afresh")
    J.write_json_atomic(manifest, path)


def _clean(out: Path) -> None:
    """Remove the temporary files that killed writers left in ``out`` and its result folders."""
    for d in (out, J.routes_dir(out), out / "videos"):
        remove_stale_tmp(d)


def evaluate(agent: Any = "route_follower", suite: str = "test50", seeds: int = 1, workers: int = 1,
             out: str | Path = "results/eval", video: bool = False, max_routes: int | None = None,
             config: Mapping[str, Any] | None = None, *, agent_name: str | None = None,
             frames_per_batch: int = FRAMES_PER_WORKER, progress: bool = True,
             n_boot: int = 2000, isolate_agent: bool = False,
             route_timeout: float = DEFAULT_ROUTE_TIMEOUT_S) -> dict:
    """Evaluate ``agent`` on ``suite`` and return the summary (see module docstring).

    Args:
        agent: registered name, ``path.py:Class``, picklable factory, or TorchRL policy module.
        suite: suite name (``test50``, ``val``, ``train``) or path to a suite JSON.
        seeds: seed indices per route. workers: worker processes running jobs at a time.
        out: output directory (created; resumed when it holds results of the same run; locked
            while the run lasts).
        video: a top-down GIF per route in ``<out>/videos``.
        max_routes: only the first ``max_routes`` routes of the suite.
        config: ``EnvConfig`` overrides (e.g. ``{"num_vehicles": 10}``).
        agent_name: display name (default: from the spec, factory or module class).
        frames_per_batch: frames per worker between two progress checks.
        isolate_agent: run the agent in a separate process from the simulator (module docstring).
        route_timeout: wall-clock limit of one job in seconds (a job that overruns fails).

    Returns:
        The summary dict also written to ``<out>/summary.json``.

    Raises:
        ValueError: a bad argument, agent or suite, ``out`` is a file or another run holds it
            (``v2xbench.locks.DirectoryLocked``), results of another run are in ``out``.
        RuntimeError: the workers cannot start (their output says why).
    """
    torch.set_num_threads(1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers={workers!r} must be a positive int")
    route_timeout = check_route_timeout(route_timeout)
    out = check_output_dir(out, "evaluation output directory")
    routes = load_suite_cached(str(suite))
    jobs = J.make_jobs([r.id for r in routes], seeds, max_routes)
    policy_mode = _is_policy(agent)
    spec, name = agent_label(None if policy_mode else agent)
    if policy_mode:
        spec = name = agent_name or type(agent).__name__
    name = agent_name or name
    if isolate_agent and policy_mode:
        raise ValueError("--isolate-agent needs a protocol agent; a TorchRL policy runs in the collector "
                         "(wrap it in agents.torchrl_policy.TensorDictPolicyAgent)")
    privileged = False
    if not policy_mode:
        from v2xbench.agents.interface import granted_privilege

        privileged = granted_privilege(agent)
        if isolate_agent and privileged:
            raise ValueError(f"agent {spec!r} is privileged (it reads the simulator) and cannot run "
                             "isolated; evaluate it without --isolate-agent")
    if not isinstance(agent, str):  # workers get the agent or policy pickled
        import pickle

        try:
            pickle.dumps(agent)
        except Exception as e:  # noqa: BLE001
            what = "policy" if policy_mode else "agent factory"
            raise ValueError(f"{what} {agent!r} is not picklable ({e}); the worker processes need a "
                             "top-level class or function, or a spec string") from None
    if not policy_mode:  # a bad agent fails here, not in every worker process
        try:
            probe = instantiate_agent(agent, isolate_agent)
        except SystemExit as e:
            raise ValueError(f"agent {spec!r} raised SystemExit({e}) while being built") from None
        if isolate_agent:
            probe.close()
    cfg = json.loads(json.dumps(J.to_json_safe(dict(config or {}))))  # as it reads back from run.json
    manifest = {"agent": spec, "agent_name": name, "suite": str(suite), "suite_key": _suite_key(str(suite)),
                "config_overrides": cfg, "policy": policy_mode, "privileged": privileged,
                "agent_process": "isolated" if isolate_agent else "in_process"}
    with dir_lock(out, "evaluation"):
        _check_manifest(out, manifest)
        _clean(out)
        J.discard_unreadable_results(out, jobs)
        J.clear_stale_claims(out)
        t0 = time.perf_counter()
        before = {j.job_id for j in jobs if J.has_result(out, j.job_id)}
        stats = {"workers_started": 0, "timeouts": 0, "workers_died": 0}
        if len(before) < len(jobs):
            env_fn = make_env_factory(suite=str(suite), out=str(out), agent=None if policy_mode else agent,
                                      jobs=jobs, video=video, config=cfg, agent_name=name,
                                      isolate=isolate_agent)
            policy = agent if policy_mode else copy_policy()
            record = _failure_recorder(out, manifest, routes)
            stats = _run(env_fn, policy, workers, frames_per_batch, out, jobs, progress, name,
                         route_timeout, record)
            _clean(out)
        wall = time.perf_counter() - t0
        new = [r for r in J.read_results(out, jobs) if r["job_id"] not in before]
        ran, ticks = len(new), sum(int(r["ticks"]) for r in new)
        summary = summarize(out, jobs, n_boot=n_boot)
        summary["run"] = {"workers": workers, "wall_seconds": round(wall, 2), "jobs_run": ran,
                          "routes_per_minute": round(60.0 * ran / wall, 2) if ran and wall > 0 else None,
                          "sim_ticks": ticks, "ticks_per_second": round(ticks / wall, 1) if wall > 0 else None,
                          "video": bool(video), "route_timeout_s": route_timeout, **stats}
        write_summary(out, summary)
    return summary


def _failure_recorder(out: Path, manifest: dict, routes) -> Callable:
    """``record(job, kind, error, wall_s)``: write the result of a job its worker did not finish."""

    def record(job: J.Job, kind: str, error: BaseException, wall_s: float) -> None:
        spec = routes[job.route_index]
        res = build_result(job=job, spec=spec, seed=J.job_seed(spec.seed, job.seed_index),
                           suite=manifest["suite"], agent=manifest["agent"],
                           agent_name=manifest["agent_name"], privileged=manifest["privileged"],
                           agent_process=manifest["agent_process"], log=None, ended_by=ENDED_ERROR,
                           wall_s=wall_s, error=error, config=manifest["config_overrides"],
                           failure=kind)
        J.write_json_atomic(res, J.result_path(out, job.job_id))

    return record


def _run(env_fn: Callable, policy, workers: int, fpb: int, out: Path, jobs: list, progress: bool,
         name: str, route_timeout: float, record_failure: Callable) -> dict:
    """Run the jobs in supervised workers until every job has a result (``eval_workers.py``);
    ``record_failure`` writes the result of a job whose worker timed out or died."""
    return run_jobs(env_fn, policy, workers=workers, out=out, jobs=jobs,
                    record_failure=record_failure, route_timeout=route_timeout,
                    frames_per_batch=fpb, progress=progress, desc=f"eval {name}")


# ------------------------------------------------------------------------------------ summary


def summarize(out: str | Path, jobs: list[J.Job], n_boot: int = 2000) -> dict:
    """Suite summary of the results of ``jobs`` in ``out`` (see module docstring)."""
    out = Path(out)
    manifest = json.loads((out / "run.json").read_text())
    routes = load_suite_cached(manifest["suite"])
    results = {r["job_id"]: r for r in J.read_results(out, jobs)}
    n_routes = len({j.route_index for j in jobs})
    seeds = len({j.seed_index for j in jobs})

    def metric_dicts(sel):
        return [dict(results[j.job_id]["metrics"]) for j in sel if j.job_id in results]

    overall = aggregate(metric_dicts(jobs), n_routes, seeds, n_boot=n_boot)
    is_v2x = {i: any(get_scenario(s.type).v2x for s in routes[i].scenarios) for i in range(len(routes))}
    v2x_jobs = [j for j in jobs if is_v2x[j.route_index]]
    n_v2x = len({j.route_index for j in v2x_jobs})
    v2x = aggregate(metric_dicts(v2x_jobs), n_v2x, seeds, n_boot=n_boot) if n_v2x else {}
    ended = Counter(results[j.job_id]["ended_by"] for j in jobs if j.job_id in results)
    failures = [{"job_id": r["job_id"], "failure": _failure_kind(r), "error": r["error"]}
                for r in results.values() if _failure_kind(r)]
    failed = Counter(f["failure"] for f in failures)
    first = next(iter(results.values()), {})
    return {
        "agent": manifest["agent"], "agent_name": manifest["agent_name"], "suite": manifest["suite"],
        "privileged": bool(manifest.get("privileged", first.get("privileged", False))),
        "agent_process": manifest.get("agent_process", "in_process"), "seeds": seeds, "n_routes": n_routes,
        "n_jobs": len(jobs), "n_results": len(results), "config_overrides": manifest["config_overrides"],
        "metrics": overall, "v2x": v2x, "n_v2x_routes": n_v2x,
        "per_scenario": per_scenario(routes, jobs, results),
        "ended_by": {k: ended.get(k, 0) for k in ENDED_BY_NAMES},
        "failed": {k: failed.get(k, 0) for k in FAILURE_KINDS}, "failures": failures,
    }


def _failure_kind(result: dict) -> str | None:
    """``"error"`` / ``"timeout"`` for a failed route, ``None`` otherwise (results written before
    the ``failure`` key existed: from ``error``)."""
    return result.get("failure") or ("error" if result.get("error") else None)


def per_scenario(routes, jobs: list[J.Job], results: dict[str, dict]) -> dict[str, dict]:
    """Per scenario type: instances, success / collision / timeout rates, mean DS of its runs."""
    acc: dict[str, dict] = {}
    for j in jobs:
        res = results.get(j.job_id)
        ds = float(res["metrics"]["driving_score"]) if res else 0.0
        outcomes = res["scenarios"] if res else [None] * len(routes[j.route_index].scenarios)
        types = [s.type for s in routes[j.route_index].scenarios]
        for typ in set(types):
            a = acc.setdefault(typ, {"v2x": bool(get_scenario(typ).v2x), "instances": 0, "success": 0,
                                     "collision": 0, "timed_out": 0, "ds": []})
            a["ds"].append(ds if np.isfinite(ds) else 0.0)
        for typ, o in zip(types, outcomes):
            a = acc[typ]
            a["instances"] += 1
            if o is not None:
                a["success"] += bool(o["success"])
                a["collision"] += bool(o["collision"])
                a["timed_out"] += bool(o["timed_out"])
    table = {}
    for typ in sorted(acc):
        a = acc[typ]
        n = max(a["instances"], 1)
        table[typ] = {"v2x": a["v2x"], "instances": a["instances"], "runs": len(a["ds"]),
                      "success_rate": 100.0 * a["success"] / n, "collision_rate": 100.0 * a["collision"] / n,
                      "timeout_rate": 100.0 * a["timed_out"] / n, "mean_ds": float(np.mean(a["ds"]))}
    return table


def _f(x: Any, nd: int = 1) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{nd}f}"


def summary_markdown(s: dict) -> str:
    """The markdown report of a summary dict."""
    m, v = s["metrics"], s.get("v2x") or {}
    lines = [f"# {s['agent_name']} on {s['suite']}", "",
             f"Agent `{s['agent']}`{' (privileged)' if s['privileged'] else ''}"
             f"{' (isolated process)' if s.get('agent_process') == 'isolated' else ''}; {s['n_routes']} routes x "
             f"{s['seeds']} seeds = {s['n_jobs']} runs, {s['n_results']} with results.", ""]
    if s.get("config_overrides"):
        lines += [f"Config overrides: `{s['config_overrides']}`", ""]
    lines += ["| metric | all routes | V2X-type routes |", "|---|---|---|"]
    ci = f"{_f(m['driving_score'])} [{_f(m['driving_score_ci_low'])}, {_f(m['driving_score_ci_high'])}]"
    vci = (f"{_f(v['driving_score'])} [{_f(v['driving_score_ci_low'])}, {_f(v['driving_score_ci_high'])}]"
           if v else "-")
    lines.append(f"| Driving score (95% CI) | {ci} | {vci} |")
    for key, label, nd in (("route_completion", "Route completion", 1), ("infraction_score", "Infraction score", 3),
                           ("efficiency", "Efficiency", 1), ("comfortness", "Comfortness", 1),
                           ("bps", "BPS (bytes/s)", 0), ("peak_bps", "Peak BPS", 0),
                           ("km_completed", "km completed", 2)):
        lines.append(f"| {label} | {_f(m.get(key), nd)} | {_f(v.get(key), nd) if v else '-'} |")
    per_km = sorted(k for k in m if k.endswith("_per_km"))
    if per_km:
        lines += ["", "| infraction | per km |", "|---|---|"]
        lines += [f"| {k[:-7]} | {_f(m[k], 3)} |" for k in per_km]
    lines += ["", "| scenario type | V2X | instances | success % | collision % | timeout % | mean DS |",
              "|---|---|---|---|---|---|---|"]
    for typ, r in s["per_scenario"].items():
        lines.append(f"| {typ} | {'yes' if r['v2x'] else 'no'} | {r['instances']} | {_f(r['success_rate'])} | "
                     f"{_f(r['collision_rate'])} | {_f(r['timeout_rate'])} | {_f(r['mean_ds'])} |")
    lines += ["", "Routes ended by: " + ", ".join(f"{k} {n}" for k, n in s["ended_by"].items() if n)]
    if s.get("failures"):
        lines += ["", "Failed runs:", *[f"- `{f['job_id']}` ({f.get('failure') or 'error'}): {f['error']}"
                                         for f in s["failures"]]]
    if s.get("run"):
        r = s["run"]
        lines += ["", f"Run: {r['jobs_run']} runs ({r.get('sim_ticks', 0)} ticks) in {r['wall_seconds']} s on "
                  f"{r['workers']} worker(s)" + (f": {r['routes_per_minute']} routes/min, "
                                                 f"{r['ticks_per_second']} ticks/s." if r.get("routes_per_minute") else ".")]
    return "\n".join(lines) + "\n"


def write_summary(out: str | Path, summary: dict) -> None:
    """Write ``summary.json`` and ``summary.md`` into ``out``."""
    out = Path(out)
    J.write_json_atomic(summary, out / "summary.json")
    atomic_write_text(out / "summary.md", summary_markdown(summary))
