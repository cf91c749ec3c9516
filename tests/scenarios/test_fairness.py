"""The benchmark measures cooperation fairly: a hidden hazard never reacts to the ego's waiting
or to whether the ego can see it (CARLA-style triggers, then on its own), and a stop-and-wait
ego gains nothing from standing before an occluder.

Each test drives one scenario episode twice with the same seed and compares the hazard's
trajectory (small background populations keep it fast)."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.agents.route_follower import RouteFollower
from v2xbench.envs.v2x_intersection.api.observations import ego_observation
from v2xbench.envs.v2x_intersection.scenarios import build_episode
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town import get_town

SMALL = dict(num_vehicles=4, num_parked=2, num_pedestrians=2, num_bicycles=0)
CASES = [("DynamicObjectCrossing", "Town01", 5), ("ParkingCrossingPedestrian", "Town12", 2)]
BRAKE = np.array([0.0, 0.0, 1.0], np.float32)


def run(name: str, town: str, seed: int, policy, ticks: int, on_tick=None):
    """Drive scenario ``name``: ``policy(world, scenario, obs, follower) -> control`` each tick;
    returns the hazard's positions ``(T, 2)``, the ego's route progress ``(T,)`` and the
    scenario."""
    world = World(make_config(town=town, **SMALL))
    route, scenarios = build_episode(name, get_town(town), np.random.default_rng(seed))
    world.reset(seed=seed, route=route, scenarios=scenarios)
    sc, follower = scenarios[0], RouteFollower()
    row = sc.hazard_rows[0]
    xy, s = [], []
    for _ in range(ticks):
        control = policy(world, sc, ego_observation(world), follower)
        world.step(control, world.default_rsu_message())
        if on_tick is not None:
            on_tick(world)
        xy.append(world.table.pos[row].copy())
        s.append(sc.ego_s(world))
    return np.array(xy), np.array(s), sc


def stop_at(gap_m: float, then_drive: bool = False, after_s: float = 0.0):
    """A policy: follow the route, stand once ``gap_m`` m before the conflict point; with
    ``then_drive`` drive on ``after_s`` s after standing."""
    stood = {"t": 0.0}

    def policy(world, sc, obs, follower):
        if sc.conflict_s - sc.ego_s(world) > gap_m and stood["t"] == 0.0:
            return follower.act(obs)
        stood["t"] += world.config.dt
        if then_drive and stood["t"] > after_s:
            return follower.act(obs)
        return BRAKE

    return policy


@pytest.mark.parametrize("name,town,seed", CASES)
def test_a_waiting_ego_never_releases_a_hazard(name, town, seed):
    """Standing 25 s 40 m before the conflict point (inside the scenario, before any trigger)
    leaves the hazard where it waits: waiting is not a trigger."""
    xy, s, sc = run(name, town, seed, stop_at(40.0), 600)
    assert sc.triggered  # the scenario runs its hooks: only the hazard waits
    standing = s >= s[-1] - 0.5  # the ticks the ego stood
    assert standing.sum() > 150
    assert sc.hazard_trigger_tick < 0
    assert np.allclose(xy[standing], xy[standing][0])


@pytest.mark.parametrize("name,town,seed", CASES)
def test_hazard_start_same_standing_or_driving(name, town, seed):
    """Triggered by distance, the hazard starts at the same tick and walks the same first metres
    whether the ego then stands still or drives on slowly 1 s later."""
    gap = 5.0  # inside CARLA's 6 m minimum trigger distance
    xy_a, _, sc_a = run(name, town, seed, stop_at(gap), 500)
    xy_b, _, sc_b = run(name, town, seed, stop_at(gap, then_drive=True, after_s=0.3), 500)
    assert sc_a.hazard_trigger_tick >= 0 and sc_a.hazard_trigger_tick == sc_b.hazard_trigger_tick
    moved_a = np.flatnonzero(np.linalg.norm(xy_a - xy_a[0], axis=1) > 0.05)
    moved_b = np.flatnonzero(np.linalg.norm(xy_b - xy_b[0], axis=1) > 0.05)
    assert len(moved_a) and len(moved_b) and moved_a[0] == moved_b[0]
    k = moved_a[0]
    np.testing.assert_allclose(xy_a[k : k + 5], xy_b[k : k + 5])  # the first half second


@pytest.mark.parametrize("name,town,seed", CASES)
def test_hazard_ignores_the_ego_visibility_flag(name, town, seed):
    """The same episode (the same controls, replayed) with the simulator's ego-visibility flags
    forced to 'all seen' after every tick gives the same hazard trajectory: no pacing keyed on
    what the ego can see."""
    controls: list[np.ndarray] = []

    def drive(world, sc, obs, follower):
        controls.append(follower.act(obs))
        return controls[-1]

    def replay(world, sc, obs, follower):
        return controls[world.tick]

    def all_seen(world):
        world.ego_vis[:] = 1.0

    xy_a, _, sc_a = run(name, town, seed, drive, 400)
    xy_b, _, _ = run(name, town, seed, replay, 400, on_tick=all_seen)
    assert sc_a.hazard_trigger_tick >= 0, "the hazard never triggered"
    assert np.linalg.norm(xy_a[-1] - xy_a[0]) > 1.0, "the hazard never moved"
    np.testing.assert_array_equal(xy_a, xy_b)


def test_stop_and_wait_ego_stands_and_releases_nothing():
    """The registered ``stop_and_wait_ego`` stands at least 5 s before the scenario's truck while
    the hidden pedestrian waits; the pedestrian starts only after the ego drives on."""
    from v2xbench.agents.interface import load_agent

    name, town, seed = "DynamicObjectCrossing", "Town01", 7  # a truck (seed 5 draws a car)
    world = World(make_config(town=town, **SMALL))
    route, scenarios = build_episode(name, get_town(town), np.random.default_rng(seed))
    world.reset(seed=seed, route=route, scenarios=scenarios)
    assert not scenarios[0].child
    agent = load_agent("stop_and_wait_ego")
    agent.reset({})
    agent.bind(world)
    sc = scenarios[0]
    stood, stood_at, last_stand = 0, None, -1
    for _ in range(900):
        world.step(agent.act(ego_observation(world)), world.default_rsu_message())
        gap = sc.conflict_s - sc.ego_s(world)
        if world.table.speed[0] < 0.1 and 10.0 < gap < 40.0:
            stood += 1
            stood_at, last_stand = gap, world.tick
        if sc.passed:
            break
    assert stood * world.config.dt >= 5.0, "the agent did not stand before the truck"
    assert sc.hazard_trigger_tick > last_stand, "the hazard started while the ego stood"
    assert stood_at > sc.min_trigger_m


def test_walker_steps_back_for_a_car_standing_in_its_way():
    """A car standing across a walker's way that waits for it too: the walker pauses before the
    car's body, then steps back to where it waited instead of standing there for good (no
    deadlock) and never walks into the car."""
    from v2xbench.envs.v2x_intersection.evaluation import infractions as inf

    name, town, seed = CASES[0]
    world = World(make_config(town=town, **SMALL))
    route, scenarios = build_episode(name, get_town(town), np.random.default_rng(seed))
    world.reset(seed=seed, route=route, scenarios=scenarios)
    sc, t = scenarios[0], world.table
    row = sc.hazard_rows[0]
    home = t.pos[row].copy()
    sc.triggered, sc.trigger_tick = True, 0  # the scenario runs its hooks from now on
    sc.release_walker(world, row)
    way = t.cross_to[row] - home
    way /= np.linalg.norm(way)
    # the car stands across the walker's way, 4 m ahead of it, and does not move
    t.pos[0] = home + 4.0 * way
    t.yaw[0] = float(np.arctan2(way[0], -way[1]))  # its side faces the walker
    t.speed[0] = 0.0
    xy = []
    for _ in range(80):
        world.step(BRAKE, world.default_rsu_message())
        xy.append(t.pos[row].copy())
    xy = np.array(xy)
    d_home = np.linalg.norm(xy - home, axis=1)
    assert row in sc._retreating, "the walker did not step back"
    assert d_home.max() < 3.0, "the walker walked into the car"
    assert d_home[-1] < d_home.max() - 0.5, "it came back toward where it waited"
    assert world.monitor.counts[inf.COLLISION_PEDESTRIAN] == 0
