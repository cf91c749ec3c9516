"""Benchmark and profiling sub-commands: options and ``run(args)`` live in ``v2xbench.benchmarks``."""

from __future__ import annotations

import importlib


def _add_benchmark(sub, name: str, module: str, help: str, description: str) -> None:
    """Register sub-command ``name``, whose options and ``run(args)`` come from
    ``v2xbench.benchmarks.<module>``."""
    mod = importlib.import_module(f"v2xbench.benchmarks.{module}")
    p = sub.add_parser(name, help=help, description=description)
    mod.add_arguments(p)
    p.set_defaults(func=mod.run)


def register(sub) -> None:
    """Add this module's sub-commands to the ``v2xbench`` parser."""
    _add_benchmark(sub, "bench", "suite",
                   "benchmark suite: speed against highway-env, sensors, batching, eval, memory",
                   "Run the benchmark suite (benchmarks/suite.py): prints a table, writes "
                   "OUT/suite.json, OUT/suite.md and OUT/suite.png.")
    _add_benchmark(sub, "profile", "tick_profile", "where a tick's time goes: per stage and per numba kernel",
                   "Time every stage of the tick and every numba kernel "
                   "(benchmarks/tick_profile.py): prints a table, writes OUT/profile_<mode>.json and .md.")
    _add_benchmark(sub, "floor", "kernel_floor", "an objects tick's kernels back to back, without the Python between them",
                   "Time env.step, then the tick's six numba kernels called back to back on a "
                   "step's arguments, then each alone (benchmarks/kernel_floor.py): prints a table, "
                   "writes OUT/floor_objects.json and .md.")
    _add_benchmark(sub, "perf", "perf_kernels", "Linux perf over a workload, numba's kernels named",
                   "Sample a batched or objects-mode run with perf record and name the samples "
                   "inside numba's kernels (benchmarks/perf_kernels.py): prints a table, writes "
                   "OUT/perf_<mode>.json and .md. Needs perf and nm; compiles every kernel first (~1-2 min).")
    _add_benchmark(sub, "fingerprint", "fingerprint", "hash of what fixed runs compute (same hashes = same bytes)",
                   "Drive fixed configurations and hash every tick's observation, reward, "
                   "info, events and world state (benchmarks/fingerprint.py); --out saves the hashes, "
                   "--check compares with saved ones (exit 1 on a difference).")
    _add_benchmark(sub, "ab", "ab", "same-minute A/B of a tick's cost: this checkout against a git revision",
                   "Interleaved runs of a git revision (in a temporary worktree) and this "
                   "checkout, CPU time per tick (benchmarks/ab.py); prints both series and the median "
                   "ratio.")
    _add_benchmark(sub, "bench-model", "model_speed", "AURORA training samples/s and inference ms per branch",
                   "Time AURORA's perception branches at the tiny and default scales: training "
                   "samples/s per stage and inference ms per frame (benchmarks/model_speed.py); "
                   "--data also times sample loading. Writes OUT/model_speed.json and .md.")
    _add_benchmark(sub, "coverage", "rsu_coverage", "how well the route's roadside units see the V2X hazards",
                   "Drive every V2X-type scenario instance of a suite and measure how long each hazard "
                   "is hidden from the ego and seen by the active roadside unit "
                   "(benchmarks/rsu_coverage.py).")
