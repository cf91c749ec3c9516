"""The registered agent ``v2x_vit``: V2X-ViT's ego half drives, its roadside half is the unit.

``v2xbench eval --agent v2x_vit --agent-config v2x_vit.json`` with ``v2x_vit.json`` =
``{"run": "runs/v2x_vit"}`` (a run of ``v2xbench baselines train v2x_vit``). The agent observes
in ``sensors`` mode and declares the sensors of its training data: no camera images and the
data set's ``lidar_scale`` (``agents/interface.py``, "Sensors"); its ``rsu_policy`` is
:class:`~.policy.V2XViTRoadside` (the roadside half of the same checkpoint; the message a raw
payload through the channel) and it declares ``channel = {"max_payload_floats": <the message's
floats>}`` so that ``eval`` sets the env's limit. ``checkpoint`` names the weights,
``fingerprint()`` the scale and the target-speed rule. Each step:
:meth:`~.policy.V2XViTDriver.plan` -> the shared waypoint controller (V2X-ViT is a perception
method; its waypoints come from a simple waypoint head, docs/baselines.md). There are no shipped
weights: a run is required.

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

import time
from pathlib import Path


class V2XViTAgent:
    """V2X-ViT (Xu et al., ECCV 2022) as a driver (module docstring).

    Args:
        run: a trained run folder (``v2xbench baselines train v2x_vit --out RUN``).
        device: torch device.
    """

    obs_mode = "sensors"
    privileged = False

    def __init__(self, run: str | None = None, device: str = "cpu") -> None:
        if run is None:
            raise FileNotFoundError('v2x_vit agent: no run given; pass a trained run with '
                                    '--agent-config FILE holding {"run": "runs/v2x_vit"} (train '
                                    'one with `v2xbench baselines train v2x_vit --data DIR --out '
                                    'runs/v2x_vit`)')
        from .policy import V2XViTDriver, V2XViTRoadside
        from .train import load_run

        model, cfg, info = load_run(run, device)
        self.run, self.cfg, self.info = str(Path(run)), cfg, info
        scale = float(info["lidar_scale"])
        self.sensors = {"camera_images": (), "lidar_scale": scale}
        self.channel = {"max_payload_floats": cfg.message_floats()}
        self.checkpoint = [info["checkpoint"]]
        self.driver = V2XViTDriver(model.ego, cfg, scale)
        self.rsu_policy = V2XViTRoadside(model.rsu, cfg, scale, checkpoint=[info["checkpoint"]])
        self.ticks, self.infer_s = 0, 0.0

    def fingerprint(self) -> str:
        """The scale and the target-speed rule (the weights are in ``checkpoint``)."""
        from v2xbench.agents.aurora.policy import TARGET_SPEED_RULE

        return f"v2x_vit scale={self.cfg.scale} speed={TARGET_SPEED_RULE}"

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


__all__ = ["V2XViTAgent"]
