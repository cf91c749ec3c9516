"""Sensors of V2XBench: cameras, LiDARs, BEV, calibration and 3D box ground truth.

Everything is built on the 2.5D ray-casting core (:mod:`..raycast`); see DESIGN section 5.

- :class:`SensorRig` / :class:`SensorConfig` (:mod:`.rig`): capture every sensor of a world in one
  call, or one sensor at a time.
- :mod:`.camera`: 6 ego cameras (FOV 110 deg, z 1.8 m) and the RSU camera (FOV 90 deg, pitched):
  RGB, depth (optical-axis metres), semantic and instance images.
- :mod:`.lidar`: ego 360 deg LiDAR (z 2.5 m) and RSU LiDAR (64 ch, 120 deg, 75 m).
- :mod:`.bev`: ego-centred semantic BEV raster.
- :mod:`.calibration`: intrinsics and extrinsics; :mod:`.groundtruth`: ego / RSU / fused boxes.
- :mod:`.semantics`: semantic ids and the instance-id encoding; :mod:`.mosaic`: a video frame.
- Internals: :mod:`.scene` (boxes + looks), :mod:`.ground` (per-town ground raster),
  :mod:`.shading` and :mod:`.textures` (colours, labels, intensity), :mod:`.fan` (ray layouts).
"""

from .bev import BEV_CHANNELS, BevSpec, bev_actor_rows, capture_bev
from .calibration import calibration, project
from .camera import (
    EGO_CAMERA_NAMES,
    CameraSpec,
    ego_camera_specs,
    render_camera,
    render_cameras,
    rsu_camera_spec,
)
from .fan import unoccluded_pixels
from .ground import GroundRaster, ground_raster
from .groundtruth import (
    JOINT_MIN_POINTS,
    MIN_LIDAR_POINTS,
    MIN_PIXELS,
    boxes_in_frame,
    ground_truth,
)
from .lidar import POINT_FIELDS, LidarSpec, capture_lidar, ego_lidar_spec, rsu_lidar_spec
from .mosaic import mosaic
from .rig import SensorConfig, SensorRig
from .scene import Scene, build_scene
from .semantics import (
    INSTANCE_NONE,
    NUM_SEMANTIC,
    SEMANTIC_COLORS,
    SEMANTIC_NAMES,
    STATIC_INSTANCE_OFFSET,
    decode_instance,
)

__all__ = [
    "BEV_CHANNELS",
    "EGO_CAMERA_NAMES",
    "INSTANCE_NONE",
    "JOINT_MIN_POINTS",
    "MIN_LIDAR_POINTS",
    "MIN_PIXELS",
    "NUM_SEMANTIC",
    "POINT_FIELDS",
    "SEMANTIC_COLORS",
    "SEMANTIC_NAMES",
    "STATIC_INSTANCE_OFFSET",
    "BevSpec",
    "CameraSpec",
    "GroundRaster",
    "LidarSpec",
    "Scene",
    "SensorConfig",
    "SensorRig",
    "boxes_in_frame",
    "build_scene",
    "calibration",
    "bev_actor_rows",
    "capture_bev",
    "capture_lidar",
    "decode_instance",
    "ego_camera_specs",
    "ego_lidar_spec",
    "ground_raster",
    "ground_truth",
    "mosaic",
    "project",
    "render_camera",
    "render_cameras",
    "rsu_camera_spec",
    "rsu_lidar_spec",
    "unoccluded_pixels",
]
