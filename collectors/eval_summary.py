"""The summary of an evaluation directory: aggregate metrics, per-scenario table, markdown.

Summary (``metrics.aggregate`` over routes x seeds, bootstrap 95% CI of DS): DS, RC, IS,
Efficiency, Comfortness, BPS, infractions per km; the same restricted to routes that contain a
V2X scenario type (``v2x``); per scenario type: instances, success rate (passed with no collision
in the scenario window and no timeout), collision and timeout rates, mean DS of the runs whose
route contains the type (failed or missing runs count 0). It records what makes runs comparable
on the leaderboard: the observation mode, roadside policy, action mode, sensor settings (from the
env overrides), the route selection and the number of routes x seeds, and the run's fingerprint.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from v2xbench.envs.v2x_intersection.evaluation.metrics import ENDED_BY_NAMES, aggregate
from v2xbench.envs.v2x_intersection.scenarios import get_scenario
from v2xbench.envs.v2x_intersection.sim.config import SENSOR_FIELDS
from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

from v2xbench.files import atomic_write_text

from . import jobs as J
from .route_log import FAILURE_KINDS
from .route_selection import is_v2x_route


def sensor_settings(overrides: dict | None) -> dict:
    """The sensor settings among env overrides (``config.SENSOR_FIELDS``: ``camera_size``,
    ``camera_images``, ``lidar_scale``; an agent's declared ``sensors`` are among the overrides,
    ``agent_sensors.py``); ``{}``: the defaults."""
    return {k: overrides[k] for k in sorted(overrides or {}) if k in SENSOR_FIELDS}


def summarize(
    out: str | Path, jobs: list[J.Job], n_boot: int = 2000, selection: dict | None = None
) -> dict:
    """Suite summary of the results of ``jobs`` in ``out`` (see module docstring); ``selection``
    is the route selection's record (``route_selection.Selection.record``)."""
    out = Path(out)
    manifest = json.loads((out / "run.json").read_text())
    routes = load_suite_cached(manifest["suite"])
    results = {r["job_id"]: r for r in J.read_results(out, jobs)}
    n_routes = len({j.route_index for j in jobs})
    seeds = len({j.seed_index for j in jobs})

    def metric_dicts(sel):
        return [dict(results[j.job_id]["metrics"]) for j in sel if j.job_id in results]

    overall = aggregate(metric_dicts(jobs), n_routes, seeds, n_boot=n_boot)
    is_v2x = {i: is_v2x_route(routes[i]) for i in range(len(routes))}
    v2x_jobs = [j for j in jobs if is_v2x[j.route_index]]
    n_v2x = len({j.route_index for j in v2x_jobs})
    v2x = aggregate(metric_dicts(v2x_jobs), n_v2x, seeds, n_boot=n_boot) if n_v2x else {}
    ended = Counter(results[j.job_id]["ended_by"] for j in jobs if j.job_id in results)
    failures = [
        {"job_id": r["job_id"], "failure": _failure_kind(r), "error": r["error"]}
        for r in results.values()
        if _failure_kind(r)
    ]
    failed = Counter(f["failure"] for f in failures)
    first = next(iter(results.values()), {})
    overrides = manifest["config_overrides"]
    fp = manifest.get("fingerprint") or {}
    return {
        "agent": manifest["agent"],
        "agent_name": manifest["agent_name"],
        "suite": manifest["suite"],
        "privileged": bool(manifest.get("privileged", first.get("privileged", False))),
        "agent_process": manifest.get("agent_process", "in_process"),
        "seeds": seeds,
        "n_routes": n_routes,
        "n_jobs": len(jobs),
        "n_results": len(results),
        "config_overrides": manifest["config_overrides"],
        "metrics": overall,
        "v2x": v2x,
        "n_v2x_routes": n_v2x,
        "per_scenario": per_scenario(routes, jobs, results),
        "ended_by": {k: ended.get(k, 0) for k in ENDED_BY_NAMES},
        "failed": {k: failed.get(k, 0) for k in FAILURE_KINDS},
        "failures": failures,
        "obs_mode": manifest.get("obs_mode", overrides.get("obs_mode", "unknown")),
        "rsu_policy": manifest.get("rsu_policy", overrides.get("rsu_policy", "unknown")),
        "action_mode": manifest.get("action_mode", overrides.get("action_mode", "unknown")),
        "sensors": sensor_settings(overrides),
        "agent_config": manifest.get("agent_config"),
        "selection": selection,
        "fingerprint": fp.get("digest"),
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
            a = acc.setdefault(
                typ,
                {
                    "v2x": bool(get_scenario(typ).v2x),
                    "instances": 0,
                    "success": 0,
                    "collision": 0,
                    "timed_out": 0,
                    "ds": [],
                },
            )
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
        table[typ] = {
            "v2x": a["v2x"],
            "instances": a["instances"],
            "runs": len(a["ds"]),
            "success_rate": 100.0 * a["success"] / n,
            "collision_rate": 100.0 * a["collision"] / n,
            "timeout_rate": 100.0 * a["timed_out"] / n,
            "mean_ds": float(np.mean(a["ds"])),
        }
    return table


def _f(x: Any, nd: int = 1) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{nd}f}"


def _ds_ci(m: dict) -> str:
    return (
        f"{_f(m['driving_score'])} [{_f(m['driving_score_ci_low'])}, "
        f"{_f(m['driving_score_ci_high'])}]"
    )


def summary_markdown(s: dict) -> str:
    """The markdown report of a summary dict."""
    m, v = s["metrics"], s.get("v2x") or {}
    sel = (s.get("selection") or {}).get("label")
    sel = None if sel is None or sel.startswith("all ") else sel
    lines = [
        f"# {s['agent_name']} on {s['suite']}",
        "",
        f"Agent `{s['agent']}`{' (privileged)' if s['privileged'] else ''}"
        f"{' (isolated process)' if s.get('agent_process') == 'isolated' else ''}; "
        f"{s['n_routes']} routes{f' ({sel})' if sel else ''} x {s['seeds']} seeds = "
        f"{s['n_jobs']} runs, "
        f"{s['n_results']} with results.",
        "",
        f"Observation mode `{s.get('obs_mode', 'unknown')}`, roadside policy "
        f"`{s.get('rsu_policy', 'unknown')}`, action mode `{s.get('action_mode', 'unknown')}`, "
        f"sensors `{s.get('sensors') or 'default'}`.",
        "",
    ]
    if s.get("agent_config"):
        lines += [f"Agent config: `{json.dumps(s['agent_config'], sort_keys=True)}`", ""]
    if s.get("config_overrides"):
        lines += [f"Config overrides: `{s['config_overrides']}`", ""]
    if s.get("fingerprint"):
        lines += [f"Fingerprint: `{s['fingerprint'][:16]}` (OUT/run.json lists what it covers)", ""]
    lines += ["| metric | all routes | V2X-type routes |", "|---|---|---|"]
    lines.append(f"| Driving score (95% CI) | {_ds_ci(m)} | {_ds_ci(v) if v else '-'} |")
    for key, label, nd in (
        ("route_completion", "Route completion", 1),
        ("infraction_score", "Infraction score", 3),
        ("efficiency", "Efficiency", 1),
        ("comfortness", "Comfortness", 1),
        ("bps", "BPS (bytes/s)", 0),
        ("peak_bps", "Peak BPS", 0),
        ("km_completed", "km completed", 2),
    ):
        lines.append(f"| {label} | {_f(m.get(key), nd)} | {_f(v.get(key), nd) if v else '-'} |")
    per_km = sorted(k for k in m if k.endswith("_per_km"))
    if per_km:
        lines += ["", "| infraction | per km |", "|---|---|"]
        lines += [f"| {k[:-7]} | {_f(m[k], 3)} |" for k in per_km]
    lines += [
        "",
        "| scenario type | V2X | instances | success % | collision % | timeout % | mean DS |",
        "|---|---|---|---|---|---|---|",
    ]
    for typ, r in s["per_scenario"].items():
        lines.append(
            f"| {typ} | {'yes' if r['v2x'] else 'no'} | {r['instances']} | "
            f"{_f(r['success_rate'])} | {_f(r['collision_rate'])} | {_f(r['timeout_rate'])} | "
            f"{_f(r['mean_ds'])} |"
        )
    lines += [
        "",
        "Routes ended by: " + ", ".join(f"{k} {n}" for k, n in s["ended_by"].items() if n),
    ]
    if s.get("failures"):
        lines += [
            "",
            "Failed runs:",
            *[
                f"- `{f['job_id']}` ({f.get('failure') or 'error'}): {f['error']}"
                for f in s["failures"]
            ],
        ]
    if s.get("run"):
        r = s["run"]
        lines += [
            "",
            f"Run: {r['jobs_run']} runs ({r.get('sim_ticks', 0)} ticks) in {r['wall_seconds']} s "
            f"on {r['workers']} worker(s)"
            + (
                f": {r['routes_per_minute']} routes/min, {r['ticks_per_second']} ticks/s."
                if r.get("routes_per_minute")
                else "."
            ),
        ]
    return "\n".join(lines) + "\n"


def write_summary(out: str | Path, summary: dict) -> None:
    """Write ``summary.json`` and ``summary.md`` into ``out``."""
    out = Path(out)
    J.write_json_atomic(summary, out / "summary.json")
    atomic_write_text(out / "summary.md", summary_markdown(summary))
