"""``v2xbench experiments status DIR``: where a (long) experiment run stands, job by job.

Reads only files (the config copy, ``experiments.json``, each job's ``result.json`` /
``failed.json`` and its evaluation folder): safe to call while ``experiments run`` works on
``DIR``. A closed-loop job that has not finished shows how many of its route x seed runs have a
result so far (``eval/routes/*.json`` of the job's selection), so a run of many hours can be
followed and its remaining time estimated from the runs' own wall time.
"""

from __future__ import annotations

import json
from pathlib import Path

from .config import Config, Job, load_config
from .runner import FAILED, RESULT, STATE, load_config_copy


def _closed_loop_progress(job: Job, d: Path) -> dict:
    """``{"runs", "of", "wall_s"}``: the job's selected runs with a result in ``d/eval`` and the
    sum of their wall time."""
    from v2xbench.collectors import jobs as J
    from v2xbench.collectors.route_selection import selected_jobs

    _, _, jobs = selected_jobs(str(job.get("suite")), job.get("seeds", 1), routes=job.get("routes"),
                               scenario=job.get("scenario"), v2x_only=job.get("v2x_only", False),
                               max_routes=job.get("max_routes"))
    out, done, wall = d / "eval", 0, 0.0
    for j in jobs:
        if J.has_result(out, j.job_id):
            done += 1
            try:
                wall += float(json.loads(J.result_path(out, j.job_id).read_text()).get("wall_seconds") or 0.0)
            except ValueError:  # a file being replaced or broken: counted, its time unknown
                pass
    return {"runs": done, "of": len(jobs), "wall_s": wall}


def experiment_status(root: str | Path, config: str | Path | None = None) -> list[dict]:
    """One row per job of the experiment folder ``root``: ``id``, ``kind``, ``status`` (``done``,
    ``failed``, ``not available``, ``blocked``, ``unfinished`` (its folder exists: running, or
    stopped before its end) or ``not started``), ``detail``, and for
    an unfinished closed-loop job its ``progress`` (:func:`_closed_loop_progress`).

    Raises:
        FileNotFoundError: ``root`` has no config copy (no run yet) and no ``config`` is given
            (pass ``--config FILE`` or a shipped name then).
    """
    root = Path(root)
    if config is None:
        try:
            cfg = load_config_copy(root, "experiments status")
        except FileNotFoundError as e:
            raise FileNotFoundError(f"{e}; or give --config FILE or a shipped name") from None
    else:
        cfg = config if isinstance(config, Config) else load_config(config)
    state = json.loads((root / STATE).read_text()).get("jobs", {}) if (root / STATE).is_file() else {}
    rows = []
    for job in cfg.jobs:
        d, rec = root / job.id, state.get(job.id, {})
        row: dict = {"id": job.id, "kind": job.kind, "detail": ""}
        if (d / RESULT).is_file():
            r = json.loads((d / RESULT).read_text())
            row.update(status="done", detail=f"{r.get('elapsed_s', 0.0) / 60:.1f} min, {r.get('finished', '')}")
        elif (d / FAILED).is_file():
            row.update(status="failed", detail=json.loads((d / FAILED).read_text()).get("error", ""))
        elif rec.get("status") in ("not available", "blocked"):
            row.update(status=rec["status"], detail=rec.get("reason") or "")
        else:
            row["status"] = "unfinished" if d.is_dir() else "not started"
        if job.kind == "closed_loop" and row["status"] != "done":
            p = row["progress"] = _closed_loop_progress(job, d)
            if p["runs"]:
                left = p["wall_s"] / p["runs"] * (p["of"] - p["runs"]) / 60.0
                row["detail"] = (f"{p['runs']} of {p['of']} runs, ~{left:.0f} min of one "
                                 f"worker left at {p['wall_s'] / p['runs']:.0f} s a run")
            else:
                row["detail"] = f"0 of {p['of']} runs"
        rows.append(row)
    return rows


def status_markdown(rows: list[dict]) -> str:
    """The rows as a Markdown table."""
    lines = ["| job | kind | status | detail |", "|---|---|---|---|"]
    lines += [f"| {r['id']} | {r['kind']} | {r['status']} | {r['detail']} |" for r in rows]
    return "\n".join(lines) + "\n"


__all__ = ["experiment_status", "status_markdown"]
