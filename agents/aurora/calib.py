"""Camera calibration as tensors: the one home for AURORA's camera geometry and branch frames.

Both sources give the same numbers: recorded frames of the data set (``calib/*``,
:mod:`v2xbench.collectors.dataset.record`) and, in closed loop, the sensor rig
(:func:`v2xbench.envs.v2x_intersection.sensors.calibration`). Both already use the OpenCV
optical convention (x right, y down, z forward; ``K @ p`` projects a point), so nothing is
flipped here (checked by ``tests/test_aurora_data.py``: a ground-truth box centre projects onto
its own actor's pixels of the rig's instance image).

Branch frames (``x`` forward, ``y`` left, ``z`` up, metres):

- ``ego``: the ego frame (box centre on the ground, ``calib/T_world_ego``);
- ``rsu``: the roadside unit's *ground* frame: origin at the foot of the unit's pole (``z = 0``
  on the ground), ``x`` along the unit's heading (its yaw), no pitch or roll
  (:func:`rsu_ground_pose`). The unit's 5 m height, 12 deg pitch and 1 deg roll stay in the
  camera's ``cam_to_frame``; a level frame keeps the perception range's ``z`` band on the
  ground at every distance and yaw a ground heading, as in the ego frame.

``cam_to_frame`` maps the camera optical frame to the branch frame; ``intrinsics`` are pixel
intrinsics for the image size the model sees (scaled when images are resized).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from v2xbench.envs.v2x_intersection.core.geometry import invert_transform
from v2xbench.envs.v2x_intersection.sensors import EGO_CAMERA_NAMES, boxes_in_frame

from .config import check_branch

RSU_CAMERA = "rsu_cam"
#: Rows of ``calib/cam_intrinsics`` / ``calib/T_ego_cam`` per branch (the record's camera order).
CAMERA_ROWS = {"ego": tuple(range(len(EGO_CAMERA_NAMES))), "rsu": (len(EGO_CAMERA_NAMES),)}
CAMERA_NAMES = {"ego": tuple(EGO_CAMERA_NAMES), "rsu": (RSU_CAMERA,)}


def _np(x) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def rsu_ground_pose(t_world_rsu: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` ``T_world_rsuground``: the unit's position on the ground, its yaw only."""
    t = np.asarray(t_world_rsu, np.float64)
    yaw = np.arctan2(t[..., 1, 0], t[..., 0, 0])  # Rz(yaw) Ry(pitch) Rx(roll): x axis heading
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros(t.shape)
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    out[..., 2, 2] = out[..., 3, 3] = 1.0
    out[..., 0, 3], out[..., 1, 3] = t[..., 0, 3], t[..., 1, 3]
    return out


def world_frame_pose(calib: Mapping, branch: str) -> np.ndarray:
    """``(4, 4)`` ``T_world_frame`` of the branch frame of a recorded frame's ``calib``."""
    if check_branch(branch) == "ego":
        return np.asarray(_np(calib["T_world_ego"]), np.float64)
    return rsu_ground_pose(_np(calib["T_world_rsu"]))


def ego_frame_pose(calib: Mapping, branch: str) -> np.ndarray:
    """``(4, 4)`` ``T_ego_frame`` (branch frame -> ego frame) of a recorded frame's ``calib``."""
    if check_branch(branch) == "ego":
        return np.eye(4)
    t_world_rsu = np.asarray(_np(calib["T_world_rsu"]), np.float64)
    t_rsu_ground = invert_transform(t_world_rsu) @ rsu_ground_pose(t_world_rsu)
    return np.asarray(_np(calib["T_ego_rsu"]), np.float64) @ t_rsu_ground


def scale_intrinsics(k: np.ndarray, src_size: tuple[int, int],
                     dst_size: tuple[int, int]) -> np.ndarray:
    """Intrinsics ``(..., 3, 3)`` of images resized from ``src_size`` to ``dst_size``
    (``(width, height)``; continuous pixel coordinates scale with the image)."""
    sx, sy = dst_size[0] / src_size[0], dst_size[1] / src_size[1]
    out = np.array(k, np.float64, copy=True)
    out[..., 0, :] *= sx
    out[..., 1, :] *= sy
    return out


def camera_tensors(intrinsics: np.ndarray, t_ego_cam: np.ndarray, t_ego_frame: np.ndarray,
                   src_size: tuple[int, int], dst_size: tuple[int, int] | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(intrinsics (N, 3, 3), cam_to_frame (N, 4, 4))`` float32 tensors.

    Args:
        intrinsics: ``(N, 3, 3)`` pixel intrinsics at ``src_size``.
        t_ego_cam: ``(N, 4, 4)`` camera optical frame -> ego frame.
        t_ego_frame: ``(4, 4)`` branch frame -> ego frame.
        src_size, dst_size: ``(width, height)`` of the recorded and the model's images.
    """
    k = np.asarray(intrinsics, np.float64)
    if dst_size is not None and tuple(dst_size) != tuple(src_size):
        k = scale_intrinsics(k, src_size, dst_size)
    c2f = invert_transform(np.asarray(t_ego_frame, np.float64)) @ np.asarray(t_ego_cam, np.float64)
    return torch.from_numpy(k.astype(np.float32)), torch.from_numpy(c2f.astype(np.float32))


def frame_camera_tensors(calib: Mapping, branch: str, src_size: tuple[int, int],
                         dst_size: tuple[int, int] | None = None
                         ) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`camera_tensors` of a recorded frame's ``calib`` (``cam_intrinsics``, ``T_ego_cam``,
    ``T_ego_rsu``, ``T_world_rsu``) for the branch's cameras."""
    rows = list(CAMERA_ROWS[check_branch(branch)])
    return camera_tensors(_np(calib["cam_intrinsics"])[rows], _np(calib["T_ego_cam"])[rows],
                          ego_frame_pose(calib, branch), src_size, dst_size)


def rig_calib(cal: Mapping) -> dict:
    """The record's ``calib`` layout from a closed-loop rig calibration
    (:func:`v2xbench.envs.v2x_intersection.sensors.calibration`): the same matrices the data
    set stores, so :func:`frame_camera_tensors` serves both. Raises ``ValueError`` naming a
    camera the rig lacks."""
    names = (*EGO_CAMERA_NAMES, RSU_CAMERA)
    missing = [n for n in names if n not in cal]
    if missing:
        raise ValueError(f"rig_calib: the rig calibration has no camera {missing}")
    return {
        "T_world_ego": np.asarray(cal["T_world_ego"], np.float64),
        "T_world_rsu": np.asarray(cal["T_world_rsu"], np.float64),
        "T_ego_rsu": np.asarray(cal["T_ego_rsu"], np.float64),
        "rsu_unit": np.array(cal["rsu_unit"], np.int64),
        "cam_intrinsics": np.stack([np.asarray(cal[n]["intrinsics"], np.float64) for n in names]),
        "T_ego_cam": np.stack([np.asarray(cal[n]["T_ego_sensor"], np.float64) for n in names]),
        "image_size": {n: (int(cal[n]["width"]), int(cal[n]["height"])) for n in names},
    }


def spec_calib(camera_size: tuple[int, int], t_world_rsu: np.ndarray | None = None,
               rsu_unit: int = -1) -> dict:
    """The record's ``calib`` layout of the closed-loop sensor rig built from the cameras'
    specifications alone (no world): what an agent, which observes images but no calibration,
    knows about its own rig. ``camera_size`` is the env's ``(width, height)``; the ego frame is
    the identity and ``t_world_rsu`` (``(4, 4)``, e.g. ``calibration[0]`` of the roadside unit's
    observation) places the unit's camera. Gives the same matrices as :func:`rig_calib` of the
    rig's calibration (``tests/test_aurora_policy.py``)."""
    from v2xbench.envs.v2x_intersection.sensors.camera import ego_camera_specs, rsu_camera_spec
    from v2xbench.envs.v2x_intersection.sim.world import EGO_LENGTH, EGO_WIDTH

    w, h = (int(v) for v in camera_size)
    specs = {s.name: s for s in ego_camera_specs(w, h, EGO_LENGTH, EGO_WIDTH)}
    t_wr = np.eye(4) if t_world_rsu is None else np.asarray(_np(t_world_rsu), np.float64)
    if t_wr.shape != (4, 4):
        raise ValueError(f"spec_calib: t_world_rsu has shape {t_wr.shape}; expected (4, 4)")
    rsu = rsu_camera_spec(w, h)
    cams = [specs[n] for n in EGO_CAMERA_NAMES]
    return {
        "T_world_ego": np.eye(4), "T_world_rsu": t_wr, "T_ego_rsu": t_wr.copy(),
        "rsu_unit": np.array(int(rsu_unit), np.int64),
        "cam_intrinsics": np.stack([c.intrinsics for c in cams] + [rsu.intrinsics]),
        "T_ego_cam": np.stack([c.T_parent_optical() for c in cams]
                              + [t_wr @ rsu.T_parent_optical()]),
        "image_size": {n: (w, h) for n in (*EGO_CAMERA_NAMES, RSU_CAMERA)},
    }


def boxes_to_frame(boxes: np.ndarray, t_frame_ego: np.ndarray) -> np.ndarray:
    """Ego-frame boxes ``(M, 9)`` ``x, y, z, l, w, h, yaw, vx, vy`` in another frame
    (:func:`~v2xbench.envs.v2x_intersection.sensors.boxes_in_frame`: centres transformed,
    headings and velocities rotated)."""
    b = np.asarray(boxes, np.float64).reshape(-1, 9)
    moved = boxes_in_frame({"center": b[:, :3], "yaw": b[:, 6],
                            "velocity": np.c_[b[:, 7:9], np.zeros(len(b))]},
                           np.asarray(t_frame_ego, np.float64))
    return np.c_[moved["center"], b[:, 3:6], moved["yaw"], moved["velocity"][:, :2]]


def project_points(points: np.ndarray, intrinsics: np.ndarray,
                   cam_to_frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Branch-frame points ``(M, 3)`` into one camera: ``(uv (M, 2) pixels, depth (M,))``
    (``depth <= 0``: behind the camera)."""
    t = invert_transform(np.asarray(cam_to_frame, np.float64))
    p = np.asarray(points, np.float64).reshape(-1, 3) @ t[:3, :3].T + t[:3, 3]
    uvw = p @ np.asarray(intrinsics, np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[:, :2] / uvw[:, 2:3]
    return uv, p[:, 2]


__all__ = ["CAMERA_NAMES", "CAMERA_ROWS", "RSU_CAMERA", "boxes_to_frame", "camera_tensors",
           "ego_frame_pose", "frame_camera_tensors", "project_points", "rig_calib",
           "rsu_ground_pose", "scale_intrinsics", "spec_calib", "world_frame_pose"]
