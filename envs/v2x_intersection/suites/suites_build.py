"""Build the route suites shipped in ``suites/``: ``python -m v2xbench.envs.v2x_intersection.suites.suites_build``.

Each route chains several scenario sites: it starts with a run-up before the first site, drives
to the next site along the shortest lane path (no lane changes), and so on, then runs out 60 m.
Every scenario instance gets its own parameters, drawn from ``scenarios/param_ranges.py``.
``test50`` uses only the held-out test town; ``train`` and ``val`` only training towns, so no
town is shared between training and testing (as the paper's Town12 test split).
"""

from __future__ import annotations

import argparse
import functools

import numpy as np

from ..scenarios import SCENARIOS, get_scenario
from ..scenarios.param_ranges import draw_params
from ..scenarios.placement import extend_lanes, run_up
from ..town import TEST_TOWNS, TRAIN_TOWNS, get_town
from ..town.routes import route_from_lanes, shortest_lane_path
from .route_files import (
    ROUTE_FORMAT,
    SUITE_DIR,
    SUITE_FORMAT,
    TIMES_OF_DAY,
    WEATHERS,
    _to_json,
    parse_route,
    save_json_atomic,
)

MIN_GAP = 60.0  # m between consecutive scenario conflict points
MAX_LINK = 320.0  # m of driving between two sites


@functools.cache
def _sites_cached(town_name: str, name: str) -> tuple:
    town = get_town(town_name)
    return tuple(s for s in get_scenario(name).find_sites(town) if run_up(town, s) >= 50.0)


def _sites(town, name):
    return list(_sites_cached(town.name, name))


def compose_route(town, rng: np.random.Generator, types: list[str], route_id: str, seed: int) -> dict | None:
    """A route dict through one site of each type in ``types`` (in order), or ``None``."""
    if any(get_scenario(n).starts_route for n in types[1:]):
        return None  # such a type cuts the route to start at its site: it can only come first
    placed: list[tuple[str, object, int]] = []  # (type, site, index of the site's first lane)
    lanes: list[int] = []
    for name in types:
        sites = _sites(town, name)
        if not sites:
            return None
        order = rng.permutation(len(sites))[:40]
        for k in order:
            site = sites[int(k)]
            if not lanes:
                pre, shift = extend_lanes(town, rng, list(site.lanes), 80.0, 0.0)
                lanes = pre
                placed.append((name, site, shift))
                break
            if any(ln in lanes for ln in site.lanes):
                continue
            try:
                link = shortest_lane_path(town, lanes[-1], site.lanes[0], lane_changes=False)
            except ValueError:
                continue
            mid = link[1:-1]
            if any(ln in lanes for ln in mid):
                continue
            dist = float(sum(town.index.length[mid]))
            if dist > MAX_LINK:
                continue
            placed.append((name, site, len(lanes) + len(mid)))
            lanes = lanes + mid + list(site.lanes)
            break
        else:
            return None
    lanes, _ = extend_lanes(town, rng, lanes, 0.0, 60.0)
    route = route_from_lanes(town, lanes)
    conflicts = []
    scen = []
    for i, (name, site, start) in enumerate(placed):
        key_lane = lanes[start + site.key]
        hits = np.flatnonzero(route.lane_ids == key_lane)
        cs = float(route.s[hits[0]] + site.s_on_key)
        conflicts.append(cs)
        cls = get_scenario(name)
        k = int(np.searchsorted(route.s, cs))
        kt = int(np.searchsorted(route.s, max(cs - cls.trigger_distance, 0.0)))
        # parameters from their own stream, so drawing them leaves the route's composition as it was
        params = draw_params(name, cls.defaults, np.random.default_rng([seed, i]))
        scen.append({"type": name, "params": params,
                     "site": {"lanes": [int(x) for x in site.lanes], "key": site.key, "s_on_key": site.s_on_key,
                              "extra": _to_json(site.extra)},
                     "trigger": route.points[min(kt, len(route.points) - 1)].round(3).tolist(),
                     "conflict": route.points[min(k, len(route.points) - 1)].round(3).tolist()})
    if np.any(np.diff(conflicts) < MIN_GAP) or conflicts[0] < 40.0:
        return None
    on_route = set(lanes)
    if any(get_scenario(n).actor_lanes(town, site) & on_route for n, site, _ in placed):
        return None  # the route passes where a scenario's actors stand or drive (outside its site)
    wps = route.points[:: 20]
    wps = np.concatenate([wps, route.points[-1:]], 0)
    return {"format": ROUTE_FORMAT, "id": route_id, "town": town.name, "lanes": [int(x) for x in lanes],
            "waypoints": wps.round(3).tolist(), "scenarios": scen,
            "weather": str(rng.choice(WEATHERS)), "time_of_day": str(rng.choice(TIMES_OF_DAY)), "seed": seed}


def build_suite(name: str, towns: tuple[str, ...], n_routes: int, seed: int, per_route: tuple[int, int] = (2, 3),
                v2x_share: float = 0.8) -> dict:
    """Routes that cover every scenario type that fits ``towns``, over-sampling V2X types.

    Phase 1 places each type once (with companions when possible, alone otherwise); phase 2 fills
    the suite with routes led by a V2X type. Companions are V2X types with probability
    ``v2x_share``, so V2X types make up at least half of the scenario instances.
    """
    rng = np.random.default_rng(seed)
    fits = {t: [n for n in sorted(SCENARIOS) if _sites(get_town(t), n)] for t in towns}
    v2x = {n for n, c in SCENARIOS.items() if c.v2x}
    routes: list[dict] = []

    def companions(town_name: str, first: str | None, k: int) -> list[str]:
        share = v2x_share
        if first is None:  # phase 2 routes are all V2X types (phase 1 placed the others)
            first, share = str(rng.choice([n for n in fits[town_name] if n in v2x])), 1.0
        types = [first]
        while len(types) < k:
            later = [n for n in fits[town_name] if n not in types and not SCENARIOS[n].starts_route]
            pool = [n for n in later if (n in v2x) == (rng.random() < share)] or later
            if not pool:
                break
            types.append(str(rng.choice(pool)))
        return types

    def attempt(first: str | None) -> dict | None:
        for _ in range(40):
            ok = [t for t in towns if ((first in fits[t]) if first else any(n in v2x for n in fits[t]))]
            town_name = str(rng.choice(ok))
            k = int(rng.integers(per_route[0], per_route[1] + 1))
            for size in range(k, 0, -1):
                types = companions(town_name, first, size)
                if not types:
                    return None
                d = compose_route(get_town(town_name), rng, types, f"{name}_{len(routes):03d}",
                                  seed=int(rng.integers(2**31)))
                if d is not None:
                    return d
        return None

    todo = sorted({n for f in fits.values() for n in f})
    rng.shuffle(todo)
    for first in todo:  # phase 1: coverage
        if len(routes) >= n_routes:
            break
        d = attempt(first)
        if d is None:
            print(f"suite {name}: could not place {first}")
            continue
        parse_route(d)
        routes.append(d)
    while len(routes) < n_routes:  # phase 2: fill
        d = attempt(None)
        if d is None:
            raise RuntimeError(f"suite {name}: built only {len(routes)} of {n_routes} routes")
        parse_route(d)
        routes.append(d)
    return {"format": SUITE_FORMAT, "name": name, "split": name, "routes": routes}


SUITES = {
    "test50": dict(towns=TEST_TOWNS, n_routes=50, seed=50, per_route=(2, 4)),
    "val": dict(towns=TRAIN_TOWNS, n_routes=20, seed=20),
    "train": dict(towns=TRAIN_TOWNS, n_routes=60, seed=200),
}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("suites", nargs="*", default=list(SUITES))
    args = p.parse_args()
    for name in args.suites:
        suite = build_suite(name, **SUITES[name])
        path = save_json_atomic(suite, SUITE_DIR / f"{name}.json")
        n = sum(len(r["scenarios"]) for r in suite["routes"])
        print(f"{name}: {len(suite['routes'])} routes, {n} scenario instances -> {path}")


if __name__ == "__main__":
    main()
