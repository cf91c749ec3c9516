"""CoDriving in closed loop: the roadside policy (:class:`CoDrivingRoadside`) and the ego's
driver (:class:`CoDrivingDriver`).

- **Roadside**: at a route's start the unit gets the route the ego drives (``reset(route_info)``:
  the ego announces its route, as CoDriving's ego shares its driving intent; no bytes per tick).
  Every tick it serves the ego, :meth:`CoDrivingRoadside.act` takes the ``"rsu"`` agent's
  sensors-mode observation: its LiDAR into its ground frame (V2X-ViT's
  :func:`~..v2x_vit.policy.rsu_lidar_to_ground`); the ego's pose from ``calibration`` (``[0]``
  the unit's world pose, ``[1]`` ``T_ego_rsu``) gives ``E_{r->e}`` (AURORA's
  :func:`~v2xbench.agents.aurora.cqaf.rsu_to_ego`, as in training) and the ego's route rows
  (:func:`~.request.route_ahead`, as the ego's ``route`` observation); from those the request,
  the roadside half's choice of cells, and the message (:func:`~.message.serialize_message`),
  or nothing when no cell is chosen.
- **Ego**: :meth:`CoDrivingDriver.plan` moves the ego LiDAR into the ego frame, reads the
  received cells (``v2x_payload[:payload_length]``) and ``E_{r->e}`` (AURORA's
  :func:`~v2xbench.agents.aurora.rsu_agent.received_pose`); without a message, nothing is
  covered. Its waypoints and AURORA's target speed go to the native controller
  (:mod:`.controller`, in :class:`~.agent.CoDrivingAgent`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping

import numpy as np
import torch
from v2xbench.agents.aurora.cqaf import rsu_to_ego
from v2xbench.agents.aurora.rsu_agent import received_pose
from v2xbench.agents.devices import run_on_module
from v2xbench.envs.v2x_intersection.core.geometry import invert_transform, world_to_local_2d
from v2xbench.envs.v2x_intersection.sensors.lidar import scaled_lidar_specs

from ..common.policy import planning_inputs, received_message, waypoints_and_speed
from ..v2x_vit.data import lidar_points
from ..v2x_vit.policy import rsu_lidar_to_ground
from .config import CoDrivingConfig
from .message import dense_message, deserialize_message, sent_cells, serialize_message
from .request import request_map, route_ahead

UNIT_Z = 3  # rsu_obs["unit"]: unit_id, x, y, z, yaw, pitch


def observed_lidar(obs: Mapping, who: str) -> tuple[np.ndarray, int]:
    """``(padded points (L, 6), count)`` of an observation's ``lidar``; ``ValueError`` naming
    what is missing (evaluate in ``sensors`` mode: the agent declares its LiDAR)."""
    lid = obs.get("lidar")
    if not isinstance(lid, Mapping) or "points" not in lid or "count" not in lid:
        raise ValueError(f"CoDriving: the {who} observation has no lidar points/count (evaluate "
                         "with obs_mode='sensors'; the agent declares its lidar_scale)")
    return np.asarray(lid["points"]), int(np.asarray(lid["count"]))


def ego_pose_of(rsu_obs: Mapping) -> tuple[np.ndarray, np.ndarray]:
    """``(T_world_ego, T_world_rsu)`` (4, 4) of a roadside observation's ``calibration``."""
    cal = np.asarray(rsu_obs["calibration"], np.float64)
    t_world_rsu = cal[0]
    return t_world_rsu @ invert_transform(cal[1]), t_world_rsu


class CoDrivingRoadside:
    """CoDriving's roadside policy (module docstring).

    Args:
        net: the trained :class:`~.model.RoadsideNet`. cfg: its configuration.
        lidar_scale: the env's ``lidar_scale``. checkpoint: weight files.
    """

    def __init__(self, net: torch.nn.Module, cfg: CoDrivingConfig, lidar_scale: float,
                 checkpoint: str | list[str] | None = None) -> None:
        self.net, self.cfg, self.lidar_scale = net.eval(), cfg, float(lidar_scale)
        if checkpoint is not None:
            self.checkpoint = checkpoint
        self.route: np.ndarray | None = None
        self.progress, self.messages, self.silent, self.cells, self.infer_s = 0, 0, 0, 0, 0.0
        self.chosen = 0  # choose() calls since reset: the first sees the env before its step

    def reset(self, route_info: dict) -> None:
        """A new route: the ego's route (``route_points``, world frame), the counters."""
        if "route_points" not in route_info:
            raise ValueError("CoDriving roadside reset: route_info has no route_points (the "
                             "ego's route the request is built from)")
        self.route = np.asarray(route_info["route_points"], np.float64)
        self.progress, self.messages, self.silent, self.cells, self.infer_s = 0, 0, 0, 0, 0.0
        self.chosen = 0

    @torch.no_grad()
    def choose(self, rsu_obs: Mapping) -> tuple[torch.Tensor, torch.Tensor]:
        """``(cells (K, 2), features (K, C))`` the unit sends this tick."""
        if self.route is None:
            raise ValueError("CoDriving roadside: no route (call reset(route_info) first)")
        t0 = time.perf_counter()
        pts, n = observed_lidar(rsu_obs, "roadside")
        t = rsu_lidar_to_ground(float(np.asarray(rsu_obs["unit"])[UNIT_Z]), self.lidar_scale)
        points, mask = lidar_points(pts, n, t)
        t_world_ego, t_world_rsu = ego_pose_of(rsu_obs)
        ego_xy = t_world_ego[:2, 3]
        rows, self.progress = route_ahead(self.route, ego_xy, self.progress, self.cfg,
                                          advance=self.chosen > 0)
        self.chosen += 1
        yaw = math.atan2(t_world_ego[1, 0], t_world_ego[0, 0])
        route = torch.from_numpy(world_to_local_2d(rows, ego_xy, yaw).astype(np.float32))
        e = rsu_to_ego(t_world_ego, t_world_rsu)
        out = run_on_module(self.net, points[None], mask[None],
                            request_map(route[None], e[None], self.cfg))
        self.infer_s += time.perf_counter() - t0
        return sent_cells(out["features"], out["sent"])

    def act(self, rsu_obs: Mapping) -> np.ndarray | None:
        """The message of this tick as a raw payload, or ``None`` when no cell is chosen."""
        cells, feats = self.choose(rsu_obs)
        if len(cells) == 0:
            self.silent += 1
            return None
        self.messages += 1
        self.cells += len(cells)
        return serialize_message(cells, feats, self.cfg)


class CoDrivingDriver:
    """The ego half of a trained :class:`~.model.CoDriving` on one observation (module
    docstring).

    Args:
        ego: the trained :class:`~.model.EgoNet`. cfg: its configuration.
        lidar_scale: the env's ``lidar_scale``. fusion: use the received message.
    """

    def __init__(self, ego: torch.nn.Module, cfg: CoDrivingConfig, lidar_scale: float,
                 fusion: bool = True) -> None:
        self.ego, self.cfg, self.fusion = ego.eval(), cfg, bool(fusion)
        self.t_ego_lidar = scaled_lidar_specs(float(lidar_scale))[0].T_parent_sensor()
        self.need_floats = cfg.message_floats()

    def _message(self, obs: Mapping) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        got = received_message(obs, self.fusion, self.need_floats, "CoDriving",
                               lambda raw: deserialize_message(raw, self.cfg))
        if got is None:
            return (*dense_message(torch.zeros(0, 2, dtype=torch.long),
                                   torch.zeros(0, self.cfg.sent_channels()), self.cfg),
                    torch.eye(4)[None])
        received, sent = dense_message(*got, self.cfg)
        return received, sent, received_pose(np.asarray(obs["v2x_info"], np.float64))[None]

    @torch.no_grad()
    def plan(self, obs: Mapping) -> tuple[np.ndarray, float]:
        """``(waypoints (6, 2) ego frame, target speed m/s)`` of a sensors-mode observation."""
        pts, n = observed_lidar(obs, "ego")
        points, mask = lidar_points(pts, n, self.t_ego_lidar)
        received, sent, e = self._message(obs)
        batch = {"ego/points": points[None], "ego/point_mask": mask[None],
                 **planning_inputs(obs, self.cfg)}
        out = run_on_module(self.ego, batch, received, sent, e)
        return waypoints_and_speed(out["waypoints"], self.cfg)


__all__ = ["CoDrivingDriver", "CoDrivingRoadside", "ego_pose_of", "observed_lidar"]
