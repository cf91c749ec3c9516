"""Where do the learned planners run out of time? From the per-route results of `v2xbench eval`
(the ego's speed every tick, ``record.ego_speed``), per evaluation folder: the share of ticks the
ego stands (< 0.3 m/s), the runs that end standing still for their last 60 s or more without
completing, the runs that never move, and per route the tick from which the ego stands for good.

    python docs/results/standstill/standstill.py NAME=EVAL_DIR [NAME=EVAL_DIR ...] [--out FILE]

Numbers in docs/baselines.md ("Why the baselines run out of time"): the shipped baselines'
closed-loop folders of the planning table (first 10 test50 routes x 3 seeds).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from v2xbench.agents.aurora.frame_balance import REST_SPEED

from v2xbench.files import atomic_write_text

STILL = REST_SPEED  # m/s: standing (the threshold of the training-frame balance)
TAIL = 600  # ticks (60 s at 10 Hz): standing for good


def stands_from(speeds: np.ndarray) -> int:
    """The tick from which the ego stands (< ``STILL``) to the end: 0 when it never moves,
    ``len(speeds)`` when it moves at the last tick."""
    moving = np.flatnonzero(np.asarray(speeds, float) > STILL)
    return int(moving[-1]) + 1 if len(moving) else 0


def write_json(obj: dict, path: Path) -> None:
    """``obj`` as indented JSON with a final newline, written atomically."""
    atomic_write_text(path, json.dumps(obj, indent=1) + "\n")


def summarize(folder: Path) -> dict:
    """The standstill numbers of one evaluation folder (module docstring)."""
    runs, still, ticks = {}, 0, 0
    for f in sorted((folder / "routes").glob("*.json")):
        r = json.loads(f.read_text())
        v = np.asarray(r["record"]["ego_speed"], float)
        moving = v > STILL
        runs[r["job_id"]] = {"ended_by": r["ended_by"], "ticks": len(v),
                             "stands_from_tick": stands_from(v),
                             "never_moves": bool(not moving.any()),
                             "scenario_types": r["scenario_types"]}
        still, ticks = still + int((~moving).sum()), ticks + len(v)
    if not runs:
        raise SystemExit(f"{folder}: no results in {folder / 'routes'}")
    stuck = [k for k, x in runs.items()
             if x["ended_by"] != "completed" and x["ticks"] - x["stands_from_tick"] >= TAIL]
    return {"folder": str(folder), "runs": len(runs), "share_of_ticks_standing": still / ticks,
            "runs_ending_standing_60s": len(stuck), "stuck_runs": stuck,
            "runs_never_moving": sum(x["never_moves"] for x in runs.values()), "per_run": runs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", metavar="NAME=EVAL_DIR")
    ap.add_argument("--out", type=Path, default=None, help="write the numbers as JSON here")
    args = ap.parse_args()
    out = {}
    for item in args.folders:
        name, sep, path = item.partition("=")
        if not sep:
            raise SystemExit(f"{item!r}: expected NAME=EVAL_DIR")
        s = out[name] = summarize(Path(path))
        print(f"{name}: {s['runs']} runs, standing {100 * s['share_of_ticks_standing']:.0f} % of "
              f"ticks, {s['runs_ending_standing_60s']} end standing >= 60 s, "
              f"{s['runs_never_moving']} never move")
    if args.out is not None:
        write_json(out, args.out)


if __name__ == "__main__":
    main()
