"""Where the CPU goes, numba's kernels named: Linux ``perf`` over a workload (``v2xbench perf``).

``v2xbench profile`` times each kernel call as a whole; it cannot see inside a kernel, nor tell a
kernel's own work from numba's dispatch or the CPython code around it. This samples the whole
process with ``perf record`` and names the samples that fall in numba's compiled code: after the
run it writes ``/tmp/perf-<pid>.map`` (perf's map for JIT code) from the object code of every
kernel the run compiled. Kernels must be compiled in the process (numba keeps no object code for
kernels it loads from its cache), so the workload runs in a child process with an empty
``NUMBA_CACHE_DIR``: expect ~1-2 minutes of compilation before the sampled seconds.

Workloads: ``batched`` (one ``V2XTorchEnv`` of ``--worlds`` worlds in TorchRL's ``Collector``
with a uniform random policy, the suite's batched row in one process) and ``objects`` (the
suite's objects row: ``gym.make`` on test50 route 0, a constant action). The report lists the
symbols with the most samples (``module.function`` for numba's, the shared object otherwise)
and the share of each shared object; ``OUT/perf_<mode>.md`` and ``.json``. Needs ``perf`` and
``nm`` (binutils) on the PATH, and permission to sample one's own processes
(``/proc/sys/kernel/perf_event_paranoid`` <= 2).

This is how stop 22 found that ``leaders_kernel`` took 9 % of a batched run's CPU (a branch per
pair of actors that the CPU mispredicted), which the per-kernel timers had only shown as part of
``traffic_batch_kernel``.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

MODES = ("batched", "objects")
#: s, shortest and longest warm-up (numba compiles each kernel on its first use)
WARMUP_MIN_S = 30.0
WARMUP_MAX_S = 180.0


def demangle(symbol: str) -> str:
    """``module.function`` of a numba symbol (``_ZN8v2xbench4envs...14leaders_kernelB4v309...``),
    the symbol itself when it is not one."""
    m = re.match(r"_ZN((?:\d+[A-Za-z_][A-Za-z0-9_]*)+)", symbol)
    if not m:
        return symbol
    parts, rest = [], m.group(1)
    while rest and rest[0].isdigit():
        n = int(re.match(r"\d+", rest).group())
        k = len(str(n))
        parts.append(rest[k:k + n])
        rest = rest[k + n:]
    name = ".".join(parts).replace("_3clocals_3e", "<locals>")
    return name.removeprefix("v2xbench.envs.v2x_intersection.")


def write_perf_map(pid: int | None = None) -> int:
    """Write ``/tmp/perf-<pid>.map`` for every kernel compiled in this process; returns the
    number of symbols."""
    from numba.core.registry import CPUDispatcher

    nm = shutil.which("nm")
    if nm is None:
        raise RuntimeError("perf map: `nm` (binutils) is not on the PATH")
    rows: dict[int, tuple[int, str]] = {}
    seen: set[int] = set()
    for obj in gc.get_objects():
        try:
            if not isinstance(obj, CPUDispatcher):
                continue
        except ReferenceError:  # a weak proxy whose object is gone
            continue
        for cres in list(obj.overloads.values()):
            lib = cres.library
            blob = getattr(lib, "_compiled_object", None)
            if id(lib) in seen or not blob:
                continue
            seen.add(id(lib))
            with tempfile.NamedTemporaryFile(suffix=".o", delete=False) as f:
                f.write(blob)
            try:
                out = subprocess.run([nm, "-S", "--defined-only", f.name], capture_output=True, text=True).stdout
            finally:
                os.unlink(f.name)
            syms = [(int(p[0], 16), int(p[1], 16), p[3]) for p in (line.split() for line in out.splitlines())
                    if len(p) == 4 and p[2] in "Tt"]
            entry = [s for s in syms if s[2] == cres.fndesc.llvm_func_name]
            if not entry:
                continue
            base = lib.get_pointer_to_function(entry[0][2]) - entry[0][0]
            for off, size, name in syms:
                rows[base + off] = (size, demangle(name))
    path = Path(f"/tmp/perf-{pid or os.getpid()}.map")
    with open(path, "w") as fh:
        for addr, (size, name) in sorted(rows.items()):
            fh.write(f"{addr:x} {size:x} {name}\n")
    return len(rows)


def _workload(mode: str, worlds: int):
    """A callable that runs one unit of the workload (a collector batch, or 200 ticks)."""
    import numpy as np
    import torch

    torch.set_num_threads(1)
    if mode == "batched":
        from torchrl.collectors import Collector
        from v2xbench.benchmarks.batched_speed import uniform_policy
        from v2xbench.envs.v2x_intersection import V2XTorchEnv

        env = V2XTorchEnv(num_worlds=worlds)
        env.set_seed(0)
        it = iter(Collector(env, policy=uniform_policy, frames_per_batch=worlds * 32, total_frames=-1,
                            device="cpu", trust_policy=True))
        return lambda: next(it)
    import gymnasium as gym
    from v2xbench.benchmarks.suite import OBJECTS_CONFIG

    import v2xbench  # noqa: F401

    env = gym.make("V2XIntersection-v0", **OBJECTS_CONFIG)
    env.reset(seed=0)
    act = np.array([0.5, 0.0, 0.0], np.float32)

    def ticks():
        for _ in range(200):
            _, _, term, trunc, _ = env.step(act)
            if term or trunc:
                env.reset()
    return ticks


def child(mode: str, worlds: int, seconds: float, data: str) -> None:
    """Run in the child: warm up, sample ``seconds`` of the workload, write the map."""
    step = _workload(mode, worlds)
    # warm up until numba has compiled what the workload uses: at least WARMUP_MIN_S (resets keep
    # reaching code paths that compile on first use), then until two units in a row are within
    # 30 % of the fastest so far (a unit that compiles takes seconds), for at most WARMUP_MAX_S
    times: list[float] = []
    t_start = time.perf_counter()
    while time.perf_counter() - t_start < WARMUP_MAX_S:
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
        warm = time.perf_counter() - t_start >= WARMUP_MIN_S
        if warm and len(times) >= 4 and max(times[-2:]) < 1.3 * min(times):
            break
    gc.collect()
    rec = subprocess.Popen(["perf", "record", "-F", "2000", "-p", str(os.getpid()), "-o", data],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(0.5)
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        step()
    rec.send_signal(signal.SIGINT)
    rec.wait()
    print(f"perf map: {write_perf_map()} symbols", flush=True)


def summarize(data: str, top: int = 30) -> dict:
    """Shares of samples per symbol and per shared object from ``perf report``."""
    out = subprocess.run(["perf", "report", "-i", data, "--no-children", "--sort", "dso,sym", "--stdio"],
                         capture_output=True, text=True).stdout
    syms: Counter = Counter()
    dsos: Counter = Counter()
    for line in out.splitlines():
        m = re.match(r"\s*([\d.]+)%\s+(\S+(?: tid \d+)?)\s+\[[.k]\]\s+(.+)$", line)
        if not m:
            continue
        pct, dso, sym = float(m.group(1)), m.group(2), m.group(3).strip()
        dso = "numba JIT" if dso.startswith("[JIT]") else dso
        dsos[dso] += pct
        syms[(dso, sym)] += pct
    # numba compiling a kernel on its first use inside the sampled seconds (a reset reaching a new
    # code path) is not the workload's cost: left out, the rest rescaled to 100 %
    compiling = sum(v for k, v in dsos.items() if "llvmlite" in k)
    scale = 100.0 / max(100.0 - compiling, 1e-9)
    return {"compiling_percent": round(compiling, 2),
            "by_object": [{"object": k, "percent": round(v * scale, 2)} for k, v in dsos.most_common()
                          if "llvmlite" not in k],
            "top_symbols": [{"object": d, "symbol": s, "percent": round(v * scale, 2)}
                            for (d, s), v in syms.most_common() if "llvmlite" not in d][:top]}


def render(report: dict) -> str:
    lines = [f"perf over the {report['mode']} workload, {report['seconds']:.0f} s sampled, {report['when']}; "
             f"{report['compiling_percent']:.1f} % of the samples were numba compiling (left out, the rest scaled "
             "to 100 %)", "", "| object | % of samples |", "| --- | ---: |"]
    lines += [f"| {r['object']} | {r['percent']:.1f} |" for r in report["by_object"][:10]]
    lines += ["", "| symbol | object | % of samples |", "| --- | --- | ---: |"]
    lines += [f"| `{r['symbol'][:90]}` | {r['object']} | {r['percent']:.2f} |" for r in report["top_symbols"]]
    if report["compiling_percent"] > 5.0:
        lines += ["", "A kernel compiled inside the sampled seconds; numba's compiler is Python, so some of "
                  "the Python samples above are compiling too: run it again for a cleaner picture."]
    lines += ["", "An address in numba JIT that no kernel's object code covers (e.g. `0x7f...059`) is code numba "
              "compiles for itself, most likely its runtime's reference counting."]
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mode", choices=MODES, default="batched")
    p.add_argument("--worlds", type=int, default=32, help="worlds of the batched workload")
    p.add_argument("--seconds", type=float, default=10.0, help="sampled seconds")
    p.add_argument("--out", default="benchmarks/results", help="folder for perf_<mode>.md/.json")


def run(args: argparse.Namespace) -> int:
    for tool in ("perf", "nm"):
        if shutil.which(tool) is None:
            print(f"v2xbench perf: `{tool}` is not on the PATH (Linux perf and binutils are needed)", file=sys.stderr)
            return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="v2xbench-perf-") as tmp:
        data = str(Path(tmp) / "perf.data")
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"),  # compile here: object code
                   V2XBENCH_CACHE_DIR=str(Path(tmp) / "v2xbench"))  # kept, no cache hit
        print(f"[perf] {args.mode}: compiling every kernel in a fresh process, then {args.seconds:.0f} s sampled ...",
              flush=True)
        proc = subprocess.Popen([sys.executable, "-m", "v2xbench.benchmarks.perf_kernels", "--child", args.mode,
                                 str(args.worlds), str(args.seconds), data], env=env)
        code = proc.wait()
        perf_map = Path(f"/tmp/perf-{proc.pid}.map")
        try:
            if code != 0 or not Path(data).exists():
                print("v2xbench perf: the sampled run failed (is perf allowed here? see "
                      "/proc/sys/kernel/perf_event_paranoid)", file=sys.stderr)
                return 1
            report = {"benchmark": "perf_kernels", "mode": args.mode, "seconds": args.seconds,
                      "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), **summarize(data)}
        finally:
            perf_map.unlink(missing_ok=True)
    text = render(report)
    print(text)
    for name, body in ((f"perf_{args.mode}.json", json.dumps(report, indent=2)), (f"perf_{args.mode}.md", text)):
        tmp_path = out / (name + ".tmp")
        tmp_path.write_text(body + "\n")
        tmp_path.replace(out / name)
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 6 and sys.argv[1] == "--child":
        child(sys.argv[2], int(sys.argv[3]), float(sys.argv[4]), sys.argv[5])
    else:
        print("run it as `v2xbench perf`", file=sys.stderr)
        sys.exit(2)
