"""The ``v2xbench`` command line.

Commands:
    drive       drive a route with the built-in route follower, write a top-down GIF and a sensor
                mosaic GIF (6 ego cameras, RSU camera, BEV, LiDAR), print a summary
    towns       list the named towns (training / test split)
    scenarios   list the 38 scenario types, or render a video of each
    eval        closed-loop evaluation of an agent on a route suite (per-route JSON, summary)
    leaderboard leaderboard table, plots and per-scenario breakdown from evaluation results
    bench       benchmark suite (speed vs highway-env, sensors, batched worlds, eval time, memory)
    profile     where a tick's time goes: per stage and per numba kernel (objects or batched)
    floor       an objects tick's kernels back to back, without the Python between them
    fingerprint hash of what fixed runs compute (same hashes = same bytes, for speed work)
    ab          same-minute A/B of a tick's cost: this checkout against a git revision
    collect     expert data collection into TensorDict memmap shards (resumable)
    data        validate a collected data set (missing / corrupt shards)
    qa          build Chat-V2XBench from a data set, print its statistics, score answers
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from pathlib import Path


def _drive(args: argparse.Namespace) -> int:
    import numpy as np
    from PIL import Image
    from tqdm import tqdm

    from v2xbench.agents.route_follower import RouteFollower
    from v2xbench.envs.v2x_intersection import V2XIntersectionEnv
    from v2xbench.envs.v2x_intersection.infractions import EVENT_NAMES
    from v2xbench.envs.v2x_intersection.render import save_video
    from v2xbench.envs.v2x_intersection.sensors import SensorRig, mosaic

    env = V2XIntersectionEnv(render_mode="rgb_array", town=args.town, route_length=args.route_length,
                             render_size=args.size)
    obs, info = env.reset(seed=args.seed)
    agent = RouteFollower(use_v2x=not args.no_v2x)
    agent.reset()
    frames = [env.render()]
    rig = SensorRig() if args.sensors_every > 0 else None
    mosaics = []
    total = 0.0
    t0 = time.perf_counter()
    ticks = 0
    with tqdm(total=100, desc=f"{args.town} seed {args.seed}", unit="% route", disable=args.quiet) as bar:
        while True:
            obs, reward, terminated, truncated, info = env.step(agent.act(obs))
            total += reward
            ticks += 1
            if ticks % args.frame_every == 0:
                frames.append(env.render())
            if rig is not None and ticks % args.sensors_every == 0:
                mosaics.append(mosaic(rig.capture(env.world)))
            bar.update(round(info["route_completion"] - bar.n, 1))
            if terminated or truncated:
                break
    wall = time.perf_counter() - t0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    video = save_video(frames, out / "drive.gif", fps=max(1, 10 // args.frame_every))
    sensors_video = None
    if mosaics:
        sensors_video = save_video(mosaics, out / "sensors.gif", fps=max(1, 10 // args.sensors_every))
        Image.fromarray(mosaics[len(mosaics) // 2]).save(out / "sensors.png")
    summary = {
        "town": args.town, "seed": args.seed, "ticks": ticks, "sim_seconds": round(ticks * 0.1, 1),
        "route_length_m": round(info["route_length"], 1),
        "route_completion": round(info["route_completion"], 1),
        "ended_by": "route complete / deviation / blocked" if terminated else "time budget",
        "return": round(total, 2),
        "events": {k: int(v) for k, v in zip(EVENT_NAMES, np.asarray(info["events"]))},
        "v2x_bytes_per_s": round(info["v2x_bps"], 1),
        "wall_seconds": round(wall, 2), "video": str(video),
        "sensors_video": None if sensors_video is None else str(sensors_video),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))
    return 0


def _towns(args: argparse.Namespace) -> int:
    from v2xbench.envs.v2x_intersection.town import NAMED_TOWNS, TEST_TOWNS, get_town

    for name, (template, seed, _size) in NAMED_TOWNS.items():
        t = get_town(name)
        split = "test" if name in TEST_TOWNS else "train"
        print(f"{name:8s} {split:5s} template={template:9s} seed={seed:<3d} lanes={len(t.lanes):4d} "
              f"junctions={len(t.junctions):3d} crosswalks={len(t.crosswalks):3d} buildings={len(t.buildings)}")
    return 0


def _scenarios_list(args: argparse.Namespace) -> int:
    from v2xbench.envs.v2x_intersection.scenarios import SCENARIOS
    from v2xbench.envs.v2x_intersection.town import TEST_TOWNS, get_town

    test = get_town(TEST_TOWNS[0])
    rows = sorted(SCENARIOS.values(), key=lambda c: (not c.v2x, c.family, c.name))
    print(f"{'scenario':32s} {'family':12s} {'V2X':4s} {'fits ' + test.name:12s} preferred towns")
    for c in rows:
        fits = "yes" if c.find_sites(test) else "no"
        print(f"{c.name:32s} {c.family:12s} {'yes' if c.v2x else 'no':4s} {fits:12s} {', '.join(c.towns) or 'any'}")
    print(f"{len(rows)} scenario types, {sum(c.v2x for c in rows)} V2X-specific")
    return 0


def _scenarios_render(args: argparse.Namespace) -> int:
    from v2xbench.envs.v2x_intersection.scenarios import SCENARIOS
    from v2xbench.envs.v2x_intersection.scenarios.gallery import render_gallery

    names = args.names or sorted(SCENARIOS)
    unknown = [n for n in names if n not in SCENARIOS]
    if unknown:
        raise ValueError(f"unknown scenarios: {', '.join(unknown)}")
    index = render_gallery(names, Path(args.out), seed=args.seed, size=args.size, quiet=args.quiet)
    print(f"wrote {len(names)} videos and {index}")
    return 0


def _parse_set(items: list[str]) -> dict:
    """``key=value`` pairs of ``--set`` (values parsed as JSON when possible: 10, 0.5, null)."""
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--set {item!r}: expected key=value (an EnvConfig field)")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def _eval(args: argparse.Namespace) -> int:
    from v2xbench.collectors.evaluate import evaluate, summary_markdown

    summary = evaluate(args.agent, suite=args.suite, seeds=args.seeds, workers=args.workers, out=args.out,
                       video=args.video, max_routes=args.max_routes, config=_parse_set(args.set),
                       agent_name=args.agent_name, progress=not args.quiet,
                       isolate_agent=args.isolate_agent)
    print(summary_markdown(summary))
    print(f"results: {Path(args.out) / 'routes'}, summary: {Path(args.out) / 'summary.md'}")
    return 0


def _add_benchmark(sub, name: str, module: str, help: str, description: str) -> None:
    """Register sub-command ``name``, whose options and ``run(args)`` come from
    ``v2xbench.benchmarks.<module>``."""
    mod = importlib.import_module(f"v2xbench.benchmarks.{module}")
    p = sub.add_parser(name, help=help, description=description)
    mod.add_arguments(p)
    p.set_defaults(func=mod.run)


def _leaderboard(args: argparse.Namespace) -> int:
    from v2xbench.collectors.leaderboard import build_leaderboard

    res = build_leaderboard(args.results, args.out, plots=not args.no_plots)
    print(Path(res["markdown"]).read_text())
    if res["note"]:
        print(res["note"], file=sys.stderr)
    print(f"wrote {res['markdown']}" + (f" and {len(res['plots'])} plots" if res["plots"] else ""))
    return 0


def _collect(args: argparse.Namespace) -> int:
    from v2xbench.collectors.dataset.collect import CollectConfig, collect

    size = tuple(int(v) for v in args.camera_size.lower().split("x")) if args.camera_size else None
    sensors = tuple(s for s in args.sensors.split(",") if s) if args.sensors is not None else None
    cfg = CollectConfig.for_scale(args.scale, suite=args.suite, seeds=args.seeds, max_routes=args.max_routes,
                                  max_ticks=args.max_ticks, sensors=sensors, camera_size=size,
                                  perturb=False if args.no_perturb else None, env=_parse_set(args.set) or None,
                                  val_fraction=args.val_fraction, lidar_scale=args.lidar_scale)
    t0 = time.perf_counter()
    man = collect(cfg, args.out, workers=args.workers, progress=not args.quiet, max_episodes=args.max_episodes)
    frames = sum(s["frames"] for s in man["shards"].values())
    keyframes = sum(s["keyframes"] for s in man["shards"].values())
    state = "complete" if man.get("complete") else f"{len(man['episodes']) - len(man['shards'])} episodes pending"
    for sid, err in man.get("failed", {}).items():
        print(f"FAILED {sid}: {err}", file=sys.stderr)
    print(f"{len(man['shards'])}/{len(man['episodes'])} episodes, {frames} frames, {keyframes} keyframes "
          f"in {args.out} ({state}; this run {time.perf_counter() - t0:.0f} s)")
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

    res = build(args.root, seed=args.seed, out=args.out)
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
    from v2xbench.collectors.chat.export import load_items
    from v2xbench.collectors.chat.scoring import score

    items = load_items(args.reference)
    preds = {}
    with open(args.predictions) as f:
        for line in f:
            if line.strip():
                d = json.loads(line)
                preds[d["id"]] = d["answer"]
    print(json.dumps(score(items, preds), indent=1))
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``v2xbench`` command."""
    p = argparse.ArgumentParser(prog="v2xbench", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("drive", help="drive a route with the built-in route follower and write a GIF")
    d.add_argument("--town", default="Town01")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--route-length", type=float, default=300.0, help="metres")
    d.add_argument("--out", default="out/drive")
    d.add_argument("--size", type=int, default=384, help="GIF frame size in pixels")
    d.add_argument("--frame-every", type=int, default=2, help="keep one frame every N ticks")
    d.add_argument("--sensors-every", type=int, default=5,
                   help="also write the camera/LiDAR/BEV mosaic every N ticks to sensors.gif (0: off)")
    d.add_argument("--no-v2x", action="store_true", help="ignore what the RSU sends")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_drive)
    t = sub.add_parser("towns", help="list the named towns")
    t.set_defaults(func=_towns)
    sc = sub.add_parser("scenarios", help="list scenario types or render a video of each")
    scs = sc.add_subparsers(dest="scenarios_command", required=True)
    sl = scs.add_parser("list", help="print all scenario types with family and V2X flag")
    sl.set_defaults(func=_scenarios_list)
    sr = scs.add_parser("render", help="write a short video per scenario (top-down ego and RSU views)")
    sr.add_argument("names", nargs="*", help="scenario types (default: all)")
    sr.add_argument("--out", default="docs/gallery")
    sr.add_argument("--seed", type=int, default=0)
    sr.add_argument("--size", type=int, default=256)
    sr.add_argument("--quiet", action="store_true")
    sr.set_defaults(func=_scenarios_render)
    ev = sub.add_parser("eval", help="evaluate an agent on a route suite (resumable)",
                        description="Closed-loop evaluation through TorchRL collectors. Writes "
                        "OUT/routes/<route>_s<k>.json per run and OUT/summary.{json,md}; running "
                        "again on the same OUT resumes.")
    ev.add_argument("--agent", default="route_follower",
                    help="registered agent name (route_follower, expert, ...) or path/to/file.py:ClassName")
    ev.add_argument("--suite", default="test50", help="suite name (test50, val, train) or suite JSON path")
    ev.add_argument("--seeds", type=int, default=1, help="seed indices per route")
    ev.add_argument("--workers", type=int, default=1, help="collector worker processes")
    ev.add_argument("--out", default="results/eval")
    ev.add_argument("--video", action="store_true", help="save a top-down GIF per route in OUT/videos")
    ev.add_argument("--max-routes", type=int, default=None, help="only the first N routes of the suite")
    ev.add_argument("--set", action="append", metavar="KEY=VALUE",
                    help="environment config override, e.g. --set num_vehicles=10 (repeatable)")
    ev.add_argument("--agent-name", default=None, help="display name in the summary and leaderboard")
    ev.add_argument("--isolate-agent", action="store_true",
                    help="run the agent in a separate process that receives only route_info and its "
                    "observations (it cannot read or patch the simulator); not for the privileged "
                    "built-in expert and oracles")
    ev.add_argument("--quiet", action="store_true", help="no progress bar")
    ev.set_defaults(func=_eval)
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
    _add_benchmark(sub, "coverage", "rsu_coverage", "how well the route's roadside units see the V2X hazards",
                   "Drive every V2X-type scenario instance of a suite and measure how long each hazard "
                   "is hidden from the ego and seen by the active roadside unit "
                   "(benchmarks/rsu_coverage.py).")
    lb = sub.add_parser("leaderboard", help="leaderboard table and plots from evaluation result dirs")
    lb.add_argument("results", nargs="+", help="result directories (each with a summary.json)")
    lb.add_argument("--out", default="leaderboard")
    lb.add_argument("--no-plots", action="store_true", help="only the markdown and JSON tables")
    lb.set_defaults(func=_leaderboard)
    co = sub.add_parser("collect", help="expert data collection into memmap shards (resumable)",
                        description="Drive the expert on a suite's routes with recovery noise and record "
                        "every tick (sensors, calibration, 3 GT box sets, expert labels, channel stats) into "
                        "OUT/shards/<route>_s<k>/, plus keyframe facts and images for Chat-V2XBench. Running "
                        "again on the same OUT resumes.")
    co.add_argument("--suite", default="train", help="suite name (train, val, test50) or suite JSON path")
    co.add_argument("--out", default="data/v2x")
    co.add_argument("--workers", type=int, default=1, help="episode worker processes")
    co.add_argument("--scale", default="default", choices=("tiny", "default", "paper"),
                    help="tiny: 3 routes x 150 ticks; default: every route once; paper: 2 seeds per route (~105K frames)")
    co.add_argument("--seeds", type=int, default=None, help="seed indices per route (overrides the scale)")
    co.add_argument("--max-routes", type=int, default=None, help="only the first N routes")
    co.add_argument("--max-ticks", type=int, default=None, help="cap per episode (ticks)")
    co.add_argument("--max-episodes", type=int, default=None, help="stop after N new episodes (resume later)")
    co.add_argument("--sensors", default=None,
                    help="comma list stored every tick, of rgb,depth,semantic,lidar,bev (default rgb,bev)")
    co.add_argument("--camera-size", default=None, help="WxH of the 7 cameras (default 128x64)")
    co.add_argument("--lidar-scale", type=float, default=None,
                    help="fraction of the default LiDAR channels/azimuths (faster, coarser GT visibility)")
    co.add_argument("--val-fraction", type=float, default=None,
                    help="share of train-suite routes held out as the val split (default 0.1)")
    co.add_argument("--no-perturb", action="store_true", help="no recovery noise")
    co.add_argument("--set", action="append", metavar="KEY=VALUE", help="environment config override (repeatable)")
    co.add_argument("--quiet", action="store_true", help="no progress bar")
    co.set_defaults(func=_collect)
    da = sub.add_parser("data", help="data set tools")
    das = da.add_subparsers(dest="data_command", required=True)
    dv = das.add_parser("validate", help="find missing, corrupt and unlisted shards (exit 1 if any)")
    dv.add_argument("root", help="data set folder")
    dv.add_argument("--quick", action="store_true", help="sizes only, no checksums")
    dv.set_defaults(func=_data_validate)
    qa = sub.add_parser("qa", help="Chat-V2XBench: build, stats, score")
    qas = qa.add_subparsers(dest="qa_command", required=True)
    qb = qas.add_parser("build", help="generate QA pairs (our JSONL + LLaVA JSONL) from a data set")
    qb.add_argument("root", help="data set folder")
    qb.add_argument("--seed", type=int, default=0, help="paraphrase seed")
    qb.add_argument("--out", default=None, help="output folder (default ROOT/chat)")
    qb.set_defaults(func=_qa_build)
    qs = qas.add_parser("stats", help="counts per level, question type and scenario")
    qs.add_argument("path", help="data set folder or qa.jsonl")
    qs.add_argument("--json", action="store_true")
    qs.set_defaults(func=_qa_stats)
    qw = qas.add_parser("show", help="mosaic of a keyframe's 7 camera images + its QA pairs (Markdown)")
    qw.add_argument("root", help="data set folder (after `qa build`)")
    qw.add_argument("--out", default="keyframe.png")
    qw.add_argument("--keyframe", default=None, help="<episode>_t<tick> (default: the most informative)")
    qw.add_argument("--scale", type=int, default=3, help="image upscaling factor")
    qw.set_defaults(func=_qa_show)
    qc = qas.add_parser("score", help="score predicted answers (JSONL of {id, answer}) against the reference")
    qc.add_argument("reference", help="data set folder or qa.jsonl")
    qc.add_argument("predictions", help="JSONL with one {\"id\", \"answer\"} per line")
    qc.set_defaults(func=_qa_score)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``v2xbench`` command."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as e:
        print(f"v2xbench: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
