"""V2X-specific scenarios with a triggered hazard (the NonSignalizedJunction* flows:
``tests/scenarios/test_scenarios_v2x_flows.py``): each spawns, triggers, its hazard really happens near the ego, and the
hazard is hidden from the ego for at least 1 s before the ego reaches the conflict point while
the active roadside unit sees it (where the route's roadside units cover it: ``UNCOVERED``).

Everything is measured from the probe record (per-tick positions and visibility) and the world
state, never from flags the scenarios set themselves. One probe run per scenario is shared by its
tests (small background populations keep the file fast).
"""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.actors import RIDER
from v2xbench.envs.v2x_intersection.core.classes import BICYCLE, PEDESTRIAN
from v2xbench.envs.v2x_intersection.scenarios import get_scenario
from v2xbench.envs.v2x_intersection.scenarios.probe import hidden_seconds, probe
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.model import LEFT, RIGHT

SMALL = dict(num_vehicles=6, num_parked=4, num_pedestrians=4, num_bicycles=1)

#: scenario -> (town, seed) of the probe run its tests share
CASES = {
    "DynamicObjectCrossing": ("Town01", 5),
    "ParkingCrossingPedestrian": ("Town12", 2),
    "PedestrianCrossing": ("Town01", 4),
    "VehicleTurningRoute": ("Town01", 4),  # a left turn
    "VehicleTurningRoutePedestrian": ("Town12", 2),  # a right turn
    "CrossingBicycleFlow": ("Town01", 3),
}

_RECORDS: dict = {}


def record(name: str):
    """The (cached) probe run of scenario ``name``."""
    if name not in _RECORDS:
        town, seed = CASES[name]
        _RECORDS[name] = probe(name, seed, town=town, max_ticks=700, stop_after_pass=1.0, **SMALL)
    return _RECORDS[name]


def conflict_entries(rec, reach: float = 30.0) -> np.ndarray:
    """``(T, H)`` bool: hazard ``h`` is on the ego's path at the conflict point (within half a lane
    of the route, within 6 m of the conflict along it) at tick ``t`` while the ego is still before
    the conflict point and at most ``reach`` m from it."""
    sc, world = rec.scenario, rec.world
    route = world.route
    near = (route.s > sc.conflict_s - 6.0) & (route.s < sc.conflict_s + 6.0)
    pts = route.points[near]
    half = 0.5 * world.town.index.width[route.lane_ids[near]].min()
    d = np.linalg.norm(rec.hazard_xy[:, :, None, :] - pts[None, None], axis=3).min(2)
    gap = sc.conflict_s - rec.ego_s
    ego_close = (gap > -0.5) & (gap < reach) & rec.triggered
    return (d < half) & ego_close[:, None]


@pytest.mark.parametrize("name", list(CASES))
def test_spawns_triggers_and_hazard_happens(name):
    rec = record(name)
    sc = rec.scenario
    assert sc.hazard_rows, "no hazard actors"
    assert rec.triggered.any(), "the scenario never triggered"
    moved = np.linalg.norm(rec.hazard_xy[-1] - rec.hazard_xy[0], axis=1)
    assert moved.max() > 3.0, "the hazard never moved"
    hit = conflict_entries(rec)
    assert hit.any(), "no hazard reached the ego's path ahead of it"
    # the hazard only moves after the trigger
    first = int(np.argmax(rec.triggered))
    assert np.allclose(rec.hazard_xy[first], rec.hazard_xy[0])


#: probe cases where the route's own roadside units (placed without knowing the scenario, #29)
#: do not see the hidden hazard for 1 s before the ego reaches it: a measured coverage gap
UNCOVERED = {"CrossingBicycleFlow"}


@pytest.mark.parametrize("name", [
    pytest.param(n, marks=pytest.mark.xfail(strict=True, reason="route-only RSU coverage gap"))
    if n in UNCOVERED else n for n in CASES])
def test_hidden_from_ego_seen_by_rsu(name):
    rec = record(name)
    hidden = max(hidden_seconds(rec, h) for h in range(rec.hazard_xy.shape[1]))
    assert hidden >= 1.0, f"hidden from the ego while the RSU sees it for only {hidden:.1f} s"


def test_pedestrian_crossing_group_crosses():
    rec = record("PedestrianCrossing")
    t = rec.world.table
    assert len(rec.scenario.hazard_rows) == 3
    assert all(t.kind[r] == PEDESTRIAN for r in rec.scenario.hazard_rows)
    assert conflict_entries(rec).any(0).sum() >= 2, (
        "fewer than two pedestrians crossed in front of the ego"
    )


def test_turning_hazards_cross_after_a_turn():
    for name, kind in (
        ("VehicleTurningRoute", BICYCLE),
        ("VehicleTurningRoutePedestrian", PEDESTRIAN),
    ):
        rec = record(name)
        town = rec.world.town
        assert rec.world.table.kind[rec.scenario.hazard_rows[0]] == kind
        # the hazard crosses the lane the ego turned into
        hit = np.flatnonzero(conflict_entries(rec).any(1))
        lanes = rec.world.route.lane_ids
        k = np.clip(np.searchsorted(rec.world.route.s, rec.scenario.conflict_s), 0, len(lanes) - 1)
        turned = [town.lanes[ln].turn for ln in lanes[:k]]
        assert LEFT in turned or RIGHT in turned
        assert len(hit)


def test_bicycle_flow_crosses_in_front_of_the_ego():
    rec = record("CrossingBicycleFlow")
    t = rec.world.table
    rows = rec.scenario.hazard_rows
    assert len(rows) >= 3
    assert all(t.kind[r] == BICYCLE and t.behaviour[r] == RIDER for r in rows)
    assert conflict_entries(rec, reach=40.0).any(0).sum() >= 2, (
        "fewer than two bicycles crossed the ego's path"
    )


@pytest.mark.parametrize("name", list(CASES))
def test_fits_training_and_test_towns(name):
    cls = get_scenario(name)
    assert cls.v2x
    assert cls.find_sites(get_town("Town12")), "no site on the held-out test town"
    assert cls.find_sites(get_town(cls.towns[0] if cls.towns else "Town01"))


@pytest.mark.parametrize("name", ["DynamicObjectCrossing", "ParkingCrossingPedestrian"])
def test_crossing_walker_ends_on_the_far_sidewalk(name):
    """The walker's crossing ends off every driving lane, also on multi-lane roads (a fixed
    offset left test50_039's pedestrian standing in a lane the route used later)."""
    from v2xbench.envs.v2x_intersection.evaluation.infractions import _driving_point_ids
    from v2xbench.envs.v2x_intersection.scenarios import build_episode
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

    town = get_town("Town12")
    world = World(make_config(town="Town12", **SMALL))
    episodes = [build_episode(name, town, np.random.default_rng(seed)) for seed in range(3)]
    with_type = [r for r in load_suite_cached("test50") if any(s.type == name for s in r.scenarios)]
    for spec in with_type:  # and every test50 instance of the type (the suite's own sites)
        episodes.append((None, spec))
    pts = _driving_point_ids(town)
    for k, (route, scs) in enumerate(episodes):
        if route is None:
            world.reset(seed=0, spec=scs)
            sc = next(s for s in world.scenarios if s.name == name)
        else:
            world.reset(seed=k, route=route, scenarios=scs)
            sc = world.scenarios[0]
        end = world.table.cross_to[sc.hazard_rows[0]]
        lane, _, dist = town.index.project_near(end[None], pts)
        assert dist[0] > town.index.width[lane[0]] / 2 + 0.5, (k, end, int(lane[0]))
