"""How fast an objects tick would be with no Python between its kernels (``v2xbench floor``).

The suite's objects row (``suite.OBJECTS_CONFIG``: ``gym.make``, a test50 route with its scenarios,
a constant action) calls six numba kernels a tick: the RSU's message, the traffic (ego, NPCs,
pedestrians), the event monitor, perception, the message's decode and the observation. Everything
else in ``env.step`` is Python: the action check, the stages' glue, the scenarios' hooks, the
channel's bookkeeping, the episode tracker and its info dict, Gymnasium's wrappers.

For each of ``episodes`` episodes (seeds ``0..episodes-1``) this module

1. times ``env.step`` over the whole episode (CPU time, ``k`` ticks, resets not timed);
2. resets the same episode, steps once with each kernel wrapped to keep its arguments, then calls
   the six kernels ``k`` times back to back on those arguments: a tick with the Python taken out.
   The world goes on moving (the traffic kernel advances it under the captured control, the other
   kernels read what it leaves), so the calls see ``k`` different states, as a tick would;
3. calls each kernel alone ``k`` times in a row (hot: its code and data stay in the CPU's caches).

``python_us`` (1 minus 2) is what the Python of a tick costs, its effect on the kernels' caches
included; ``interleave_us`` (2 minus the sum of 3) is what the kernels pay for running after each
other instead of alone. Each loop is preceded by a full garbage collection. numba only.

Run ``v2xbench floor``; writes ``OUT/floor_objects.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import time
from datetime import datetime, timezone
from pathlib import Path

from .settle import settle

#: ``(module under v2xbench.envs.v2x_intersection, kernel name)`` of the six per-tick kernels, in
#: the order a tick calls them (the module is where the tick looks the name up)
KERNELS = (
    ("sim.world", "builtin_message_kernel"),
    ("sim.jit_batch", "traffic_one_kernel"),
    ("evaluation.infractions", "monitor_kernel"),
    ("sim.jit_batch", "perceive_one_kernel"),
    ("v2x.channel", "decode_kernel"),
    ("api.observations", "ego_obs_packed_kernel"),
)
#: most ticks timed per episode (an episode that has not ended by then is cut there)
MAX_TICKS = 2000


def _capturing(calls: dict):
    """Wrap the six kernels where the tick looks them up (a context manager): each call stores
    ``(kernel, args)`` in ``calls[name]`` (the last call wins) and runs the kernel. The originals
    are put back on exit (:func:`.tick_profile.patched`)."""
    import importlib

    from .tick_profile import patched

    patches = []
    for mod_name, name in KERNELS:
        mod = importlib.import_module(f"v2xbench.envs.v2x_intersection.{mod_name}")
        kernel = getattr(mod, name)

        def wrapped(*args, _k=kernel, _n=name):
            calls[_n] = (_k, args)
            return _k(*args)

        patches.append((mod, name, wrapped))
    return patched(patches)


def measure(episodes: int = 30, max_ticks: int = MAX_TICKS) -> dict:
    """Run the three loops over ``episodes`` episodes (see the module docstring); returns a
    JSON-able report (microseconds per tick).

    Raises:
        ValueError: ``episodes < 1`` or ``max_ticks < 1``.
        RuntimeError: numba is not available (there are no kernels to time).
    """
    if episodes < 1 or max_ticks < 1:
        raise ValueError(f"floor: episodes={episodes!r} and max_ticks={max_ticks!r} must be >= 1")
    import gymnasium as gym
    import numpy as np
    from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT

    import v2xbench  # noqa: F401  (registers the ids)

    from .env_speed import WARMUP_STEPS, warm_up
    from .suite import OBJECTS_CONFIG

    if not HAVE_JIT:
        raise RuntimeError("floor: numba is not available (or V2XBENCH_NO_JIT is set): there are no kernels to time")
    env = gym.make("V2XIntersection-v0", **OBJECTS_CONFIG)
    action = np.array([0.3, 0.0, 0.0], np.float32)
    warm_up(env, action, 0, WARMUP_STEPS)
    clock = time.process_time
    step_s = chain_s = 0.0
    alone_s = {name: 0.0 for _, name in KERNELS}
    ticks = 0
    called: set[str] = set()  # kernels captured on the first step of at least one episode
    calls: dict = {}
    for ep in range(episodes):
        env.reset(seed=ep)
        settle()
        k, c0 = 0, clock()
        while k < max_ticks:
            _, _, term, trunc, _ = env.step(action)
            k += 1
            if term or trunc:
                break
        step_s += clock() - c0
        ticks += k
        env.reset(seed=ep)
        calls.clear()
        with _capturing(calls):
            env.step(action)
        chain = [calls[name] for _, name in KERNELS if name in calls]
        called |= set(calls)
        settle()
        c0 = clock()
        for _ in range(k):
            for kernel, args in chain:
                kernel(*args)
        chain_s += clock() - c0
        for _, name in KERNELS:
            if name not in calls:
                continue
            kernel, args = calls[name]
            settle()
            c0 = clock()
            for _ in range(k):
                kernel(*args)
            alone_s[name] += clock() - c0
    env.close()
    us = 1e6 / ticks
    missing = {name for _, name in KERNELS if name not in called}
    alone = {name: s * us for name, s in alone_s.items() if name in called}
    step_us, chain_us = step_s * us, chain_s * us
    return {
        "benchmark": "kernel_floor", "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "config": dict(OBJECTS_CONFIG), "episodes": episodes, "ticks": ticks,
        "env_step_us": step_us, "kernels_back_to_back_us": chain_us, "kernels_alone_us": alone,
        "kernels_alone_sum_us": sum(alone.values()), "python_us": step_us - chain_us,
        "interleave_us": chain_us - sum(alone.values()), "kernels_not_called": sorted(missing),
    }


def table(r: dict) -> str:
    """The report as Markdown."""
    step = r["env_step_us"]
    lines = [
        f"Kernel floor, objects ({r['config']}), {r['episodes']} episodes, {r['ticks']} ticks, {r['date']}",
        "",
        "| loop | us per tick | ticks per second | share of env.step |",
        "| --- | ---: | ---: | ---: |",
        f"| env.step | {step:.1f} | {1e6 / step:,.0f} | 100 % |",
        f"| the six kernels back to back | {r['kernels_back_to_back_us']:.1f} | "
        f"{1e6 / r['kernels_back_to_back_us']:,.0f} | {100 * r['kernels_back_to_back_us'] / step:.0f} % |",
        f"| the kernels alone, summed | {r['kernels_alone_sum_us']:.1f} | "
        f"{1e6 / r['kernels_alone_sum_us']:,.0f} | {100 * r['kernels_alone_sum_us'] / step:.0f} % |",
        "",
        f"Python between the kernels: {r['python_us']:.1f} us a tick; the kernels' cost of running after "
        f"each other instead of alone: {r['interleave_us']:.1f} us.",
        "",
        "| kernel, alone | us per tick |",
        "| --- | ---: |",
    ]
    lines += [f"| {k} | {v:.1f} |" for k, v in r["kernels_alone_us"].items()]
    if r["kernels_not_called"]:
        lines += ["", f"Not called on any episode's captured step: {', '.join(r['kernels_not_called'])}."]
    return "\n".join(lines) + "\n"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--episodes", type=int, default=30, help="episodes of test50 route 0 (default 30)")
    p.add_argument("--max-ticks", type=int, default=MAX_TICKS, help=f"most ticks per episode (default {MAX_TICKS})")
    p.add_argument("--out", default="benchmarks/results", help="directory for floor_objects.json and .md")


def run(args: argparse.Namespace) -> int:
    from .suite import _write

    report = measure(args.episodes, args.max_ticks)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    md = table(report)
    _write(out / "floor_objects.json", json.dumps(report, indent=2))
    _write(out / "floor_objects.md", md)
    print(md)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="v2xbench floor", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
