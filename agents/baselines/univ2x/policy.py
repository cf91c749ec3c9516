"""UniV2X in closed loop: the roadside policy (:class:`UniV2XRoadside`) and the ego's driver
(:class:`UniV2XDriver`).

- **Roadside**: every tick a unit serves the ego, the harness hands the ``"rsu"`` agent's
  sensors-mode observation to :meth:`UniV2XRoadside.act`: the roadside half
  (:class:`~.model.RoadsideNet`) runs on the unit's camera (calibration from the rig's camera
  specification and the unit's pose ``calibration[0]``: AURORA's
  :meth:`~v2xbench.agents.aurora.rsu_agent.AuroraRoadside.inputs`), and the message
  (:func:`~.message.rsu_message`) goes out as a raw payload (:func:`~.message.serialize_message`).
- **Ego**: :meth:`UniV2XDriver.plan` runs the ego half on the six ego cameras (calibration from
  the rig's specifications: the observation has none) with the received message
  (``v2x_payload[:payload_length]``, :func:`~.message.deserialize_message`) and ``E_{r->e}`` from
  ``v2x_info`` (AURORA's :func:`~v2xbench.agents.aurora.rsu_agent.received_pose`); without a
  message, the empty one. Its 6 waypoints and the target speed of AURORA's rule
  (:func:`~v2xbench.agents.aurora.policy.target_speed`) go to the shared waypoint controller.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np
import torch
from v2xbench.agents.aurora.calib import frame_camera_tensors, spec_calib
from v2xbench.agents.aurora.data import model_images
from v2xbench.agents.aurora.rsu_agent import AuroraRoadside, received_pose
from v2xbench.agents.devices import run_on_module
from v2xbench.envs.v2x_intersection.sensors import EGO_CAMERA_NAMES

from ..common.policy import planning_inputs, received_message, waypoints_and_speed
from . import message as univ2x_message
from .config import UniV2XConfig


class UniV2XRoadside(AuroraRoadside):
    """UniV2X's roadside policy (module docstring).

    Args:
        net: the trained :class:`~.model.RoadsideNet`. cfg: its configuration.
        camera_size: the env's ``(width, height)``. checkpoint: the weight files it came from.
    """

    #: The method's message module (``rsu_message``, ``serialize_message``).
    wire = univ2x_message

    def __init__(self, net: torch.nn.Module, cfg: UniV2XConfig,
                 camera_size: tuple[int, int] = (128, 64),
                 checkpoint: str | list[str] | None = None) -> None:
        super().__init__(net, cfg.data_config(), camera_size, checkpoint)  # camera geometry
        self.ucfg = cfg

    @torch.no_grad()
    def message(self, rsu_obs: Mapping) -> dict[str, torch.Tensor]:
        """The message tensors (:func:`~.message.rsu_message`, batch 1) of one observation."""
        t0 = time.perf_counter()
        msg = self.wire.rsu_message(run_on_module(self.branch, self.inputs(rsu_obs)), self.ucfg)
        self.infer_s += time.perf_counter() - t0
        return msg

    def act(self, rsu_obs: Mapping) -> np.ndarray:
        """The message of this tick as a raw payload (:func:`~.message.serialize_message`)."""
        payload = self.wire.serialize_message(self.message(rsu_obs))
        self.messages += 1
        return payload


class UniV2XDriver:
    """The ego half of a trained :class:`~.model.UniV2X` on one observation (module docstring).

    Args:
        ego: the trained :class:`~.model.EgoNet` (eval mode). cfg: its configuration.
        camera_size: the env's ``(width, height)``. fusion: use the received message.
    """

    #: The method's name in messages and its message module (``empty_message``,
    #: ``deserialize_message``).
    title, wire = "UniV2X", univ2x_message

    def __init__(self, ego: torch.nn.Module, cfg: UniV2XConfig, camera_size: tuple[int, int],
                 fusion: bool = True) -> None:
        self.ego, self.cfg, self.fusion = ego.eval(), cfg, bool(fusion)
        self.camera_size = tuple(int(v) for v in camera_size)
        k, c2f = frame_camera_tensors(spec_calib(self.camera_size), "ego", self.camera_size,
                                      tuple(cfg.image_size))
        self.intrinsics, self.cam_to_frame = k[None], c2f[None]
        self.need_floats = cfg.message_floats()

    def _message(self, obs: Mapping) -> tuple[dict[str, torch.Tensor], torch.Tensor, bool]:
        msg = received_message(obs, self.fusion, self.need_floats, self.title,
                               lambda raw: self.wire.deserialize_message(raw, self.cfg))
        if msg is None:
            return self.wire.empty_message(self.cfg, 1), torch.eye(4)[None], False
        return msg, received_pose(obs["v2x_info"])[None], True

    @torch.no_grad()
    def plan(self, obs: Mapping) -> tuple[np.ndarray, float]:
        """``(waypoints (6, 2) ego frame, target speed m/s)`` of a sensors-mode observation."""
        cams = obs["cameras"]
        rgb = torch.stack([torch.as_tensor(np.asarray(cams[n]["rgb"])) for n in EGO_CAMERA_NAMES])
        images = model_images(rgb, tuple(self.cfg.image_size))[None]
        msg, e, has = self._message(obs)
        batch = {"ego/images": images, "ego/intrinsics": self.intrinsics,
                 "ego/cam_to_frame": self.cam_to_frame, **planning_inputs(obs, self.cfg)}
        out = run_on_module(self.ego, batch, msg, e, torch.tensor([has]))
        return waypoints_and_speed(out["waypoints"], self.cfg)


__all__ = ["UniV2XDriver", "UniV2XRoadside"]
