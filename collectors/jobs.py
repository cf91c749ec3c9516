"""Evaluation jobs and the files that coordinate them: results, claims, NaN-safe JSON.

A *job* is one route of a suite driven with one seed index ``k``; its id is
``{route_id}_s{k}`` and its world seed ``spec.seed + 1000 * k`` (:func:`job_seed`). An output
directory holds::

    <out>/run.json                 what was evaluated: the run's fingerprint (agent code,
                                   checkpoint, agent config, env overrides, ...:
                                   ``agent_fingerprint.py``) and labels
    <out>/routes/<job_id>.json     one result per job, written atomically (``v2xbench.files``),
                                   carrying the fingerprint's digest
    <out>/claims/<job_id>          created with O_CREAT | O_EXCL by the worker that runs the job;
                                   holds the worker's pid, its mtime is when the job started
    <out>/videos/<job_id>.gif      top-down video (``--video``)
    <out>/summary.json, summary.md
    <out>/.v2xbench.lock           held by the running ``eval`` (``v2xbench.locks.dir_lock``)

Several workers share one queue: a worker takes the first job that has neither a result nor a
claim and claims it atomically (:func:`try_claim`), so no job runs twice. A claim without a
result is stale when no worker runs it (an interrupted run): the harness removes those at start
(:func:`clear_stale_claims`), and jobs whose result exists are skipped, which makes runs resumable.
A result file that does not read back as a result of its job (empty, truncated, edited) counts as
missing: :func:`discard_unreadable_results` removes it with a warning naming it, and the job runs
again; one of another fingerprint is refused (:class:`ForeignResults`). :func:`remove_run_files`
empties a directory for ``--overwrite``, :func:`failed_jobs` lists the jobs ``--retry-failed``
runs again.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import warnings
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from v2xbench.files import atomic_write_json

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


def make_jobs(route_ids: Sequence[str], seeds: int = 1, max_routes: int | None = None,
              indices: Sequence[int] | None = None) -> list[Job]:
    """Jobs for the routes at ``indices`` of ``route_ids`` (all by default; then only the first
    ``max_routes``) x ``seeds`` seed indices.

    Ordered seed-major (every route with seed 0 first), so an interrupted run has covered the
    suite as evenly as possible.
    """
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"seeds={seeds!r} must be a positive int")
    if max_routes is not None and (not isinstance(max_routes, int) or max_routes < 1):
        raise ValueError(f"max_routes={max_routes!r} must be a positive int or None")
    sel = list(range(len(route_ids))) if indices is None else [int(i) for i in indices]
    bad = [i for i in sel if not 0 <= i < len(route_ids)]
    if bad:
        raise ValueError(f"route indices {bad} are out of range for {len(route_ids)} routes")
    sel = sel if max_routes is None else sel[:max_routes]
    return [Job(job_id(route_ids[r], k), r, k) for k in range(seeds) for r in sel]


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


def claim_pids(out: str | Path) -> set[int]:
    """Process ids written in the claim files of ``out``: every worker that claimed a job."""
    d = claims_dir(out)
    pids = set()
    for p in d.iterdir() if d.is_dir() else ():
        try:
            text = p.read_text().strip()
        except FileNotFoundError:
            continue
        if text.isdigit():
            pids.add(int(text))
    return pids


class Claim(NamedTuple):
    """A claimed job without a result: who runs it and since when.

    Attributes:
        job_id: the claimed job.
        pid: process id of the worker that claimed it (``None`` while the claim is being written).
        since: when it was claimed (the claim file's mtime, ``time.time()`` clock), s.
    """

    job_id: str
    pid: int | None
    since: float


def open_claims(out: str | Path, jobs: Iterable[Job]) -> dict[str, Claim]:
    """The claims of ``jobs`` that have no result yet (the jobs being run), by job id."""
    d = claims_dir(out)
    if not d.is_dir():
        return {}
    wanted = {j.job_id for j in jobs}
    names = {p.name for p in os.scandir(routes_dir(out))} if routes_dir(out).is_dir() else set()
    claims = {}
    for entry in os.scandir(d):
        jid = entry.name
        if jid not in wanted or f"{jid}.json" in names:
            continue
        try:
            since = entry.stat().st_mtime
            text = Path(entry.path).read_text().strip()
        except FileNotFoundError:  # released in the meantime
            continue
        claims[jid] = Claim(jid, int(text) if text.isdigit() else None, since)
    return claims


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
    """Write ``obj`` as standard JSON (NaN -> null) to ``path`` atomically (fsynced temporary file
    renamed over it: ``v2xbench.files.atomic_write_json``)."""
    return atomic_write_json(path, to_json_safe(obj), indent=1, allow_nan=False)


#: Keys every result file has (``route_log.build_result``); a file without them is unreadable.
RESULT_KEYS = ("job_id", "ended_by", "metrics", "scenarios", "ticks")


def _load_result(path: Path, jid: str) -> dict:
    """The result dict stored in ``path`` for job ``jid``; ``ValueError`` naming the file if it
    is not one (empty, truncated, not JSON, another job's, keys missing)."""
    try:
        text = path.read_text()
        d = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        what = "is empty" if not path.stat().st_size else f"is not valid JSON ({e})"
        raise ValueError(f"result file {path} {what}") from None
    if not isinstance(d, dict):
        raise ValueError(f"result file {path} holds a JSON {type(d).__name__}, not a result object")
    missing = [k for k in RESULT_KEYS if k not in d]
    if missing:
        raise ValueError(f"result file {path} lacks {', '.join(missing)} (truncated or edited?)")
    if d["job_id"] != jid:
        raise ValueError(f"result file {path} holds job {d['job_id']!r}, not {jid!r}")
    if not isinstance(d["metrics"], dict):
        raise ValueError(f"result file {path}: 'metrics' is not an object")
    return d


def read_result(out: str | Path, jid: str) -> dict:
    """The result dict of job ``jid`` (metric ``None`` values read back as NaN).

    Raises:
        ValueError: the file is not a result of ``jid`` (the message names it).
    """
    d = _load_result(result_path(out, jid), jid)
    d["metrics"] = {k: (float("nan") if v is None else v) for k, v in d["metrics"].items()}
    return d


def read_results(out: str | Path, jobs: Iterable[Job]) -> list[dict]:
    """Results of the ``jobs`` that have one, in job order."""
    return [read_result(out, j.job_id) for j in jobs if has_result(out, j.job_id)]


def all_results(out: str | Path) -> list[dict]:
    """Every result in ``out/routes`` (whatever the jobs that made them), in job-id order.

    Raises:
        FileNotFoundError: ``out`` holds no result file (the message names it).
        ValueError: a file is not a result (the message names it).
    """
    files = sorted(routes_dir(out).glob("*.json")) if routes_dir(out).is_dir() else []
    if not files:
        raise FileNotFoundError(f"{out}: no route results (routes/*.json); is it a v2xbench eval folder?")
    return [read_result(out, f.stem) for f in files]


class UnreadableResultWarning(UserWarning):
    """A result file could not be read back; its job is run again."""


class ForeignResults(ValueError):
    """Result files of another fingerprint (or of none) in an output directory."""


def retag_results(out: str | Path, old: str, new: str) -> int:
    """Rewrite the ``fingerprint`` digest of ``out``'s result files from ``old`` to ``new``
    (atomically, one file at a time; a file of another digest is left alone). Returns how many
    were rewritten. For a fingerprint whose form changed while the run it describes did not
    (``agent_fingerprint.legacy_match``)."""
    n = 0
    for path in sorted(routes_dir(out).glob("*.json")):
        try:
            d = json.loads(path.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError):
            continue  # unreadable: discard_unreadable_results deals with it
        if isinstance(d, dict) and d.get("fingerprint") == old:
            d["fingerprint"] = new
            write_json_atomic(d, path)
            n += 1
    return n


def discard_unreadable_results(out: str | Path, jobs: Iterable[Job],
                               fingerprint: str | None = None) -> list[Path]:
    """Remove the result files of ``jobs`` that do not read back (:func:`read_result`), each with
    an :class:`UnreadableResultWarning` naming it, so their jobs count as missing and run again.
    Returns the removed paths.

    Raises:
        ForeignResults: with ``fingerprint``, results whose ``fingerprint`` is another (or
            missing): the message names them.
    """
    removed, foreign = [], []
    for j in jobs:
        path = result_path(out, j.job_id)
        if not path.is_file():
            continue
        try:
            d = _load_result(path, j.job_id)
        except (ValueError, OSError) as e:
            warnings.warn(f"{e}; treating job {j.job_id} as missing and running it again",
                          UnreadableResultWarning, stacklevel=2)
            path.unlink(missing_ok=True)
            removed.append(path)
            continue
        if fingerprint is not None and d.get("fingerprint") != fingerprint:
            foreign.append(path.name)
    if foreign:
        raise ForeignResults(
            f"{len(foreign)} result file(s) in {routes_dir(out)} were written by another run than "
            f"the one {Path(out) / 'run.json'} describes ({', '.join(foreign[:5])}"
            f"{', ...' if len(foreign) > 5 else ''}); use --overwrite to delete them and run "
            "afresh")
    return removed


def failed_jobs(out: str | Path, jobs: Iterable[Job]) -> list[Job]:
    """The ``jobs`` whose result is a failure (``failure`` ``"error"`` / ``"timeout"``; results
    written before that key: an ``error``)."""
    failed = []
    for j in jobs:
        if has_result(out, j.job_id):
            d = read_result(out, j.job_id)
            if d.get("failure") or d.get("error"):
                failed.append(j)
    return failed


#: what an evaluation writes into its output directory (``--overwrite`` removes these only)
RUN_FILES = ("run.json", "summary.json", "summary.md")
RUN_DIRS = ("routes", "claims", "videos")


def remove_run_files(out: str | Path) -> int:
    """Remove what an evaluation wrote into ``out`` (:data:`RUN_FILES`, :data:`RUN_DIRS`; other
    files stay); returns how many result files were removed."""
    out = Path(out)
    n = len(list(routes_dir(out).glob("*.json"))) if routes_dir(out).is_dir() else 0
    for d in RUN_DIRS:
        if (out / d).is_dir():
            shutil.rmtree(out / d)
    for f in RUN_FILES:
        (out / f).unlink(missing_ok=True)
    return n
