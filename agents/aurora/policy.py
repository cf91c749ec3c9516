"""AURORA as a policy: a ``TensorDictModule`` and the registered agents ``aurora`` and
``no_fusion``.

:class:`AuroraPolicyNet` maps the sensors-mode ego observation and the received roadside
payload to waypoints, batched (``TensorDict`` rows are samples):

1. the ego branch on the six ego cameras' ``rgb`` images (calibration from the rig's camera
   specifications, :func:`~.calib.spec_calib`: the observation carries no calibration);
2. the roadside message: ``v2x_payload[:payload_length]`` deserialized
   (:func:`~.rsu_agent.deserialize_message`) with ``E_{r->e}`` from ``v2x_info``
   (:func:`~.rsu_agent.received_pose`); no message, a message of another kind, or a model
   without fusion -> the empty message;
3. DET-/MAP-CQAF and semantic fusion; the language model on the run-time prompt (speed
   ``ego[0]``, navigation command ``route[0, 2]``, the unit's pose from the message or "no
   message received", the planning question) ending with ``<wp>``;
4. the planner (the run's: VAE by default, its latent's mean) on ``h_wp``, the command and
   (``plan_route_points`` > 0) the route points ahead of ``route``
   (:func:`~.route_input.planner_route_points`, the function training uses):
   ``waypoints`` ``(B, 6, 2)`` ego frame, 0.5 s apart, and ``target_speed`` ``(B,)``
   (:func:`target_speed`: the speed between waypoints 0 and 1).

:func:`policy_module` is ``TensorDictModule(AuroraPolicyNet(...), in_keys=IN_KEYS,
out_keys=OUT_KEYS)``; the registered agents (:mod:`.agent`) feed it one observation at a time.
A smaller ``v2x_payload`` than the message needs is refused at the first step, naming the
``--set max_payload_floats=N`` to use (:func:`~.rsu_agent.message_floats`).
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn
from v2xbench.envs.v2x_intersection.sensors import EGO_CAMERA_NAMES

IN_KEYS = [("cameras", name, "rgb") for name in EGO_CAMERA_NAMES] + \
    ["ego", "route", "v2x_info", "v2x_payload"]
OUT_KEYS = ["waypoints", "target_speed"]
SPEED, COMMAND = 0, 2  # obs["ego"][SPEED]; obs["route"][:, COMMAND]


#: How :func:`target_speed` reads the waypoints (part of the agents' fingerprint).
TARGET_SPEED_RULE = "wp0-wp1"


def target_speed(waypoints: torch.Tensor, dt: float) -> torch.Tensor:
    """``(B,)`` target speed (m/s) of ``(B, T >= 2, 2)`` waypoints ``dt`` s apart: the mean speed
    between waypoints 0 and 1 (0.5-1 s ahead), not from the ego to waypoint 0 (0-0.5 s). From
    rest the near segment still averages the start: on the default training frames where the
    expert drives off from rest (:func:`~.planner_losses.start_from_rest`; every 5th frame),
    ``|wp0| / dt`` of the expert's own waypoints is 0.67 m/s on average and ``|wp1 - wp0| / dt``
    1.25 m/s (its 3 s mean: 1.97 m/s), so a proportional speed controller fed the former barely
    moves; on moving frames both are within 0.1 m/s of the current speed on average."""
    if waypoints.dim() != 3 or waypoints.shape[1] < 2 or waypoints.shape[2] != 2:
        raise ValueError(f"target_speed: waypoints of shape {tuple(waypoints.shape)}; "
                         "expected (B, >= 2, 2)")
    return (waypoints[:, 1] - waypoints[:, 0]).norm(dim=-1) / dt


class AuroraPolicyNet(nn.Module):
    """Observation tensors -> waypoints (module docstring).

    Args:
        system: the trained :class:`~.system.AuroraSystem` (eval mode).
        tokenizer: its tokenizer. camera_size: the env's ``(width, height)``.
    """

    def __init__(self, system: nn.Module, tokenizer, camera_size: tuple[int, int],
                 say_speed: bool = True) -> None:
        super().__init__()
        self.say_speed = bool(say_speed)  # False: the prompt reads "Ego speed: unknown"
        from v2xbench.agents.devices import module_device

        from .calib import frame_camera_tensors, spec_calib
        from .rsu_agent import message_floats

        self.system, self.tok, self.cfg = system, tokenizer, system.cfg
        self.camera_size = tuple(int(v) for v in camera_size)
        k, c2f = frame_camera_tensors(spec_calib(self.camera_size), "ego", self.camera_size,
                                      self.cfg.image_size("ego"))
        self.register_buffer("intrinsics", k, persistent=False)
        self.register_buffer("cam_to_frame", c2f, persistent=False)
        self.need_floats = message_floats(self.cfg)
        self.to(module_device(system))  # the camera buffers where the model is

    def _message(self, info: np.ndarray, payload: np.ndarray):
        """``(message tensors | None, E_{r->e} | None)`` of one row's received payload."""
        from .rsu_agent import deserialize_message, received_payload, received_pose

        if not self.system.fusion:
            return None, None
        raw = received_payload({"v2x_info": info, "v2x_payload": payload})
        if raw is None:
            return None, None
        return deserialize_message(raw, self.cfg), received_pose(info)

    def forward(self, *args: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``IN_KEYS`` tensors (batched) -> ``(waypoints (B, T, 2), target_speed (B,))``."""
        from .data import model_images
        from .prompt import PLAN_QUESTION, build_prompt
        from .route_input import PATH_KEY, ROUTE_KEY, planner_route_path, planner_route_points
        from .system import MSG_FEATURES

        cams, (ego, route, info, payload) = args[:len(EGO_CAMERA_NAMES)], args[-4:]
        cfg, dev = self.cfg, self.intrinsics.device
        b = ego.shape[0]
        if payload.shape[-1] < self.need_floats and self.system.fusion:
            raise ValueError(f"AURORA: v2x_payload holds {payload.shape[-1]} floats; the roadside "
                             f"message needs {self.need_floats}: evaluate with --set "
                             f"max_payload_floats={self.need_floats}")
        size = cfg.image_size("ego")
        images = torch.stack([torch.stack([model_images(c[i][None], size)[0] for c in cams])
                              for i in range(b)]).to(dev)
        info_np, pay_np = info.cpu().numpy(), payload.cpu().numpy()
        msgs, poses, prompts = [], [], []
        for i in range(b):
            msg, e = self._message(info_np[i], pay_np[i])
            msgs.append(msg)
            poses.append(e)
            said = float(ego[i, SPEED]) if self.say_speed else None
            prompts.append(build_prompt(said, int(round(float(route[i, 0,
                                        COMMAND]))), e, PLAN_QUESTION,
                                        num_det=cfg.num_det_queries,
                                        num_map=cfg.num_map_queries, waypoint=True))
        enc = self.tok(prompts, padding=True, return_tensors="pt")
        has = torch.tensor([m is not None for m in msgs], device=dev)
        batch = {"ego/images": images,
                 "ego/intrinsics": self.intrinsics.expand(b, -1, -1, -1),
                 "ego/cam_to_frame": self.cam_to_frame.expand(b, -1, -1, -1),
                 "input_ids": enc["input_ids"].to(dev),
                 "attention_mask": enc["attention_mask"].to(dev),
                 "command": route[:, 0, COMMAND].round().long().to(dev), "has_rsu": has,
                 ROUTE_KEY: planner_route_points(route.cpu(), cfg).to(dev),
                 "rsu_to_ego": torch.stack([e if e is not None else torch.eye(4)
                                            for e in poses]).to(dev)}
        if cfg.plan_frame == "route":
            batch[PATH_KEY] = planner_route_path(route.cpu(), cfg).to(dev)
        if bool(has.any()):
            like = next(m for m in msgs if m is not None)
            for k in MSG_FEATURES:
                batch[f"msg/{k}"] = torch.cat([m[k] if m is not None else torch.zeros_like(
                    like[k]) for m in msgs]).to(dev)
        out = self.system(batch, plan=True)
        wps = out["plan"]["waypoints"]
        return wps, target_speed(wps, cfg.plan_dt)


def policy_module(system: nn.Module, tokenizer, camera_size: tuple[int, int],
                  say_speed: bool = True) -> TensorDictModule:
    """``TensorDictModule(AuroraPolicyNet(...), in_keys=IN_KEYS, out_keys=OUT_KEYS)``."""
    return TensorDictModule(AuroraPolicyNet(system, tokenizer, camera_size, say_speed),
                            in_keys=IN_KEYS, out_keys=OUT_KEYS)


__all__ = ["IN_KEYS", "OUT_KEYS", "TARGET_SPEED_RULE", "AuroraPolicyNet", "policy_module",
           "target_speed"]
