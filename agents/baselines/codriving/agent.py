"""The registered agent ``codriving``: CoDriving's ego half drives with its native controller,
its roadside half is the unit.

``v2xbench eval --agent codriving --agent-config codriving.json`` with ``codriving.json`` =
``{"run": "runs/codriving"}`` (a run of ``v2xbench baselines train codriving``). The agent
observes in ``sensors`` mode and declares the sensors of its training data (no camera images,
the data set's ``lidar_scale``); its ``rsu_policy`` is :class:`~.policy.CoDrivingRoadside` (the
roadside half of the same checkpoint, told the ego's route at each route's start) and it
declares ``channel = {"max_payload_floats": <the largest message's floats>}`` so that ``eval``
sets the env's limit (messages are shorter when fewer cells are chosen). Each step:
:meth:`~.policy.CoDrivingDriver.plan` -> the native controller (:mod:`.controller`: PID on the
waypoints; a ``(3,)`` throttle, steer, brake action, so the env's ``action_mode`` must be
``carla``). ``{"light_brake": true}`` adds the published system's traffic-light brake
(:class:`~.controller.LightBrake`, from the ego vector's light state: our CoDriving has no
camera). Without a run it loads the shipped weights (``agents/baselines/weights/codriving``)
where the repository has them.

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

import time

import numpy as np

from ..common.agent import BaselineAgent
from ..common.policy import LIGHT_STATE, SPEED, STOP_DIST
from .controller import LightBrake, NativeController


class CoDrivingAgent(BaselineAgent):
    """CoDriving (Liu et al., IEEE TPAMI 2025) as a driver (module docstring;
    :class:`~..common.agent.BaselineAgent`)."""

    method = "codriving"
    driver_cls, roadside_cls = "CoDrivingDriver", "CoDrivingRoadside"

    def __init__(self, run: str | None = None, device: str = "cpu",
                 light_brake: bool = False) -> None:
        if not isinstance(light_brake, bool):
            raise ValueError(f"codriving: light_brake={light_brake!r} must be true or false")
        super().__init__(run, device)
        self.controller = NativeController()
        self.light_brake = LightBrake() if light_brake else None

    def _sensors(self, info: dict):
        """The sensors declaration and the setting its driver takes."""
        scale = float(info["lidar_scale"])
        return {"camera_images": (), "lidar_scale": scale}, scale

    def fingerprint(self) -> str:
        """The shared fingerprint plus the native controller."""
        light = f" light-brake={self.light_brake}" if self.light_brake else ""
        return super().fingerprint() + " controller=native-pid" + light

    def reset(self, route_info: dict) -> None:
        """A new route: the counters and the controller's PIDs."""
        super().reset(route_info)
        self.controller.reset()

    def act(self, obs: dict) -> np.ndarray:
        """``(3,)`` throttle, steer, brake of the native controller on the planned waypoints."""
        t0 = time.perf_counter()
        wps, speed = self.driver.plan(obs)
        self.infer_s += time.perf_counter() - t0
        self.ticks += 1
        ego = obs["ego"]
        control = self.controller.control(wps, float(ego[SPEED]), speed)
        if self.light_brake is not None and self.light_brake(ego[LIGHT_STATE], ego[STOP_DIST],
                                                             float(ego[SPEED])):
            control[0], control[2] = 0.0, 1.0
        return control


__all__ = ["CoDrivingAgent"]
