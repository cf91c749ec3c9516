"""PettingZoo parallel environment: the ego vehicle and the active roadside unit(s) as agents.

===================  ===========================================================================
agents               ``"ego"``, ``"rsu"`` (``rsu_slots > 1``: ``"rsu"``, ``"rsu_1"``, ...)
ego observation      ``observations.ego_space``: ego state, route, seen objects, received V2X
ego action           ``config.action_mode`` (:mod:`.actions`): ``carla`` ``Box(3)`` throttle [0, 1],
                     steer [-1, 1], brake [0, 1]; ``accel_steer`` ``Box(2)`` accel, steer in [-1, 1]
                     (clipped; a wrong shape, NaN or inf raise)
rsu observation      ``observations.rsu_space``: unit id + pose, calibration, objects it sees
rsu action           its V2X message: ``Dict(length=Discrete(L+1), payload=Box(L),
                     format=Discrete(2))`` (``channel.message_space``; format 0 = an object list,
                     decoded into the ego's ``v2x_objects``, 1 = a raw payload of its own design;
                     every payload reaches the ego's ``v2x_payload``; the channel serializes,
                     counts bytes, delays, drops; BPS is measured there)
rewards              ego: :mod:`.episode` terms; rsu: the same (a cooperative team reward)
state                ``state()``: every agent's observation flattened (``gymnasium.spaces.flatten``)
                     and concatenated, inside ``state_space`` (a ``Box``)
===================  ===========================================================================

Each RSU agent always denotes *the currently active unit* of its slot (the nearest
forward-facing one); which physical unit that is appears in its ``unit`` observation.
Arguments: any :class:`~.config.EnvConfig` key. Version history: v0 - first release.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from ..core.validation import check_options
from ..evaluation.episode import EpisodeTracker
from ..sim.config import make_config
from ..sim.world import StepError, World
from .actions import action_space, validate_action
from .gym_env import RESET_OPTIONS
from .observations import (
    ego_observation,
    ego_space,
    rsu_action_space,
    rsu_observation,
    rsu_space,
)


def parallel_env(**config: Any) -> V2XParallelEnv:
    """Create the PettingZoo parallel environment (see module docstring)."""
    return V2XParallelEnv(**config)


class V2XParallelEnv(ParallelEnv):
    """Ego + RSU agents over one :class:`World`."""

    metadata = {"name": "v2x_intersection_v0", "render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None, **config: Any) -> None:
        self.config = make_config(**config)
        self.world = World(self.config)
        self.render_mode = render_mode
        self.rsu_agents = ["rsu"] + [f"rsu_{k}" for k in range(1, self.config.rsu_slots)]
        self.possible_agents = ["ego", *self.rsu_agents]
        self.agents: list[str] = []
        self._obs_spaces = {"ego": ego_space(self.config), **{a: rsu_space(self.config) for a in self.rsu_agents}}
        msg_space = rsu_action_space(self.world.channel_config)
        self._act_spaces = {"ego": action_space(self.config.action_mode), **{a: msg_space for a in self.rsu_agents}}
        self.state_space = state_space(self._obs_spaces, self.possible_agents)
        self._tracker: EpisodeTracker | None = None

    @functools.cache  # noqa: B019 - the same object on every call, as PettingZoo asks
    def observation_space(self, agent: str):
        return self._obs_spaces[agent]

    @functools.cache  # noqa: B019
    def action_space(self, agent: str):
        return self._act_spaces[agent]

    def _observe(self) -> dict:
        obs = {"ego": ego_observation(self.world)}
        for k, a in enumerate(self.rsu_agents):
            obs[a] = rsu_observation(self.world, k)
        return obs

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Start an episode; ``options`` as the Gymnasium env's (``gym_env.RESET_OPTIONS``)."""
        options = check_options(options, RESET_OPTIONS)
        if seed is None and self._tracker is None:
            seed = self.config.seed
        self.world.reset(seed=seed, route=options.get("route"), scenarios=options.get("scenarios"),
                         spec=options.get("spec"))
        self._tracker = EpisodeTracker(self.world)
        self.agents = list(self.possible_agents)
        info = self._tracker.info()
        return self._observe(), {a: dict(info) for a in self.agents}

    def step(self, actions: dict):
        if self._tracker is None or not self.agents:
            raise StepError("step() called before reset() or after the episode ended")
        unknown = set(actions) - set(self.agents)
        if unknown:
            raise ValueError(f"actions for unknown agents: {sorted(unknown)}")
        if "ego" not in actions:
            raise ValueError("actions must include 'ego'")
        control = validate_action(actions["ego"], self.config.action_mode, "ego action")
        message = actions.get("rsu")  # only the first slot's unit transmits in v0
        events = self.world.step(control, message)
        reward, terminated, truncated, info = self._tracker.after_step(events)
        agents = list(self.agents)
        obs = self._observe()
        rewards = dict.fromkeys(agents, reward)
        terms = dict.fromkeys(agents, terminated)
        truncs = dict.fromkeys(agents, truncated)
        infos = {a: dict(info) for a in agents}
        if terminated or truncated:
            self.agents = []
        return obs, rewards, terms, truncs, infos

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from ..render.topdown import render_topdown

        return render_topdown(self.world, self.config.render_size)

    def state(self) -> np.ndarray:
        """Global state (for CTDE): every agent's observation, ``possible_agents`` order, each
        flattened by ``gymnasium.spaces.flatten`` (keys sorted); inside :attr:`state_space`."""
        obs = self._observe()
        flat = [spaces.flatten(self._obs_spaces[a], obs[a]) for a in self.possible_agents]
        return np.concatenate(flat)


def state_space(obs_spaces: dict, agents: list[str]) -> spaces.Box:
    """The ``Box`` of :meth:`V2XParallelEnv.state`: the agents' flattened observation spaces
    (``gymnasium.spaces.flatten_space``) end to end, their bounds and the common dtype."""
    flat = [spaces.flatten_space(obs_spaces[a]) for a in agents]
    dtype = np.result_type(*(f.dtype for f in flat))
    low = np.concatenate([f.low.astype(dtype) for f in flat])
    high = np.concatenate([f.high.astype(dtype) for f in flat])
    return spaces.Box(low, high, dtype=dtype)
