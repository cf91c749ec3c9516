"""The registered AURORA agents: ``aurora`` (with its roadside unit as a learned agent) and
``no_fusion`` (the roadside input switched off: the paper's No Fusion row).

``v2xbench eval --agent aurora --agent-config aurora.json --set max_payload_floats=5680``
with ``aurora.json`` = ``{"run": "runs/aurora"}`` drives with a trained run (its latest stage of
3-5; ``"stage": 4`` picks another). The agent observes in ``sensors`` mode and declares the
sensors of its training data (``camera_size`` of the data set, ``rgb`` only:
``agents/interface.py``, "Sensors"). Its
``rsu_policy`` is :class:`~.rsu_agent.AuroraRoadside` (the roadside branch of the same
checkpoint, its message a raw payload over the channel), whose size at the default scale (5,680
floats; :func:`~.rsu_agent.message_floats`) is above the env's default ``max_payload_floats``
(320): the ``--set`` raises it (an agent cannot change the env's channel itself). ``no_fusion``
sends nothing (``rsu_policy = "none"``) and ignores ``v2x_payload``; its default run is
``runs/aurora_no_fusion`` (``v2xbench aurora train --no-fusion``). ``checkpoint`` declares the
stage's weights and the base LM's folder, ``fingerprint()`` the stage, fusion and planner, so
results of other weights never mix. Each step goes through the ``TensorDictModule`` of
:mod:`.policy`; its waypoints go to the shared waypoint controller (``interface.to_control``).

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

DEFAULT_RUN = "runs/aurora"
DEFAULT_NO_FUSION_RUN = "runs/aurora_no_fusion"
OBS_KEYS = ("cameras", "ego", "route", "v2x_info", "v2x_payload")


class AuroraAgent:
    """The learned AURORA driver (``v2xbench eval --agent aurora``; module docstring).

    Args:
        run: the trained run folder (stages 3-5; its latest stage is used).
        stage: a stage to use instead of the latest (3, 4 or 5).
        device: torch device.
    """

    obs_mode = "sensors"
    privileged = False
    fusion = True

    def __init__(self, run: str = DEFAULT_RUN, stage: int | None = None,
                 device: str = "cpu") -> None:
        from .policy import policy_module
        from .rsu_agent import AuroraRoadside
        from .system import load_system

        system, tok, info = load_system(run, stage, device)
        system.lm.lm.merge_adapter()  # inference only: LoRA folded into the base weights
        if not self.fusion:
            system.fusion = False
        self.run, self.info = str(Path(run)), info
        size = tuple(int(v) for v in info.get("camera_size", system.cfg.ego_image_size))
        self.sensors = {"camera_size": size, "camera_images": ("rgb",)}
        self.checkpoint = [info["checkpoint"], info["lm_dir"]]
        self.policy = policy_module(system, tok, size)
        self.cfg = system.cfg
        self.rsu_policy = AuroraRoadside(system.rsu, system.cfg, size,
                                         checkpoint=[info["checkpoint"]]) \
            if self.fusion else "none"
        self.ticks, self.infer_s = 0, 0.0

    def fingerprint(self) -> str:
        """What else the behaviour depends on: the stage and whether fusion is on."""
        return f"stage={self.info['stage']} fusion={self.fusion} planner={self.cfg.planner}"

    def reset(self, route_info: dict) -> None:
        """A new route (the model keeps no state between ticks)."""
        self.ticks, self.infer_s = 0, 0.0

    def act(self, obs: dict) -> dict:
        """``{"waypoints": (6, 2) ego frame, "speed": m/s}`` for the shared controller."""
        import torch
        from v2xbench.agents.torchrl_policy import obs_to_tensordict

        t0 = time.perf_counter()
        td = obs_to_tensordict({k: v for k, v in obs.items() if k in OBS_KEYS})
        with torch.no_grad():
            out = self.policy(td)
        wps = out["waypoints"][0].cpu().numpy().astype(np.float64)
        speed = float(out["target_speed"][0])
        self.infer_s += time.perf_counter() - t0
        self.ticks += 1
        return {"waypoints": wps, "speed": speed}


class NoFusionAgent(AuroraAgent):
    """AURORA with the roadside input switched off (the paper's No Fusion row): the unit sends
    nothing and the prompt says no message arrived. ``run`` is best a run trained the same way
    (``v2xbench aurora train --no-fusion``)."""

    fusion = False

    def __init__(self, run: str = DEFAULT_NO_FUSION_RUN, stage: int | None = None,
                 device: str = "cpu") -> None:
        super().__init__(run, stage, device)


__all__ = ["DEFAULT_NO_FUSION_RUN", "DEFAULT_RUN", "AuroraAgent", "NoFusionAgent"]
