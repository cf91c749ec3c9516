"""Objects-mode simulation speed, with highway-env ``intersection-v0`` measured in the same run.

Prints a table and writes JSON (``--out``). Run: ``python benchmarks/env_speed.py``.

V2XBench: ``gym.make("V2XIntersection-v0")`` on Town01 with the default population (30 NPC
vehicles, 10 parked, 12 pedestrians, 3 bicycles + ego = 56 actors), the built-in RSU policy and a
constant action; one ``env.step`` = one 0.1 s tick. highway-env: ``intersection-v0`` and
``highway-fast-v0`` with their default configs and the idle action; one ``env.step`` there is one
policy step (``simulation_frequency / policy_frequency`` physics frames, 1 s of simulated time in
``intersection-v0``). Two ratios are printed: env steps per second, and simulated seconds per wall
second (fairer, since the step lengths differ). Single process, ``torch`` not involved. Both are
timed after a few untimed steps from the same reset (numba's kernels load on their first call).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from datetime import datetime, timezone
from pathlib import Path

from .settle import settle

_CPU_RATE: dict = {}
#: untimed V2XBench steps before the clock starts (highway-env gets 2, ~0.1 s of its time)
WARMUP_STEPS = 100
#: most extra warm-up steps spent waiting for the first episode to end (see :func:`timed_steps`)
WARMUP_EPISODE_CAP = 5000


def timed_steps(env, action, steps: int, seed: int = 0, warmup: int = 0) -> tuple[float, float]:
    """Wall and CPU seconds of ``steps`` env steps (resetting when an episode ends), timed after
    a full garbage collection and, when ``warmup > 0``, at least ``warmup`` untimed steps that
    also take the env through one episode end, its reset and the step after it (at most
    ``WARMUP_EPISODE_CAP`` steps more). numba loads each kernel from its disk cache on its first
    call in a process: ~160 ms over V2XBench's first 50 steps, which 3,000 timed steps would read
    as ~50 us a step; and some paths are first taken after a second reset (a new episode's
    arguments replace the first one's in the kernels' typed lists: ~12 ms on the first step
    after it, 3.6 % of the objects row's 3,000 timed steps when it fell inside them)."""
    env.reset(seed=seed)
    k, after_reset = 0, -1  # warm-up steps; steps since the warm-up's first reset (-1: none yet)
    while warmup and (k < warmup or after_reset < 1) and k < warmup + WARMUP_EPISODE_CAP:
        _, _, term, trunc, _ = env.step(action)
        k += 1
        after_reset += after_reset >= 0
        if term or trunc:
            env.reset(seed=seed + k)
            after_reset = max(after_reset, 0)
    env.reset(seed=seed)
    settle()
    n = 0
    t0, c0 = time.perf_counter(), time.process_time()
    while n < steps:
        _, _, term, trunc, _ = env.step(action)
        n += 1
        if term or trunc:
            env.reset(seed=seed + n)
    return time.perf_counter() - t0, time.process_time() - c0


def _rate(env, action, steps: int, seed: int = 0, warmup: int = 0) -> float:
    """Env steps per wall second (:func:`timed_steps`; the rate per CPU second is left in
    ``_CPU_RATE[id(env)]``)."""
    wall, cpu = timed_steps(env, action, steps, seed, warmup)
    _CPU_RATE[id(env)] = steps / max(cpu, 1e-9)
    return steps / wall


def measure(steps: int, config: dict | None = None) -> dict:
    """Measure V2XBench (``gym.make`` with ``config``) and highway-env step rates; returns a
    JSON-able dict."""
    import gymnasium as gym
    import numpy as np

    import v2xbench  # noqa: F401  (registers the ids)

    env = gym.make("V2XIntersection-v0", **(config or {}))
    env.reset(seed=0)
    w = env.unwrapped.world
    actors = int(w.table.active.sum())
    ours = _rate(env, np.array([0.3, 0.0, 0.0], np.float32), steps, warmup=WARMUP_STEPS)
    rows = {"v2xbench_objects": {"steps_per_s": ours, "steps_per_cpu_s": _CPU_RATE[id(env)], "actors": actors,
                                 "sim_s_per_step": 0.1,
                                 "sim_s_per_wall_s": ours * 0.1, "config": dict(config or {}),
                                 "scenarios": [type(sc).__name__ for sc in w.scenarios]}}
    try:
        import highway_env  # noqa: F401

        gym.register_envs(highway_env)
        for name in ("intersection-v0", "highway-fast-v0"):
            he = gym.make(name)
            he.reset(seed=0)
            idle = 1  # IDLE in DiscreteMetaAction
            cfg = he.unwrapped.config
            frames = cfg["simulation_frequency"] // cfg["policy_frequency"]
            rate = _rate(he, idle, max(steps // 10, 20), warmup=2)
            sim = 1.0 / cfg["policy_frequency"]
            rows[name] = {"steps_per_s": rate, "steps_per_cpu_s": _CPU_RATE[id(he)], "frames_per_step": frames,
                          "sim_s_per_step": sim,
                          "sim_s_per_wall_s": rate * sim, "ratio_v2xbench_to_this": ours / rate,
                          "sim_time_ratio": ours * 0.1 / (rate * sim)}
    except ImportError:
        rows["highway-env"] = {"error": "highway-env not installed (pip install -e '.[dev]')"}
    return {
        "benchmark": "env_speed", "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": f"{platform.machine()} {os.cpu_count()} cpus, {platform.python_implementation()} "
                   f"{platform.python_version()}",
        "steps": steps, "results": rows, "goal": "v2xbench >= 50x highway-env intersection-v0 (later issue)",
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--quick", action="store_true", help="tiny run for CI smoke tests")
    p.add_argument("--out", default="benchmarks/results")
    args = p.parse_args()
    res = measure(100 if args.quick else args.steps)
    print(f"{'env':18s} {'steps/s':>9s} {'sim s/step':>10s} {'sim s/wall s':>12s} {'step ratio':>10s} {'sim-time ratio':>14s}")
    for name, r in res["results"].items():
        if "error" in r:
            print(f"{name:18s} {r['error']}")
            continue
        ratio, sratio = r.get("ratio_v2xbench_to_this"), r.get("sim_time_ratio")
        print(f"{name:18s} {r['steps_per_s']:9.1f} {r['sim_s_per_step']:10.3f} {r['sim_s_per_wall_s']:12.1f} "
              f"{'' if ratio is None else f'{ratio:10.2f}'} {'' if sratio is None else f'{sratio:14.2f}'}")
    print("ratios: V2XBench over the row's env (step ratio: env steps/s; sim-time ratio: simulated seconds/s)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "env_speed.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(res, indent=2))
    tmp.replace(path)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
