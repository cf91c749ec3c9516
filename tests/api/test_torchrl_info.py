"""The TorchRL env's reset and step TensorDicts carry the episode information (#30 item 8): every
numeric key of the Gymnasium env's ``info`` under ``"info"``, with specs, the same values as the
Gymnasium env for the same seeds and actions."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs
from v2xbench.envs.v2x_intersection import V2XIntersectionEnv, V2XTorchEnv
from v2xbench.envs.v2x_intersection.api.torchrl_env import INFO_SPECS
from v2xbench.envs.v2x_intersection.evaluation.episode import COLLISIONS, INFRACTIONS

torch.set_num_threads(1)

SMALL = dict(num_vehicles=10, num_parked=4, num_pedestrians=6, num_bicycles=1, route_length=100.0)
DERIVED = ("collisions", "infractions")


def _numeric(info: dict) -> dict:
    return {k: v for k, v in info.items()
            if isinstance(v, int | float | np.integer | np.floating)
            or (isinstance(v, np.ndarray) and v.dtype.kind in "iuf")}


def test_info_specs_cover_every_numeric_gym_info_key():
    env = V2XIntersectionEnv(**SMALL)
    _, info = env.reset(seed=0)
    _, _, _, _, info = env.step(env.action_space.sample())
    numeric = _numeric(info)
    assert numeric == info  # the gym info is all numbers
    assert set(INFO_SPECS) - set(DERIVED) == set(info)
    for k, (dtype, width) in INFO_SPECS.items():
        if k in info:
            assert np.size(info[k]) == width, k
            is_int = np.issubdtype(np.asarray(info[k]).dtype, np.integer)
            assert (dtype == torch.int64) == bool(is_int), k


def test_rollout_has_info_and_specs_check():
    env = V2XTorchEnv(num_worlds=2, **SMALL)
    env.set_seed(1)
    check_env_specs(env)
    td = env.rollout(15)
    info = td["next", "info"]
    for k, (dtype, width) in INFO_SPECS.items():
        assert info[k].shape == (2, 15, width) and info[k].dtype == dtype, k
    assert (info["tick"][:, :, 0] == torch.arange(1, 16)).all()
    assert info["route_completion"].max() > 0  # the random policy moves along the route
    assert "info" in env.observation_spec.keys()
    assert env.reset()["info", "tick"].eq(0).all()


def test_info_can_be_left_out():
    env = V2XTorchEnv(num_worlds=2, info=False, **SMALL)
    env.set_seed(1)
    check_env_specs(env)
    td = env.rollout(3)
    assert "info" not in td["next"].keys() and "info" not in env.observation_spec.keys()
    assert env.batch.with_infos is False
    with pytest.raises(ValueError, match="info must be True or False"):
        V2XTorchEnv(num_worlds=1, info="yes")


def _gym_info_as_row(info: dict) -> dict:
    row = {k: np.atleast_1d(np.asarray(v)) for k, v in info.items()}
    row["collisions"] = np.array([info["events"][list(COLLISIONS)].sum()])
    row["infractions"] = np.array([info["events"][list(INFRACTIONS)].sum()])
    return row


def test_step_info_matches_the_gym_env_for_the_same_seeds_and_actions():
    n, seed = 2, 7
    tenv = V2XTorchEnv(num_worlds=n, **SMALL)
    tenv.set_seed(seed)
    td = tenv.reset()
    rng = np.random.default_rng(seed)  # the env's own draw of its worlds' reset seeds
    seeds = [int(rng.integers(2**31)) for _ in range(n)]
    genvs = [V2XIntersectionEnv(**SMALL) for _ in range(n)]
    infos = [g.reset(seed=s)[1] for g, s in zip(genvs, seeds)]

    def same(td_info, infos) -> None:
        for i, info in enumerate(infos):
            want = _gym_info_as_row(info)
            for k in INFO_SPECS:
                got = td_info[k][i].numpy()
                np.testing.assert_array_equal(got, want[k].astype(got.dtype), err_msg=k)

    same(td["info"], infos)
    torch.manual_seed(seed)
    progress = 0.0
    for _ in range(80):
        td["action"] = tenv.action_spec.rand()
        td["action"][:, 0] = 1.0  # full throttle: progress, and events along the way
        out = tenv.step(td)["next"]
        actions = td["action"].numpy()
        steps = [g.step(actions[i]) for i, g in enumerate(genvs)]
        same(out["info"], [s[4] for s in steps])
        rewards = np.float32([s[1] for s in steps])
        np.testing.assert_array_equal(out["reward"].numpy()[:, 0], rewards)
        progress += float(out["info", "reward_progress"].sum())
        if out["done"].any():
            break
        td = out
    assert progress > 0 and out["info", "route_completion"].min() > 0
    assert out["info", "driven_m"].min() > 0 and out["info", "v2x_bytes_total"].max() > 0
