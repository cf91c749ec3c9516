"""First-use cost: compiling the numba kernels in a fresh environment, and loading them after.

Runs ``v2xbench warmup`` in a child process twice with the same, initially empty, kernel cache
(``V2XBENCH_CACHE_DIR`` in a temporary folder): the first run is what a new user pays once per
machine (and again after any kernel source changes), the second what every later process pays.
``quick`` (CI) runs only the second kind against the user's own cache.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time


def _warmup(cache_dir: str | None) -> dict:
    env = dict(os.environ)
    if cache_dir is not None:
        env["V2XBENCH_CACHE_DIR"] = cache_dir
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "v2xbench.cli", "warmup", "--quiet"], env=env,
                          capture_output=True, text=True)
    return {"seconds": time.perf_counter() - t0, "returncode": proc.returncode,
            "stderr_tail": proc.stderr[-2000:] if proc.returncode else ""}


def measure(quick: bool) -> dict:
    """``{"cold": {...} | None, "warm": {...}}`` with ``seconds`` and ``returncode`` each."""
    if quick:
        return {"cold": None, "warm": _warmup(None)}
    with tempfile.TemporaryDirectory(prefix="v2xbench-firstuse-") as tmp:
        cold = _warmup(tmp)
        warm = _warmup(tmp)
    return {"cold": cold, "warm": warm}
