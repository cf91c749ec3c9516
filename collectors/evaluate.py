"""Closed-loop evaluation of an agent on a route suite through TorchRL collectors.

::

    from v2xbench.collectors.evaluate import evaluate

    if __name__ == "__main__":          # needed with workers > 1 (spawned worker processes)
        summary = evaluate("route_follower", suite="test50", seeds=3, workers=2, out="results/rf")

or ``v2xbench eval --agent route_follower --suite test50 --seeds 3 --workers 2 --out results/rf``.

The jobs are the suite's routes x ``seeds`` seed indices (``jobs.py``: job ``{route_id}_s{k}``,
world seed ``route seed + 1000 k``). Each collector worker holds one :class:`~.eval_env.EvalEnv`
that claims jobs from the shared queue in ``<out>/claims`` and writes ``<out>/routes/<job>.json``;
``workers == 1`` runs a ``torchrl.collectors.Collector`` in this process, more run a
``MultiSyncCollector`` (spawned processes). The harness iterates the collector's batches, counts
result files for the progress bar and stops when every job has a result, then writes
``<out>/summary.json`` and ``<out>/summary.md`` (:func:`summarize`). Running again on the same
``out`` resumes: finished jobs are skipped, claims left by an interrupted run are cleared.

``agent`` is a registered agent name, ``path/to/file.py:ClassName``, a picklable zero-argument
factory, or a TorchRL policy (a ``TensorDictModule`` reading the observation keys of
:class:`~.eval_env.EvalEnv` and writing ``action``; it must be picklable for ``workers > 1``).

Trust: only the built-in expert and oracles are privileged (``interface.PRIVILEGED_AGENTS``;
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
from v2xbench.envs.v2x_intersection.metrics import ENDED_BY_NAMES, aggregate
from v2xbench.envs.v2x_intersection.route_files import load_suite_cached
from v2xbench.envs.v2x_intersection.scenarios import get_scenario

from . import jobs as J
from .eval_env import agent_label, copy_policy, instantiate_agent, make_env_factory

FRAMES_PER_WORKER = 64  # collector frames per worker and batch (the harness checks progress per batch)
SHUTDOWN_TIMEOUT_S = 3.0  # s for the workers to exit after the last result (then terminated)


def _is_policy(agent: Any) -> bool:
    return isinstance(agent, torch.nn.Module)


def _suite_key(suite: str) -> str:
    p = Path(suite)
    return str(p.resolve()) if p.suffix else str(suite)


def _check_manifest(out: Path, manifest: dict) -> None:
    """Refuse to mix results of another agent, suite or config in one directory."""
    path = out / "run.json"
    if path.is_file():
        old = json.loads(path.read_text())
        old.setdefault("agent_process", "in_process")  # directories written before isolation existed
        for key in ("agent", "suite_key", "config_overrides", "agent_process"):
            if old.get(key) != manifest[key]:
                raise ValueError(f"{out} holds results with {key}={old.get(key)!r}, not {manifest[key]!r}; "
                                 "use another --out (or delete it) to start afresh")
    J.write_json_atomic(manifest, path)


def _make_collector(env_fn: Callable, policy, workers: int, frames_per_batch: int):
    from torchrl.collectors import Collector, MultiSyncCollector

    if workers == 1:
        return Collector(env_fn, policy, frames_per_batch=frames_per_batch, total_frames=-1,
                         auto_register_policy_transforms=False)
    return MultiSyncCollector([env_fn] * workers, policy, frames_per_batch=frames_per_batch * workers,
                              total_frames=-1, num_threads=1, num_sub_threads=1, cat_results="stack",
                              auto_register_policy_transforms=False)


def evaluate(agent: Any = "route_follower", suite: str = "test50", seeds: int = 1, workers: int = 1,
             out: str | Path = "results/eval", video: bool = False, max_routes: int | None = None,
             config: Mapping[str, Any] | None = None, *, agent_name: str | None = None,
             frames_per_batch: int = FRAMES_PER_WORKER, progress: bool = True,
             n_boot: int = 2000, isolate_agent: bool = False) -> dict:
    """Evaluate ``agent`` on ``suite`` and return the summary (see module docstring).

    Args:
        agent: registered name, ``path.py:Class``, picklable factory, or TorchRL policy module.
        suite: suite name (``test50``, ``val``, ``train``) or path to a suite JSON.
        seeds: seed indices per route. workers: collector worker processes (1: in-process).
        out: output directory (created; resumed when it holds results of the same run).
        video: a top-down GIF per route in ``<out>/videos``.
        max_routes: only the first ``max_routes`` routes of the suite.
        config: ``EnvConfig`` overrides (e.g. ``{"num_vehicles": 10}``).
        agent_name: display name (default: from the spec, factory or module class).
        frames_per_batch: frames per worker between two progress checks.
        isolate_agent: run the agent in a separate process from the simulator (module docstring).

    Returns:
        The summary dict also written to ``<out>/summary.json``.
    """
    torch.set_num_threads(1)
    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers={workers!r} must be a positive int")
    out = Path(out)
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
    if not policy_mode and not isinstance(agent, str) and (workers > 1 or isolate_agent):
        import pickle

        try:
            pickle.dumps(agent)
        except Exception as e:  # noqa: BLE001
            raise ValueError(f"agent factory {agent!r} is not picklable ({e}); workers > 1 and "
                             "--isolate-agent need a top-level class or function, or a spec string") from None
    if not policy_mode and workers > 1:  # a bad agent fails here, not in every worker process
        probe = instantiate_agent(agent, isolate_agent)
        if isolate_agent:
            probe.close()
    cfg = json.loads(json.dumps(J.to_json_safe(dict(config or {}))))  # as it reads back from run.json
    manifest = {"agent": spec, "agent_name": name, "suite": str(suite), "suite_key": _suite_key(str(suite)),
                "config_overrides": cfg, "policy": policy_mode, "privileged": privileged,
                "agent_process": "isolated" if isolate_agent else "in_process"}
    out.mkdir(parents=True, exist_ok=True)
    _check_manifest(out, manifest)
    J.clear_stale_claims(out)
    t0 = time.perf_counter()
    before = {j.job_id for j in jobs if J.has_result(out, j.job_id)}
    done0 = len(before)
    if done0 < len(jobs):
        env_fn = make_env_factory(suite=str(suite), out=str(out), agent=None if policy_mode else agent,
                                  jobs=jobs, video=video, config=cfg, agent_name=name,
                                  isolate=isolate_agent)
        policy = agent if policy_mode else copy_policy()
        _run(env_fn, policy, workers, frames_per_batch, out, jobs, done0, progress, name)
    wall = time.perf_counter() - t0
    new = [r for r in J.read_results(out, jobs) if r["job_id"] not in before]
    ran, ticks = len(new), sum(int(r["ticks"]) for r in new)
    summary = summarize(out, jobs, n_boot=n_boot)
    summary["run"] = {"workers": workers, "wall_seconds": round(wall, 2), "jobs_run": ran,
                      "routes_per_minute": round(60.0 * ran / wall, 2) if ran and wall > 0 else None,
                      "sim_ticks": ticks, "ticks_per_second": round(ticks / wall, 1) if wall > 0 else None,
                      "video": bool(video)}
    write_summary(out, summary)
    return summary


def _run(env_fn, policy, workers: int, fpb: int, out: Path, jobs: list, done0: int,
         progress: bool, name: str) -> None:
    """Iterate the collector until every job has a result."""
    from tqdm import tqdm

    collector = _make_collector(env_fn, policy, workers, fpb)
    idle_batches, finished = 0, False
    try:
        with tqdm(total=len(jobs), initial=done0, desc=f"eval {name}", unit="route",
                  disable=not progress) as bar:
            for batch in collector:
                done = J.count_results(out, jobs)
                bar.update(done - bar.n)
                if done >= len(jobs):
                    finished = True
                    break
                # every worker idle for two batches while results are missing: the missing jobs'
                # claims were lost (no worker runs them); free them so idle workers take them
                idle = bool((batch["job"] < 0).all() and (batch["next", "job"] < 0).all())
                idle_batches = idle_batches + 1 if idle else 0
                if idle_batches >= 2:
                    J.clear_stale_claims(out, jobs)
                    idle_batches = 0
    finally:
        # once every result is on disk (written atomically) the workers may be terminated quickly
        collector.shutdown(timeout=SHUTDOWN_TIMEOUT_S if finished else None)


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
    first = next(iter(results.values()), {})
    return {
        "agent": manifest["agent"], "agent_name": manifest["agent_name"], "suite": manifest["suite"],
        "privileged": bool(manifest.get("privileged", first.get("privileged", False))),
        "agent_process": manifest.get("agent_process", "in_process"), "seeds": seeds, "n_routes": n_routes,
        "n_jobs": len(jobs), "n_results": len(results), "config_overrides": manifest["config_overrides"],
        "metrics": overall, "v2x": v2x, "n_v2x_routes": n_v2x,
        "per_scenario": per_scenario(routes, jobs, results),
        "ended_by": {k: ended.get(k, 0) for k in ENDED_BY_NAMES},
        "failures": [{"job_id": r["job_id"], "error": r["error"]} for r in results.values() if r.get("error")],
    }


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
        lines += ["", "Failed runs:", *[f"- `{f['job_id']}`: {f['error']}" for f in s["failures"]]]
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
    (out / "summary.md").write_text(summary_markdown(summary))
