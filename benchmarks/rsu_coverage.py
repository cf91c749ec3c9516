"""How well the route's own roadside units cover the V2X hazards of a suite.

Roadside units are placed from the town and the route only (``rsu.deploy``), never from the
scenario list, so whether a unit sees a hazard is measured, not arranged. For every V2X-type
scenario instance of the suite (seed index 0), a driver (default: the privileged ``expert``, which
drives as a careful human would) drives the route, and every tick between the hazard's start and
the ego reaching the conflict point is classified by the visible fraction (>= 0.1) of the moving
hazard actors:

- ``hidden_s``: the ego cannot see any of them;
- ``covered_s``: the ego cannot see them and the active roadside unit can (what V2X adds);
- ``rsu_s``: the active roadside unit sees one of them.

Geometric coverage: ``in_view`` is whether the conflict point lies within range and the camera's
horizontal field of view of the unit that is active when the ego is 15 m before it.

Prints a per-type table and writes ``OUT/rsu_coverage.{json,md}``.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np

from v2xbench.files import atomic_write_json, atomic_write_text

VISIBLE = 0.1  # visible fraction counted as seen
COVERED_S = 0.5  # s of covered time that counts an instance as covered


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``v2xbench coverage``."""
    p.add_argument("--suite", default="test50", help="suite name or JSON path")
    p.add_argument("--agent", default="expert", help="privileged built-in driver")
    p.add_argument("--max-routes", type=int, default=None, help="only the first N routes")
    p.add_argument("--out", default="benchmarks/results", help="output directory")


def _in_view(world, sc) -> bool:
    """Whether the conflict point is in range and in the camera FOV of the unit active 15 m
    before it."""
    from v2xbench.envs.v2x_intersection.core.geometry import wrap_angle
    from v2xbench.envs.v2x_intersection.v2x.rsu import VIEW_HALF_ANGLE, select_active

    r = world.route
    k = min(max(int(np.searchsorted(r.s, sc.conflict_s - 15.0)), 0), len(r.points) - 1)
    if len(world.rsus) == 0:
        return False
    u = int(select_active(world.rsus, r.points[k], float(r.headings[k]), world.config.rsu_range)[0])
    x, y, _, yaw = world.rsus.pose[u]
    d = sc.conflict_point - (x, y)
    ang = abs(float(wrap_angle(np.arctan2(d[1], d[0]) - yaw)))
    return bool(np.hypot(*d) < world.config.rsu_range and ang < VIEW_HALF_ANGLE)


def measure(suite: str = "test50", agent: str = "expert", max_routes: int | None = None,
            progress: bool = True) -> list[dict]:
    """One record per V2X-type scenario instance (see the module docstring)."""
    import torch
    from tqdm import tqdm
    from v2xbench.agents.interface import load_agent
    from v2xbench.collectors import jobs as J
    from v2xbench.envs.v2x_intersection.api.observations import ego_observation
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite

    torch.set_num_threads(1)
    routes = load_suite(suite)[1][:max_routes]
    world = World(make_config(town=routes[0].town))
    out = []
    for spec in tqdm(routes, desc="coverage", disable=not progress):
        world.reset(seed=J.job_seed(spec.seed, 0), spec=spec)
        scs = [sc for sc in world.scenarios if sc.v2x]
        if not scs:
            continue
        drv = load_agent(agent)
        drv.reset({})
        drv.bind(world)
        rec = {id(sc): {"route": spec.id, "type": sc.name, "in_view": _in_view(world, sc),
                        "hidden_s": 0.0, "covered_s": 0.0, "rsu_s": 0.0} for sc in scs}
        dt = world.config.dt
        for _ in range(int(600 / dt)):
            world.step(drv.act(ego_observation(world)), world.default_rsu_message())
            t = world.table
            for sc in scs:
                moving = [r for r in sc.hazard_rows if t.active[r] and t.speed[r] > 0.2]
                if not moving or sc.ego_s(world) >= sc.conflict_s:
                    continue
                ego_sees = world.ego_vis[moving].max() >= VISIBLE
                rsu_sees = world.rsu_vis[:, moving].max() >= VISIBLE
                r = rec[id(sc)]
                r["hidden_s"] += dt * float(not ego_sees)
                r["covered_s"] += dt * float(not ego_sees and rsu_sees)
                r["rsu_s"] += dt * float(rsu_sees)
            if world.ended or world.is_route_complete() or all(sc.passed for sc in scs):
                break
        out += [{k: round(float(v), 1) if isinstance(v, (float, np.floating)) else v
                 for k, v in r.items()}
                for r in rec.values()]
    return out


def summarize(records: list[dict]) -> list[dict]:
    """Per scenario type: instances, in view, hidden (>= 0.5 s) and covered (>= 0.5 s)."""
    by = defaultdict(list)
    for r in records:
        by[r["type"]].append(r)
    rows = []
    for name, rs in sorted(by.items()):
        rows.append({"type": name, "n": len(rs), "in_view": int(sum(r["in_view"] for r in rs)),
                     "hidden": int(sum(r["hidden_s"] >= COVERED_S for r in rs)),
                     "covered": int(sum(r["covered_s"] >= COVERED_S for r in rs))})
    total = {"type": "all", **{k: sum(r[k] for r in rows) for k in ("n", "in_view", "hidden", "covered")}}
    return rows + [total]


def markdown(rows: list[dict]) -> str:
    """The per-type table."""
    lines = ["| scenario type | instances | conflict point in view | hazard hidden from the ego "
             f">= {COVERED_S} s | hidden and seen by the RSU >= {COVERED_S} s |",
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['type']} | {r['n']} | {r['in_view']} | {r['hidden']} | {r['covered']} |")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    records = measure(args.suite, args.agent, args.max_routes)
    rows = summarize(records)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = markdown(rows)
    atomic_write_json(out / "rsu_coverage.json", {"suite": args.suite, "agent": args.agent,
                                                  "types": rows, "instances": records}, indent=1)
    atomic_write_text(out / "rsu_coverage.md", table)
    print(table)
    print(f"wrote {out / 'rsu_coverage.md'} and rsu_coverage.json")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="v2xbench coverage", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
