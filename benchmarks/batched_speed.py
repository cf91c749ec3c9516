"""Batched agent-steps per second: ``N`` worlds in the native TorchRL env, on up to 2 processes.

``N = 1`` runs in-process (one :class:`V2XTorchEnv` with one world); ``N >= 2`` runs TorchRL's
``MultiSyncCollector`` with 2 worker processes (``device="cpu"``), each stepping one
``V2XTorchEnv(num_worlds=N/2)`` with random actions: :func:`uniform_policy`, uniform over the
action box (no policy network). TorchRL's default for ``policy=None``, ``RandomPolicy`` over the
env's action spec, cost ~0.4 ms per batch step (pyinstrument, 32 worlds, 2026-11-26), ~13 us
per agent-step at ``N = 64``: the policy's cost, not the simulator's. An agent-step is one world
advancing one tick with its observation written. ``MultiSyncCollector`` waits for both workers'
batches before either goes on, so the slower worker's batch sets the pace (two single-process
collectors side by side measured 11,750 and 9,208 agent-steps/s, 2026-11-26); the last row runs
``N = 64`` through ``MultiAsyncCollector``, which yields each worker's batch as it comes (the
same frames, no barrier). Collector start-up (process spawn, imports, first reset) is not timed:
the clock starts at the first batch. Each worker steps its worlds ``STEPS_PER_BATCH`` times per
batch (a batch of ``N * 32`` frames, as RL batches of a few thousand frames): each batch costs
a round trip between the workers and the main process, which at 4 steps per batch took ~12 % of
the throughput at ``N = 64`` (8,228 / 8,337 against 9,281 / 9,674 agent-steps/s, 2026-11-25).
At least 4 batches and ``MIN_SECONDS`` of wall time are timed, after ``WARMUP_SECONDS`` of untimed
batches (``N = 1``: ``WARMUP_STEPS_ONE`` steps) in which every world reaches its first episode
end: numba loads some code on the first step after a second reset (``env_speed.warm_up``).
"""

from __future__ import annotations

import functools
import time

from .settle import settle

#: env steps of each worker per collector batch
STEPS_PER_BATCH = 32
#: s, least wall time of a collector row: 4 batches (~1 s at N = 64) gave 7,353 to 11,103
#: agent-steps/s for the same code in four runs
MIN_SECONDS = 4.0
#: s of untimed collector batches before the clock starts (episodes of the default config end
#: after ~130-230 ticks: ~0.1-0.5 s of a worker's 2-32 worlds)
WARMUP_SECONDS = 2.0
#: untimed steps of the in-process ``N = 1`` row
WARMUP_STEPS_ONE = 400


#: the action box, ``(throttle, steer, brake)``: ``low + span * U[0, 1)``
_LOW = (0.0, -1.0, 0.0)
_SPAN = (1.0, 2.0, 1.0)


def uniform_policy(td):
    """Random actions uniform over the action box for every world of ``td`` (module level, so the
    collector's workers can unpickle it)."""
    import torch

    n = td.batch_size[0]
    return td.set("action", torch.rand(n, 3) * torch.tensor(_SPAN) + torch.tensor(_LOW))


def _settled_env(n: int, config: dict):
    """A ``V2XTorchEnv`` of ``n`` worlds (one torch thread), after a full garbage collection (in
    a collector's worker the imports' objects are collected here, not in a timed batch)."""
    import torch
    from v2xbench.envs.v2x_intersection import V2XTorchEnv

    torch.set_num_threads(1)
    env = V2XTorchEnv(num_worlds=n, **config)
    settle()
    return env


def _make(n: int, config: dict):
    return functools.partial(_settled_env, n, config)


def measure_one(n: int, steps: int, config: dict | None = None, min_seconds: float = 0.0,
                collector: str = "sync", warmup_seconds: float = 0.0) -> dict:
    """Agent-steps/s for ``n`` worlds with at least ``steps`` agent-steps (and, for ``n >= 2``, 4
    collector batches and ``min_seconds`` of wall time) timed after ``warmup_seconds`` of untimed
    batches (``n = 1``: ``WARMUP_STEPS_ONE`` untimed steps when ``warmup_seconds > 0``, else 5);
    ``collector``: ``"sync"`` (``MultiSyncCollector``) or ``"async"`` (``MultiAsyncCollector``)
    for ``n >= 2``."""
    if collector not in ("sync", "async"):
        raise ValueError(f"collector={collector!r}: expected 'sync' or 'async'")
    import torch

    config = dict(config or {})
    torch.set_num_threads(1)
    if n == 1:
        env = _make(1, config)()
        env.set_seed(0)
        env.rollout(WARMUP_STEPS_ONE if warmup_seconds > 0 else 5, policy=uniform_policy,
                    break_when_any_done=False)
        settle()
        t0 = time.perf_counter()
        td = env.rollout(steps, policy=uniform_policy, break_when_any_done=False)
        dt = time.perf_counter() - t0
        return {"worlds": 1, "processes": 1, "collector": "in-process", "agent_steps": int(td.numel()),
                "seconds": dt, "agent_steps_per_s": td.numel() / dt}
    from torchrl.collectors import MultiAsyncCollector, MultiSyncCollector

    per = n // 2
    batch = 2 * per * STEPS_PER_BATCH
    frames = max(steps, 4 * batch)
    if collector == "async":  # each worker's batch is yielded as it comes: no barrier between them
        col = MultiAsyncCollector([_make(per, config)] * 2, policy=uniform_policy, frames_per_batch=batch // 2,
                                  total_frames=-1, device="cpu", trust_policy=True)
    else:
        col = MultiSyncCollector([_make(per, config)] * 2, policy=uniform_policy, frames_per_batch=batch,
                                 total_frames=-1, cat_results="stack", device="cpu", trust_policy=True)
    try:
        it = iter(col)
        next(it)  # warm-up batch: workers are up and every world has been reset
        t_warm = time.perf_counter()
        while time.perf_counter() - t_warm < warmup_seconds:
            next(it)
        got, t0 = 0, time.perf_counter()
        while got < frames or time.perf_counter() - t0 < min_seconds:
            got += next(it).numel()
        dt = time.perf_counter() - t0
    finally:
        col.shutdown()
    return {"worlds": n, "processes": 2, "collector": collector, "agent_steps": got, "seconds": dt,
            "agent_steps_per_s": got / dt}


def measure(worlds=(1, 4, 16, 64), steps: int = 2000, config: dict | None = None,
            min_seconds: float = MIN_SECONDS, async_worlds=(64,), warmup_seconds: float = WARMUP_SECONDS) -> dict:
    """One row per ``N`` in ``worlds`` (``MultiSyncCollector`` for ``N >= 2``), then one per ``N``
    in ``async_worlds`` with ``MultiAsyncCollector``."""
    rows = [measure_one(n, steps, config, min_seconds, warmup_seconds=warmup_seconds) for n in worlds]
    rows += [measure_one(n, steps, config, min_seconds, "async", warmup_seconds) for n in async_worlds]
    return {"rows": rows, "goal_agent_steps_per_s": 20000.0, "min_seconds": min_seconds,
            "warmup_seconds": warmup_seconds}


if __name__ == "__main__":
    import json

    print(json.dumps(measure(), indent=2))
