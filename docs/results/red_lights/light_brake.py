"""CoDriving with and without its light brake on the same route runs: docs/baselines.md, "Red
lights". Reads two ``v2xbench eval`` output folders and compares the runs both hold (matched by
job id: route and seed): the package's suite summary of those runs (``aggregate``: mean DS with
its bootstrap 95 % CI, RC, infractions per km driven), and the paired DS difference (per run)
with its bootstrap CI.

    python docs/results/red_lights/light_brake.py NAME=EVAL_DIR BASE=EVAL_DIR ... --out FILE.json

The first folder is compared with each of the others on their common runs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from v2xbench.collectors.jobs import all_results
from v2xbench.envs.v2x_intersection.evaluation.metrics import aggregate, bootstrap_ci

from v2xbench.files import atomic_write_text


def runs(folder: str | Path) -> dict[str, dict]:
    """Job id -> metrics of every result in an eval folder."""
    return {r["job_id"]: r["metrics"] for r in all_results(folder)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", help="NAME=EVAL_DIR (the first is compared with the rest)")
    ap.add_argument("--out")
    a = ap.parse_args()
    named = [x.split("=", 1) for x in a.folders]
    (name, first), others = named[0], named[1:]
    mine, result = runs(first), {}
    for other, folder in others:
        theirs = runs(folder)
        common = sorted(set(mine) & set(theirs))
        diff = [mine[j]["driving_score"] - theirs[j]["driving_score"] for j in common]
        d = {"jobs": common, name: aggregate([mine[j] for j in common], len(common)),
             other: aggregate([theirs[j] for j in common], len(common)),
             "paired_ds_difference": float(np.mean(diff)),
             "paired_ds_difference_ci": list(bootstrap_ci(diff))}
        result[f"{name} vs {other}"] = d
        for who in (name, other):
            s = d[who]
            print(f"{who:28s} {s['n_finished']:.0f} runs DS {s['driving_score']:.1f} "
                  f"[{s['driving_score_ci_low']:.1f}, {s['driving_score_ci_high']:.1f}] "
                  f"RC {s['route_completion']:.1f} red/km {s['red_light_per_km']:.2f} stop/km "
                  f"{s['stop_sign_per_km']:.2f} veh/km {s['collision_vehicle_per_km']:.2f} "
                  f"ped/km {s['collision_pedestrian_per_km']:.2f}")
        print(f"paired DS difference {d['paired_ds_difference']:+.1f} "
              f"[{d['paired_ds_difference_ci'][0]:+.1f}, {d['paired_ds_difference_ci'][1]:+.1f}]")
    if a.out:
        atomic_write_text(a.out, json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
