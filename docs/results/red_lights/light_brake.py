"""CoDriving with and without its light brake on the same route runs: docs/baselines.md, "Red
lights". Reads two ``v2xbench eval`` output folders and compares the runs both hold (matched by
job id: route and seed): mean DS with its bootstrap 95 % CI (the package's ``bootstrap_ci``),
RC, infractions per km driven, and the paired DS difference (per run) with its bootstrap CI.

    python docs/results/red_lights/light_brake.py NAME=EVAL_DIR BASE=EVAL_DIR ... --out FILE.json

The first folder is compared with each of the others on their common runs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from v2xbench.envs.v2x_intersection.evaluation.metrics import bootstrap_ci

COUNTS = ("red_light", "stop_sign", "collision_vehicle", "collision_pedestrian")


def runs(folder: str | Path) -> dict[str, dict]:
    """Job id -> metrics of every result in an eval folder."""
    out = {}
    for f in sorted((Path(folder) / "routes").glob("*.json")):
        r = json.loads(f.read_text())
        out[r["job_id"]] = r["metrics"]
    return out


def stats(ms: list[dict]) -> dict:
    """Mean DS [CI], RC and infractions per km of a list of per-run metrics."""
    ds = [m["driving_score"] for m in ms]
    lo, hi = bootstrap_ci(ds)
    km = sum(m["km_completed"] for m in ms)
    return {"runs": len(ms), "driving_score": float(np.mean(ds)), "ci": [lo, hi],
            "route_completion": float(np.mean([m["route_completion"] for m in ms])),
            "km": km, **{f"{c}_per_km": sum(m[f"n_{c}"] for m in ms) / km for c in COUNTS}}


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
        result[f"{name} vs {other}"] = {"jobs": common, name: stats([mine[j] for j in common]),
                                        other: stats([theirs[j] for j in common]),
                                        "paired_ds_difference": float(np.mean(diff)),
                                        "paired_ds_difference_ci": list(bootstrap_ci(diff))}
        for who in (name, other):
            s = result[f"{name} vs {other}"][who]
            print(f"{who:28s} {s['runs']} runs DS {s['driving_score']:.1f} [{s['ci'][0]:.1f}, "
                  f"{s['ci'][1]:.1f}] RC {s['route_completion']:.1f} red/km "
                  f"{s['red_light_per_km']:.2f} stop/km {s['stop_sign_per_km']:.2f} veh/km "
                  f"{s['collision_vehicle_per_km']:.2f} ped/km {s['collision_pedestrian_per_km']:.2f}")
        d = result[f"{name} vs {other}"]
        print(f"paired DS difference {d['paired_ds_difference']:+.1f} "
              f"[{d['paired_ds_difference_ci'][0]:+.1f}, {d['paired_ds_difference_ci'][1]:+.1f}]")
    if a.out:
        Path(a.out).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
