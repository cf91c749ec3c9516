"""The shipped AURORA / No Fusion runs of this machine against the first-10 table's runs of an
earlier machine (docs/baselines.md, "Same code, another machine"): per run DS, ticks and end.

    python docs/results/aurora/other_machine.py aurora=EVAL_DIR no_fusion=EVAL_DIR --out FILE.json

EVAL_DIR: a ``v2xbench eval --agent NAME --suite test50 --max-routes 10`` folder of this machine;
the earlier runs are the ``per_run`` of docs/results/planning_first10.json.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from v2xbench.collectors.jobs import all_results

from v2xbench.files import atomic_write_text
from v2xbench.platform_info import run_platform

TABLE = Path(__file__).resolve().parents[1] / "planning_first10.json"


def compare(key: str, folder: str) -> dict:
    """Per run of ``folder`` that the table also holds: the table's and this machine's run."""
    earlier = json.loads(TABLE.read_text())[key]["per_run"]
    runs = {}
    for r in all_results(folder):
        old = earlier.get(r["job_id"])
        if old is not None:
            runs[r["job_id"]] = {"earlier": {k: old[k] for k in ("driving_score", "ticks", "ended_by")},
                                 "here": {"driving_score": r["metrics"]["driving_score"], "ticks": r["ticks"],
                                          "ended_by": r["ended_by"]}}
    ds = [(v["earlier"]["driving_score"], v["here"]["driving_score"]) for v in runs.values()]
    same = sum(v["earlier"]["ticks"] == v["here"]["ticks"] and abs(a - b) < 1e-9
               for v, (a, b) in zip(runs.values(), ds))
    return {"runs": runs, "n": len(runs), "mean_earlier": statistics.fmean(a for a, _ in ds),
            "mean_here": statistics.fmean(b for _, b in ds), "identical": same,
            "max_abs_difference": max(abs(a - b) for a, b in ds)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", help="KEY=EVAL_DIR (KEY: aurora, no_fusion)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    out = {"platform_here": run_platform()}
    for item in a.folders:
        key, folder = item.split("=", 1)
        out[key] = c = compare(key, folder)
        print(f"{key}: {c['n']} runs, DS {c['mean_earlier']:.1f} (earlier machine) -> {c['mean_here']:.1f} "
              f"(here), identical {c['identical']}, largest difference {c['max_abs_difference']:.1f}")
    atomic_write_text(a.out, json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
