"""Route files: schema validation with errors naming the bad field; replay of a route file."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection import V2XIntersectionEnv
from v2xbench.envs.v2x_intersection.suites.route_files import (
    SUITE_DIR,
    build_episode_from_spec,
    load_route_file,
    parse_route,
    save_json_atomic,
)
from v2xbench.envs.v2x_intersection.suites.suites_build import compose_route
from v2xbench.envs.v2x_intersection.town import get_town


@pytest.fixture(scope="module")
def route_dict():
    town = get_town("Town01")
    for seed in range(20):
        d = compose_route(
            town,
            np.random.default_rng(seed),
            ["DynamicObjectCrossing", "DynamicObjectCrossing"],
            "r0",
            seed=5,
        )
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


def _scen(d, k=0):
    return d["scenarios"][k]


def _far(d):
    d["waypoints"][1] = [5000.0, 5000.0]


@pytest.mark.parametrize(
    "mutate,match",
    [
        (lambda d: d.pop("town"), "^route: town: missing required field$"),
        (lambda d: d.update(town="Atlantis"), "^route: town: 'Atlantis' is not one of"),
        (lambda d: d.update(format="v0"), "^route: format: 'v0' is not 'v2xbench-route/1'"),
        (lambda d: d.update(id="../x"), "^route: id: '../x' must be letters, digits"),
        (
            lambda d: d.update(lanes=[0, 999999]),
            r"^route: lanes\[1\]: lane 999999 is outside \[0, ",
        ),
        (
            lambda d: d["lanes"].__setitem__(1, "7"),
            r"^route: lanes\[1\]: expected a lane id \(int\), got str",
        ),
        (
            lambda d: d.update(lanes=list(reversed(d["lanes"]))),
            r"^route: lanes\[1\]: lane .* does not follow",
        ),
        (lambda d: d.update(waypoints=[[0, 0]]), "^route: waypoints: expected a list of 2 to 2000"),
        (
            lambda d: d["waypoints"].__setitem__(0, [float("nan"), 0.0]),
            r"^route: waypoints\[0\]: .* is not finite",
        ),
        (
            _far,
            r"^route: waypoints\[1\]: waypoint \[5000.0, 5000.0\] is .* m from the route "
            r"\(at most 5 m\)",
        ),
        (
            lambda d: d.update(wether="rain"),
            "^route: wether: unknown field; did you mean 'weather'",
        ),
        (lambda d: d.update(weather="hail"), "^route: weather: 'hail' is not one of"),
        (lambda d: d.update(time_of_day=3), "^route: time_of_day: 3 is not one of"),
        (lambda d: d.update(seed="7"), "^route: seed: expected an int, got str '7'"),
        (lambda d: d.update(seed=-5), r"^route: seed: -5 is outside \[0, 4294967295\]"),
        (
            lambda d: d.update(seed=2**40),
            r"^route: seed: 1099511627776 is outside \[0, 4294967295\]",
        ),
        (
            lambda d: d.update(scenarios={}),
            "^route: scenarios: expected a list of at most 16 scenarios, got dict",
        ),
        (
            lambda d: d.update(scenarios=[_scen(d)] * 20),
            "^route: scenarios: expected a list of at most 16 .* got 20",
        ),
        (
            lambda d: d.update(scenarios=[_scen(d)] * 2),
            r"^route: scenarios\[1\]: repeats scenarios\[0\]",
        ),
        (
            lambda d: d["scenarios"].reverse(),
            r"^route: scenarios\[1\]: its conflict point .* driving order",
        ),
        (
            lambda d: d["scenarios"].__setitem__(0, 5),
            r"^route: scenarios\[0\]: expected an object, got int",
        ),
        (lambda d: _scen(d).update(colour=1), r"^route: scenarios\[0\].colour: unknown field"),
        (
            lambda d: _scen(d).update(type="Ghost"),
            r"^route: scenarios\[0\].type: unknown scenario 'Ghost'",
        ),
        (
            lambda d: _scen(d).update(params={"colour": 1}),
            r"^route: scenarios\[0\].params.colour: unknown field",
        ),
        (
            lambda d: _scen(d).update(params=[1]),
            r"^route: scenarios\[0\].params: expected an object, got list",
        ),
        (
            lambda d: _scen(d).update(params={"speed": "fast"}),
            r"^route: scenarios\[0\].params.speed: expected a number, got str 'fast'",
        ),
        (
            lambda d: _scen(d).update(params={"speed": 1e9}),
            r"^route: scenarios\[0\].params.speed: 1000000000.0 is outside \[0, 30\] m/s$",
        ),
        (
            lambda d: _scen(d, 1).update(params={"speed": float("nan")}),
            r"^route: scenarios\[1\].params.speed: nan is not a finite number",
        ),
        (
            lambda d: _scen(d).update(params={"side": 0.5}),
            r"^route: scenarios\[0\].params.side: 0.5 is not one of",
        ),
        (lambda d: _scen(d).pop("site"), r"^route: scenarios\[0\].site: missing required field"),
        (
            lambda d: _scen(d)["site"].update(key=9),
            r"^route: scenarios\[0\].site.key: 9 is outside \[0, ",
        ),
        (
            lambda d: _scen(d)["site"].update(key=True),
            r"^route: scenarios\[0\].site.key: expected an int, got bool",
        ),
        (
            lambda d: _scen(d)["site"].update(lanes=[d["lanes"][-1], d["lanes"][0]]),
            r"^route: scenarios\[0\].site.lanes: .* is not a stretch of the route's lanes",
        ),
        (
            lambda d: _scen(d)["site"].update(s_on_key=float("nan")),
            r"^route: scenarios\[0\].site.s_on_key: nan is not a finite number",
        ),
        (
            lambda d: _scen(d)["site"].update(s_on_key=float("inf")),
            r"^route: scenarios\[0\].site.s_on_key: inf is not a finite number",
        ),
        (
            lambda d: _scen(d)["site"].update(s_on_key=1e6),
            r"^route: scenarios\[0\].site.s_on_key: 1000000.0 is outside \[0, .*\] m "
            r"\(the length of key lane",
        ),
        (
            lambda d: _scen(d)["site"].update(s_on_key=-1.0),
            r"^route: scenarios\[0\].site.s_on_key: -1.0 is outside",
        ),
        (
            lambda d: _scen(d)["site"].update(s_on_key="8"),
            r"^route: scenarios\[0\].site.s_on_key: expected a number",
        ),
        (
            lambda d: _scen(d)["site"].update(extra=[["a"], {"x": 1}]),
            r"^route: scenarios\[0\].site.extra: DynamicObjectCrossing takes no extra data",
        ),
        (
            lambda d: _scen(d)["site"].update(extra="junk"),
            r"^route: scenarios\[0\].site.extra: expected a list",
        ),
        (
            lambda d: _scen(d).update(trigger=5),
            r"^route: scenarios\[0\].trigger: expected an \[x, y\] pair",
        ),
        (
            lambda d: _scen(d).update(trigger=[1e5, 0.0]),
            r"^route: scenarios\[0\].trigger: trigger .* from the route",
        ),
        (
            lambda d: _scen(d).update(conflict=[float("inf"), 0.0]),
            r"^route: scenarios\[0\].conflict: .* not finite",
        ),
    ],
)
def test_malformed_route_names_the_field(route_dict, mutate, match):
    d = copy.deepcopy(route_dict)
    mutate(d)
    with pytest.raises(ValueError, match=match):
        parse_route(d)


@pytest.fixture(scope="module")
def test50_raw():
    return json.loads((SUITE_DIR / "test50.json").read_text())


def _with_type(raw: dict, typ: str) -> tuple[dict, int]:
    """A copy of the first test50 route with a ``typ`` scenario, and that scenario's index."""
    for r in raw["routes"]:
        for k, s in enumerate(r["scenarios"]):
            if s["type"] == typ:
                return copy.deepcopy(r), k
    raise AssertionError(f"no {typ} in test50")


@pytest.mark.parametrize(
    "typ,mutate,match",
    [
        (
            "OppositeVehicleTakingPriority",
            lambda s: s.update(params={"direction": "up"}),
            r"params.direction: 'up' is not one of \('right', 'left', 'any'\)",
        ),
        (
            "OppositeVehicleTakingPriority",
            lambda s: s.update(params={"direction": "Left"}),
            "params.direction: 'Left' is not one of .*; did you mean 'left'",
        ),
        (
            "PedestrianCrossing",
            lambda s: s.update(params={"count": 10**9}),
            r"params.count: 1000000000 is outside \[1, 3\]",
        ),
        (
            "PedestrianCrossing",
            lambda s: s.update(params={"count": 2.5}),
            "params.count: expected an int, got float",
        ),
        (
            "CrossingBicycleFlow",
            lambda s: s.update(params={"count": 6}),
            r"params.count: 6 is outside \[1, 5\]",
        ),
        (
            "EnterActorFlow",
            lambda s: s.update(params={"spacing_min": 80.0}),
            "params.spacing_min: spacing_min=80.0 is above spacing_max=70.0",
        ),
        (
            "ControlLoss",
            lambda s: s.update(params={"steer_std": -0.1}),
            r"params.steer_std: -0.1 is outside \[0, 1\]",
        ),
        (
            "NonSignalizedJunctionLeftTurn",
            lambda s: s["site"].update(extra=[["a"], 3]),
            r"site.extra\[0\]\[0\]: expected a lane id \(int\), got str 'a'",
        ),
        (
            "NonSignalizedJunctionLeftTurn",
            lambda s: s["site"].update(extra=[[0, 1, 2, 3], 1.0]),
            r"site.extra\[0\]\[\d\]: lane \d+ does not follow lane \d+",
        ),
        (
            "NonSignalizedJunctionLeftTurn",
            lambda s: s["site"]["extra"].__setitem__(1, 1e9),
            r"site.extra\[1\]: 1000000000.0 is outside \[0, .*\] m \(the length of the lane path\)",
        ),
        (
            "NonSignalizedJunctionLeftTurn",
            lambda s: s["site"].update(extra=[s["site"]["extra"]]),
            r"site.extra: expected a \[lane path, s\] pair",
        ),
        (
            "NonSignalizedJunctionLeftTurn",
            lambda s: s["site"].pop("extra"),
            r"site.extra: NonSignalizedJunctionLeftTurn needs its \[lane path, s\] pair, got \[\]",
        ),
        (
            "EnterActorFlow",
            lambda s: s["site"].update(extra=s["site"]["extra"] * 5),
            "site.extra: EnterActorFlow takes 1 to 4 \\[lane path, s\\] pairs, got 5",
        ),
        (
            "EnterActorFlow",
            lambda s: s["site"].update(extra=[[[1], "x"]]),
            r"site.extra\[0\]\[1\]: expected a number, got str 'x'",
        ),
        (
            "HighwayCutIn",
            lambda s: s["site"].update(extra=s["site"]["extra"] * 2),
            r"site.extra: HighwayCutIn takes 1 \[lane path, s\] pair, got 2",
        ),
    ],
)
def test_malformed_scenario_fields_name_the_field(test50_raw, typ, mutate, match):
    d, k = _with_type(test50_raw, typ)
    parse_route(copy.deepcopy(d))  # valid before the change
    mutate(d["scenarios"][k])
    with pytest.raises(ValueError, match=rf"^route: scenarios\[{k}\]\.{match}"):
        parse_route(d)


def test_route_file_errors_name_the_file(route_dict, tmp_path):
    d = copy.deepcopy(route_dict)
    d["scenarios"][1]["params"] = {"speed": 1e9}
    path = save_json_atomic(d, tmp_path / "bad.json")
    with pytest.raises(
        ValueError, match=rf"^route file {path}: scenarios\[1\].params.speed: .* outside \[0, 30\]"
    ):
        load_route_file(path)
    with pytest.raises(FileNotFoundError, match="route file .*missing.json: no such file"):
        load_route_file(tmp_path / "missing.json")


def test_not_json_is_a_clear_error(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_route_file(p)


def test_scenario_config_and_make_seed():
    import gymnasium as gym

    import v2xbench  # noqa: F401

    env = gym.make(
        "v2xbench:V2XIntersection-v0", scenario="DynamicObjectCrossing", seed=3, num_vehicles=4
    )
    env.reset()
    a = env.unwrapped.world.scenarios[0].conflict_s
    env.reset(seed=3)
    assert env.unwrapped.world.scenarios[0].conflict_s == a
    with pytest.raises(ValueError, match="unknown scenario 'Ghost'"):
        gym.make("v2xbench:V2XIntersection-v0", scenario="Ghost")


def test_instances_get_their_own_parameters_in_range(route_dict):
    """Each scenario instance carries parameters drawn from PARAM_RANGES, different per instance,
    and the scenario built from the file uses them."""
    from v2xbench.envs.v2x_intersection.scenarios.param_ranges import PARAM_RANGES

    lo, hi = PARAM_RANGES["DynamicObjectCrossing"]["speed"]
    speeds = [inst["params"]["speed"] for inst in route_dict["scenarios"]]
    assert all(lo <= v <= hi for v in speeds) and speeds[0] != speeds[1]
    _, scenarios = build_episode_from_spec(parse_route(route_dict))
    assert [sc.params["speed"] for sc in scenarios] == speeds


def test_param_ranges_name_real_parameters():
    """Every ranged parameter exists in its type's defaults, ints stay ints, a bad range is refused."""
    from v2xbench.envs.v2x_intersection.scenarios import SCENARIOS
    from v2xbench.envs.v2x_intersection.scenarios.param_ranges import PARAM_RANGES, draw_params
    from v2xbench.envs.v2x_intersection.suites.route_schema import check_params

    rng = np.random.default_rng(0)
    for name in PARAM_RANGES:
        for _ in range(10):  # every draw passes the route schema's bounds
            check_params(name, draw_params(name, SCENARIOS[name].defaults, rng),
                         SCENARIOS[name].defaults, f"{name}.params")
        params = draw_params(name, SCENARIOS[name].defaults, rng)
        for key, value in params.items():
            assert isinstance(value, int) == isinstance(SCENARIOS[name].defaults[key], int), key
    with pytest.raises(ValueError, match="not a parameter"):
        draw_params("DynamicObjectCrossing", {"other": 1.0}, rng)


def test_a_route_starting_scenario_must_come_first():
    """ParkingExit cuts the route to start in its parking slot: the builder never places it
    after another scenario, and a route file that does is refused naming the scenario."""
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite

    for name in ("train", "val", "test50"):
        for spec in load_suite(name)[1]:
            assert all(s.type != "ParkingExit" for s in spec.scenarios[1:]), spec.id
    town = get_town("Town01")
    assert compose_route(town, np.random.default_rng(0), ["Accident", "ParkingExit"], "r", 1) is None
    d = next(d for seed in range(40) if (d := compose_route(
        town, np.random.default_rng(seed), ["ParkingExit", "Accident"], "r", 1)) is not None)
    d["scenarios"] = d["scenarios"][::-1]
    with pytest.raises(ValueError, match=r"scenarios\[1\]: ParkingExit starts the route"):
        parse_route(d)
