"""Calibration of every sensor: intrinsics and extrinsics, the way a dataset ships them.

Frames (``T_a_b`` maps points in frame ``b`` to frame ``a``, ``geometry`` convention):

- ``world``; ``ego``: the ego actor frame (origin at its box centre on the ground, x forward,
  y left, z up) = ``pose_matrix(x, y, 0, yaw)`` of ``world.table`` row 0;
- ``rsu``: the active unit's body frame ``world.rsus.matrix(u)`` (5 m up, yaw, pitched down by
  ``rsu.RSU_PITCH``, rolled by ``rsu.RSU_ROLL``);
- camera sensors: their **optical** frame (x right, y down, z forward), so that
  ``K @ (T_cam_parent @ p)[:3]`` projects a point; LiDAR sensors: their level sensor frame
  (x along the sensor's yaw, y left, z up; :mod:`.lidar`).

:func:`calibration` returns::

    {
      "T_world_ego": (4, 4), "rsu_unit": int (-1: none), "T_world_rsu": (4, 4),
      "T_ego_rsu": (4, 4) = geometry.relative_transform(T_world_ego, T_world_rsu),
      <sensor name>: {
          "parent": "ego" | "world",
          "extrinsics": (4, 4) sensor -> parent (ego sensors: -> ego; RSU sensors: -> world),
          "T_world_sensor": (4, 4), "T_ego_sensor": (4, 4),
          "intrinsics": (3, 3)  (cameras only), "width", "height" (cameras only),
      }, ...
    }

All matrices are float64. Without an active RSU, ``T_world_rsu`` and the RSU sensors' matrices
are identities and ``rsu_unit`` is -1.
"""

from __future__ import annotations

import numpy as np

from ..core.geometry import pose_matrix, relative_transform
from .camera import CameraSpec, ego_camera_specs, rsu_camera_spec
from .lidar import LidarSpec, ego_lidar_spec, rsu_lidar_spec


def ego_pose(world) -> np.ndarray:
    """``(4, 4)`` ``T_world_ego`` (ego box centre on the ground, x forward)."""
    t = world.table
    return pose_matrix(float(t.pos[0, 0]), float(t.pos[0, 1]), 0.0, float(t.yaw[0]))


def active_unit(world, slot: int = 0) -> int:
    """Index of the active RSU in ``slot`` (-1: none)."""
    if len(world.rsus) == 0 or len(world.active_rsu) <= slot:
        return -1
    return int(world.active_rsu[slot])


def rsu_pose(world, unit: int) -> np.ndarray:
    """``(4, 4)`` ``T_world_rsu`` of ``unit`` (identity for -1)."""
    return world.rsus.matrix(unit) if unit >= 0 else np.eye(4)


def rsu_lidar_pose(world, unit: int, spec: LidarSpec) -> np.ndarray:
    """``(4, 4)`` ``T_world_lidar`` of the RSU's level LiDAR (no pitch or roll)."""
    if unit < 0:
        return np.eye(4)
    x, y, z, yaw = (float(v) for v in world.rsus.pose[unit])
    return pose_matrix(x, y, z, yaw) @ spec.T_parent_sensor()


_DEFAULT = object()


def calibration(
    world,
    ego_cameras=_DEFAULT,
    ego_lidar=_DEFAULT,
    rsu_camera=_DEFAULT,
    rsu_lidar=_DEFAULT,
    slot: int = 0,
) -> dict:
    """Intrinsics and extrinsics of every sensor (layout in the module docstring).

    Args:
        world: a :class:`~..world.World` after ``reset``.
        ego_cameras: tuple of :class:`.camera.CameraSpec` (mounts in the ego frame); default:
            the six default ego cameras.
        ego_lidar: :class:`.lidar.LidarSpec` or ``None`` (off); default: the default ego LiDAR.
        rsu_camera, rsu_lidar: sensors of the active RSU (mounts in the unit frame), or
            ``None``; default: the default RSU camera and LiDAR.
        slot: which active-RSU slot (``world.active_rsu``).

    Returns:
        The calibration dict (``SensorRig.calibration`` passes its own sensors).
    """
    if ego_cameras is _DEFAULT:
        ego_cameras = ego_camera_specs()
    if ego_lidar is _DEFAULT:
        ego_lidar = ego_lidar_spec()
    if rsu_camera is _DEFAULT:
        rsu_camera = rsu_camera_spec()
    if rsu_lidar is _DEFAULT:
        rsu_lidar = rsu_lidar_spec()
    ego_cameras = ego_cameras or ()
    t_we = ego_pose(world)
    unit = active_unit(world, slot)
    t_wr = rsu_pose(world, unit)
    t_ew = np.linalg.inv(t_we)
    out: dict = {
        "T_world_ego": t_we,
        "rsu_unit": unit,
        "T_world_rsu": t_wr,
        "T_ego_rsu": relative_transform(t_we, t_wr),
    }

    def put(name: str, parent: str, ext: np.ndarray, t_ws: np.ndarray, cam: CameraSpec | None):
        entry = {
            "parent": parent,
            "extrinsics": ext.copy(),
            "T_world_sensor": t_ws,
            "T_ego_sensor": t_ew @ t_ws,
        }
        if cam is not None:
            entry.update(intrinsics=cam.intrinsics.copy(), width=cam.width, height=cam.height)
        out[name] = entry

    for cam in ego_cameras:
        ext = cam.T_parent_optical()
        put(cam.name, "ego", ext, t_we @ ext, cam)
    if ego_lidar is not None:
        ext = ego_lidar.T_parent_sensor()
        put(ego_lidar.name, "ego", ext, t_we @ ext, None)
    if rsu_camera is not None:
        t_ws = t_wr @ rsu_camera.T_parent_optical() if unit >= 0 else np.eye(4)
        put(rsu_camera.name, "world", t_ws, t_ws, rsu_camera)
    if rsu_lidar is not None:
        t_ws = rsu_lidar_pose(world, unit, rsu_lidar)
        put(rsu_lidar.name, "world", t_ws, t_ws, None)
    return out


def project(calib_entry: dict, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into a camera with its calibration entry (``K``, ``T_world_sensor``).

    Args:
        calib_entry: a camera's entry of :func:`calibration`.
        points_world: ``(M, 3)`` points (m).

    Returns:
        ``(uv (M, 2) continuous pixel coordinates, z (M,) optical-axis depth in m)``; points
        with ``z <= 0`` are behind the camera.
    """
    t_cw = np.linalg.inv(calib_entry["T_world_sensor"])
    p = np.asarray(points_world, np.float64) @ t_cw[:3, :3].T + t_cw[:3, 3]
    z = p[:, 2]
    uvw = p @ calib_entry["intrinsics"].T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[:, :2] / uvw[:, 2:3]
    return uv, z


__all__ = ["active_unit", "calibration", "ego_pose", "project", "rsu_lidar_pose", "rsu_pose"]
