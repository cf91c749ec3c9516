"""``v2xbench warmup``: compile every numba kernel ahead of time, with a progress bar.

The first use of the simulator in a fresh environment compiles its numba kernels (about
1-2 minutes on a 2-core machine); the compiled code is cached in the user cache folder
(``envs/v2x_intersection/core/jit_cache.py``) and every later process and clone with the same
sources loads it in about a second. ``warmup`` runs one short workload per subsystem so that
none of that cost lands in the middle of a training or evaluation run.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable


def _objects_env() -> None:
    import numpy as np

    from v2xbench.envs.v2x_intersection import V2XIntersectionEnv

    env = V2XIntersectionEnv(town="Town01", route_length=120.0)
    env.reset(seed=0)
    for _ in range(30):
        env.step(np.array([0.6, 0.0, 0.0], np.float32))


def _expert() -> None:
    from v2xbench.agents.expert import Expert
    from v2xbench.envs.v2x_intersection import V2XIntersectionEnv

    env = V2XIntersectionEnv(town="Town01", route_length=120.0)
    obs, _ = env.reset(seed=1)
    agent = Expert()
    agent.bind(env.world)
    agent.reset()
    for _ in range(30):
        obs, *_ = env.step(agent.act(obs))


def _sensors() -> None:
    from v2xbench.envs.v2x_intersection import V2XIntersectionEnv
    from v2xbench.envs.v2x_intersection.sensors import SensorRig

    env = V2XIntersectionEnv(town="Town01", route_length=120.0)
    env.reset(seed=0)
    SensorRig().capture(env.world)


def _batched() -> None:
    import torch

    from v2xbench.envs.v2x_intersection.api.torchrl_env import V2XTorchEnv

    torch.set_num_threads(1)
    env = V2XTorchEnv(num_worlds=2)
    td = env.reset()
    for _ in range(10):
        td = env.rand_step(td)


#: (name, workload) in the order they run.
STAGES: tuple[tuple[str, Callable[[], None]], ...] = (
    ("simulator (objects observation)", _objects_env),
    ("expert driver", _expert),
    ("sensors (cameras, LiDAR, BEV)", _sensors),
    ("batched TorchRL env", _batched),
)


def _warmup(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from v2xbench.envs.v2x_intersection.core import jit

    if not jit.HAVE_JIT:
        print("numba is not available or disabled (V2XBENCH_NO_JIT): nothing to compile")
        return 0
    t0 = time.perf_counter()
    times = {}
    with tqdm(STAGES, desc="compiling kernels", unit="stage", disable=args.quiet) as bar:
        for name, fn in bar:
            bar.set_postfix_str(name)
            t = time.perf_counter()
            fn()
            times[name] = time.perf_counter() - t
    for name, s in times.items():
        print(f"  {name:34s} {s:6.1f} s")
    print(f"kernels ready in {time.perf_counter() - t0:.1f} s; cache: {jit.KERNEL_CACHE_DIR}")
    return 0


def register(sub) -> None:
    """Add ``warmup`` to the ``v2xbench`` parser."""
    w = sub.add_parser("warmup", help="compile the numba kernels ahead of time (first use: 1-2 min)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    w.add_argument("--quiet", action="store_true", help="no progress bar")
    w.set_defaults(func=_warmup)
