"""One call before every timed loop of the benchmarks: a full garbage collection.

Imports and set-up (gymnasium, numba, torch, highway-env, town building) leave hundreds of
thousands of long-lived objects behind, and Python's collector examines them all in its next
full (generation-2) collection. With torch imported that took 50-190 ms here, and where it fell
inside a timed loop it was read as the simulator's cost: 3,000 objects ticks timed at 5,409/s
with one inside and at 7,064/s without, and `v2xbench profile` put 60 us a tick into whichever
stage it hit. Collecting first (what pyperformance does; ``timeit`` goes further and turns the
collector off) leaves the collector on for the timed loop, so the garbage the loop itself makes
is still paid for.
"""

from __future__ import annotations

import gc


def settle() -> None:
    """Collect all garbage now (all generations), so that set-up's objects are not examined by
    a full collection inside the timed loop that follows."""
    gc.collect()
