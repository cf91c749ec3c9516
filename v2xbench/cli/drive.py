"""``v2xbench drive``, ``towns`` and ``scenarios``: look at the simulator."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def check_drive_args(args: argparse.Namespace) -> Path:
    """Check ``drive``'s options before anything is built or driven; returns the output folder.

    Raises:
        ValueError: an option out of range, or ``--out`` cannot be a folder (message names it).
    """
    from v2xbench.files import check_output_dir

    if args.frame_every < 1:
        raise ValueError(f"--frame-every {args.frame_every} must be >= 1 (one frame every N ticks)")
    if args.sensors_every < 0:
        raise ValueError(f"--sensors-every {args.sensors_every} must be >= 0 (0: no sensor video)")
    if not 0 <= args.seed < 2**32:
        raise ValueError(f"--seed {args.seed} must be in [0, 2**32)")
    if args.size < 1:
        raise ValueError(f"--size {args.size} must be a positive number of pixels")
    if not 0 < args.route_length < float("inf"):
        raise ValueError(f"--route-length {args.route_length} must be a positive number of metres")
    return check_output_dir(args.out, "--out")


def _drive(args: argparse.Namespace) -> int:
    out = check_drive_args(args)
    import numpy as np
    from PIL import Image
    from tqdm import tqdm

    from v2xbench.agents.route_follower import RouteFollower
    from v2xbench.collectors.route_log import ended_by_code
    from v2xbench.envs.v2x_intersection import V2XIntersectionEnv
    from v2xbench.envs.v2x_intersection.evaluation.infractions import EVENT_NAMES
    from v2xbench.envs.v2x_intersection.evaluation.metrics import ENDED_BY_NAMES
    from v2xbench.envs.v2x_intersection.render.topdown import save_video
    from v2xbench.envs.v2x_intersection.sensors import SensorRig, mosaic
    from v2xbench.files import atomic_write, atomic_write_json

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
            bar.update(int(info["route_completion"]) - bar.n)  # whole %, not 83.79999999999964
            if terminated or truncated:
                break
    wall = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    video = save_video(frames, out / "drive.gif", fps=max(1, 10 // args.frame_every))
    sensors_video = None
    if mosaics:
        sensors_video = save_video(mosaics, out / "sensors.gif", fps=max(1, 10 // args.sensors_every))
        with atomic_write(out / "sensors.png", "wb") as f:
            Image.fromarray(mosaics[len(mosaics) // 2]).save(f, format="PNG")
    summary = {
        "town": args.town, "seed": args.seed, "ticks": ticks, "sim_seconds": round(ticks * 0.1, 1),
        "route_length_m": round(info["route_length"], 1),
        "route_completion": round(info["route_completion"], 1),
        "ended_by": ENDED_BY_NAMES[ended_by_code(env.world, terminated, truncated)],
        "return": round(total, 2),
        "events": {k: int(v) for k, v in zip(EVENT_NAMES, np.asarray(info["events"]))},
        "v2x_bytes_per_s": round(info["v2x_bps"], 1),
        "wall_seconds": round(wall, 2), "video": str(video),
        "sensors_video": None if sensors_video is None else str(sensors_video),
    }
    atomic_write_json(out / "summary.json", summary, indent=2)
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


def register(sub) -> None:
    """Add this module's sub-commands to the ``v2xbench`` parser."""
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
