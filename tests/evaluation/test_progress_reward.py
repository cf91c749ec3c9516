"""The continuous progress reward (episode.route_progress, jit_route.route_progress_kernel)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.evaluation.episode import route_progress
from v2xbench.envs.v2x_intersection.evaluation.jit_route import route_progress_kernel

EMPTY = {"num_vehicles": 0, "num_parked": 0, "num_pedestrians": 0, "num_bicycles": 0}


def test_kernel_on_a_straight_route():
    pts = np.stack([np.arange(11.0), np.zeros(11)], 1)  # (11, 2), 1 m apart along x
    s = np.arange(11.0)
    # 1 m beside the route at x = 2.5: the furthest route position within 3 m is 2.5 + sqrt(8)
    assert route_progress_kernel(pts, s, 2, 2.5, 1.0, 3.0, 40) == pytest.approx(2.5 + np.sqrt(8.0))
    assert route_progress_kernel(pts, s, 2, 2.6, 1.0, 3.0, 40) == pytest.approx(2.6 + np.sqrt(8.0))
    assert route_progress_kernel(pts, s, 9, 9.5, 0.0, 3.0, 40) == 10.0  # capped at the route's end
    assert route_progress_kernel(pts, s, 4, 5.0, 3.5, 3.0, 40) == 4.0  # > 3 m away: stays at s[k0]
    assert route_progress_kernel(pts, s, 2, 2.5, 0.0, 3.0, 3) == 4.0  # only points k0..k0+2


def test_small_forward_move_gives_proportional_reward():
    env = gym.make("V2XIntersection-v0", **EMPTY)
    env.reset(seed=0)
    w = env.unwrapped.world
    for _ in range(3):  # the monitor's progress settles on the first tick
        env.step(np.zeros(3, np.float32))
    rewards, moves = [], []
    for throttle in (0.05, 0.1, 0.2):
        x0 = w.table.pos[0].copy()
        _, _, _, _, info = env.step(np.array([throttle, 0.0, 0.0], np.float32))
        moves.append(float(np.linalg.norm(w.table.pos[0] - x0)))
        rewards.append(info["reward_progress"])
    assert 0 < moves[0] < 0.01  # millimetres: far below the route points' 1 m spacing
    for r, m in zip(rewards, moves):
        assert r == pytest.approx(m / 10.0, rel=0.02)  # the reward is metres along the route / 10
    env.step(np.array([0.0, 0.0, 1.0], np.float32))  # stopped: no progress
    _, _, _, _, info = env.step(np.array([0.0, 0.0, 1.0], np.float32))
    assert info["reward_progress"] == 0.0


def test_progress_stays_within_the_monitors_route_point():
    """The continuous progress lies between the monitor's progress point and the next one, so
    the summed progress reward matches route completion."""
    from v2xbench.agents.interface import load_agent, to_control
    from v2xbench.collectors.eval_env import route_info

    env = gym.make("V2XIntersection-v0", route_length=120.0, **EMPTY)
    obs, info = env.reset(seed=3)
    w = env.unwrapped.world
    agent = load_agent("route_follower")
    agent.reset(route_info(w, w.config.town, 3))
    total = 0.0
    for _ in range(400):
        obs, _, term, trunc, info = env.step(to_control(agent.act(obs), obs).astype(np.float32))
        total += info["reward_progress"] * 10.0
        k, s = w.monitor.progress, w.route.s
        cont = env.unwrapped._tracker.prev_s
        assert s[k] <= cont and (k + 1 == len(s) or cont < s[k + 1])
        assert route_progress(w) <= cont + 1e-12
        if term or trunc:
            break
    assert total > 50.0
    metres = info["route_completion"] / 100.0 * w.route.length
    assert abs(total - metres) < 4.0  # the monitor credits up to 3 m at the start
