"""Children: a share of every walker population (background and scenario) is child-sized, and
ParkingCrossingPedestrian hides a child behind parked cars only, so that no large vehicle (what
``cautious_ego`` keys on) and no walker size marks the hazard."""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.core import actors
from v2xbench.envs.v2x_intersection.core.actors import (
    CHILD_HEIGHT,
    CHILD_SHARE,
    SIZES,
    WALKER,
    child_size,
    draw_size,
)
from v2xbench.envs.v2x_intersection.core.classes import LARGE_VEHICLE, PEDESTRIAN
from v2xbench.envs.v2x_intersection.scenarios import build_episode
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town import get_town

from tests.scenarios.test_scenarios_v2x import record


def _is_child(height: np.ndarray) -> np.ndarray:
    return np.asarray(height) <= CHILD_HEIGHT[1] + 1e-9


def test_draw_size_makes_children_without_new_draws():
    """The same three draws as before (the generator's stream is unchanged); about CHILD_SHARE of
    pedestrians are children, no other class is."""
    a, b = np.random.default_rng(3), np.random.default_rng(3)
    sizes = np.array([draw_size(PEDESTRIAN, a) for _ in range(4000)])
    b.uniform(size=3 * 4000)
    assert a.uniform() == b.uniform()  # no draw added
    share = _is_child(sizes[:, 2]).mean()
    assert abs(share - CHILD_SHARE) < 0.03, share
    kids = sizes[_is_child(sizes[:, 2])]
    assert kids[:, 2].min() >= CHILD_HEIGHT[0] - 1e-9
    adults = sizes[~_is_child(sizes[:, 2])]
    assert adults[:, 2].min() >= SIZES[PEDESTRIAN][2][0]
    cars = np.array([draw_size(LARGE_VEHICLE, a) for _ in range(200)])
    assert cars[:, 2].min() >= SIZES[LARGE_VEHICLE][2][0]


def test_background_walkers_include_children_in_the_scenario_childs_range():
    """Background walkers (the numba spawn path and the Python one) hold children whose sizes
    cover the range a scenario child is drawn from."""
    heights = []
    for seed in range(6):
        world = World(make_config(town="Town03", num_vehicles=0, num_parked=0,
                                  num_pedestrians=60, num_bicycles=0))
        world.reset(seed=seed)
        t = world.table
        walk = t.active & (t.behaviour == WALKER) & (t.kind == PEDESTRIAN)
        heights += t.height[walk].tolist()
    heights = np.array(heights)
    share = _is_child(heights).mean()
    assert 0.07 < share < 0.25, share
    kids = heights[_is_child(heights)]
    lo, hi = child_size(*(np.array(r) for r in SIZES[PEDESTRIAN]))[2]
    assert kids.min() < lo + 0.1 and kids.max() > hi - 0.1  # the whole child range occurs
    assert actors.CHILD_HEIGHT[1] < SIZES[PEDESTRIAN][2][0]  # children and adults apart


def test_parking_crossing_hides_a_child_behind_cars_only():
    """The hazard is a child shorter than every parked car of the row; nothing large stands
    within 30 m of the conflict point."""
    town = get_town("Town12")
    world = World(make_config(town="Town12", num_vehicles=6, num_parked=6, num_pedestrians=4,
                              num_bicycles=0))
    for seed in range(3):
        route, scs = build_episode("ParkingCrossingPedestrian", town, np.random.default_rng(seed))
        world.reset(seed=seed, route=route, scenarios=scs)
        sc, t = world.scenarios[0], world.table
        child = sc.hazard_rows[0]
        assert _is_child(t.height[child])
        own = [int(r) for r in sc.rows if t.active[r] and int(r) != child]
        assert len(own) >= 2 and (t.height[own] > t.height[child] + 0.05).all()
        near = np.linalg.norm(t.pos - sc.conflict_point, axis=1) < 30.0
        assert not (near & t.active & (t.kind == LARGE_VEHICLE)).any()


def test_parking_crossing_child_is_hidden_from_the_ego_not_from_the_rsu():
    """Measured on the shared probe run: the ego cannot see the moving child for >= 0.5 s while
    the active roadside unit can (what only cooperation gives)."""
    rec = record("ParkingCrossingPedestrian")
    moving = rec.hazard_speed[:, 0] > 0.2
    before = rec.ego_s < rec.scenario.conflict_s
    hidden = moving & before & (rec.ego_vis[:, 0] < 0.1)
    covered = hidden & (rec.rsu_vis[:, 0] >= 0.1)
    dt = rec.world.config.dt
    assert covered.sum() * dt >= 0.5, (hidden.sum() * dt, covered.sum() * dt)


def _speed_near_conflict(agent_name: str) -> float:
    """Drive ParkingCrossingPedestrian (Town12, seed 2) with a registered agent; the ego's top
    speed over the 8 m before the conflict point."""
    from v2xbench.agents.interface import load_agent
    from v2xbench.envs.v2x_intersection.api.observations import ego_observation

    world = World(make_config(town="Town12", num_vehicles=4, num_parked=2, num_pedestrians=2,
                              num_bicycles=0))
    route, scs = build_episode("ParkingCrossingPedestrian", get_town("Town12"),
                               np.random.default_rng(2))
    world.reset(seed=2, route=route, scenarios=scs)
    agent = load_agent(agent_name)
    agent.reset({})
    agent.bind(world)
    sc, top = scs[0], 0.0
    for _ in range(600):
        world.step(agent.act(ego_observation(world)), world.default_rsu_message())
        gap = sc.conflict_s - sc.ego_s(world)
        if 0.0 < gap < 8.0:
            top = max(top, float(world.table.speed[0]))
        if sc.passed or world.ended:
            break
    return top


def test_wary_ego_slows_past_the_parked_cars_cautious_ego_does_not():
    """``wary_ego`` keys on every standing vehicle (3 m/s past the row), ``cautious_ego`` only on
    large ones: it passes the parked cars at speed."""
    wary = _speed_near_conflict("wary_ego")
    cautious = _speed_near_conflict("cautious_ego")
    assert wary <= 3.3, wary
    assert cautious > 4.5, cautious
