"""The registered agent ``univ2x``: UniV2X's ego half drives, its roadside half is the unit.

``v2xbench eval --agent univ2x --agent-config univ2x.json`` with ``univ2x.json`` =
``{"run": "runs/univ2x"}`` (a run of ``v2xbench baselines train univ2x``). The agent observes in
``sensors`` mode and declares the sensors of its training data (``camera_size`` of the data set,
``rgb`` only); its ``rsu_policy`` is :class:`~.policy.UniV2XRoadside` (the roadside half of the
same checkpoint; the message a raw payload through the channel) and it declares ``channel =
{"max_payload_floats": <the message's floats>}`` so that ``eval`` sets the env's limit
(``agents/interface.py``, "Channel"). ``checkpoint`` names the weights, ``fingerprint()`` the
scale and the target-speed rule. Each step: :meth:`~.policy.UniV2XDriver.plan` -> the shared
waypoint controller. There are no shipped weights: a run is required.

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

import time
from pathlib import Path


class UniV2XAgent:
    """UniV2X (Yu et al., AAAI 2025) as a driver (module docstring).

    Args:
        run: a trained run folder (``v2xbench baselines train univ2x --out RUN``).
        device: torch device.
    """

    obs_mode = "sensors"
    privileged = False

    def __init__(self, run: str | None = None, device: str = "cpu") -> None:
        if run is None:
            raise FileNotFoundError('univ2x agent: no run given; pass a trained run with '
                                    '--agent-config FILE holding {"run": "runs/univ2x"} (train '
                                    'one with `v2xbench baselines train univ2x --data DIR --out '
                                    'runs/univ2x`)')
        from .policy import UniV2XDriver, UniV2XRoadside
        from .train import load_run

        model, cfg, info = load_run(run, device)
        self.run, self.cfg, self.info = str(Path(run)), cfg, info
        size = tuple(int(v) for v in info["camera_size"])
        self.sensors = {"camera_size": size, "camera_images": ("rgb",)}
        self.channel = {"max_payload_floats": cfg.message_floats()}
        self.checkpoint = [info["checkpoint"]]
        self.driver = UniV2XDriver(model.ego, cfg, size)
        self.rsu_policy = UniV2XRoadside(model.rsu, cfg, size, checkpoint=[info["checkpoint"]])
        self.ticks, self.infer_s = 0, 0.0

    def fingerprint(self) -> str:
        """The scale and the target-speed rule (the weights are in ``checkpoint``)."""
        from v2xbench.agents.aurora.policy import TARGET_SPEED_RULE

        return f"univ2x scale={self.cfg.scale} speed={TARGET_SPEED_RULE}"

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


__all__ = ["UniV2XAgent"]
