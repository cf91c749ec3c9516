"""Closed-loop evaluation of an agent on a route suite through TorchRL collectors.

::

    from v2xbench.collectors.evaluate import evaluate

    if __name__ == "__main__":          # needed: the routes run in worker processes
        summary = evaluate("route_follower", suite="test50", seeds=3, workers=2, out="results/rf")

or ``v2xbench eval --agent route_follower --suite test50 --seeds 3 --workers 2 --out results/rf``.

The jobs are the selected routes of the suite x ``seeds`` seed indices (``route_selection.py``:
``routes``, ``scenario``, ``v2x_only``, ``max_routes``; ``jobs.py``: job ``{route_id}_s{k}``,
world seed ``route seed + 1000 k``). ``workers`` worker processes each run a
``torchrl.collectors.Collector`` over one :class:`~.eval_env.EvalEnv` that claims jobs from the
shared queue in ``<out>/claims`` and writes ``<out>/routes/<job>.json``. The harness supervises
them (``eval_workers.py``): a job that runs longer than ``route_timeout`` seconds of wall clock,
or whose worker dies (``os._exit`` in the agent, a crash), is recorded as that job's failure
(result ``failure = "timeout"`` / ``"error"``, ``ended_by = "error"``, DS 0) and a new worker
takes the remaining jobs. When every job has a result it writes ``<out>/summary.json`` and
``<out>/summary.md`` (``eval_summary.py``). With ``backend="ray"`` (``--backend ray
[--address ADDR]``) each job is a Ray task on a local or remote Ray cluster running the same
worker code, whose result the driver writes into ``<out>`` (``eval_ray.py``): the same results,
resume and failure handling; ``summary["run"]`` records the backend (and the Ray address).

The run holds ``v2xbench.locks.dir_lock(out)`` from start to end: a second evaluation on the same
``out`` is refused (``DirectoryLocked`` names the holder).

**Results are keyed by a fingerprint** (``agent_fingerprint.py``): the agent's code (the file of
``path.py:Class``, the modules of a built-in), its declared checkpoint and ``fingerprint()``, the
agent config, the env overrides, obs_mode / rsu_policy / action_mode, the suite and the agent
process (the overrides include the sensor configuration an agent declares, ``agent_sensors.py``:
the env is configured from it, and a ``--set`` that differs from it is refused); for an agent
that brings its own roadside policy (``roadside.py``: ``rsu_policy`` is
then ``custom:<ClassName>`` in the manifest, every summary and the leaderboard) also that
policy's code, checkpoint and ``fingerprint()``. ``<out>/run.json`` holds it and every result
its digest. Running again on the same ``out`` with the same fingerprint resumes: finished jobs
are skipped; claims and temporary files left by an interrupted run are removed, and a result
file that does not read back (empty, truncated) is removed with a warning naming it, so its job
runs again. With another fingerprint (an edited agent file, other weights, another config) it
is refused with a message naming what differs, unless ``overwrite`` (``--overwrite``), which
deletes the directory's results first and says so. ``retry_failed`` (``--retry-failed``) runs
the selected jobs whose result is a failure (error or wall-clock timeout) again, same
fingerprint required.

``agent`` is a registered agent name, ``path/to/file.py:ClassName``, a picklable factory, or a
TorchRL policy (a ``TensorDictModule`` reading the observation keys of
:class:`~.eval_env.EvalEnv` and writing ``action``); factories and policies must be picklable
(they are sent to the worker processes). ``agent_config`` (a JSON file or a dict,
``agent_config.py``) is passed to a protocol agent's constructor as keyword arguments.

Trust: ``path/to/file.py:ClassName`` executes that file: in this process (the agent is built
once to fail early) and in every worker, or only in the agent's own process with
``isolate_agent`` (docs/evaluation.md, "Trust"). Only the built-in expert and oracles are
privileged (``interface.PRIVILEGED_AGENTS``;
results and summary record the harness's decision, not the agent's claim). With
``isolate_agent=True`` (``--isolate-agent``) a protocol agent runs in a process of its own and
sees only ``route_info`` and its observations (``agent_process.py``); privileged agents and
TorchRL policies cannot be isolated (``ValueError``). Every result and the summary record
``agent_process`` (``"isolated"`` or ``"in_process"``), part of the fingerprint.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from v2xbench.envs.v2x_intersection.evaluation.metrics import ENDED_ERROR
from v2xbench.envs.v2x_intersection.sim.config import EnvConfig, make_config

from v2xbench.files import check_output_dir, remove_stale_tmp
from v2xbench.locks import dir_lock

from . import jobs as J
from .agent_config import resolve_agent_config
from .agent_fingerprint import (
    agent_identity,
    code_digests,
    declared,
    describe_differences,
    legacy_match,
    make_fingerprint,
    policy_digest,
)
from .agent_sensors import apply_agent_channel, apply_agent_sensors
from .eval_env import agent_label, copy_policy, instantiate_agent, make_env_factory
from .eval_ray import check_backend, ray_address, run_jobs_ray
from .eval_summary import per_scenario, summarize, summary_markdown, write_summary
from .eval_workers import DEFAULT_ROUTE_TIMEOUT_S, check_route_timeout, run_jobs
from .roadside import policy_label, roadside_component
from .route_log import build_result
from .route_selection import selected_jobs

__all__ = ["evaluate", "per_scenario", "summarize", "summary_markdown", "write_summary"]

FRAMES_PER_WORKER = 64  # collector frames per worker between two looks for more work


def _is_policy(agent: Any) -> bool:
    return isinstance(agent, torch.nn.Module)


def _suite_key(suite: str) -> str:
    p = Path(suite)
    return str(p.resolve()) if p.suffix else str(suite)


def _say(msg: str) -> None:
    print(f"v2xbench eval: {msg}", file=sys.stderr, flush=True)


def _config_default(name: str) -> Any:
    return {f.name: f.default for f in dataclasses.fields(EnvConfig)}[name]


def _check_overrides(cfg: dict) -> None:
    """Refuse bad env overrides here, before anything is written or a worker starts (each
    worker's env would refuse them, naming the field, only after the run began)."""
    bad = sorted({"suite", "route_index"} & set(cfg))
    if bad:
        raise ValueError(f"--set {', '.join(bad)}: chosen by the job queue (use --suite and "
                         "--routes)")
    try:
        make_config(**cfg)
    except ValueError as e:
        raise ValueError(f"--set: {e}") from None


def _read_run_json(path: Path) -> dict | None:
    """The manifest in ``path`` (``None`` when there is none); ``ValueError`` when unreadable."""
    if not path.is_file():
        return None
    try:
        old = json.loads(path.read_text())
        if not isinstance(old, dict):
            raise ValueError(f"a JSON {type(old).__name__}, not an object")
    except (ValueError, UnicodeDecodeError) as e:
        raise ValueError(
            f"{path} is unreadable ({e}); it says what this directory holds: fix it, "
            "or use --overwrite to delete this directory's results (or another --out)"
        ) from None
    return old


def _prepare_directory(out: Path, manifest: dict, overwrite: bool) -> None:
    """Refuse results of another fingerprint in ``out`` (or delete them with ``overwrite``), then
    write ``run.json``. Call while holding the directory's lock."""
    path = out / "run.json"
    has_results = J.routes_dir(out).is_dir() and any(J.routes_dir(out).glob("*.json"))
    if overwrite:
        if path.is_file() or has_results:
            n = J.remove_run_files(out)
            _say(f"--overwrite: deleted {n} result(s) of the previous run in {out}")
    else:
        old = _read_run_json(path)
        if old is None and has_results:
            raise ValueError(
                f"{out} holds results but no run.json saying what produced them; use "
                "--overwrite to delete them and run afresh (or another --out)"
            )
        if old is not None and "fingerprint" not in old:
            raise ValueError(
                f"{out} holds results of an evaluation written before results were "
                "keyed by a fingerprint of the agent (run.json has none), so they "
                "cannot be trusted to match this one; use --overwrite to delete "
                "them and run afresh (or another --out)"
            )
        if old is not None:
            comp = (old.get("fingerprint") or {}).get("components") or {}
            new_fp = manifest["fingerprint"]
            diffs = describe_differences(comp, new_fp["components"])
            if diffs and legacy_match(comp, new_fp["components"]):
                n = J.retag_results(out, old["fingerprint"].get("digest"), new_fp["digest"])
                _say(f"{out}: run.json keyed the shipped weights by their absolute path (written "
                     f"before v2xbench keyed them by their path in the package); same agent, "
                     f"same weights: {n} result(s) re-keyed and resumed")
                diffs = []
            if diffs:
                raise ValueError(
                    f"{out} holds results of another run; what differs: "
                    + "; ".join(diffs)
                    + ". Use --overwrite to delete them and run "
                    "afresh (or another --out)"
                )
    J.write_json_atomic(manifest, path)


def _retry_failed(out: Path, jobs: list[J.Job]) -> list[str]:
    """Remove the failed results of ``jobs`` so they run again; returns their ids."""
    failed = J.failed_jobs(out, jobs)
    for j in failed:
        J.result_path(out, j.job_id).unlink(missing_ok=True)
    ids = [j.job_id for j in failed]
    _say(
        f"--retry-failed: running {len(ids)} failed route run(s) again"
        + (f": {', '.join(ids[:10])}{', ...' if len(ids) > 10 else ''}" if ids else "")
    )
    return ids


def _clean(out: Path) -> None:
    """Remove the temporary files that killed writers left in ``out`` and its result folders."""
    for d in (out, J.routes_dir(out), out / "videos"):
        remove_stale_tmp(d)


def _probe_agent(agent: Any, spec: str, isolate: bool, config: dict | None) -> dict:
    """Build the agent once here (a bad agent fails now, not in every worker) and return what the
    fingerprint needs of it: ``obs_mode``, ``rsu_policy`` (``custom:<ClassName>`` for its own
    roadside policy), its declarations, its roadside policy's (``roadside.py``) and the sensors
    it declares (``interface.declared_sensors``)."""
    from v2xbench.agents.interface import declared_channel, declared_sensors

    try:
        probe = instantiate_agent(agent, isolate, config)
    except SystemExit as e:
        raise ValueError(f"agent {spec!r} raised SystemExit({e}) while being built") from None
    if isolate:
        probe.close()
        decl, roadside = probe.declared, probe.roadside
    else:
        decl, roadside = declared(probe, spec), roadside_component(probe)
    return {"obs_mode": str(probe.obs_mode), "rsu_policy": policy_label(probe), "declared": decl,
            "roadside": roadside, "sensors": declared_sensors(probe, spec),
            "channel": declared_channel(probe, spec)}


def evaluate(
    agent: Any = "route_follower",
    suite: str = "test50",
    seeds: int = 1,
    workers: int = 1,
    out: str | Path = "results/eval",
    video: bool = False,
    max_routes: int | None = None,
    config: Mapping[str, Any] | None = None,
    *,
    agent_name: str | None = None,
    frames_per_batch: int = FRAMES_PER_WORKER,
    progress: bool = True,
    n_boot: int = 2000,
    isolate_agent: bool = False,
    route_timeout: float = DEFAULT_ROUTE_TIMEOUT_S,
    agent_config: Mapping[str, Any] | str | Path | None = None,
    routes: str | Sequence[str] | None = None,
    scenario: str | Sequence[str] | None = None,
    v2x_only: bool = False,
    overwrite: bool = False,
    retry_failed: bool = False,
    backend: str = "local",
    address: str | None = None,
) -> dict:
    """Evaluate ``agent`` on ``suite`` and return the summary (see module docstring).

    Args:
        agent: registered name, ``path.py:Class``, picklable factory, or TorchRL policy module.
        suite: suite name (``test50``, ``val``, ``train``) or path to a suite JSON.
        seeds: seed indices per route. workers: worker processes running jobs at a time.
        out: output directory (created; resumed when it holds results of the same fingerprint;
            locked while the run lasts).
        video: a top-down GIF per route in ``<out>/videos``.
        max_routes: only the first ``max_routes`` of the selected routes.
        config: ``EnvConfig`` overrides (e.g. ``{"num_vehicles": 10}``).
        agent_name: display name (default: from the spec, factory or module class).
        frames_per_batch: frames per worker between two progress checks.
        isolate_agent: run the agent in a separate process from the simulator (module docstring).
        route_timeout: wall-clock limit of one job in seconds (a job that overruns fails).
        agent_config: keyword arguments of the agent's constructor: a JSON file or a dict.
        routes: only these route ids (list or comma-separated). scenario: only routes containing
            one of these scenario types. v2x_only: only routes with a V2X scenario type.
        overwrite: delete the results already in ``out`` first (whatever their fingerprint).
        retry_failed: run the selected jobs whose result is a failure again.
        backend: ``"local"`` (worker processes, ``eval_workers.py``) or ``"ray"`` (one Ray task per
            job, ``eval_ray.py``; the same results, resume and failures).
        address: the Ray cluster of ``backend="ray"`` (``HEAD:6379``, ``auto``); ``None``: the
            ``RAY_ADDRESS`` environment variable, or a local Ray instance with ``workers`` CPUs.

    Returns:
        The summary dict also written to ``<out>/summary.json``.

    Raises:
        ValueError: a bad argument, agent, agent config, route selection or suite (Ray not
            installed for ``backend="ray"``: ``eval_ray.RayUnavailable``); ``out`` is a
            file or another run holds it (``v2xbench.locks.DirectoryLocked``); results of
            another fingerprint are in ``out`` (the message names what differs).
        FileNotFoundError: the agent config file does not exist.
        RuntimeError: the workers cannot start (their output says why).
    """
    torch.set_num_threads(1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers={workers!r} must be a positive int")
    if overwrite and retry_failed:
        raise ValueError(
            "--overwrite deletes every result and --retry-failed keeps the good ones: "
            "give one of them"
        )
    route_timeout = check_route_timeout(route_timeout)
    check_backend(backend, address)
    out = check_output_dir(out, "evaluation output directory")
    suite_routes, selection, jobs = selected_jobs(
        suite, seeds, routes=routes, scenario=scenario, v2x_only=v2x_only, max_routes=max_routes
    )
    agent_cfg, agent_cfg_file = resolve_agent_config(agent_config)
    agent_cfg = agent_cfg or None
    policy_mode = _is_policy(agent)
    spec, name = agent_label(None if policy_mode else agent)
    if policy_mode:
        spec = name = agent_name or type(agent).__name__
    name = agent_name or name
    if policy_mode and (isolate_agent or agent_cfg):
        what = "--isolate-agent" if isolate_agent else "--agent-config"
        raise ValueError(
            f"{what} needs a protocol agent; a TorchRL policy runs in the collector "
            "(wrap it in agents.torchrl_policy.TensorDictPolicyAgent)"
        )
    privileged = False
    if not policy_mode:
        from v2xbench.agents.interface import granted_privilege

        privileged = granted_privilege(agent)
        if isolate_agent and privileged:
            raise ValueError(
                f"agent {spec!r} is privileged (it reads the simulator) and cannot run "
                "isolated; evaluate it without --isolate-agent"
            )
    if not isinstance(agent, str):  # workers get the agent or policy pickled
        import pickle

        try:
            pickle.dumps(agent)
        except Exception as e:  # noqa: BLE001
            what = "policy" if policy_mode else "agent factory"
            raise ValueError(
                f"{what} {agent!r} is not picklable ({e}); the worker processes need a "
                "top-level class or function, or a spec string"
            ) from None
    # the overrides as they read back from run.json
    cfg = json.loads(json.dumps(J.to_json_safe(dict(config or {}))))
    if policy_mode:
        facts = {
            "obs_mode": cfg.get("obs_mode", _config_default("obs_mode")),
            "rsu_policy": cfg.get("rsu_policy", _config_default("rsu_policy")),
            "declared": {"checkpoint": {"policy": policy_digest(agent)}, "fingerprint": None},
        }
        identity, code = f"policy {type(agent).__name__}", {}
    else:
        facts = _probe_agent(agent, spec, isolate_agent, agent_cfg)
        identity, code = agent_identity(agent), code_digests(agent)
        # the agent's declared sensors configure the env; a --set that differs is refused
        cfg = apply_agent_sensors(cfg, facts["sensors"], spec)
        cfg = apply_agent_channel(cfg, facts["channel"], spec)  # its declared payload limit
    obs_mode = cfg.get("obs_mode", facts["obs_mode"])
    rsu_policy = cfg.get("rsu_policy", facts["rsu_policy"])
    if facts.get("roadside") is not None and "rsu_policy" in cfg:
        raise ValueError(f"--set rsu_policy={cfg['rsu_policy']!r} conflicts with the agent's own "
                         f"roadside policy ({facts['rsu_policy']}); drop the override")
    action_mode = cfg.get("action_mode", _config_default("action_mode"))
    _check_overrides(cfg)
    agent_process = "isolated" if isolate_agent else "in_process"
    roadside = {"roadside": facts["roadside"]} if facts.get("roadside") is not None else {}
    fingerprint = make_fingerprint(
        {
            **roadside,  # only with the agent's own roadside policy: other runs keep their digest
            "suite": _suite_key(str(suite)),
            "agent": identity,
            "agent_code": code,
            "checkpoint": facts["declared"]["checkpoint"],
            "agent_fingerprint": facts["declared"]["fingerprint"],
            "agent_config": agent_cfg,
            "config_overrides": cfg,
            "obs_mode": obs_mode,
            "rsu_policy": rsu_policy,
            "action_mode": action_mode,
            "agent_process": agent_process,
        }
    )
    manifest = {
        "agent": spec,
        "agent_name": name,
        "suite": str(suite),
        "suite_key": _suite_key(str(suite)),
        "config_overrides": cfg,
        "policy": policy_mode,
        "privileged": privileged,
        "agent_process": agent_process,
        "obs_mode": obs_mode,
        "rsu_policy": rsu_policy,
        "action_mode": action_mode,
        "agent_config": agent_cfg,
        "agent_config_file": agent_cfg_file,
        "fingerprint": fingerprint,
    }
    with dir_lock(out, "evaluation"):
        _prepare_directory(out, manifest, overwrite)
        _clean(out)
        J.discard_unreadable_results(out, jobs, fingerprint["digest"])
        if retry_failed:
            _retry_failed(out, jobs)
        J.clear_stale_claims(out)
        t0 = time.perf_counter()
        before = {j.job_id for j in jobs if J.has_result(out, j.job_id)}
        stats = {"workers_started": 0, "timeouts": 0, "workers_died": 0}
        if len(before) < len(jobs):
            env_fn = make_env_factory(
                suite=str(suite),
                out=str(out),
                agent=None if policy_mode else agent,
                jobs=jobs,
                video=video,
                config=cfg,
                agent_name=name,
                isolate=isolate_agent,
                agent_config=agent_cfg,
                fingerprint=fingerprint["digest"],
            )
            policy = agent if policy_mode else copy_policy()
            record = _failure_recorder(out, manifest, suite_routes)
            run_kw = {} if backend == "local" else {"backend": backend, "address": address,
                                                    "code": code}
            stats = _run(
                env_fn,
                policy,
                workers,
                frames_per_batch,
                out,
                jobs,
                progress,
                name,
                route_timeout,
                record,
                **run_kw,
            )
            _clean(out)
        wall = time.perf_counter() - t0
        new = [r for r in J.read_results(out, jobs) if r["job_id"] not in before]
        ran, ticks = len(new), sum(int(r["ticks"]) for r in new)
        summary = summarize(out, jobs, n_boot=n_boot, selection=selection.record)
        summary["run"] = {
            "backend": backend,
            **({"ray_address": ray_address(address)} if backend == "ray" else {}),
            "workers": workers,
            "wall_seconds": round(wall, 2),
            "jobs_run": ran,
            "routes_per_minute": round(60.0 * ran / wall, 2) if ran and wall > 0 else None,
            "sim_ticks": ticks,
            "ticks_per_second": round(ticks / wall, 1) if wall > 0 else None,
            "video": bool(video),
            "route_timeout_s": route_timeout,
            **stats,
        }
        write_summary(out, summary)
    return summary


def _failure_recorder(out: Path, manifest: dict, routes) -> Callable:
    """``record(job, kind, error, wall_s)``: write the result of a job its worker did not finish."""

    def record(job: J.Job, kind: str, error: BaseException, wall_s: float) -> None:
        spec = routes[job.route_index]
        res = build_result(
            job=job,
            spec=spec,
            seed=J.job_seed(spec.seed, job.seed_index),
            suite=manifest["suite"],
            agent=manifest["agent"],
            agent_name=manifest["agent_name"],
            privileged=manifest["privileged"],
            agent_process=manifest["agent_process"],
            log=None,
            ended_by=ENDED_ERROR,
            wall_s=wall_s,
            error=error,
            config=manifest["config_overrides"],
            failure=kind,
            fingerprint=manifest["fingerprint"]["digest"],
        )
        J.write_json_atomic(res, J.result_path(out, job.job_id))

    return record


def _run(
    env_fn: Callable,
    policy,
    workers: int,
    fpb: int,
    out: Path,
    jobs: list,
    progress: bool,
    name: str,
    route_timeout: float,
    record_failure: Callable,
    backend: str = "local",
    address: str | None = None,
    code: dict | None = None,
) -> dict:
    """Run the jobs in supervised workers until every job has a result (``eval_workers.py``, or
    Ray tasks with ``backend="ray"``: ``eval_ray.py``); ``record_failure`` writes the result of a
    job whose worker timed out or died."""
    if backend == "ray":
        return run_jobs_ray(env_fn, policy, workers=workers, out=out, jobs=jobs,
                            record_failure=record_failure, route_timeout=route_timeout,
                            frames_per_batch=fpb, progress=progress, desc=f"eval {name}",
                            address=address, code=code)
    return run_jobs(
        env_fn,
        policy,
        workers=workers,
        out=out,
        jobs=jobs,
        record_failure=record_failure,
        route_timeout=route_timeout,
        frames_per_batch=fpb,
        progress=progress,
        desc=f"eval {name}",
    )
