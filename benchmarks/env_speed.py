"""Objects-mode simulation speed, with highway-env ``intersection-v0`` measured in the same run.

Prints a table and writes JSON (``--out``). Run: ``python -m v2xbench.benchmarks.env_speed``.

V2XBench: ``gym.make("V2XIntersection-v0")`` (the suite passes a test50 route with its scenarios;
by default Town01 with the default population), the built-in RSU policy and a constant action;
one ``env.step`` = one 0.1 s tick. highway-env: ``intersection-v0`` and ``highway-fast-v0`` with
their default configs and the idle action; one ``env.step`` there is one policy step
(``simulation_frequency / policy_frequency`` physics frames, 1 s of simulated time in
``intersection-v0``). Ratios are printed per env step and per simulated second (fairer, since
the step lengths differ); the suite's target compares our ticks with highway-env's physics frames.
Single process, ``torch`` not involved.

The envs take turns: ``rounds`` rounds, in each of which every env steps for ``seconds / rounds``
of wall time (episodes go on across rounds, reset where they end). This machine's speed moves by
up to ~1.7x within minutes (2026-11-26: highway-env ``intersection-v0`` 326 then 431 frames/s in
two runs ten minutes apart, the full sensor rig 96 then 224 ticks/s); measured one after the
other, the envs could land in different spells and their ratio move with them. Taking turns,
each env sees the same mix of spells. Every env is warmed up first (:func:`warm_up`).
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

#: least untimed V2XBench steps before the clock starts (highway-env: 2), both then on through an
#: episode end (:func:`warm_up`)
WARMUP_STEPS = 100
#: most extra warm-up steps spent waiting for the first episode to end (see :func:`warm_up`)
WARMUP_EPISODE_CAP = 5000
#: turns each env takes, and the wall seconds each env is timed in all (the suite's objects row)
ROUNDS = 5
SECONDS = 10.0


def warm_up(env, action, seed: int = 0, warmup: int = 0) -> None:
    """Reset ``env`` with ``seed`` and, when ``warmup > 0``, step it at least ``warmup`` times and
    on through one episode end, its reset and the step after it (at most ``WARMUP_EPISODE_CAP``
    steps more); then reset it with ``seed`` again. numba loads each kernel from its disk cache on
    its first call in a process: ~160 ms over V2XBench's first 50 steps, which 3,000 timed steps
    would read as ~50 us a step; and some paths are first taken after a second reset (a new
    episode's arguments replace the first one's in the kernels' typed lists: ~12 ms on the first
    step after it, 3.6 % of 3,000 timed objects steps when it fell inside them)."""
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


class Stepper:
    """An env stepped in timed stretches with a constant action; episodes go on across stretches
    (reset with ``seed + steps so far`` where they end). ``steps``, ``wall`` and ``cpu`` add up
    the timed stretches."""

    def __init__(self, env, action, seed: int = 0, warmup: int = 0) -> None:
        self.env, self.action, self.seed = env, action, seed
        warm_up(env, action, seed, warmup)
        self.steps, self.wall, self.cpu = 0, 0.0, 0.0

    def run(self, steps: int | None = None, seconds: float | None = None) -> None:
        """Step ``steps`` times, or for at least ``seconds`` of wall time (one step at least),
        after a full garbage collection (untimed)."""
        env, action, clock = self.env, self.action, time.perf_counter
        settle()
        n = 0
        t0, c0 = clock(), time.process_time()
        while (n < steps) if steps is not None else (n == 0 or clock() - t0 < seconds):
            _, _, term, trunc, _ = env.step(action)
            n += 1
            if term or trunc:
                env.reset(seed=self.seed + self.steps + n)
        self.wall += clock() - t0
        self.cpu += time.process_time() - c0
        self.steps += n

    def rates(self) -> tuple[float, float]:
        """Steps per wall second and per CPU second."""
        return self.steps / max(self.wall, 1e-9), self.steps / max(self.cpu, 1e-9)


def timed_steps(env, action, steps: int, seed: int = 0, warmup: int = 0) -> tuple[float, float]:
    """Wall and CPU seconds of ``steps`` env steps after :func:`warm_up` (resetting when an
    episode ends)."""
    st = Stepper(env, action, seed, warmup)
    st.run(steps=steps)
    return st.wall, st.cpu


def measure(seconds: float = SECONDS, config: dict | None = None, rounds: int = ROUNDS) -> dict:
    """Measure V2XBench (``gym.make`` with ``config``) and highway-env step rates, taking turns
    (see the module docstring); returns a JSON-able dict.

    Raises:
        ValueError: ``seconds <= 0`` or ``rounds < 1``.
    """
    if not seconds > 0 or rounds < 1:
        raise ValueError(f"env_speed: seconds={seconds!r} must be > 0 and rounds={rounds!r} >= 1")
    import gymnasium as gym
    import numpy as np

    import v2xbench  # noqa: F401  (registers the ids)

    env = gym.make("V2XIntersection-v0", **(config or {}))
    env.reset(seed=0)
    w = env.unwrapped.world
    actors = int(w.table.active.sum())
    steppers = {"v2xbench_objects": Stepper(env, np.array([0.3, 0.0, 0.0], np.float32), warmup=WARMUP_STEPS)}
    rows: dict = {}
    try:
        import highway_env  # noqa: F401

        gym.register_envs(highway_env)
        for name in ("intersection-v0", "highway-fast-v0"):
            he = gym.make(name)
            steppers[name] = Stepper(he, 1, warmup=2)  # 1: IDLE in DiscreteMetaAction
    except ImportError:
        rows["highway-env"] = {"error": "highway-env not installed (pip install -e '.[dev]')"}
    for _ in range(rounds):
        for st in steppers.values():
            st.run(seconds=seconds / rounds)
    mine = steppers.pop("v2xbench_objects")
    ours, ours_cpu = mine.rates()
    rows = {"v2xbench_objects": {"steps_per_s": ours, "steps_per_cpu_s": ours_cpu, "actors": actors,
                                 "sim_s_per_step": 0.1, "sim_s_per_wall_s": ours * 0.1,
                                 "config": dict(config or {}), "scenarios": [type(sc).__name__ for sc in w.scenarios],
                                 "timed_steps": mine.steps, "timed_seconds": mine.wall}, **rows}
    for name, st in steppers.items():
        rate, cpu_rate = st.rates()
        cfg = st.env.unwrapped.config
        sim = 1.0 / cfg["policy_frequency"]
        rows[name] = {"steps_per_s": rate, "steps_per_cpu_s": cpu_rate,
                      "frames_per_step": cfg["simulation_frequency"] // cfg["policy_frequency"],
                      "sim_s_per_step": sim, "sim_s_per_wall_s": rate * sim, "ratio_v2xbench_to_this": ours / rate,
                      "sim_time_ratio": ours * 0.1 / (rate * sim), "timed_steps": st.steps,
                      "timed_seconds": st.wall}
    return {
        "benchmark": "env_speed", "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": f"{platform.machine()} {os.cpu_count()} cpus, {platform.python_implementation()} "
                   f"{platform.python_version()}",
        "seconds_per_env": seconds, "rounds": rounds, "results": rows,
        "goal": "v2xbench >= 50x highway-env intersection-v0 physics frames per second",
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--seconds", type=float, default=SECONDS, help="wall seconds each env is timed, in all")
    p.add_argument("--rounds", type=int, default=ROUNDS, help="turns each env takes")
    p.add_argument("--quick", action="store_true", help="tiny run for CI smoke tests")
    p.add_argument("--out", default="benchmarks/results")
    args = p.parse_args()
    res = measure(0.3 if args.quick else args.seconds, rounds=1 if args.quick else args.rounds)
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
