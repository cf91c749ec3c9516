"""NonSignalizedJunctionLeftTurn / RightTurn (CARLA LB2.0 flows at junctions without lights, with
a truck that hides the flow): where they are set, where the truck stands and where it comes from,
a flow that runs whatever the ego does, per-instance draws, and who sees the flow."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from v2xbench.agents.route_follower import RouteFollower
from v2xbench.envs.v2x_intersection.api.observations import ego_observation
from v2xbench.envs.v2x_intersection.core.actors import PARKED
from v2xbench.envs.v2x_intersection.core.classes import LARGE_VEHICLE
from v2xbench.envs.v2x_intersection.scenarios import build_episode, get_scenario, v2x_junction
from v2xbench.envs.v2x_intersection.scenarios.flows import connectors, side_of
from v2xbench.envs.v2x_intersection.scenarios.probe import hidden_seconds, probe
from v2xbench.envs.v2x_intersection.scenarios.timed import SPEED_SCALE
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.model import LEFT

SMALL = dict(num_vehicles=4, num_parked=2, num_pedestrians=2, num_bicycles=0)
BRAKE = np.array([0.0, 0.0, 1.0], np.float32)
TYPES = {"NonSignalizedJunctionLeftTurn": "opposite", "NonSignalizedJunctionRightTurn": "left"}


def episode(name: str, town: str, seed: int):
    world = World(make_config(town=town, **SMALL))
    route, scenarios = build_episode(name, get_town(town), np.random.default_rng(seed))
    world.reset(seed=seed, route=route, scenarios=scenarios)
    return world, scenarios[0]


@pytest.mark.parametrize("town", ["Town01", "Town12"])
@pytest.mark.parametrize("name", list(TYPES))
def test_sites_make_the_ego_yield_to_a_flow_from_the_right_side(name, town):
    t = get_town(town)
    sites = get_scenario(name).find_sites(t)
    assert sites
    for s in sites:
        j = t.junctions[t.index.junction[s.lanes[1]]]
        assert s.lanes[0] in j.stop_lanes  # the ego must yield
        path, s_path = s.extra
        assert side_of(t, s.lanes[0], path[0]) == TYPES[name]
        assert 0.0 < s_path < sum(t.index.length[list(path)])
        if name == "NonSignalizedJunctionLeftTurn":  # an inner lane where the truck waits to turn
            inner = t.lanes[path[0]].left
            assert inner >= 0 and connectors(t, inner, (LEFT,))
        else:  # the flow goes straight into the lane the ego turns into
            assert path[-1] == s.lanes[2]


@pytest.mark.parametrize("name", list(TYPES))
def test_truck_comes_from_truck_size_and_stands_off_both_paths(name, monkeypatch):
    size = (8.123, 2.456, 3.5)
    monkeypatch.setattr(v2x_junction, "truck_size", lambda rng: size)
    world, sc = episode(name, "Town01", 1)
    t, town = world.table, world.town
    row = int(sc.rows[0])
    assert t.kind[row] == LARGE_VEHICLE and t.behaviour[row] == PARKED and t.speed[row] == 0.0
    assert (t.length[row], t.width[row], t.height[row]) == pytest.approx(size)
    # clear of the ego's path around the conflict and of the flow's lane
    near = np.abs(world.route.s - sc.conflict_s) < 15.0
    d_route = np.linalg.norm(world.route.points[near] - t.pos[row], axis=1).min()
    assert d_route > 0.5 * t.width[row] + 1.0
    flow = sc.flows[0]
    pts = np.array([flow.point(town, s)[0] for s in np.arange(0.0, flow.cum[-1], 0.5)])
    d_flow = np.linalg.norm(pts - t.pos[row], axis=1).min()
    assert d_flow > 0.5 * t.width[row] + 1.0
    if name == "NonSignalizedJunctionLeftTurn":  # waiting to turn left in the oncoming approach
        inner = town.lanes[int(sc.site.extra[0][0])].left
        lanes = [inner, *connectors(town, inner, (LEFT,))]
        _, _, dist = town.index.project(t.pos[row][None], np.array(lanes[:1]))
        _, _, dist2 = town.index.project(t.pos[row][None], np.array(lanes[1:2]))
        assert min(dist[0], dist2[0]) < 0.5


@pytest.mark.parametrize("name", list(TYPES))
def test_flow_runs_from_reset_whatever_the_ego_does(name):
    """The flow moves before any trigger and its vehicles drive the same whether the ego stands
    still or drives up to the junction (until the driving ego is close to the flow's lane)."""
    follower = RouteFollower()
    runs = []
    for drive in (False, True):
        world, sc = episode(name, "Town12", 2)
        rows = [int(r) for r in sc.hazard_rows]
        xy, gap = [], []
        for _ in range(120):
            control = follower.act(ego_observation(world)) if drive else BRAKE
            world.step(control, world.default_rsu_message())
            xy.append(world.table.pos[rows].copy())
            gap.append(sc.conflict_s - sc.ego_s(world))
        runs.append((np.array(xy), np.array(gap), sc))
    (xy_a, _, sc_a), (xy_b, gap_b, _) = runs
    assert not sc_a.triggered
    assert np.linalg.norm(xy_a[-1] - xy_a[0], axis=1).max() > 20.0, "the flow did not move"
    far = gap_b > 25.0
    assert far.sum() > 30
    np.testing.assert_array_equal(xy_a[far], xy_b[far])


@pytest.mark.parametrize("name", list(TYPES))
def test_speed_and_truck_place_are_drawn_per_instance(name):
    scales, places = set(), set()
    for seed in range(4):
        world, sc = episode(name, "Town01", seed)
        assert SPEED_SCALE[0] <= sc.speed_scale <= SPEED_SCALE[1]
        assert sc.flows[0].speed == pytest.approx(float(sc.params["speed"]) * sc.speed_scale)
        scales.add(round(sc.speed_scale, 6))
        places.add(round(sc.position_jitter, 6))
    assert len(scales) == 4 and len(places) == 4


def test_right_turn_flow_hidden_from_ego_seen_by_rsu():
    rec = probe("NonSignalizedJunctionRightTurn", 4, town="Town12", max_ticks=500,
                stop_after_pass=1.0, **SMALL)
    hidden = max(hidden_seconds(rec, h) for h in range(rec.hazard_xy.shape[1]))
    assert hidden >= 1.0, f"hidden from the ego while the RSU sees it for only {hidden:.1f} s"


def test_left_turn_flow_hidden_from_ego_seen_by_rsu():
    """The left-turn junction unit (near-right corner, looking across the junction at the
    oncoming approach) sees the flow car the waiting truck hides from the ego."""
    rec = probe("NonSignalizedJunctionLeftTurn", 1, town="Town12", max_ticks=500,
                stop_after_pass=1.0, **SMALL)
    hidden = max(hidden_seconds(rec, h) for h in range(rec.hazard_xy.shape[1]))
    assert hidden >= 1.0


@pytest.mark.parametrize("name", list(TYPES))
def test_a_site_without_its_flow_pair_is_named(name):
    town = get_town("Town01")
    route, (sc,) = build_episode(name, town, np.random.default_rng(0))
    bad = get_scenario(name)(route, dataclasses.replace(sc.site, extra=()), sc.conflict_s)
    world = World(make_config(town="Town01", **SMALL))
    with pytest.raises(ValueError, match=f"{name}: site.extra must be one"):
        world.reset(seed=0, route=route, scenarios=[bad])
