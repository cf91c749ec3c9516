"""The ``v2xbench`` command line.

Commands:
    drive   drive a route with the built-in route follower, write a top-down GIF, print a summary
    towns   list the named towns (training / test split)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def _drive(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from v2xbench.agents.route_follower import RouteFollower
    from v2xbench.envs.v2x_intersection import V2XIntersectionEnv
    from v2xbench.envs.v2x_intersection.infractions import EVENT_NAMES
    from v2xbench.envs.v2x_intersection.render import save_video

    env = V2XIntersectionEnv(render_mode="rgb_array", town=args.town, route_length=args.route_length,
                             render_size=args.size)
    obs, info = env.reset(seed=args.seed)
    agent = RouteFollower(use_v2x=not args.no_v2x)
    agent.reset()
    frames = [env.render()]
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
            bar.update(round(info["route_completion"] - bar.n, 1))
            if terminated or truncated:
                break
    wall = time.perf_counter() - t0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    video = save_video(frames, out / "drive.gif", fps=max(1, 10 // args.frame_every))
    summary = {
        "town": args.town, "seed": args.seed, "ticks": ticks, "sim_seconds": round(ticks * 0.1, 1),
        "route_length_m": round(info["route_length"], 1),
        "route_completion": round(info["route_completion"], 1),
        "ended_by": "route complete / deviation / blocked" if terminated else "time budget",
        "return": round(total, 2),
        "events": {k: int(v) for k, v in zip(EVENT_NAMES, np.asarray(info["events"]))},
        "v2x_bytes_per_s": round(info["v2x_bps"], 1),
        "wall_seconds": round(wall, 2), "video": str(video),
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
    d.add_argument("--no-v2x", action="store_true", help="ignore what the RSU sends")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_drive)
    t = sub.add_parser("towns", help="list the named towns")
    t.set_defaults(func=_towns)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``v2xbench`` command."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ValueError as e:
        print(f"v2xbench: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
