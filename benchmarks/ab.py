"""Same-minute A/B of the tick's cost: this checkout against another git revision.

On a shared 2-core machine the cost of a tick drifts by +-25 % within minutes, so two versions
compare only when measured in the same minutes, alternately. ``v2xbench ab REV`` checks ``REV``
out into a temporary git worktree and runs ``--pairs`` pairs of fresh processes, the revision
then this checkout, each timing CPU seconds per tick of one workload:

- ``objects``: ``gym.make`` on test50 route 0, constant action, resets included (the suite's
  objects row), 300 ticks of warm-up then ``--ticks`` timed;
- ``batched``: the native TorchRL env with 32 worlds and random actions, per world-step;
- ``test50``: every test50 route in turn (``--ticks`` / 50 ticks each, constant action, resets
  included; the routes built and 20 ticks of each driven before the clock starts), the workload
  of ``v2xbench profile --mode test50``, with all 38 scenario types' hooks;
- ``expert``: the privileged expert drives test50 route 0 (``Expert.act`` then ``env.step``),
  resets included, 300 ticks of warm-up then ``--ticks`` timed: the closed-loop evaluation's and
  the dataset collection's tick;
- ``perception``: ``World.perceive`` alone, hot, on the states of the ``objects`` workload: after
  each of ``--ticks`` steps it is called three more times (it writes only its outputs, the same
  each time) and the third call is timed (same code on both sides: 4 pairs within 13.8-14.3 us,
  median ratio 0.995). A kernel looped on one state can mislead: the vectorized sight test of
  2026-11-26 took perception from 11.5 to 9.0 us on tick 60 of test50 route 0, and from 15.3 to
  15.2 us over 500 of its states (docs/performance.md, "How to measure").

It prints both series and the median of the pairwise ratios (REV / this: above 1 means this
checkout is faster), and writes them as JSON with ``--out``. Both sides are imported the same way:
from a package directory of symlinks into their tree (the editable install bypassed), with the
same installed dependencies, after one untimed run each in which numba compiles or loads every
kernel. (Measuring this checkout through its editable install instead, and the revision without
that untimed run, read identical code as 1.16x faster on this side: the revision's first runs
compiled kernels that a 300-tick warm-up does not reach, such as those of resets.)
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from .suite import _write as write_atomic

#: the child process: ``python -c CHILD <mode> <ticks> [package dir]``
CHILD = r"""
import gc, sys, time
if len(sys.argv) > 3:  # import the revision: bypass the editable install, put its tree first
    sys.meta_path = [f for f in sys.meta_path if "editable" not in (type(f).__module__ + type(f).__name__).lower()]
    sys.path.insert(0, sys.argv[3])
import numpy as np
mode, ticks = sys.argv[1], int(sys.argv[2])
if mode == "test50":
    import gymnasium as gym
    import v2xbench  # noqa: F401
    envs = [gym.make("V2XIntersection-v0", suite="test50", route_index=i) for i in range(50)]
    act = np.array([0.4, 0.0, 0.0], np.float32)
    def drive(env, n):
        env.reset(seed=0)
        for k in range(n):
            _, _, term, trunc, _ = env.step(act)
            if term or trunc:
                env.reset(seed=k + 1)
    for env in envs:
        drive(env, 20)
    per = max(ticks // 50, 1)
    gc.collect()  # as benchmarks/settle.py: no full collection of set-up's objects in the timed loop
    c0 = time.process_time()
    for env in envs:
        drive(env, per)
    print(1e6 * (time.process_time() - c0) / (per * 50))
elif mode == "perception":
    import gymnasium as gym
    import v2xbench  # noqa: F401
    env = gym.make("V2XIntersection-v0", suite="test50", route_index=0)
    act = np.array([0.3, 0.0, 0.0], np.float32)
    w, clock, spent = env.unwrapped.world, time.perf_counter_ns, 0
    env.reset(seed=0)
    for k in range(300 + ticks):
        _, _, term, trunc, _ = env.step(act)
        if term or trunc:
            env.reset(seed=k + 1)
        w.perceive()
        w.perceive()
        t0 = clock()
        w.perceive()
        spent += (clock() - t0) if k >= 300 else 0
    print(spent / 1e3 / ticks)
elif mode in ("objects", "expert"):  # a constant action, or the expert driving
    import gymnasium as gym
    import v2xbench  # noqa: F401
    env = gym.make("V2XIntersection-v0", suite="test50", route_index=0)
    if mode == "expert":
        from v2xbench.agents.expert import Expert
        agent = Expert()
        act = agent.act
        def start(seed):
            obs, _ = env.reset(seed=seed)
            agent.bind(env.unwrapped.world)
            return obs
    else:
        const = np.array([0.3, 0.0, 0.0], np.float32)
        act = lambda obs: const  # noqa: E731
        def start(seed):
            return env.reset(seed=seed)[0]
    def run(n, seed):
        obs = start(seed)
        for k in range(n):
            obs, _, term, trunc, _ = env.step(act(obs))
            if term or trunc:
                obs = start(seed + k + 1)
    run(300, 1)
    gc.collect()  # as benchmarks/settle.py: no full collection of set-up's objects in the timed loop
    c0 = time.process_time()
    run(ticks, 0)
    print(1e6 * (time.process_time() - c0) / ticks)
else:
    import torch
    torch.set_num_threads(1)
    from v2xbench.envs.v2x_intersection import V2XTorchEnv
    env = V2XTorchEnv(num_worlds=32)
    env.set_seed(0)
    env.rollout(20, break_when_any_done=False)
    steps = max(ticks // 32, 10)
    gc.collect()  # as benchmarks/settle.py: no full collection of set-up's objects in the timed loop
    c0 = time.process_time()
    env.rollout(steps, break_when_any_done=False)
    print(1e6 * (time.process_time() - c0) / (steps * 32))
"""

MODES = ("objects", "batched", "test50", "perception", "expert")
_PARTS = ("envs", "agents", "collectors", "benchmarks")
#: ticks of the untimed run of each side before the pairs (every kernel compiled or cached)
WARMUP_TICKS = 2000


def _package_dir(tree: Path, into: Path) -> Path:
    """A directory holding a ``v2xbench`` package assembled from ``tree`` by symlinks (the layout
    that pyproject's package-dir mapping gives)."""
    pkg = into / "v2xbench"
    pkg.mkdir(parents=True)
    for f in (tree / "v2xbench").iterdir():
        (pkg / f.name).symlink_to(f)
    for part in _PARTS:
        (pkg / part).symlink_to(tree / part)
    return into


def _measure(mode: str, ticks: int, pkg: Path | None) -> float:
    cmd = [sys.executable, "-c", CHILD, mode, str(ticks)] + ([str(pkg)] if pkg else [])
    out = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"measurement failed ({'revision' if pkg else 'this checkout'}):\n{out.stderr[-2000:]}")
    return float(out.stdout.strip().splitlines()[-1])


def ab(rev: str, mode: str = "objects", pairs: int = 5, ticks: int = 4000, repo: Path | None = None) -> dict:
    """Interleaved A/B of ``rev`` (A) against the checkout at ``repo`` (B); us per tick (objects,
    test50) or per world-step (batched)."""
    repo = Path(repo or Path(__file__).resolve().parents[1])
    with tempfile.TemporaryDirectory(prefix="v2xbench-ab-") as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "-C", str(repo), "worktree", "add", "--detach", "-f", str(tree), rev],
                       check=True, capture_output=True)
        try:
            sha = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], check=True,
                                 capture_output=True, text=True).stdout.strip()
            pkg = _package_dir(tree, Path(tmp) / "pkg")
            here = _package_dir(repo, Path(tmp) / "here")  # imported the same way as the revision
            for p in (pkg, here):  # untimed: numba compiles or loads every kernel into its tree's cache
                _measure(mode, WARMUP_TICKS, p)
            a, b = [], []
            for k in range(pairs):
                a.append(_measure(mode, ticks, pkg))
                b.append(_measure(mode, ticks, here))
                print(f"pair {k + 1}/{pairs}: {rev} {a[-1]:.1f} us, this checkout {b[-1]:.1f} us", flush=True)
        finally:
            subprocess.run(["git", "-C", str(repo), "worktree", "remove", "--force", str(tree)], check=False,
                           capture_output=True)
    ratios = [x / y for x, y in zip(a, b)]
    unit = {"batched": "us per world-step", "perception": "us per call"}.get(mode, "us per tick")
    return {"revision": rev, "commit": sha, "mode": mode, "unit": unit, "revision_us": a, "this_us": b,
            "median_ratio": statistics.median(ratios)}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("rev", help="git revision to compare this checkout with (e.g. HEAD~3, a commit, a branch)")
    p.add_argument("--mode", choices=MODES, default="objects")
    p.add_argument("--pairs", type=int, default=5, help="pairs of runs (default 5)")
    p.add_argument("--ticks", type=int, default=4000, help="timed ticks per run (world-steps in batched)")
    p.add_argument("--out", default=None, help="write the result as JSON")


def run(args: argparse.Namespace) -> int:
    if args.pairs < 1 or args.ticks < 1:
        raise SystemExit("--pairs and --ticks must be positive")
    res = ab(args.rev, args.mode, args.pairs, args.ticks)
    digits = 1 if args.mode == "perception" else 0
    fmt = lambda xs: " / ".join(f"{x:.{digits}f}" for x in xs)  # noqa: E731
    print(f"{args.mode}, {res['unit']}: {args.rev} ({res['commit']}) {fmt(res['revision_us'])} -> "
          f"this checkout {fmt(res['this_us'])}; median ratio {res['median_ratio']:.3f} "
          f"(above 1: this checkout is faster)")
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(out, json.dumps(res, indent=2) + "\n")
    return 0
