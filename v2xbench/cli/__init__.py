"""The ``v2xbench`` command line.

Commands:
    drive       drive a route with the built-in route follower, write a top-down GIF and a sensor
                mosaic GIF (6 ego cameras, RSU camera, BEV, LiDAR), print a summary
    towns       list the named towns (training / test split)
    scenarios   list the 38 scenario types, or render a video of each
    eval        closed-loop evaluation of an agent on a route suite (per-route JSON, summary)
    leaderboard leaderboard table, plots and per-scenario breakdown from evaluation results
    incidents   how an agent's red lights (set off after standing, slowed, drove through) and
                vehicle collisions (drove into a car, was hit, side; repeats) happened
    compare     agents on the runs they share, paired run by run (DS difference with its CI)
    bench       benchmark suite (speed vs highway-env, sensors, batched worlds, eval time, memory)
    profile     where a tick's time goes: per stage and per numba kernel (objects or batched)
    floor       an objects tick's kernels back to back, without the Python between them
    fingerprint hash of what fixed runs compute (same hashes = same bytes, for speed work)
    ab          same-minute A/B of a tick's cost: this checkout against a git revision
    collect     expert data collection into TensorDict memmap shards (resumable)
    data        validate a collected data set (missing / corrupt shards)
    qa          build Chat-V2XBench from a data set, print its statistics, score answers
    warmup      compile the numba kernels ahead of time (first use in a fresh environment)
    aurora      AURORA: train (stages 0-5, pipeline), export weights, evaluate perception and
                planning, ask / answer Chat-V2XBench questions
    baselines   the paper's cooperative baselines (V2X-ViT, CoDriving, UniV2X, UniMM-V2X): train,
                export weights, evaluate perception and open-loop planning
    experiments run a config of trainings and evaluations (resumable), build the paper's tables
"""

from __future__ import annotations

import argparse
import sys

from v2xbench.cli import aurora, baselines, bench, data, drive, evaluation, experiments, warmup

#: Sub-command modules, each with ``register(subparsers)``, in help order.
COMMAND_MODULES = (drive, evaluation, bench, data, warmup, aurora, baselines, experiments)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``v2xbench`` command."""
    p = argparse.ArgumentParser(prog="v2xbench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    for mod in COMMAND_MODULES:
        mod.register(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``v2xbench`` command."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as e:
        print(f"v2xbench: error: {e}", file=sys.stderr)
        return 2

