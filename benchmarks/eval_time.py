"""Wall time of ``v2xbench eval --agent expert --suite test50`` on 2 workers (a fresh output dir,
so nothing is resumed), run as a subprocess exactly as a user would."""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path


def measure(workers: int = 2, max_routes: int | None = None, extra: list[str] | None = None,
            suite: str = "test50", agent: str = "expert", timeout: float = 3600.0) -> dict:
    with tempfile.TemporaryDirectory(prefix="v2xbench-eval-") as tmp:
        cmd = [sys.executable, "-m", "v2xbench.cli", "eval", "--agent", agent, "--suite", suite,
               "--workers", str(workers), "--out", str(Path(tmp) / "eval"), "--quiet"]
        if max_routes is not None:
            cmd += ["--max-routes", str(max_routes)]
        cmd += extra or []
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
            code, text = proc.returncode, proc.stderr or proc.stdout
        except subprocess.TimeoutExpired:
            code, text = -1, f"timed out after {timeout:.0f} s"
        dt = time.perf_counter() - t0
    out = {"command": " ".join(["v2xbench", *cmd[3:]]),
           "seconds": dt, "returncode": code, "goal_seconds": 600.0}
    if code != 0:
        out["error"] = text[-2000:]
    return out
