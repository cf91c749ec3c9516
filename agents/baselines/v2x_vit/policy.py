"""V2X-ViT in closed loop: the roadside policy (:class:`V2XViTRoadside`) and the ego's driver
(:class:`V2XViTDriver`).

- **Roadside**: every tick a unit serves the ego, the harness hands the ``"rsu"`` agent's
  sensors-mode observation to :meth:`V2XViTRoadside.act`: its LiDAR (``lidar``: ``points`` in the
  sensor frame, ``count``) moves into the unit's ground frame (the LiDAR is level at the unit's
  position and yaw, ``unit[3]`` metres up: :func:`rsu_lidar_to_ground`), the roadside half makes
  its feature map, and the map goes out as a raw payload (:func:`~.message.serialize_message`).
- **Ego**: :meth:`V2XViTDriver.plan` moves the ego LiDAR into the ego frame (the rig's mount,
  :func:`~v2xbench.envs.v2x_intersection.sensors.lidar.scaled_lidar_specs`), reads the received
  map (``v2x_payload[:payload_length]``), ``E_{r->e}`` (AURORA's
  :func:`~v2xbench.agents.aurora.rsu_agent.received_pose`) and the message's age
  (``v2x_info``'s ``age_ticks``); without a message, the empty map. Its waypoints and the target
  speed of AURORA's rule (:func:`~v2xbench.agents.aurora.policy.target_speed`) go to the shared
  waypoint controller.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np
import torch
from v2xbench.agents.aurora.rsu_agent import received_pose
from v2xbench.agents.devices import run_on_module
from v2xbench.envs.v2x_intersection.api.observations import V2X_INFO_FEATURES
from v2xbench.envs.v2x_intersection.core.geometry import pose_matrix
from v2xbench.envs.v2x_intersection.sensors.lidar import scaled_lidar_specs

from ..common.policy import planning_inputs, received_message, waypoints_and_speed
from .config import V2XViTConfig
from .data import lidar_points
from .message import deserialize_message, empty_features, serialize_message

UNIT_Z = 3  # rsu_obs["unit"]: unit_id, x, y, z, yaw, pitch
AGE = V2X_INFO_FEATURES.index("age_ticks")


def observed_lidar(obs: Mapping, who: str) -> tuple[np.ndarray, int]:
    """``(padded points (L, 6), count)`` of an observation's ``lidar``; ``ValueError`` naming
    what is missing (evaluate in ``sensors`` mode: the agent declares its LiDAR)."""
    lid = obs.get("lidar")
    if not isinstance(lid, Mapping) or "points" not in lid or "count" not in lid:
        raise ValueError(f"V2X-ViT: the {who} observation has no lidar points/count (evaluate "
                         "with obs_mode='sensors'; the agent declares its lidar_scale)")
    return np.asarray(lid["points"]), int(np.asarray(lid["count"]))


def rsu_lidar_to_ground(unit_z: float, lidar_scale: float) -> np.ndarray:
    """``(4, 4)``: the unit's LiDAR frame -> its ground frame (the LiDAR's mount in the unit frame,
    the unit ``unit_z`` metres above the ground)."""
    return pose_matrix(0.0, 0.0, float(unit_z), 0.0) @ scaled_lidar_specs(lidar_scale)[1] \
        .T_parent_sensor()


class V2XViTRoadside:
    """V2X-ViT's roadside policy (module docstring).

    Args:
        net: the trained :class:`~.model.RoadsideNet`. cfg: its configuration.
        lidar_scale: the env's ``lidar_scale`` (the LiDAR's mount). checkpoint: weight files.
    """

    def __init__(self, net: torch.nn.Module, cfg: V2XViTConfig, lidar_scale: float,
                 checkpoint: str | list[str] | None = None) -> None:
        self.net, self.cfg, self.lidar_scale = net.eval(), cfg, float(lidar_scale)
        if checkpoint is not None:
            self.checkpoint = checkpoint
        self.messages, self.infer_s = 0, 0.0

    def reset(self, route_info: dict) -> None:
        """A new route: reset the counters."""
        self.messages, self.infer_s = 0, 0.0

    @torch.no_grad()
    def features(self, rsu_obs: Mapping) -> torch.Tensor:
        """The sent map ``(1, C, nx, ny)`` of one roadside observation."""
        t0 = time.perf_counter()
        pts, n = observed_lidar(rsu_obs, "roadside")
        t = rsu_lidar_to_ground(float(np.asarray(rsu_obs["unit"])[UNIT_Z]), self.lidar_scale)
        points, mask = lidar_points(pts, n, t)
        out = run_on_module(self.net, points[None], mask[None])
        self.infer_s += time.perf_counter() - t0
        return out

    def act(self, rsu_obs: Mapping) -> np.ndarray:
        """The message of this tick as a raw payload (:func:`~.message.serialize_message`)."""
        payload = serialize_message(self.features(rsu_obs))
        self.messages += 1
        return payload


class V2XViTDriver:
    """The ego half of a trained :class:`~.model.V2XViT` on one observation (module docstring).

    Args:
        ego: the trained :class:`~.model.EgoNet`. cfg: its configuration.
        lidar_scale: the env's ``lidar_scale``. fusion: use the received message.
    """

    def __init__(self, ego: torch.nn.Module, cfg: V2XViTConfig, lidar_scale: float,
                 fusion: bool = True) -> None:
        self.ego, self.cfg, self.fusion = ego.eval(), cfg, bool(fusion)
        self.t_ego_lidar = scaled_lidar_specs(float(lidar_scale))[0].T_parent_sensor()
        self.need_floats = cfg.message_floats()

    def _message(self, obs: Mapping) -> tuple[torch.Tensor, torch.Tensor, bool, int]:
        sent = received_message(obs, self.fusion, self.need_floats, "V2X-ViT",
                                lambda raw: deserialize_message(raw, self.cfg))
        if sent is None:
            return empty_features(self.cfg, 1), torch.eye(4)[None], False, 0
        info = np.asarray(obs["v2x_info"], np.float64)
        return sent, received_pose(info)[None], True, int(round(info[AGE]))

    @torch.no_grad()
    def plan(self, obs: Mapping) -> tuple[np.ndarray, float]:
        """``(waypoints (6, 2) ego frame, target speed m/s)`` of a sensors-mode observation."""
        pts, n = observed_lidar(obs, "ego")
        points, mask = lidar_points(pts, n, self.t_ego_lidar)
        received, e, has, age = self._message(obs)
        batch = {"ego/points": points[None], "ego/point_mask": mask[None],
                 **planning_inputs(obs, self.cfg)}
        out = run_on_module(self.ego, batch, received, e, torch.tensor([has]),
                            torch.tensor([age]))
        return waypoints_and_speed(out["waypoints"], self.cfg)


__all__ = ["V2XViTDriver", "V2XViTRoadside", "observed_lidar", "rsu_lidar_to_ground"]
