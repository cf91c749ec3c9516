"""``v2xbench collect``, ``data`` and ``qa``: the expert data set and Chat-V2XBench."""

from __future__ import annotations

import argparse
import json
import re
import sys
import time

from v2xbench.cli.common import parse_set

MAX_SHOW_SCALE = 16


def _int_in(lo: int, hi: int | None = None):
    """An argparse ``type``: an int in ``[lo, hi]`` (refused up front, with the bound)."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if v < lo or (hi is not None and v > hi):
            span = f"in [{lo}, {hi}]" if hi is not None else f">= {lo}"
            raise argparse.ArgumentTypeError(f"{v} must be {span}")
        return v
    return parse


def _camera_size(text: str) -> tuple[int, int]:
    """``--camera-size``: ``WxH`` (e.g. ``128x64``)."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"{text!r}: expected WxH (width x height in pixels), "
                                         "e.g. 128x64")
    return int(m.group(1)), int(m.group(2))


def _driver_config(args: argparse.Namespace) -> dict | None:
    """``--driver-config FILE``: the driver's keyword arguments (a JSON object)."""
    if args.driver_config is None:
        return None
    if args.driver is None:
        raise ValueError("collect: --driver-config needs --driver")
    from v2xbench.collectors.agent_config import load_agent_config

    return load_agent_config(args.driver_config)


def _collect(args: argparse.Namespace) -> int:
    from v2xbench.collectors.dataset.collect import CollectConfig, collect

    sensors = tuple(s for s in args.sensors.split(",") if s) if args.sensors is not None else None
    cfg = CollectConfig.for_scale(args.scale, suite=args.suite, seeds=args.seeds,
                                  first_seed=args.first_seed, max_routes=args.max_routes,
                                  max_ticks=args.max_ticks, sensors=sensors, camera_size=args.camera_size,
                                  perturb=False if args.no_perturb else None, env=parse_set(args.set) or None,
                                  val_fraction=args.val_fraction, lidar_scale=args.lidar_scale,
                                  driver=args.driver, driver_config=_driver_config(args),
                                  expert_share=args.expert_share)
    t0 = time.perf_counter()
    man = collect(cfg, args.out, workers=args.workers, progress=not args.quiet, max_episodes=args.max_episodes)
    frames = sum(s["frames"] for s in man["shards"].values())
    keyframes = sum(s["keyframes"] for s in man["shards"].values())
    state = "complete" if man.get("complete") else f"{len(man['episodes']) - len(man['shards'])} episodes pending"
    for sid, err in man.get("failed", {}).items():
        print(f"FAILED {sid}: {err}", file=sys.stderr)
    print(f"{len(man['shards'])}/{len(man['episodes'])} episodes, {frames} frames, {keyframes} keyframes "
          f"in {args.out} ({state}; this run {time.perf_counter() - t0:.0f} s)")
    if man.get("failed"):
        print(f"v2xbench: {len(man['failed'])} episodes failed (listed above); run again to retry",
              file=sys.stderr)
        return 1
    return 0


def _data_merge(args: argparse.Namespace) -> int:
    from v2xbench.collectors.dataset.merge import merge

    man = merge(args.sources, args.out)
    frames = sum(s["frames"] for s in man["shards"].values())
    print(f"{len(man['shards'])} episodes, {frames} frames from {len(args.sources)} data sets in "
          f"{args.out}")
    return 0


def _data_validate(args: argparse.Namespace) -> int:
    from v2xbench.collectors.dataset.shards import validate

    rep = validate(args.root, deep=not args.quick)
    for sid in rep["missing"]:
        print(f"MISSING  {sid}")
    for sid, problems in rep["corrupt"].items():
        for p in problems:
            print(f"CORRUPT  {sid}: {p}")
    for sid in rep["unlisted"]:
        print(f"UNLISTED {sid}")
    if rep["pending"]:
        print(f"pending (not collected yet): {len(rep['pending'])} episodes; run `v2xbench collect` again to resume")
    if rep["temporary"]:
        print(f"temporary folders of an interrupted run: {', '.join(rep['temporary'])} (removed on resume)")
    print(f"{'OK' if rep['ok'] else 'FAILED'}: {rep['shards']} shards checked, {len(rep['missing'])} missing, "
          f"{len(rep['corrupt'])} corrupt, {len(rep['unlisted'])} unlisted")
    return 0 if rep["ok"] else 1


def _qa_build(args: argparse.Namespace) -> int:
    from v2xbench.collectors.chat.export import build, stats_text

    res = build(args.root, seed=args.seed, out=args.out, hints_in_prompt=args.with_hints)
    print(stats_text(res["stats"]))
    print(f"wrote {res['qa']} and {res['llava']}")
    return 0


def _qa_stats(args: argparse.Namespace) -> int:
    from v2xbench.collectors.chat.export import load_items, stats, stats_text

    st = stats(load_items(args.path))
    print(json.dumps(st, indent=1) if args.json else stats_text(st))
    return 0


def _qa_show(args: argparse.Namespace) -> int:
    from v2xbench.collectors.chat.show import show

    print(show(args.root, args.out, args.keyframe, args.scale))
    print(f"\nwrote {args.out}")
    return 0


def _qa_score(args: argparse.Namespace) -> int:
    from v2xbench.collectors.chat.export import load_items, split_items
    from v2xbench.collectors.chat.scoring import load_predictions, score

    items = split_items(load_items(args.reference), args.split, "qa score")
    preds = load_predictions(args.predictions)
    print(json.dumps(score(items, preds), indent=1))
    return 0


def register(sub) -> None:
    """Add this module's sub-commands to the ``v2xbench`` parser."""
    co = sub.add_parser("collect", help="expert data collection into memmap shards (resumable)",
                        description="Drive the expert on a suite's routes with recovery noise and record "
                        "every tick (sensors, calibration, 3 GT box sets, expert labels, channel stats) into "
                        "OUT/shards/<route>_s<k>/, plus keyframe facts and images for Chat-V2XBench. Running "
                        "again on the same OUT resumes; one collect at a time per OUT (locked). Exit "
                        "status 1 when an episode failed, 2 for bad arguments.")
    co.add_argument("--suite", default="train", help="suite name (train, val, test50) or suite JSON path")
    co.add_argument("--out", default="data/v2x")
    co.add_argument("--workers", type=_int_in(1), default=1, help="episode worker processes")
    co.add_argument("--scale", default="default", choices=("tiny", "default", "paper"),
                    help="tiny: 3 routes x 150 ticks; default: every route once; paper: 2 seeds per route (~105K frames)")
    co.add_argument("--seeds", type=_int_in(1), default=None,
                    help="seed indices per route (overrides the scale)")
    co.add_argument("--first-seed", type=_int_in(0), default=None,
                    help="first seed index (default 0): episodes <route>_s<K>..., other world "
                    "seeds of the same routes (for `data merge`)")
    co.add_argument("--max-routes", type=_int_in(1), default=None, help="only the first N routes")
    co.add_argument("--max-ticks", type=_int_in(1), default=None, help="cap per episode (ticks)")
    co.add_argument("--max-episodes", type=_int_in(1), default=None,
                    help="stop after N new episodes (resume later)")
    co.add_argument("--sensors", default=None,
                    help="comma list stored every tick, of rgb,depth,semantic,lidar,bev (default "
                    "rgb,bev); its images are EnvConfig.camera_images in the manifest's "
                    "sensor_config")
    co.add_argument("--camera-size", type=_camera_size, default=None,
                    help="WxH of the 7 cameras (default 128x64; EnvConfig.camera_size)")
    co.add_argument("--lidar-scale", type=float, default=None,
                    help="fraction of the default LiDAR channels/azimuths (EnvConfig.lidar_scale; "
                    "< 1: faster, coarser GT visibility)")
    co.add_argument("--val-fraction", type=float, default=None,
                    help="share of train-suite routes held out as the val split (default 0.1)")
    co.add_argument("--no-perturb", action="store_true", help="no recovery noise")
    co.add_argument("--driver", default=None, metavar="AGENT",
                    help="DAgger: this agent (as v2xbench eval --agent) drives, the expert labels "
                    "every frame (collectors/dataset/driver.py)")
    co.add_argument("--driver-config", default=None, metavar="FILE",
                    help="the driver's keyword arguments (JSON, as --agent-config)")
    co.add_argument("--expert-share", type=float, default=None, metavar="P",
                    help="with --driver: share of ticks on which the expert's control executes "
                    "(DAgger's beta; default 0)")
    co.add_argument("--set", action="append", metavar="KEY=VALUE", help="environment config override (repeatable)")
    co.add_argument("--quiet", action="store_true", help="no progress bar")
    co.set_defaults(func=_collect)
    da = sub.add_parser("data", help="data set tools")
    das = da.add_subparsers(dest="data_command", required=True)
    dv = das.add_parser("validate", help="find missing, corrupt and unlisted shards (exit 1 if any)")
    dv.add_argument("root", help="data set folder")
    dv.add_argument("--quick", action="store_true", help="sizes only, no checksums")
    dv.set_defaults(func=_data_validate)
    dm = das.add_parser("merge", help="one data set from several (hard links; e.g. the expert's "
                        "and a --driver collection)")
    dm.add_argument("sources", nargs="+", help="data set folders (same sensors, no shared shards)")
    dm.add_argument("--out", required=True, help="the new data set folder (must not exist)")
    dm.set_defaults(func=_data_merge)
    qa = sub.add_parser("qa", help="Chat-V2XBench: build, stats, score")
    qas = qa.add_subparsers(dest="qa_command", required=True)
    qb = qas.add_parser("build", help="generate QA pairs (our JSONL + LLaVA JSONL) from a data set")
    qb.add_argument("root", help="data set folder")
    qb.add_argument("--seed", type=_int_in(0, 2**63 - 1), default=0, help="paraphrase seed")
    qb.add_argument("--out", default=None, help="output folder (default ROOT/chat)")
    qb.add_argument("--with-hints", action="store_true",
                    help="LLaVA prompts carry the ground-truth object hints (the auto-labelling "
                    "form) instead of the hint-free run-time context")
    qb.set_defaults(func=_qa_build)
    qs = qas.add_parser("stats", help="counts per level, question type and scenario")
    qs.add_argument("path", help="data set folder or qa.jsonl")
    qs.add_argument("--json", action="store_true")
    qs.set_defaults(func=_qa_stats)
    qw = qas.add_parser("show", help="mosaic of a keyframe's 7 camera images + its QA pairs (Markdown)")
    qw.add_argument("root", help="data set folder (after `qa build`)")
    qw.add_argument("--out", default="keyframe.png")
    qw.add_argument("--keyframe", default=None, help="<episode>_t<tick> (default: the most informative)")
    qw.add_argument("--scale", type=_int_in(1, MAX_SHOW_SCALE), default=3, help="image upscaling factor")
    qw.set_defaults(func=_qa_show)
    qc = qas.add_parser("score", help="score predicted answers (JSONL of {id, answer}) against the reference")
    qc.add_argument("reference", help="data set folder or qa.jsonl")
    qc.add_argument("predictions", help="JSONL with one {\"id\", \"answer\"} per line")
    qc.add_argument("--split", default="all",
                    help="score only the items of this split (train, val, test; default all)")
    qc.set_defaults(func=_qa_score)
