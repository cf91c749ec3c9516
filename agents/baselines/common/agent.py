"""The registered baseline agents' shared part: load a trained run, declare the sensors and the
channel, name the checkpoint, and drive with the method's driver (:class:`BaselineAgent`).

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any


class BaselineAgent:
    """A baseline as a driver: its ego half drives, its roadside half is the ``"rsu"`` policy.

    Subclasses set :attr:`method`, :attr:`driver_cls` and :attr:`roadside_cls` (class names in
    the ``policy`` module of the subclass's package; the run loads with its ``train`` module's
    ``load_run``) and implement :meth:`_sensors`.

    Args:
        run: a trained run folder (``v2xbench baselines train METHOD --out RUN``) or exported
            weights (``v2xbench baselines export``); default: the repository's shipped
            ``agents/baselines/weights/<method>`` (SHA-256 checked), where the method has them.
        device: torch device.

    Raises:
        FileNotFoundError: no run given and no shipped weights, or not a trained run of the
            method. ValueError: exported or shipped weights that fail their SHA-256 check.
    """

    obs_mode = "sensors"
    privileged = False
    #: The registered name (``univ2x``).
    method: str = ""
    #: The ego driver and the roadside policy: class names in the package's ``policy`` module.
    driver_cls: str = ""
    roadside_cls: str = ""

    def __init__(self, run: str | None = None, device: str = "cpu") -> None:
        from .export import MANIFEST, SHIPPED, verify

        m = self.method
        if run is None and (SHIPPED / m).is_dir():
            run = str(SHIPPED / m)
        if run is not None and (Path(run) / MANIFEST).is_file():
            verify(run, m)  # exported weights: every file as exported
        if run is None:
            raise FileNotFoundError(f'{m} agent: no run given and no shipped weights at '
                                    f'{SHIPPED / m}; pass a trained run with --agent-config '
                                    f'FILE holding {{"run": "runs/{m}"}} (train one with '
                                    f'`v2xbench baselines train {m} --data DIR --out runs/{m}`; '
                                    f'`v2xbench baselines export {m} --run runs/{m}` ships it)')
        load_run, driver_cls, roadside_cls = self._load()
        model, cfg, info = load_run(run, device)
        self.run, self.cfg, self.info = str(Path(run)), cfg, info
        self.sensors, setting = self._sensors(info)
        self.channel = {"max_payload_floats": cfg.message_floats()}
        self.checkpoint = [info["checkpoint"]]
        self.driver = driver_cls(model.ego, cfg, setting)
        self.rsu_policy = roadside_cls(model.rsu, cfg, setting, checkpoint=[info["checkpoint"]])
        self.ticks, self.infer_s = 0, 0.0

    def _load(self) -> tuple[Any, type, type]:
        """``(load_run, driver class, roadside policy class)`` of the subclass's package."""
        import importlib

        package = type(self).__module__.rsplit(".", 1)[0]
        policy = importlib.import_module(f"{package}.policy")
        load_run = importlib.import_module(f"{package}.train").load_run
        return load_run, getattr(policy, self.driver_cls), getattr(policy, self.roadside_cls)

    def _sensors(self, info: dict) -> tuple[dict, Any]:
        """``(sensors declaration, the sensor setting the driver and roadside policy take)`` of
        the run file ``info``."""
        raise NotImplementedError

    def fingerprint(self) -> str:
        """The scale and the target-speed rule (the weights are in ``checkpoint``)."""
        from v2xbench.agents.aurora.policy import TARGET_SPEED_RULE

        return f"{self.method} scale={self.cfg.scale} speed={TARGET_SPEED_RULE}"

    def reset(self, route_info: dict) -> None:
        """A new route (the model keeps no state between ticks)."""
        self.ticks, self.infer_s = 0, 0.0

    def act(self, obs: dict) -> dict:
        """``{"waypoints": (6, 2) ego frame, "speed": m/s}`` for the shared controller."""
        t0 = time.perf_counter()
        wps, speed = self.driver.plan(obs)
        self.infer_s += time.perf_counter() - t0
        self.ticks += 1
        return {"waypoints": wps, "speed": speed}


__all__ = ["BaselineAgent"]
