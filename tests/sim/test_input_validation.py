"""Input validation (#31 items 6, 7, 10): config sizes and types with their bounds in the message,
impossible combinations, shortfall warnings, reset options, TorchRL's step after done, and the
rule tables of the route schema."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection import V2XIntersectionEnv, parallel_env
from v2xbench.envs.v2x_intersection.core.validation import ShortfallWarning, reset_warned
from v2xbench.envs.v2x_intersection.scenarios import SCENARIOS
from v2xbench.envs.v2x_intersection.sim.config import (
    CONFIG_FIELDS,
    FIELD_RULES,
    EnvConfig,
    make_config,
)
from v2xbench.envs.v2x_intersection.sim.world import StepError, World
from v2xbench.envs.v2x_intersection.suites.route_schema import (
    EXTRA_SHAPES,
    PARAM_OVERRIDES,
    PARAM_RULES,
    param_rule,
)

SMALL = dict(num_vehicles=2, num_parked=1, num_pedestrians=1, num_bicycles=0, route_length=120.0)


# ------------------------------------------------------------------------------ config sizes
@pytest.mark.parametrize(
    "key,value,bound",
    [
        ("max_objects", 10**9, "[1, 256]"),
        ("render_size", 10**5, "[16, 4096]"),
        ("route_points", 10**8, "[1, 200]"),
        ("rsu_slots", 10**6, "[1, 16]"),
        ("route_step", 10**6, "[1, 50]"),
        ("latency_ticks", 10**6, "[1, 100]"),
        ("max_payload_floats", 10**9, "[10, 65535]"),
        ("max_steps", 10**9, "[1, 100000]"),
        ("route_length", 1e9, "[10, 5000]"),
        ("ego_range", 1e6, "[1, 500]"),
        ("rsu_range", 0.0, "[1, 500]"),
        ("bandwidth_bytes_per_s", 1e30, "(0, 1e+12]"),
        ("num_vehicles", 501, "[0, 500]"),  # item 10: an unbounded num_vehicles fails here
        ("num_vehicles", 10**9, "[0, 500]"),
        ("num_vehicles", -3, "[0, 500]"),
        ("num_pedestrians", -1, "[0, 500]"),
        ("route_index", 10**9, "[0, 100000]"),
    ],
)
def test_oversized_or_negative_values_are_refused_with_their_bound(key, value, bound):
    with pytest.raises(
        ValueError,
        match=rf"config: {key}: {value!r} is outside {bound}".replace("[", r"\[")
        .replace("(", r"\(")
        .replace("+", r"\+"),
    ):
        make_config(**{key: value})


@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_route_length_must_be_finite(value):
    with pytest.raises(ValueError, match="config: route_length: .* is not a finite number"):
        make_config(route_length=value)


@pytest.mark.parametrize(
    "key,value,match",
    [
        ("terminate_on_collision", "no", "expected true or false, got str 'no'"),
        ("terminate_on_collision", 0, "expected true or false, got int 0"),
        ("num_vehicles", 3.0, "expected an int, got float"),
        ("num_vehicles", "3", "expected an int, got str"),
        ("num_vehicles", True, "expected an int, got bool"),
        ("loss_prob", True, "expected a number, got bool"),
        ("loss_prob", "0.1", "expected a number, got str"),
        ("seed", -1, r"-1 is outside \[0, "),
        ("encoding", "int8", "is not one of"),
        ("obs_mode", "radar", "is not one of"),
        ("town", 5, "is not a known town"),
        ("scenario", 7, "expected a scenario name"),
        ("suite", 3, "expected a string"),
        ("dt", 0.05, "fixed at 0.1 s"),
    ],
)
def test_field_types_are_checked(key, value, match):
    with pytest.raises(ValueError, match=f"config: {key}: .*{match}"):
        make_config(**{key: value})


def test_payload_too_small_for_one_object_is_an_error():
    with pytest.raises(
        ValueError, match=r"max_payload_floats: 5 is outside \[10, .*one object of 10 floats"
    ):
        make_config(max_payload_floats=5)
    assert make_config(max_payload_floats=10).max_payload_floats == 10


def test_impossible_combinations_are_refused():
    with pytest.raises(ValueError, match="route_index=3 needs a suite"):
        make_config(route_index=3)
    with pytest.raises(
        ValueError, match=r"route_index: 50 is outside \[0, 49\] \(suite 'test50' has 50"
    ):
        make_config(suite="test50", route_index=50)
    with pytest.raises(ValueError, match="exclude each other"):
        make_config(suite="test50", scenario="DynamicObjectCrossing")
    with pytest.raises(ValueError, match="config: suite: unknown suite 'nope'"):
        make_config(suite="nope")
    assert make_config(suite="test50", route_index=49).route_index == 49


def test_every_config_field_has_a_rule_and_the_defaults_pass():
    assert set(FIELD_RULES) == set(CONFIG_FIELDS)
    EnvConfig()  # the defaults satisfy every rule
    # a value within bounds passes, with or without make_config
    assert EnvConfig(num_vehicles=500, render_size=4096, max_objects=256).render_size == 4096


def test_world_batch_and_torchrl_bound_num_worlds():
    from v2xbench.envs.v2x_intersection import V2XTorchEnv
    from v2xbench.envs.v2x_intersection.api.batch import WorldBatch

    with pytest.raises(ValueError, match=r"num_worlds: 100000 is outside \[1, 1024\]"):
        WorldBatch(10**5)
    with pytest.raises(ValueError, match=r"num_worlds: 100000 is outside \[1, 1024\]"):
        V2XTorchEnv(num_worlds=10**5)
    with pytest.raises(ValueError, match="num_worlds: expected an int"):
        WorldBatch(2.0)


def test_camera_sizes_are_bounded():
    from v2xbench.envs.v2x_intersection.sensors.rig import SensorConfig

    for size in ((10**5, 10**5), (64, 2.5), (64,), (True, 64)):
        with pytest.raises(ValueError, match=r"camera_size=.* ints in \[2, 4096\]"):
            SensorConfig(camera_size=size)
    with pytest.raises(ValueError, match="rsu_camera_size"):
        SensorConfig(rsu_camera_size=(8192, 64))
    assert SensorConfig(camera_size=(4096, 2)).camera_size == (4096, 2)


# ------------------------------------------------------------------------- shortfall warnings
def test_fewer_vehicles_than_asked_warns_once_with_numbers():
    reset_warned()
    world = World(make_config(num_vehicles=500, num_parked=0, num_pedestrians=0, num_bicycles=0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        world.reset(seed=0)
        placed = int(world.table.active.sum()) - 1  # minus the ego (no scenarios here)
        world.reset(seed=1)
    short = [w for w in caught if issubclass(w.category, ShortfallWarning)]
    assert len(short) == 1, [str(w.message) for w in short]
    msg = str(short[0].message)
    assert 0 < placed < 500
    assert f"num_vehicles=500 but only {placed} fit in Town01" in msg


def test_no_shortfall_warning_when_everything_fits():
    reset_warned()
    world = World(make_config(**SMALL))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ShortfallWarning)
        world.reset(seed=0)


def test_shorter_route_than_asked_warns_once_with_numbers():
    reset_warned()
    env = V2XIntersectionEnv(
        town="Town02",
        route_length=3000.0,
        num_vehicles=0,
        num_parked=0,
        num_pedestrians=0,
        num_bicycles=0,
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env.reset(seed=0)
        env.reset(seed=1)
    short = [str(w.message) for w in caught if issubclass(w.category, ShortfallWarning)]
    assert (
        len(short) == 1
        and "route_length=3000 m asked, but the longest random route found in Town02" in short[0]
    )
    assert env.world.route.length < 3000.0


# ---------------------------------------------------------------------------- reset options
def test_unknown_reset_options_raise_in_gymnasium_and_pettingzoo():
    env = V2XIntersectionEnv(**SMALL)
    with pytest.raises(ValueError, match="reset: unknown option 'sped'; did you mean 'spec'"):
        env.reset(seed=0, options={"sped": None})
    with pytest.raises(ValueError, match="options must be a dict"):
        env.reset(seed=0, options=["spec"])
    env.reset(seed=0, options={})  # empty options are fine
    penv = parallel_env(**SMALL)
    with pytest.raises(ValueError, match="reset: unknown option 'reset_mask'"):
        penv.reset(seed=0, options={"reset_mask": [True]})


def test_unknown_reset_options_raise_in_the_vector_env():
    from v2xbench.envs.v2x_intersection.api.batch import V2XVectorEnv

    venv = V2XVectorEnv(num_envs=2, **SMALL)
    with pytest.raises(ValueError, match="V2XVectorEnv.reset: unknown option 'mask'"):
        venv.reset(seed=0, options={"mask": [True, False]})
    with pytest.raises(ValueError, match=r"reset_mask'\] must be a bool array of shape \(2,\)"):
        venv.reset(seed=0, options={"reset_mask": [1, 0, 1]})
    venv.reset(seed=0, options={"reset_mask": np.array([True, True])})


def test_torchrl_reset_refuses_unknown_arguments_and_options():
    from v2xbench.envs.v2x_intersection import V2XTorchEnv

    env = V2XTorchEnv(num_worlds=1, **SMALL)
    with pytest.raises(ValueError, match="V2XTorchEnv.reset: unknown option 'spec'"):
        env.reset(options={"spec": None})
    with pytest.raises(ValueError, match="V2XTorchEnv.reset: unknown argument.*'seed'.*set_seed"):
        env.reset(seed=3)
    env.reset(options={})


def test_torchrl_step_after_done_raises_like_gymnasium():
    import torch
    from v2xbench.envs.v2x_intersection import V2XTorchEnv

    env = V2XTorchEnv(num_worlds=2, max_steps=2, **SMALL)
    td = env.reset()
    td["action"] = torch.zeros(2, 3)
    for _ in range(2):
        out = env.step(td)["next"]
    assert out["done"].all()
    with pytest.raises(StepError, match="world 0: step\\(\\) called after the episode ended"):
        env.step(td)
    # a partial reset of world 0 only: world 1 still has to be reset
    td["_reset"] = torch.tensor([[True], [False]])
    env.reset(td.select("_reset"))
    with pytest.raises(StepError, match="world 1: step\\(\\) called after the episode ended"):
        env.step(td.exclude("_reset"))
    env.reset()
    env.step(td.exclude("_reset"))  # both reset: steps again


def test_torchrl_rollout_with_auto_reset_still_runs():
    from v2xbench.envs.v2x_intersection import V2XTorchEnv

    env = V2XTorchEnv(num_worlds=2, max_steps=2, **SMALL)
    td = env.rollout(5, break_when_any_done=False)  # step_and_maybe_reset resets the ended worlds
    assert td.batch_size[-1] == 5


# ---------------------------------------------------------------------- route schema tables
def test_every_scenario_parameter_has_a_rule_and_its_default_passes():
    for name, cls in SCENARIOS.items():
        for key, default in cls.defaults.items():
            rule = param_rule(name, key)
            assert rule is not None, f"{name}.{key} has no rule in route_schema.PARAM_RULES"
            rule.check(default, f"{name}.params.{key}")
    used = {k for cls in SCENARIOS.values() for k in cls.defaults}
    assert set(PARAM_RULES) <= used, f"rules for unknown parameters: {set(PARAM_RULES) - used}"
    for scenario, key in PARAM_OVERRIDES:
        assert key in SCENARIOS[scenario].defaults
    assert set(EXTRA_SHAPES) <= set(SCENARIOS)
