"""Ego action modes (envs/v2x_intersection/api/actions.py): spaces and specs per mode in every API,
the accel_steer mapping and dynamics, progress under uniform random actions, bad shapes, and a
2-D agent through ``v2xbench eval --set action_mode=accel_steer``."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs
from v2xbench.envs.v2x_intersection import V2XTorchEnv, make_config, parallel_env
from v2xbench.envs.v2x_intersection.api.actions import (
    BRAKE_PER_ACCEL,
    validate_action,
    validate_actions,
)
from v2xbench.envs.v2x_intersection.api.batch import WorldBatch
from v2xbench.envs.v2x_intersection.core.dynamics import VehicleParams

from v2xbench import cli

EMPTY = {"num_vehicles": 0, "num_parked": 0, "num_pedestrians": 0, "num_bicycles": 0}
DT = 0.1


def test_config_default_and_unknown_mode():
    assert make_config().action_mode == "carla"
    assert make_config(action_mode="accel_steer").action_mode == "accel_steer"
    with pytest.raises(ValueError, match=r"action_mode: 'accel' is not one of .*did you mean"):
        make_config(action_mode="accel")


@pytest.mark.parametrize("mode,low,high", [("carla", [0, -1, 0], [1, 1, 1]),
                                           ("accel_steer", [-1, -1], [1, 1])])
def test_spaces_and_specs_per_mode(mode, low, high):
    d = len(low)
    env = gym.make("V2XIntersection-v0", action_mode=mode, **EMPTY)
    assert env.action_space.shape == (d,) and env.action_space.dtype == np.float32
    assert env.action_space.low.tolist() == low and env.action_space.high.tolist() == high
    penv = parallel_env(action_mode=mode, **EMPTY)
    assert penv.action_space("ego") == env.action_space
    venv = gym.make_vec("V2XIntersection-v0", num_envs=2, vectorization_mode="vector_entry_point",
                        action_mode=mode, **EMPTY)
    assert venv.single_action_space == env.action_space and venv.action_space.shape == (2, d)
    tenv = V2XTorchEnv(num_worlds=3, action_mode=mode, **EMPTY)
    spec = tenv.action_spec
    assert spec.shape == (3, d) and spec.dtype == torch.float32
    assert spec.space.low[0].tolist() == low and spec.space.high[0].tolist() == high
    check_env_specs(tenv)  # random actions drawn from the spec go through the batch
    td = tenv.rollout(3)
    assert td["action"].shape == (3, 3, d) and torch.isfinite(td["next", "reward"]).all()


def test_mapping_accelerates_brakes_coasts():
    assert validate_action(np.array([1.0, 0.25]), "accel_steer").tolist() == [1.0, 0.25, 0.0]
    assert validate_action(np.array([0.0, -0.5]), "accel_steer").tolist() == [0.0, -0.5, 0.0]
    full_brake = [0.0, 0.0, BRAKE_PER_ACCEL]
    assert validate_action(np.array([-1.0, 0.0]), "accel_steer").tolist() == full_brake
    assert validate_action([-3.0, 0.0], "accel_steer").tolist() == full_brake  # clipped
    assert validate_action([0.5, 2.0], "accel_steer").tolist() == [0.5, 1.0, 0.0]
    p = VehicleParams()
    assert BRAKE_PER_ACCEL * p.max_brake == pytest.approx(p.max_accel)  # +-1 are +-3.5 m/s^2
    a = np.random.default_rng(0).uniform(-1.5, 1.5, (64, 2))  # batched mapping = single one
    rows = np.array([validate_action(r, "accel_steer") for r in a])
    assert np.array_equal(validate_actions(a, 64, "accel_steer"), rows)
    assert np.array_equal(validate_actions(a[:, :1].repeat(3, 1), 64, "carla"),
                          np.array([validate_action(r, "carla") for r in a[:, :1].repeat(3, 1)]))


def test_accel_steer_dynamics():
    """+1 accelerates at max_accel, 0 coasts (drag only), -1 brakes at max_accel."""
    p = VehicleParams()
    env = gym.make("V2XIntersection-v0", action_mode="accel_steer", **EMPTY)
    env.reset(seed=0)
    w = env.unwrapped.world
    v = float(w.table.speed[0])
    for accel, ticks in ((1.0, 15), (0.0, 5), (-1.0, 5)):
        before = v
        for _ in range(ticks):
            obs, *_ = env.step(np.array([accel, 0.0], np.float32))
            v = max(v + (accel * p.max_accel - p.drag * v) * DT, 0.0)
            assert float(w.table.speed[0]) == pytest.approx(v, abs=1e-9)
        if accel > 0:
            assert v - before > 0.9 * p.max_accel * ticks * DT
            assert obs["ego"][3] == 1.0 and obs["ego"][5] == 0.0  # throttle 1, brake 0
        elif accel == 0:
            assert 0 < before - v <= p.drag * before * ticks * DT  # drag only: ~1 % in 0.5 s
        else:
            assert before - v > 0.95 * p.max_accel * ticks * DT
            assert obs["ego"][3] == 0.0 and obs["ego"][5] == pytest.approx(BRAKE_PER_ACCEL)


def _random_progress(mode: str, seeds=(0, 1, 2), ticks: int = 200) -> float:
    """Mean route progress (m, summed progress reward x 10) of uniform random actions."""
    env = gym.make("V2XIntersection-v0", action_mode=mode, **EMPTY)
    env.action_space.seed(0)
    total = []
    for seed in seeds:
        env.reset(seed=seed)
        metres = 0.0
        for _ in range(ticks):
            _, _, term, trunc, info = env.step(env.action_space.sample())
            metres += 10.0 * info["reward_progress"]
            if term or trunc:
                break
        total.append(metres)
    return float(np.mean(total))


def test_uniform_random_accel_steer_makes_far_more_progress():
    """Measured: carla ~0.8 m, accel_steer ~25 m in 200 ticks (20 s); asserted with margin."""
    carla, accel = _random_progress("carla"), _random_progress("accel_steer")
    assert carla < 3.0
    assert accel > 8.0 and accel > 5.0 * carla, (carla, accel)


def test_bad_shapes_raise_naming_mode_and_shape():
    with pytest.raises(ValueError, match=r"\(2,\) = \(accel, steer\) for action_mode='accel_st"):
        validate_action(np.zeros(3), "accel_steer")
    with pytest.raises(ValueError, match=r"\(3,\) = \(throttle, steer, brake\) for action_mode="):
        validate_action(np.zeros(2), "carla")
    with pytest.raises(ValueError, match="NaN or inf"):
        validate_action(np.array([np.nan, 0.0]), "accel_steer")
    with pytest.raises(ValueError, match="dtype"):
        validate_action(np.array(["a", "b"]), "accel_steer")
    env = gym.make("V2XIntersection-v0", action_mode="accel_steer", **EMPTY)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action_mode='accel_steer'"):
        env.step(np.zeros(3, np.float32))
    penv = parallel_env(action_mode="accel_steer", **EMPTY)
    penv.reset(seed=0)
    with pytest.raises(ValueError, match=r"ego action: expected shape \(2,\)"):
        penv.step({"ego": np.zeros(3, np.float32)})
    batch = WorldBatch(2, action_mode="accel_steer", **EMPTY)
    batch.reset([0, 1])
    with pytest.raises(ValueError, match=r"\(2, 2\) = \(accel, steer\) per world for action_mode="):
        batch.step(np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(2, 3\) = \(throttle, steer, brake\) per world"):
        WorldBatch(2, **EMPTY).step(np.zeros((2, 2)))


AGENT = '''
import numpy as np


class FullAccel:
    """Outputs a 2-D accel_steer action: full acceleration, straight."""
    obs_mode, privileged, rsu_policy = "objects", False, "none"

    def reset(self, route_info):
        pass

    def act(self, obs):
        return np.array([1.0, 0.0], np.float32)
'''


def test_eval_with_accel_steer_agent(tmp_path):
    from v2xbench.collectors.eval_env import EvalEnv

    (tmp_path / "agent.py").write_text(AGENT)
    spec = f"{tmp_path / 'agent.py'}:FullAccel"
    common = ["--suite", "test50", "--max-routes", "1", "--quiet", "--set", "max_steps=20",
              "--set", "num_vehicles=2", "--set", "num_pedestrians=0"]
    out = tmp_path / "accel"
    assert cli.main(["eval", "--agent", spec, "--out", str(out), *common,
                     "--set", "action_mode=accel_steer"]) == 0
    (res,) = [json.loads(p.read_text()) for p in (out / "routes").glob("*.json")]
    assert res["error"] is None and res["ticks"] == 20
    assert max(res["record"]["ego_speed"]) > 5.0  # 2 s at ~3.5 m/s^2
    bad = tmp_path / "carla"  # the 2-D agent under the default mode fails its route, saying why
    assert cli.main(["eval", "--agent", spec, "--out", str(bad), *common]) != 0
    (res,) = [json.loads(p.read_text()) for p in (bad / "routes").glob("*.json")]
    assert "action_mode='carla'" in res["error"]
    env = EvalEnv("test50", tmp_path / "policy", agent=None, max_routes=1,
                  config={"action_mode": "accel_steer", **EMPTY})
    assert env.action_spec.shape == (2,)  # a TorchRL policy acts in the config's mode
