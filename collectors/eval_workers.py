"""Supervised evaluation workers: a job that hangs or kills its process fails alone.

The harness (:func:`run_jobs`) never drives a route itself. It starts up to ``workers`` worker
processes; each runs a ``torchrl.collectors.Collector`` over one :class:`~.eval_env.EvalEnv`,
which claims jobs from the queue in ``<out>/claims`` and writes their results, and exits when no
job is left to claim. The harness polls every :data:`POLL_S` seconds:

- **progress**: the result files (``jobs.count_results``); it stops when every job has one;
- **hangs**: a claim whose job has run longer than ``route_timeout`` seconds (from the claim
  file's mtime) gets its worker killed with its process group (an isolated agent's process
  included) and a ``failure = "timeout"`` result (:class:`RouteTimeout`);
- **dead workers**: a worker that exited while holding a claim (``os._exit`` or a crash in the
  agent, the OOM killer) leaves that job a ``failure = "error"`` result (:class:`WorkerDied`,
  with the exit code); an exception that escapes the worker's collector (a TorchRL policy's)
  fails the running job with that exception before the worker exits;
- **replacement**: while jobs are left that no one has claimed, a new worker replaces one that was
  killed or died, up to ``workers`` at a time; claims that no live worker holds are cleared once
  no worker is left (a worker killed between creating its claim and writing its pid into it).

A worker that stops before running any job (its env or agent cannot be built) is not restarted
forever: after :data:`MAX_FUTILE_STARTS` in a row the run stops with a ``RuntimeError``. Workers
ignore SIGINT and run in a process group of their own, so Ctrl-C reaches the harness only, which
then kills them; and they exit by themselves as soon as the harness dies, even when it is killed
(:func:`exit_when_closed` on a pipe only the harness writes to: its end closes with the harness).

Workers are forked from a ``multiprocessing`` fork server that has imported the simulator and
TorchRL once (``forkserver``; ``spawn`` where that is missing), so a worker starts in
milliseconds after the first one, not in the seconds an interpreter takes to import torch.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from . import jobs as J

DEFAULT_ROUTE_TIMEOUT_S = 1800.0  # s of wall clock one job may take (start to result)
POLL_S = 0.2  # s between two checks of the harness
MAX_FUTILE_STARTS = 3  # workers in a row that exit without running a job: the run stops
SHUTDOWN_TIMEOUT_S = 5.0  # s for idle workers to exit after the last result (then killed)
PARENT_POLL_S = 1.0  # s between two checks of a worker (or agent process) that its parent lives
#: Imported once by the fork server, so each worker starts with them (numba's array support
#: pulls in scipy.linalg: most of what building the first World costs in a fresh process).
_PRELOAD = ["torch", "torchrl.collectors", "numba.np.arraymath", "v2xbench.collectors.eval_env"]


class RouteTimeout(RuntimeError):
    """A job overran the wall-clock limit; its worker was killed (recorded, never raised)."""


class WorkerDied(RuntimeError):
    """The worker process running a job ended before the job's result (recorded, never raised)."""


def check_route_timeout(route_timeout: Any) -> float:
    """``route_timeout`` as a float; ``ValueError`` unless it is a positive finite number of s."""
    try:
        t = float(route_timeout)
    except (TypeError, ValueError):
        t = float("nan")
    if isinstance(route_timeout, bool) or not 0.0 < t < float("inf"):
        raise ValueError(f"route_timeout={route_timeout!r} must be a positive finite number of "
                         "seconds (--route-timeout)")
    return t


def exit_with_parent(poll_s: float = PARENT_POLL_S) -> threading.Thread:
    """Start a daemon thread that ends this process (``os._exit(1)``) once its parent is gone
    (this process was re-parented): an isolated agent's process never outlives its worker.

    Not for processes forked by a ``multiprocessing`` fork server: their parent is the fork
    server, which lives as long as they do (use :func:`exit_when_closed`)."""
    ppid = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != ppid:
                os._exit(1)

    t = threading.Thread(target=watch, name="exit-with-parent", daemon=True)
    t.start()
    return t


def exit_when_closed(lifeline: Connection) -> threading.Thread:
    """Start a daemon thread that ends this process (``os._exit(1)``) once ``lifeline`` (the read
    end of a pipe) reads end-of-file: the process holding its write end closed it or died."""

    def watch() -> None:
        try:
            while True:
                lifeline.recv_bytes()
        except (EOFError, OSError):
            os._exit(1)

    t = threading.Thread(target=watch, name="exit-when-closed", daemon=True)
    t.start()
    return t


def worker_main(env_fn: Callable, policy: Any, frames_per_batch: int, lifeline: Connection) -> None:
    """A worker process: collect with one :class:`~.eval_env.EvalEnv` until it finds no job;
    ``lifeline`` is the read end of the harness's pipe (:func:`exit_when_closed`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the harness's to handle
    try:
        os.setpgid(0, 0)  # killing the group also kills an isolated agent's process
    except OSError:  # pragma: no cover - already a group leader
        pass
    exit_when_closed(lifeline)
    collect_jobs(env_fn, policy, frames_per_batch)


def collect_jobs(env_fn: Callable, policy: Any, frames_per_batch: int) -> None:
    """Build the :class:`~.eval_env.EvalEnv` of ``env_fn`` and run a ``Collector`` over it with
    ``policy`` until it finds no job left in its queue (the env writes each job's result). The
    work of one evaluation worker: a local worker process (:func:`worker_main`) or a Ray task
    (``eval_ray.py``). An exception that escapes the collector (a TorchRL policy's) fails the
    running job with it, then propagates."""
    import torch
    from torchrl.collectors import Collector

    torch.set_num_threads(1)
    env = env_fn()
    collector = None
    try:
        collector = Collector(env, policy, frames_per_batch=int(frames_per_batch), total_frames=-1,
                              auto_register_policy_transforms=False)
        for batch in collector:
            if bool((batch["job"] < 0).all() and (batch["next", "job"] < 0).all()):
                break  # a whole batch without a job: the queue is done for this worker
    except BaseException as e:  # the policy's, say: its job fails with it (not run again)
        env.fail_running_job(e)
        raise
    finally:
        if collector is not None:
            collector.shutdown()
        else:
            env.close()


def _context():
    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(_PRELOAD)  # no effect once the fork server runs
        return ctx
    return mp.get_context("spawn")  # pragma: no cover - platforms without fork


def _kill(proc) -> None:
    """Kill a worker and its process group, and reap it."""
    for kill in (lambda: os.killpg(proc.pid, signal.SIGKILL), proc.kill):
        try:
            kill()
        except (ProcessLookupError, PermissionError, OSError):
            continue
    proc.join(timeout=10.0)


def run_jobs(env_fn: Callable, policy: Any, *, workers: int, out: str | Path, jobs: list[J.Job],
             record_failure: Callable[[J.Job, str, BaseException, float], None],
             route_timeout: float = DEFAULT_ROUTE_TIMEOUT_S, frames_per_batch: int = 64,
             progress: bool = False, desc: str = "eval") -> dict:
    """Run ``jobs`` in supervised worker processes until each has a result (module docstring).

    Args:
        env_fn: picklable factory of the :class:`~.eval_env.EvalEnv` of a worker.
        policy: the collector policy (picklable).
        workers: most worker processes at a time.
        out: the output directory (claims and results).
        jobs: the queue.
        record_failure: ``(job, kind, error, wall_s)`` writes the result of a job that its worker
            could not finish (``kind`` ``"timeout"`` or ``"error"``).
        route_timeout: wall-clock limit of one job, s.
        frames_per_batch: frames of a worker's collector between two checks for more work.
        progress: show a progress bar (``desc`` its label).

    Returns:
        ``{"workers_started", "timeouts", "workers_died"}``.

    Raises:
        RuntimeError: :data:`MAX_FUTILE_STARTS` workers in a row ended without running a job.
    """
    from tqdm import tqdm

    route_timeout = check_route_timeout(route_timeout)
    ctx = _context()
    lifeline, lifeline_w = ctx.Pipe(duplex=False)  # workers exit when lifeline_w closes
    by_id = {j.job_id: j for j in jobs}
    procs: dict[int, Any] = {}  # pid -> live worker
    started_at: dict[int, float] = {}
    ran: set[int] = set()  # pids known to have claimed a job
    dead: dict[int, int | None] = {}  # pid -> exit code of workers that ended by themselves
    stats = {"workers_started": 0, "timeouts": 0, "workers_died": 0}
    futile, finished = 0, False

    def fail(claim: J.Claim, kind: str, error: BaseException) -> None:
        if not J.has_result(out, claim.job_id):  # it may have finished just before the kill
            record_failure(by_id[claim.job_id], kind, error, time.time() - claim.since)

    try:
        with tqdm(total=len(jobs), initial=J.count_results(out, jobs), desc=desc, unit="route",
                  disable=not progress) as bar:
            while True:
                done = J.count_results(out, jobs)
                bar.update(done - bar.n)
                if done >= len(jobs):
                    break
                ended = []
                for pid, proc in list(procs.items()):  # workers that ended (before the claims
                    if not proc.is_alive():           # are read: their claims are final then)
                        proc.join()
                        del procs[pid]
                        dead[pid] = proc.exitcode
                        ended.append(pid)
                claims = J.open_claims(out, jobs)
                ran.update(c.pid for c in claims.values() if c.pid in procs or c.pid in dead)
                now = time.time()
                for c in claims.values():
                    if c.pid in dead:  # its worker ended before writing the job's result
                        stats["workers_died"] += 1
                        fail(c, "error", WorkerDied(
                            f"the evaluation worker (pid {c.pid}) running this job exited with "
                            f"code {dead[c.pid]} before writing its result (os._exit or a crash "
                            "in the agent or the simulator?)"))
                    elif c.pid in procs and now - c.since > route_timeout:  # it overran
                        _kill(procs.pop(c.pid))
                        stats["timeouts"] += 1
                        fail(c, "timeout", RouteTimeout(
                            f"the job ran longer than the wall-clock limit of {route_timeout:g} s "
                            f"(--route-timeout); its worker (pid {c.pid}) was killed"))
                stuck = [pid for pid in procs if pid not in ran and now - started_at[pid] > route_timeout]
                if stuck or any(dead[pid] != 0 and pid not in ran for pid in ended):
                    ran.update(J.claim_pids(out))  # jobs may have come and gone between polls
                for pid in ended:
                    futile = 0 if pid in ran else futile + (dead[pid] != 0)
                for pid in stuck:
                    if pid not in ran:  # still building its env or agent after route_timeout
                        _kill(procs.pop(pid))
                        futile += 1
                if futile >= MAX_FUTILE_STARTS:
                    raise RuntimeError(
                        f"{futile} evaluation workers in a row ended before running a job (exit "
                        f"codes {sorted(set(dead.values()))}); see their output above")
                claims = J.open_claims(out, jobs)
                free = [j for j in jobs if j.job_id not in claims and not J.has_result(out, j.job_id)]
                if not procs and not free:  # claims that no live worker holds: run them again
                    J.clear_stale_claims(out, jobs)
                    claims = J.open_claims(out, jobs)
                    free = [j for j in jobs if j.job_id not in claims and not J.has_result(out, j.job_id)]
                busy = {c.pid for c in claims.values()}
                while len(procs) < workers and len(free) > sum(p not in busy for p in procs):
                    proc = ctx.Process(target=worker_main,
                                       args=(env_fn, policy, frames_per_batch, lifeline),
                                       name=f"v2xbench-eval-{stats['workers_started']}", daemon=True)
                    proc.start()
                    procs[proc.pid], started_at[proc.pid] = proc, time.time()
                    dead.pop(proc.pid, None)  # a reused pid
                    stats["workers_started"] += 1
                time.sleep(POLL_S)
        finished = True
    finally:
        deadline = time.time() + (SHUTDOWN_TIMEOUT_S if finished else 0.0)
        for proc in procs.values():  # idle once every result is in: let them close their envs
            proc.join(timeout=max(0.0, deadline - time.time()))
            if proc.is_alive():
                _kill(proc)
        lifeline.close()
        lifeline_w.close()
    return stats
