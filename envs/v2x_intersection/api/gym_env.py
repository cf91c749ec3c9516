"""Single-agent Gymnasium environment: the ego drives, the RSU runs a built-in message policy.

``gym.make("v2xbench:V2XIntersection-v0", **config)`` (any :class:`~.config.EnvConfig` key).

- Observation: ``Dict`` (``observations.ego_space``): ego state, route ahead, objects the ego
  sees, objects received over V2X (in the ego frame), the received V2X payload as sent
  (``v2x_payload``) and V2X metadata.
- Action (``config.action_mode``, :mod:`.actions`): ``"carla"`` (default) ``Box(3)`` = throttle
  in [0, 1], steer in [-1, 1], brake in [0, 1]; ``"accel_steer"`` ``Box(2)`` = signed acceleration
  in [-1, 1] (+-3.5 m/s^2) and steer in [-1, 1]. Finite values out of range are clipped; wrong
  shape, NaN or inf raise ``ValueError``.
- RSU: ``config.rsu_policy`` = ``"share_objects"`` (send the objects it sees) or ``"none"``.
- Reset options: ``spec`` (a route file's ``RouteSpec``), or ``route`` and ``scenarios``; any
  other key raises ``ValueError``.
- Reward, termination and info: :mod:`.episode`. ``render_mode="rgb_array"``: top-down view.

Version history: v0 - first release.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from ..core.validation import check_options
from ..evaluation.episode import EpisodeTracker
from ..sim.config import make_config, plain_scalar
from ..sim.world import StepError, World
from .actions import action_space, validate_action
from .observations import ego_observation, ego_space

#: the keys ``reset(options=...)`` takes: ``World.reset``'s episode arguments
RESET_OPTIONS = ("spec", "route", "scenarios")


class V2XIntersectionEnv(gym.Env):
    """The ego vehicle as a single Gymnasium agent (see module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None, **config: Any) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode={render_mode!r} not supported; use one of {self.metadata['render_modes']}")
        self.config = make_config(**config)
        self.world = World(self.config)
        self.render_mode = render_mode
        self.observation_space = ego_space(self.config)
        self.action_space = action_space(self.config.action_mode)
        self._tracker: EpisodeTracker | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode. ``options``: :data:`RESET_OPTIONS` (``World.reset``'s episode: a
        ``spec`` route file, or ``route`` and ``scenarios``); another key raises ``ValueError``."""
        options = check_options(options, RESET_OPTIONS)
        if seed is None and self._tracker is None:
            seed = self.config.seed
        seed = plain_scalar(seed)  # a NumPy integer seeds as the int it holds
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(2**31))
        self.world.reset(seed=seed, route=options.get("route"), scenarios=options.get("scenarios"),
                         spec=options.get("spec"))
        self._tracker = EpisodeTracker(self.world)
        return ego_observation(self.world), self._tracker.info()

    def step(self, action):
        if self._tracker is None:
            raise StepError("step() called before reset()")
        if self._tracker.done:
            raise StepError("step() called after the episode ended; call reset()")
        control = validate_action(action, self.config.action_mode)
        events = self.world.step_builtin(control)
        reward, terminated, truncated, info = self._tracker.after_step(events)
        return ego_observation(self.world), reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from ..render.topdown import render_topdown

        return render_topdown(self.world, self.config.render_size)
