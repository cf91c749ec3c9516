"""Memory over many episode resets: resident set size sampled while one world is reset again and
again (each reset followed by one tick), to show it stays flat (no leak)."""

from __future__ import annotations

import gc
import os
import time


def rss_mib() -> float:
    """Current resident set size of this process (MiB; Linux ``/proc``, else peak RSS)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def measure(resets: int = 10_000, samples: int = 20) -> dict:
    import numpy as np
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    world = World(make_config())
    control = np.array([0.3, 0.0, 0.0])
    every = max(1, resets // samples)
    for k in range(min(50, resets)):  # warm caches (towns, suites) before the baseline
        world.reset(seed=k)
    gc.collect()
    trace = [(0, rss_mib())]
    t0 = time.perf_counter()
    for k in range(1, resets + 1):
        world.reset(seed=k)
        world.step(control, world.default_rsu_message())
        if k % every == 0 or k == resets:
            gc.collect()
            trace.append((k, rss_mib()))
    dt = time.perf_counter() - t0
    rss = [r for _, r in trace]
    half = len(rss) // 2
    return {"resets": resets, "seconds": dt, "resets_per_s": resets / dt, "trace": trace,
            "rss_start_mib": rss[0], "rss_end_mib": rss[-1], "rss_max_mib": max(rss),
            "growth_second_half_mib": rss[-1] - rss[half]}
