"""The Ray backend of the evaluation (``v2xbench eval --backend ray [--address ADDR]``).

The local backend (``eval_workers.run_jobs``) runs worker processes that claim jobs from the
queue in ``<out>/claims`` and write their results into ``<out>`` themselves, which needs one
filesystem. Here the driver is the queue: each job is one Ray task (``num_cpus=1``, no retries)
that runs :func:`run_job` on whichever node Ray picks. The task builds the same
:class:`~.eval_env.EvalEnv` as a local worker (the run's ``env_fn`` with a queue of that one job
and a temporary output directory on the node) and drives it with the same code
(``eval_workers.collect_jobs``: a TorchRL ``Collector``, ``torch.set_num_threads(1)``); it returns
the job's result (and its GIF with ``--video``) to the driver, which writes them into ``<out>``
atomically (``jobs.write_json_atomic``, ``v2xbench.files``). So results live on the driver's
filesystem only, are byte for byte what a local worker writes (the wall-clock fields aside), and
resume, ``--retry-failed`` and ``--overwrite`` behave as with the local backend: the driver skips
the jobs whose result exists before submitting any task.

At most ``min(workers, the cluster's CPUs)`` tasks run at a time (``--workers``). Supervision
mirrors the local backend's:

- a task that has not returned ``route_timeout`` seconds after it was submitted (its env's build
  on the node included) is cancelled (``ray.cancel(force=True)`` kills its worker process, and an
  isolated agent's process ends with it) and its job gets a ``failure = "timeout"`` result;
- a task whose worker process or node died (``os._exit`` in the agent, a crash, Ray's OOM killer)
  gives its job a ``failure = "error"`` result (``eval_workers.WorkerDied``);
- a task that could not start its job (the env or agent cannot be built on the node) leaves the
  job to the next task; after ``eval_workers.MAX_FUTILE_STARTS`` such tasks in a row the run stops
  with a ``RuntimeError`` naming the node and the error;
- a node whose agent code differs from the driver's (``agent_fingerprint.code_digests``: another
  v2xbench version or agent file there) stops the run with a ``RuntimeError`` naming the node and
  the files: its results would not be the ones the run's fingerprint promises.

Ray connection (:func:`connect`): with Ray already initialised in this process (a library user's
``ray.init``) that cluster is used; else ``address`` (``HEAD:6379``, ``auto``) or the
``RAY_ADDRESS`` environment variable is connected to; else a local Ray instance with ``workers``
CPUs is started for the run and shut down after it. Ray is an optional extra
(``pip install -e ".[ray]"``); :func:`require_ray` says so when it is missing.
"""

from __future__ import annotations

import collections
import functools
import json
import os
import socket
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from v2xbench.files import atomic_write_bytes

from . import jobs as J
from .eval_workers import (
    MAX_FUTILE_STARTS,
    POLL_S,
    RouteTimeout,
    WorkerDied,
    check_route_timeout,
    collect_jobs,
)

BACKENDS = ("local", "ray")
RAY_INSTALL = 'pip install -e ".[ray]"'
CONNECT_TIMEOUT_S = 10.0  # s to reach a Ray cluster's address before refusing it


class RayUnavailable(ValueError):
    """``--backend ray`` without Ray installed (the message says how to install it)."""


class NodeMismatch(RuntimeError):
    """A Ray node runs other agent code than the driver (another v2xbench or agent file)."""


def check_backend(backend: Any, address: Any = None) -> None:
    """Refuse an unknown ``backend``, an ``address`` without ``backend="ray"``, ``"ray"``
    without Ray installed (:class:`RayUnavailable`) or a ``HOST:PORT`` address where nothing
    listens, before anything is written."""
    if backend not in BACKENDS:
        raise ValueError(f"backend={backend!r} must be one of {', '.join(BACKENDS)} (--backend)")
    if address is not None and backend != "ray":
        raise ValueError(f"--address {address!r} is the address of a Ray cluster: it needs "
                         "--backend ray")
    if address is not None and (not isinstance(address, str) or not address.strip()):
        raise ValueError(f"address={address!r} must be a Ray address such as HEAD:6379 or auto")
    if backend == "ray":
        require_ray()
        if address is not None or os.environ.get("RAY_ADDRESS"):
            _check_reachable(str(address or os.environ["RAY_ADDRESS"]))


def ray_address(address: str | None) -> str | None:
    """The cluster a run with ``address`` uses (``RAY_ADDRESS`` without one); ``None``: a local
    instance of its own (or the one this process had already initialised)."""
    return address or os.environ.get("RAY_ADDRESS") or None


def require_ray():
    """The ``ray`` module; :class:`RayUnavailable` naming the install command when it is missing."""
    try:
        import ray
    except ImportError as e:
        raise RayUnavailable(
            f"--backend ray needs Ray, which is not installed ({e}); install the optional extra "
            f"with `{RAY_INSTALL}` (the same on every node of the cluster)") from None
    return ray


def _check_reachable(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """``ValueError`` when nothing listens at a ``HOST:PORT`` address (``ray.init`` would retry
    for many minutes); other forms (``auto``, ``ray://...``) are left to Ray."""
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or "/" in address:
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise ValueError(f"no Ray cluster answers at {address} (--address / RAY_ADDRESS): {e}; "
                         "start its head node with `ray start --head` (docs/evaluation.md, "
                         "'Scale-out on Ray')") from None


def connect(address: str | None, workers: int) -> bool:
    """Connect this process to Ray (module docstring); returns whether a local instance was
    started here (then the caller shuts it down)."""
    ray = require_ray()
    if ray.is_initialized():
        return False
    if address is None and not os.environ.get("RAY_ADDRESS"):
        ray.init(address="local", num_cpus=int(workers), include_dashboard=False,
                 log_to_driver=True)  # "local": never a cluster a stale file names
        return True
    where = address or os.environ.get("RAY_ADDRESS")
    _check_reachable(str(where))
    try:
        ray.init(address=address, log_to_driver=True)
    except ConnectionError as e:
        raise ValueError(
            f"cannot connect to the Ray cluster at {where} (--address / RAY_ADDRESS): {e}. Is "
            "`ray start --head` running there? With Ray's token authentication this process "
            "needs RAY_AUTH_MODE=token and the cluster's token (~/.ray/auth_token or "
            "RAY_AUTH_TOKEN): docs/evaluation.md, 'Scale-out on Ray'") from None
    return False


# --------------------------------------------------------------------------- the task


def _check_code(agent: Any, expected: dict[str, str] | None, node: str) -> str | None:
    """``None`` when ``agent``'s code here has the digests the driver computed; else what
    differs (a :class:`NodeMismatch` message)."""
    if agent is None or not expected:
        return None
    from .agent_fingerprint import code_digests

    try:
        here = code_digests(agent)
    except ValueError as e:
        return f"node {node} cannot find the agent's code: {e}"
    diff = sorted(k for k in set(here) | set(expected) if here.get(k) != expected.get(k))
    if not diff:
        return None
    return (f"node {node} has other agent code than the driver ({', '.join(diff)} differ): "
            "install the same v2xbench and agent files on every node")


def run_job(env_fn: Callable, policy: Any, job: J.Job, frames_per_batch: int, out: str,
            cwd: str, code: dict[str, str] | None) -> dict:
    """Run one job as a local evaluation worker would and return what the driver writes.

    ``env_fn`` is the run's ``EvalEnv`` factory (``eval_env.make_env_factory``); the job runs in a
    temporary output directory on this node, from ``cwd`` (the driver's working directory, when
    it exists here, so relative agent and suite paths mean what they mean on the driver). ``code``
    are the agent's code digests on the driver (checked first).

    Returns:
        ``{"job_id", "node", "result"}`` (``result``: the result dict, ``None`` when the job has
        none) with ``"claimed"`` (whether the env started the job), ``"error"`` (what stopped
        the task early), ``"mismatch"`` (:func:`_check_code`) and ``"video"`` (the GIF's bytes).
    """
    node = socket.gethostname()
    res: dict[str, Any] = {"job_id": job.job_id, "node": node, "result": None, "claimed": False,
                           "error": None, "mismatch": None, "video": None}
    if os.path.isdir(cwd):
        os.chdir(cwd)
    res["mismatch"] = _check_code(env_fn.keywords.get("agent"), code, node)
    if res["mismatch"]:
        return res
    with tempfile.TemporaryDirectory(prefix="v2xbench-ray-") as tmp:
        try:
            collect_jobs(functools.partial(env_fn, out=tmp, jobs=[job]), policy, frames_per_batch)
        except BaseException as e:  # noqa: BLE001  (reported to the driver, which decides)
            res["error"] = "".join(traceback.format_exception(type(e), e, e.__traceback__))
        path = J.result_path(tmp, job.job_id)
        res["claimed"] = path.is_file() or (J.claims_dir(tmp) / job.job_id).exists()
        if path.is_file():
            result = json.loads(path.read_text())
            gif = Path(tmp) / "videos" / f"{job.job_id}.gif"
            if result.get("video") == str(gif) and gif.is_file():
                res["video"] = gif.read_bytes()
                result["video"] = str(Path(out) / "videos" / gif.name)  # where the driver puts it
            res["result"] = result
    return res


# --------------------------------------------------------------------------- the driver


def _write(out: Path, res: dict) -> None:
    """Write a task's video (first) and result into ``out`` atomically."""
    result = res["result"]
    if res["video"] is not None:
        atomic_write_bytes(Path(out) / "videos" / f"{res['job_id']}.gif", res["video"])
    J.write_json_atomic(result, J.result_path(out, res["job_id"]))


def run_jobs_ray(env_fn: Callable, policy: Any, *, workers: int, out: str | Path,
                 jobs: list[J.Job], record_failure: Callable[[J.Job, str, BaseException, float],
                                                             None],
                 route_timeout: float, frames_per_batch: int = 64, progress: bool = False,
                 desc: str = "eval", address: str | None = None,
                 code: dict[str, str] | None = None) -> dict:
    """Run the ``jobs`` without a result as Ray tasks until each has one (module docstring).

    Args:
        env_fn, policy, workers, out, jobs, record_failure, route_timeout, frames_per_batch,
            progress, desc: as ``eval_workers.run_jobs`` (``workers``: most tasks at a time).
        address: the Ray cluster (:func:`connect`).
        code: the agent's code digests on the driver (``agent_fingerprint.code_digests``), checked
            on every node.

    Returns:
        ``{"workers_started" (tasks submitted), "timeouts", "workers_died", "ray_cpus"}``.

    Raises:
        RuntimeError: ``MAX_FUTILE_STARTS`` tasks in a row could not start their job;
            :class:`NodeMismatch`: a node runs other agent code.
        RayUnavailable: Ray is not installed.
    """
    from tqdm import tqdm

    route_timeout = check_route_timeout(route_timeout)
    ray = require_ray()
    from ray.exceptions import RaySystemError, RayTaskError

    out = Path(out)
    started = connect(address, workers)
    stats = {"workers_started": 0, "timeouts": 0, "workers_died": 0, "ray_cpus": 0}
    inflight: dict[Any, tuple[J.Job, float]] = {}  # task ref -> (job, submitted at)
    try:
        cpus = int(ray.cluster_resources().get("CPU", 0))
        stats["ray_cpus"] = cpus
        limit = max(1, min(int(workers), cpus or int(workers)))
        task = ray.remote(run_job).options(num_cpus=1, max_retries=0, name="v2xbench-eval-job")
        env_ref, policy_ref = ray.put(env_fn), ray.put(policy)
        cwd, out_str = os.getcwd(), str(env_fn.keywords.get("out", out))
        pending = collections.deque(j for j in jobs if not J.has_result(out, j.job_id))
        futile = 0
        with tqdm(total=len(jobs), initial=J.count_results(out, jobs), desc=desc, unit="route",
                  disable=not progress) as bar:
            while pending or inflight:
                while pending and len(inflight) < limit:
                    job = pending.popleft()
                    ref = task.remote(env_ref, policy_ref, job, int(frames_per_batch), out_str,
                                      cwd, code)
                    inflight[ref] = (job, time.time())
                    stats["workers_started"] += 1
                ready, _ = ray.wait(list(inflight), num_returns=len(inflight), timeout=POLL_S)
                for ref in ready:
                    job, since = inflight.pop(ref)
                    try:
                        res = ray.get(ref)
                    except (RayTaskError, RaySystemError) as e:  # the task could not run at all
                        res = {"result": None, "claimed": False, "mismatch": None,
                               "node": "?", "error": f"{type(e).__name__}: {e}"}
                    except ray.exceptions.RayError as e:  # its worker process or node died
                        stats["workers_died"] += 1
                        record_failure(job, "error", WorkerDied(
                            f"the Ray worker running this job died before returning its result "
                            f"({type(e).__name__}: {e})"), time.time() - since)
                        futile = 0
                        continue
                    if res["mismatch"]:
                        raise NodeMismatch(res["mismatch"])
                    if res["result"] is not None:
                        _write(out, res)
                        futile = 0
                    elif res["claimed"]:  # started, but no result (should not happen)
                        record_failure(job, "error", WorkerDied(
                            f"the Ray task running this job on node {res['node']} ended without "
                            f"its result: {res['error']}"), time.time() - since)
                        futile = 0
                    else:  # the env or agent could not be built there: another task tries
                        futile += 1
                        pending.appendleft(job)
                        if futile >= MAX_FUTILE_STARTS:
                            raise RuntimeError(
                                f"{futile} Ray tasks in a row could not start their job; the "
                                f"last (node {res['node']}) said:\n{res['error']}")
                now = time.time()
                for ref, (job, since) in list(inflight.items()):
                    if now - since > route_timeout and not ray.wait([ref], timeout=0)[0]:
                        ray.cancel(ref, force=True)
                        del inflight[ref]
                        stats["timeouts"] += 1
                        record_failure(job, "timeout", RouteTimeout(
                            f"the job ran longer than the wall-clock limit of {route_timeout:g} s "
                            "(--route-timeout) from its Ray task's submission; the task was "
                            "cancelled"), now - since)
                bar.update(J.count_results(out, jobs) - bar.n)
    finally:
        for ref in inflight:  # Ctrl-C or an error: stop what still runs
            try:
                ray.cancel(ref, force=True)
            except Exception as e:  # noqa: BLE001
                print(f"v2xbench eval: could not cancel a Ray task ({e})", file=sys.stderr)
        if started:
            ray.shutdown()
    return stats
