"""Does a trained UniV2X / UniMM-V2X planner follow the route? On recorded frames, replace the
route inputs (``route_points``, and ``route_path`` for a route-frame planner) by a straight route
and by routes bending 90 deg left / right after 5 m, and report the mean 3 s waypoint.

    python docs/results/route_probe/route_probe.py univ2x RUN DATA [--stride 50] [--out FILE]

Numbers in docs/baselines.md ("What makes a planner drive here"): RUN = the UniV2X runs,
DATA = the first 10 test50 routes' camera collection, stride 50.
"""
from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path

import torch
from v2xbench.agents.aurora.data import make_loader
from v2xbench.agents.aurora.route_input import PATH_KEY, planner_route_path, route_points_ahead
from v2xbench.agents.baselines import BASELINES

ROWS, ROW_STEP, BEND_AT = 20, 2.0, 5.0  # the observed route: 20 rows 2 m apart; bend after 5 m


def bent_route(kind: str) -> torch.Tensor:
    """``(ROWS, 2)`` ego-frame route rows: ``straight``, or turning 90 deg ``left`` / ``right``."""
    side = {"straight": 0.0, "left": 1.0, "right": -1.0}[kind]
    pts = [(s, 0.0) if side == 0 or s <= BEND_AT else (BEND_AT, (s - BEND_AT) * side)
           for s in (ROW_STEP * torch.arange(ROWS)).tolist()]
    return torch.tensor(pts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("method", choices=("univ2x", "unimm_v2x"))
    ap.add_argument("run")
    ap.add_argument("data")
    ap.add_argument("--stride", type=int, default=50)
    ap.add_argument("--out", default=None, help="JSON file to write")
    a = ap.parse_args()
    torch.set_num_threads(1)
    brun = importlib.import_module(BASELINES[a.method] + ".train").RUN
    model, cfg, _ = brun.load_run(a.run)
    ds = brun.frames(a.data, "all", cfg, a.stride, False)
    out: dict = {"run": a.run, "data": a.data, "stride": a.stride, "frames": len(ds),
                 "plan_frame": cfg.plan_frame, "waypoint_3s_mean": {}}
    ends: dict[str, list] = {k: [] for k in ("straight", "left", "right")}
    with torch.no_grad():
        for b in make_loader(ds, 8, shuffle=False):
            n = len(b["command"])
            for kind in ends:
                r = bent_route(kind)
                pts = route_points_ahead(r, cfg.plan_route_points, cfg.plan_route_spacing)
                batch = dict(b, route_points=pts[None].expand(n, -1, -1).clone())
                if out["plan_frame"] == "route":
                    path = planner_route_path(r, cfg)
                    batch[PATH_KEY] = path[None].expand(n, -1, -1).clone()
                ends[kind].append(model(batch)["waypoints"][:, -1])
    for kind, w in ends.items():
        w = torch.cat(w)
        out["waypoint_3s_mean"][kind] = [round(float(w[:, 0].mean()), 2),
                                         round(float(w[:, 1].mean()), 2)]
    print(json.dumps(out, indent=1))
    if a.out:
        Path(a.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
