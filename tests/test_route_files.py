"""Route files: schema validation with errors naming the bad field; replay of a route file."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection import V2XIntersectionEnv
from v2xbench.envs.v2x_intersection.route_files import (
    build_episode_from_spec,
    load_route_file,
    parse_route,
    save_json_atomic,
)
from v2xbench.envs.v2x_intersection.suites_build import compose_route
from v2xbench.envs.v2x_intersection.town import get_town


@pytest.fixture(scope="module")
def route_dict():
    town = get_town("Town01")
    for seed in range(20):
        d = compose_route(town, np.random.default_rng(seed), ["DynamicObjectCrossing", "DynamicObjectCrossing"],
                          "r0", seed=5)
        if d is not None:
            return d
    pytest.fail("could not compose a two-scenario route on Town01")


def test_round_trip_and_replay(route_dict, tmp_path):
    path = save_json_atomic(route_dict, tmp_path / "r.json")
    spec = load_route_file(path)
    assert spec.to_dict() == parse_route(json.loads(path.read_text())).to_dict()
    route, scenarios = build_episode_from_spec(spec)
    assert len(scenarios) == 2
    # conflicts lie on the route, in order, where the file says
    cs = [s.conflict_s for s in scenarios]
    assert 0 < cs[0] < cs[1] < route.length
    for sc, inst in zip(scenarios, route_dict["scenarios"]):
        np.testing.assert_allclose(sc.conflict_point, inst["conflict"], atol=1.01)
    env = V2XIntersectionEnv(num_vehicles=4, num_pedestrians=2, num_parked=2, num_bicycles=0)
    env.reset(options={"spec": spec}, seed=spec.seed)
    assert env.world.town.name == "Town01" and len(env.world.scenarios) == 2
    # an RSU is deployed near each scenario's hazard
    for sc in env.world.scenarios:
        assert np.min(np.linalg.norm(env.world.rsus.pose[:, :2] - sc.conflict_point, axis=1)) < 30.0


@pytest.mark.parametrize(
    "mutate,match",
    [
        (lambda d: d.pop("town"), "missing field 'town'"),
        (lambda d: d.update(town="Atlantis"), "field 'town'"),
        (lambda d: d.update(format="v0"), "field 'format'"),
        (lambda d: d.update(lanes=[0, 999999]), "field 'lanes'"),
        (lambda d: d.update(lanes=list(reversed(d["lanes"]))), "does not follow"),
        (lambda d: d.update(waypoints=[[0, 0]]), "field 'waypoints'"),
        (lambda d: d["scenarios"][0].update(type="Ghost"), "field 'type'"),
        (lambda d: d["scenarios"][0].update(params={"colour": 1}), "field 'params'"),
        (lambda d: d["scenarios"][0]["site"].update(key=9), "site.key"),
        (lambda d: d.update(weather="hail"), "field 'weather'"),
        (lambda d: d.update(seed="7"), "field 'seed'"),
    ],
)
def test_malformed_route_names_the_field(route_dict, mutate, match):
    d = copy.deepcopy(route_dict)
    mutate(d)
    with pytest.raises(ValueError, match=match):
        parse_route(d)


def test_not_json_is_a_clear_error(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_route_file(p)


def test_scenario_config_and_make_seed():
    import gymnasium as gym

    import v2xbench  # noqa: F401

    env = gym.make("v2xbench:V2XIntersection-v0", scenario="DynamicObjectCrossing", seed=3, num_vehicles=4)
    env.reset()
    a = env.unwrapped.world.scenarios[0].conflict_s
    env.reset(seed=3)
    assert env.unwrapped.world.scenarios[0].conflict_s == a
    with pytest.raises(ValueError, match="unknown scenario 'Ghost'"):
        gym.make("v2xbench:V2XIntersection-v0", scenario="Ghost")
