"""Evaluation jobs and the files that coordinate them: results, claims, NaN-safe JSON.

A *job* is one route of a suite driven with one seed index ``k``; its id is
``{route_id}_s{k}`` and its world seed ``spec.seed + 1000 * k`` (:func:`job_seed`). An output
directory holds::

    <out>/run.json                 what was evaluated (agent, suite, config overrides)
    <out>/routes/<job_id>.json     one result per job, written atomically (tmp file + rename)
    <out>/claims/<job_id>          created with O_CREAT | O_EXCL by the worker that runs the job
    <out>/videos/<job_id>.gif      top-down video (``--video``)
    <out>/summary.json, summary.md

Several workers share one queue: a worker takes the first job that has neither a result nor a
claim and claims it atomically (:func:`try_claim`), so no job runs twice. A claim without a
result is stale when no worker runs it (an interrupted run): the harness removes those at start
(:func:`clear_stale_claims`), and jobs whose result exists are skipped, which makes runs resumable.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

SEED_STRIDE = 1000  # world seed = route seed + SEED_STRIDE * seed index


class Job(NamedTuple):
    """One (route, seed index) of a suite.

    Attributes:
        job_id: ``{route_id}_s{seed_index}``; names its result and claim files.
        route_index: index of the route in the suite's route list.
        seed_index: ``k`` in ``0 .. seeds - 1``.
    """

    job_id: str
    route_index: int
    seed_index: int


def job_id(route_id: str, seed_index: int) -> str:
    """The id of route ``route_id`` driven with seed index ``seed_index``."""
    return f"{route_id}_s{seed_index}"


def job_seed(route_seed: int, seed_index: int) -> int:
    """World seed of a job: the route file's seed plus ``SEED_STRIDE * seed_index``."""
    return int(route_seed) + SEED_STRIDE * int(seed_index)


def make_jobs(route_ids: Sequence[str], seeds: int = 1, max_routes: int | None = None) -> list[Job]:
    """Jobs for the first ``max_routes`` routes (all by default) x ``seeds`` seed indices.

    Ordered seed-major (every route with seed 0 first), so an interrupted run has covered the
    suite as evenly as possible.
    """
    if not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"seeds={seeds!r} must be a positive int")
    if max_routes is not None and (not isinstance(max_routes, int) or max_routes < 1):
        raise ValueError(f"max_routes={max_routes!r} must be a positive int or None")
    n = len(route_ids) if max_routes is None else min(max_routes, len(route_ids))
    return [Job(job_id(route_ids[r], k), r, k) for k in range(seeds) for r in range(n)]


# ------------------------------------------------------------------------------------ paths


def routes_dir(out: str | Path) -> Path:
    """``<out>/routes``: one result JSON per job."""
    return Path(out) / "routes"


def claims_dir(out: str | Path) -> Path:
    """``<out>/claims``: one empty file per claimed job."""
    return Path(out) / "claims"


def result_path(out: str | Path, jid: str) -> Path:
    """Result file of job ``jid``."""
    return routes_dir(out) / f"{jid}.json"


def has_result(out: str | Path, jid: str) -> bool:
    """Whether job ``jid`` has a (complete) result file."""
    return result_path(out, jid).is_file()


def count_results(out: str | Path, jobs: Iterable[Job]) -> int:
    """How many of ``jobs`` have a result file (one directory listing)."""
    d = routes_dir(out)
    if not d.is_dir():
        return 0
    names = {p.name for p in os.scandir(d)}
    return sum(f"{j.job_id}.json" in names for j in jobs)


def try_claim(out: str | Path, jid: str) -> bool:
    """Atomically claim job ``jid`` (``O_CREAT | O_EXCL``); False if already claimed."""
    d = claims_dir(out)
    d.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(d / jid, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        return False
    os.write(fd, str(os.getpid()).encode())
    os.close(fd)
    return True


def clear_stale_claims(out: str | Path, jobs: Iterable[Job] | None = None) -> list[str]:
    """Remove claims without a result (all of them, or those of ``jobs``); returns their ids.

    Only call this while no worker runs a job of this directory (at harness start, or when every
    worker is idle).
    """
    d = claims_dir(out)
    if not d.is_dir():
        return []
    wanted = None if jobs is None else {j.job_id for j in jobs}
    removed = []
    for p in d.iterdir():
        if (wanted is None or p.name in wanted) and not has_result(out, p.name):
            p.unlink(missing_ok=True)
            removed.append(p.name)
    return removed


# ------------------------------------------------------------------------------------ JSON


def to_json_safe(obj: Any) -> Any:
    """Replace non-finite floats by ``None`` (standard JSON has no NaN / inf), recursively."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): to_json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_json_safe(v) for v in obj]
    if hasattr(obj, "item") and hasattr(obj, "dtype"):  # numpy scalar
        return to_json_safe(obj.item())
    return obj


def write_json_atomic(obj: Any, path: str | Path) -> Path:
    """Write ``obj`` as standard JSON (NaN -> null) to ``path`` via a temporary file + rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(to_json_safe(obj), indent=1, allow_nan=False))
    os.replace(tmp, path)
    return path


def read_result(out: str | Path, jid: str) -> dict:
    """The result dict of job ``jid`` (metric ``None`` values read back as NaN)."""
    d = json.loads(result_path(out, jid).read_text())
    d["metrics"] = {k: (float("nan") if v is None else v) for k, v in d.get("metrics", {}).items()}
    return d


def read_results(out: str | Path, jobs: Iterable[Job]) -> list[dict]:
    """Results of the ``jobs`` that have one, in job order."""
    return [read_result(out, j.job_id) for j in jobs if has_result(out, j.job_id)]
