"""A learned driver for the collector: DAgger-style data (Ross et al., AISTATS 2011).

The expert's data shows only the states the expert visits. A learned planner that drifts off them
(stands where the expert would not, say) never sees a label for the state it is in. With
``CollectConfig(driver="univ2x")`` (``v2xbench collect --driver NAME``) the learned agent drives
the episode while the privileged expert, bound to the same world, plans every tick as before:
each frame records the state the *learned* driver reached with the *expert's* plan for it
(``expert_waypoints``, ``expert_control``, ...), and ``control`` is what was executed. With
``expert_share`` = p the expert's own control is executed instead on a share p of the ticks
(DAgger's mixture ``beta``; drawn from the episode's seed, so a resumed collection repeats it).

The driver runs as in ``v2xbench eval``: an agent spec (registered name or ``file.py:Class``)
and its config, its declared sensors and channel configure the world
(``agent_sensors.agent_env_overrides``), its own roadside policy sends the unit's messages. The
recorded frames keep the collection's settings (the sensor rig of ``--sensors`` /
``--camera-size``; ``obs/*`` is the objects-mode observation, ``observations.objects_observation``),
so a driven data set has the same schema as an expert one. The channel setting the driver
declares must be in the collection's ``env`` (``--set max_payload_floats=N``), as the recorded
``obs/v2x_payload`` has that size.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from v2xbench.agents.interface import call_act, to_control
from v2xbench.envs.v2x_intersection.api.observations import (
    ego_observation,
    ego_space,
    validate_control,
)

#: salt of the per-episode stream that chooses who drives each tick
_SHARE_SALT = 0x5DA66E12


class LearnedDriver:
    """An agent driving a collection episode (module docstring).

    Args:
        spec: the agent (registered name or ``path/file.py:Class``).
        config: its keyword arguments (``--driver-config``).
        env: the collection's ``EnvConfig`` overrides.

    Raises:
        ValueError: an unknown agent, a bad config, a privileged agent (the expert labels; a
            privileged driver would read the world), a declared channel setting missing from
            ``env``.
    """

    def __init__(self, spec: str, config: dict | None, env: dict) -> None:
        from v2xbench.agents.interface import act_info_style, declared_channel, granted_privilege

        from ..agent_sensors import agent_env_overrides
        from ..eval_env import instantiate_agent
        from ..roadside import roadside_runner

        if granted_privilege(spec):
            raise ValueError(f"collect: driver {spec!r} is privileged; the expert labels every "
                             "frame already (collect without --driver)")
        self.spec = spec
        self.agent = instantiate_agent(spec, False, config)
        _, self.overrides = agent_env_overrides(self.agent, spec, dict(env))
        missing = {k: v for k, v in declared_channel(self.agent, spec).items() if k not in env}
        if missing:
            sets = " ".join(f"--set {k}={v}" for k, v in missing.items())
            raise ValueError(f"collect: driver {spec!r} declares channel {missing} (its "
                             f"messages need it; the recorded obs/v2x_payload has that size): add "
                             f"{sets}")
        self.roadside = roadside_runner(self.agent)
        self.info_style = act_info_style(self.agent)

    def identity(self) -> dict:
        """What a driven collection's data depends on beyond its config: the driver's spec, its
        declared checkpoint digests and ``fingerprint()`` (``agent_fingerprint.declared``),
        stored in the manifest so that a resume with other weights is refused."""
        from ..agent_fingerprint import declared

        return {"spec": self.spec, **declared(self.agent, self.spec)}

    def reset(self, world, town: str, seed: int) -> None:
        """The agent's (and its roadside policy's) ``reset`` with the route's info; the keys of
        the world's Gymnasium observation, what :meth:`act` hands the agent."""
        from ..eval_env import route_info

        self._keys = tuple(ego_space(world.config).spaces)
        info = route_info(world, town, seed)
        self.agent.reset(info)
        if self.roadside is not None:
            self.roadside.reset(info)

    def act(self, world, info: dict | None) -> np.ndarray:
        """The agent's ``(3,)`` control for the world's current tick (its observation of the
        world's ``obs_mode``, as the Gymnasium env gives it; :meth:`reset` first)."""
        obs = ego_observation(world)
        view = {k: obs[k] for k in self._keys}
        out = call_act(self.agent, view, info, self.info_style)
        return validate_control(to_control(out, view, world.config.action_mode),
                                f"driver {self.spec!r} output").astype(np.float32)

    def step(self, world, control: np.ndarray) -> list:
        """Advance the world with ``control``; the agent's roadside policy speaks for the unit."""
        if self.roadside is None:
            return world.step_builtin(control)
        return world.step(control, self.roadside.message(world))


def share_stream(seed: int) -> np.random.Generator:
    """The per-episode random stream that picks the ticks the expert's control executes."""
    return np.random.default_rng([int(seed), _SHARE_SALT])


def check_driver_args(driver: Any, driver_config: Any, expert_share: Any) -> None:
    """``CollectConfig``'s driver fields, checked up front (messages name the field)."""
    if driver is not None and (not isinstance(driver, str) or not driver):
        raise ValueError(f"CollectConfig: driver={driver!r} must be an agent name or "
                         "path/file.py:Class")
    if not isinstance(driver_config, dict):
        raise ValueError(f"CollectConfig: driver_config={driver_config!r} must be a dict of the "
                         "driver's keyword arguments")
    if driver is None and driver_config:
        raise ValueError("CollectConfig: driver_config without a driver")
    ok = isinstance(expert_share, (int, float)) and not isinstance(expert_share, bool)
    if not ok or not 0.0 <= float(expert_share) <= 1.0:
        raise ValueError(f"CollectConfig: expert_share={expert_share!r} must be a number in [0, 1]")
    if driver is None and expert_share:
        raise ValueError("CollectConfig: expert_share without a driver (the expert drives every "
                         "tick already)")


__all__ = ["LearnedDriver", "check_driver_args", "share_stream"]
