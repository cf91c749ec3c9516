"""The registered AURORA agents: ``aurora`` (with its roadside unit as a learned agent) and
``no_fusion`` (the roadside input switched off: the paper's No Fusion row).

``v2xbench eval --agent aurora --agent-config aurora.json``
with ``aurora.json`` = ``{"run": "runs/aurora"}`` drives with a trained run (its latest stage of
3-5; ``"stage": 4`` picks another). The agent observes in ``sensors`` mode and declares the
sensors of its training data (``camera_size`` of the data set, ``rgb`` only:
``agents/interface.py``, "Sensors"). Its
``rsu_policy`` is :class:`~.rsu_agent.AuroraRoadside` (the roadside branch of the same
checkpoint, its message a raw payload over the channel), whose size at the default scale (5,680
floats; :func:`~.rsu_agent.message_floats`) is above the env's default ``max_payload_floats``
(320): the agent declares ``channel = {"max_payload_floats": <the message's floats>}``
(``agents/interface.py``, "Channel") and ``eval`` sets the env's limit from it. ``no_fusion``
sends nothing (``rsu_policy = "none"``) and ignores ``v2x_payload``; train its run with
``--no-fusion``. Without a ``run`` both load exported weights (:mod:`.export`): ``weights``, else
the repository's shipped ``agents/aurora/weights/aurora`` / ``no_fusion``, SHA-256 checked.
``checkpoint`` declares the weights and the base LM's folder, ``fingerprint()`` the stage,
fusion, planner, target-speed rule and route input (:mod:`.route_input`), so
results of other weights never mix. Each step goes through the ``TensorDictModule`` of
:mod:`.policy`; its waypoints go to the shared waypoint controller (``interface.to_control``).

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

#: Exported weights (:mod:`.export`) each agent loads when no run is given.
SHIPPED_NAME = {True: "aurora", False: "no_fusion"}
OBS_KEYS = ("cameras", "ego", "route", "v2x_info", "v2x_payload")
LATERAL = ("planner", "route")
#: What the planning prompt says of the ego's speed: ``"auto"`` its speed, unless the run's
#: planner never read one (``plan_speed_dropout`` 1, docs/aurora.md "A sixth run"); ``"said"``;
#: ``"unknown"`` (the speed-dropout form of training).
SPEED_PROMPT = ("auto", "said", "unknown")


class AuroraAgent:
    """The learned AURORA driver (``v2xbench eval --agent aurora``; module docstring).

    Args:
        run: a trained run folder (stages 3-5; its latest stage is used). Default: exported
            weights (``weights``, else the repository's shipped ``agents/aurora/weights/aurora``;
            SHA-256 checked).
        stage: with ``run``: a stage to use instead of the latest (3, 4 or 5).
        device: torch device.
        weights: a folder of exported weights (``v2xbench aurora export``) instead of a run.
        lateral: ``"planner"`` (default: the planner's waypoints are the path) or ``"route"``
            (a diagnostic variant: the planner sets only the speed and how far each waypoint
            lies along the path; the path itself is the observed route, so the controller
            steers along the route. It separates what the planner gets wrong laterally from
            what it gets wrong in speed; results say which was used: the fingerprint).
        speed: what the planning prompt says of the ego's speed (:data:`SPEED_PROMPT`).
    """

    obs_mode = "sensors"
    privileged = False
    fusion = True

    def __init__(self, run: str | None = None, stage: int | None = None,
                 device: str = "cpu", weights: str | None = None,
                 lateral: str = "planner", speed: str = "auto") -> None:
        from .export import SHIPPED, load_export
        from .policy import policy_module
        from .rsu_agent import AuroraRoadside
        from .system import load_system

        if run is not None and weights is not None:
            raise ValueError("AURORA agent: give either run or weights, not both")
        if lateral not in LATERAL:
            raise ValueError(f"AURORA agent: lateral={lateral!r} is not one of {LATERAL}")
        if speed not in SPEED_PROMPT:
            raise ValueError(f"AURORA agent: speed={speed!r} is not one of {SPEED_PROMPT}")
        self.lateral = lateral
        if run is not None:
            system, tok, info = load_system(run, stage, device)
        else:
            if stage is not None:
                raise ValueError("AURORA agent: stage chooses a stage of a run; exported weights "
                                 "hold one stage (give run as well, or drop stage)")
            src = Path(weights) if weights is not None else SHIPPED / SHIPPED_NAME[self.fusion]
            if weights is None and not src.is_dir():
                raise FileNotFoundError(
                    f"AURORA agent: no run given and no shipped weights at {src}; pass a trained "
                    'run (--agent-config with {"run": "runs/aurora"}) or export one with '
                    f"`v2xbench aurora export --run RUN --out {src}`")
            system, tok, info = load_export(src, device)
            run = str(src)
        system.lm.lm.merge_adapter()  # inference only: LoRA folded into the base weights
        if not self.fusion:
            system.fusion = False
        self.run, self.info = str(Path(run)), info
        size = tuple(int(v) for v in info.get("camera_size", system.cfg.ego_image_size))
        self.sensors = {"camera_size": size, "camera_images": ("rgb",)}
        if self.fusion:  # the roadside message's size: eval sets the env's payload limit from it
            from .rsu_agent import message_floats

            self.channel = {"max_payload_floats": message_floats(system.cfg)}
        self.checkpoint = [info["checkpoint"], info["lm_dir"]]
        self.say_speed = speed == "said" or (speed == "auto"
                                             and system.cfg.plan_speed_dropout < 1.0)
        self.policy = policy_module(system, tok, size, say_speed=self.say_speed)
        self.cfg = system.cfg
        self.rsu_policy = AuroraRoadside(system.rsu, system.cfg, size,
                                         checkpoint=[info["checkpoint"]]) \
            if self.fusion else "none"
        self.ticks, self.infer_s = 0, 0.0

    def fingerprint(self) -> str:
        """What else the behaviour depends on: the stage, fusion, planner and speed rule, and
        the planner's route input and route output frame where it has them (models without
        them keep their old fingerprint)."""
        from .policy import TARGET_SPEED_RULE

        route = ""
        if self.cfg.plan_route_points:
            route = (f" route={self.cfg.plan_route_points}x{self.cfg.plan_route_spacing:g}m")
        if self.cfg.plan_frame != "ego":
            route += f" frame={self.cfg.plan_frame}"
            if self.cfg.plan_route_step != "softplus":  # the fourth run's step keeps its print
                route += f" step={self.cfg.plan_route_step}"
        lateral = "" if self.lateral == "planner" else f" lateral={self.lateral}"
        if not self.say_speed:  # models told their speed keep their print
            lateral += " prompt_speed=unknown"
        return (f"stage={self.info['stage']} fusion={self.fusion} planner={self.cfg.planner} "
                f"speed={TARGET_SPEED_RULE}{route}{lateral}")

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
        if self.lateral == "route":
            wps = route_guided(wps, np.asarray(obs["route"], np.float64))
        self.infer_s += time.perf_counter() - t0
        self.ticks += 1
        return {"waypoints": wps, "speed": speed}


def route_guided(waypoints: np.ndarray, route: np.ndarray) -> np.ndarray:
    """``waypoints (K, 2)`` moved onto the ``route`` rows' polyline (``(R, >=2)`` ego frame),
    each at the arc length the planner's path reaches there (the ``lateral="route"`` variant)."""
    from .route_input import route_points_ahead

    steps = np.linalg.norm(np.diff(np.vstack([[0.0, 0.0], waypoints]), axis=0), axis=1)
    dist = np.cumsum(steps)
    fine = route_points_ahead(route, 200, 0.25).numpy().astype(np.float64)  # 0.25 .. 50 m
    idx = np.clip(np.round(dist / 0.25).astype(int) - 1, 0, len(fine) - 1)
    out = fine[idx]
    out[dist < 0.125] = waypoints[dist < 0.125]  # standing: keep the planner's (tiny) path
    return out


class NoFusionAgent(AuroraAgent):
    """AURORA with the roadside input switched off (the paper's No Fusion row): the unit sends
    nothing and the prompt says no message arrived. ``run`` is best a run trained the same way
    (``v2xbench aurora train --no-fusion``)."""

    fusion = False

    def __init__(self, run: str | None = None, stage: int | None = None,
                 device: str = "cpu", weights: str | None = None,
                 lateral: str = "planner", speed: str = "auto") -> None:
        super().__init__(run, stage, device, weights, lateral, speed)


__all__ = ["LATERAL", "SHIPPED_NAME", "SPEED_PROMPT", "AuroraAgent", "NoFusionAgent", "route_guided"]
