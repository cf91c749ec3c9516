"""Batched worlds (``WorldBatch``, ``gym.make_vec``, native TorchRL) match single worlds exactly."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict import TensorDict
from v2xbench.envs.v2x_intersection import V2XTorchEnv
from v2xbench.envs.v2x_intersection.api.batch import V2XVectorEnv, WorldBatch, validate_controls

import v2xbench  # noqa: F401

SMALL = dict(num_vehicles=8, num_parked=4, num_pedestrians=4, num_bicycles=1, route_length=150.0)
N = 3


def _actions(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform([0.0, -0.2, 0.0], [1.0, 0.2, 0.3], size=(n, 3)).astype(np.float32)


def test_make_vec_matches_single_envs_with_same_seeds_and_actions():
    venv = gym.make_vec("V2XIntersection-v0", num_envs=N, **SMALL)
    assert isinstance(venv, V2XVectorEnv)
    singles = [gym.make("V2XIntersection-v0", **SMALL) for _ in range(N)]
    obs, _ = venv.reset(seed=11)
    assert venv.observation_space.contains(obs)
    single_obs = [e.reset(seed=11 + i)[0] for i, e in enumerate(singles)]
    rng = np.random.default_rng(0)
    for t in range(40):
        for i in range(N):
            for k, v in single_obs[i].items():
                np.testing.assert_array_equal(obs[k][i], v, err_msg=f"tick {t} world {i} key {k}")
        a = _actions(rng, N)
        obs, reward, term, trunc, info = venv.step(a)
        for i, e in enumerate(singles):
            single_obs[i], r, te, tr, inf = e.step(a[i])
            assert (reward[i], term[i], trunc[i]) == (r, te, tr)
            assert info["tick"][i] == inf["tick"] and info["route_completion"][i] == inf["route_completion"]


def test_make_vec_autoresets_on_the_next_step():
    venv = gym.make_vec("V2XIntersection-v0", num_envs=2, max_steps=5, **SMALL)
    venv.reset(seed=3)
    a = np.tile(np.array([0.5, 0.0, 0.0], np.float32), (2, 1))
    for _ in range(4):
        _, _, term, trunc, _ = venv.step(a)
        assert not (term | trunc).any()
    _, _, term, trunc, _ = venv.step(a)
    assert (term | trunc).all()
    _, reward, term, trunc, info = venv.step(a)  # the reset step
    assert not (term | trunc).any() and (reward == 0).all() and (info["tick"] == 0).all()


def test_torchrl_batched_env_matches_single_worlds():
    env = V2XTorchEnv(num_worlds=N, seed=5, **SMALL)
    td = env.reset()
    seeds = np.random.default_rng(5).integers(2**31, size=N)  # drawn in world order
    singles = [gym.make("V2XIntersection-v0", **SMALL) for _ in range(N)]
    single_obs = [e.reset(seed=int(s))[0] for e, s in zip(singles, seeds)]
    rng = np.random.default_rng(1)
    for t in range(25):
        for i in range(N):
            for k, v in single_obs[i].items():
                np.testing.assert_array_equal(td[k][i].numpy(), v, err_msg=f"tick {t} world {i} key {k}")
        a = _actions(rng, N)
        td = env.step(TensorDict({"action": torch.from_numpy(a)}, batch_size=[N]))["next"]
        for i, e in enumerate(singles):
            single_obs[i], r, *_, info = e.step(a[i])
            assert td["reward"][i, 0].item() == np.float32(r)
            assert td["route_completion"][i, 0].item() == np.float32(info["route_completion"])
            assert td["v2x_bps"][i, 0].item() == np.float32(info["v2x_bps"])


def test_world_batch_partial_reset_leaves_other_worlds_alone():
    b = WorldBatch(2, **SMALL)
    b.reset([1, 2])
    b.step(np.full((2, 3), 0.4))
    ego1 = b.obs["ego"][1].copy()
    b.reset([9, None], mask=[True, False])
    np.testing.assert_array_equal(b.obs["ego"][1], ego1)
    assert b.worlds[0].tick == 0 and b.worlds[1].tick == 1


@pytest.mark.parametrize("actions, match", [
    (np.zeros((2, 2)), "shape"),
    (np.array([[0.1, 0.0, 0.0], [np.nan, 0.0, 0.0]]), r"action\[1\]"),
    (np.array([["a"] * 3] * 2), "dtype"),
])
def test_batched_actions_are_validated(actions, match):
    with pytest.raises(ValueError, match=match):
        validate_controls(actions, 2)


def test_batched_actions_are_clipped():
    out = validate_controls(np.array([[2.0, -3.0, -1.0], [0.5, 0.5, 0.5]]), 2)
    np.testing.assert_array_equal(out, [[1.0, -1.0, 0.0], [0.5, 0.5, 0.5]])
