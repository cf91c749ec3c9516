"""Spinning LiDARs on the 2.5D ray caster: points with intensity, semantic and instance ids.

A LiDAR is level (no pitch or roll): ``channels`` elevations evenly spaced over ``vfov_deg``
(both ends included) times ``azimuth_steps`` azimuths, one :func:`..raycast.first_hit_fan` call.
Azimuths: ``360`` deg sensors start at 0 (straight ahead) and go counter-clockwise in steps of
``360 / azimuth_steps``; narrower ones are centred on the sensor's x axis (``-hfov/2 + (i + 0.5) *
hfov / steps``). A return counts when its 3D range is at most ``max_range``.

Sensor frame: origin at the sensor, x along its yaw, y left, z up (level). The RSU LiDAR is
mounted level at the unit's position and yaw (5 m up); its asymmetric vertical field of view
[-45, 15] deg (paper) already looks down on the road, so it needs no pitch (which also keeps it a
fast fan). The RSU *camera* is pitched (``rsu.RSU_PITCH``); see :mod:`.calibration` for both
extrinsics.

Output of :func:`capture_lidar` (``P`` returns, ``L = max_points``):

- ``points`` float32 ``(P, 6)``: x, y, z (m, sensor frame), intensity in ``[0, 1]``
  (:func:`.shading.lidar_returns`: reflectivity x ``|cos incidence|``), semantic id, instance id
  (ids are exact in float32, see :mod:`.semantics`), ordered channel-major (top channel first)
  then by azimuth;
- ``padded`` float32 ``(L, 6)``: ``points`` followed by zero rows; ``count`` int: ``P``
  (``P <= L = channels * azimuth_steps`` always, nothing is dropped);
- ``range_image`` float32 ``(channels, azimuth_steps)``: 3D range (m), 0 for no return.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..core.geometry import memo_matrix, pose_matrix
from ..core.jit import HAVE_JIT
from ..core.raycast import GROUND, NO_HIT, first_hit_fan
from .ground import GroundRaster
from .kernels import lidar_points_kernel
from .scene import Scene
from .semantics import CLASS_REFLECTIVITY, M_TERRAIN, MATERIAL_REFLECTIVITY, MATERIAL_SEMANTIC
from .shading import lidar_returns

POINT_FIELDS = ("x", "y", "z", "intensity", "semantic", "instance")


@dataclass(frozen=True)
class LidarSpec:
    """A level spinning LiDAR and its mount in its parent frame (ego frame or RSU unit frame).

    Attributes:
        name: sensor name. channels: number of elevations. azimuth_steps: azimuths per sweep.
        hfov_deg: horizontal field of view (360 for a full sweep). vfov_deg: (lowest, highest)
            elevation (deg). max_range: farthest return (m, 3D).
        x, y, z: mount position in the parent frame (m). yaw: mount yaw (rad).
    """

    name: str
    channels: int = 32
    azimuth_steps: int = 360
    hfov_deg: float = 360.0
    vfov_deg: tuple[float, float] = (-25.0, 10.0)
    max_range: float = 70.0
    x: float = 0.0
    y: float = 0.0
    z: float = 2.5
    yaw: float = 0.0

    @property
    def max_points(self) -> int:
        """Rows of the padded point array (one per ray)."""
        return self.channels * self.azimuth_steps

    def azimuths(self) -> np.ndarray:
        """``(A,)`` azimuths relative to the sensor's x axis (rad)."""
        n, h = self.azimuth_steps, np.deg2rad(self.hfov_deg)
        if self.hfov_deg >= 360.0:
            return np.arange(n) * (2 * np.pi / n)
        return -h / 2 + (np.arange(n) + 0.5) * (h / n)

    def elevations(self) -> np.ndarray:
        """``(E,)`` elevations (rad), top channel first."""
        lo, hi = self.vfov_deg
        return np.deg2rad(np.linspace(hi, lo, self.channels))

    def T_parent_sensor(self) -> np.ndarray:
        """``(4, 4)`` sensor frame -> parent frame (read-only, computed once)."""
        return memo_matrix(
            self, "_T_parent_sensor", lambda: pose_matrix(self.x, self.y, self.z, self.yaw)
        )


def ego_lidar_spec(
    channels: int = 32, azimuth_steps: int = 360, max_range: float = 70.0
) -> LidarSpec:
    """Ego roof LiDAR: 360 deg, vertical FOV [-25, 10] deg, z 2.5 m above the ego centre."""
    return LidarSpec("lidar", channels, azimuth_steps, 360.0, (-25.0, 10.0), max_range, z=2.5)


def rsu_lidar_spec(
    channels: int = 64, azimuth_steps: int = 240, max_range: float = 75.0
) -> LidarSpec:
    """RSU LiDAR (paper): 64 channels, 120 deg HFOV, [-45, 15] deg VFOV, 75 m, at the unit's
    origin (5 m up), level (``z`` is 0 in the unit frame's origin; the unit is 5 m up)."""
    return LidarSpec("rsu_lidar", channels, azimuth_steps, 120.0, (-45.0, 15.0), max_range, z=0.0)


def scaled_lidar_specs(scale: float = 1.0) -> tuple[LidarSpec, LidarSpec]:
    """The ego and the RSU LiDAR at ``scale`` x the default channels and azimuths
    (``EnvConfig.lidar_scale``; at least 4 channels and 16 azimuths; ``1.0``: the defaults)."""
    return (ego_lidar_spec(max(4, round(32 * scale)), max(16, round(360 * scale))),
            rsu_lidar_spec(max(4, round(64 * scale)), max(16, round(240 * scale))))


def capture_lidar(
    scene: Scene,
    ground: GroundRaster,
    spec: LidarSpec,
    t_world_sensor: np.ndarray,
    exclude: np.ndarray | None = None,
) -> dict[str, np.ndarray | int]:
    """One sweep of a level LiDAR.

    Args:
        scene: boxes and their looks (:func:`.scene.build_scene`).
        ground: the town's ground raster.
        spec: the LiDAR.
        t_world_sensor: ``(4, 4)`` sensor frame -> world; must be level (only its yaw is used).
        exclude: box indices the LiDAR does not see (e.g. ``[0]``, the ego's own box).

    Returns:
        dict with ``points``, ``padded``, ``count``, ``range_image`` (module docstring).
    """
    o = t_world_sensor[:3, 3].astype(np.float64)
    yaw = float(np.arctan2(t_world_sensor[1, 0], t_world_sensor[0, 0]))
    az, k, norm, cs, max_t32, k32 = _rays(spec)
    half = np.pi if spec.hfov_deg >= 360.0 else np.deg2rad(spec.hfov_deg) / 2 + 0.01
    a = yaw + az
    c, s = np.float32(np.cos(yaw)), np.float32(np.sin(yaw))
    if HAVE_JIT:
        t, j, sel = scene.cast_fan(o, yaw, half, spec.max_range, exclude, None, a, k32, max_t32)
        pts, rng = lidar_points_kernel(
            t, j, sel, k32, bool(o[2] >= 0), np.float32(o[2]), max_t32, k, norm, cs, c,
            s, np.float32(o[0]), np.float32(o[1]), NO_HIT, GROUND, scene.geo, scene.normals, scene.sem, scene.inst,
            CLASS_REFLECTIVITY, ground.code, np.float32(ground.xmin), np.float32(ground.ymin),
            np.float32(1.0 / ground.mpp), M_TERRAIN, MATERIAL_SEMANTIC, MATERIAL_REFLECTIVITY)
    else:
        sel = scene.cull(o, yaw, half, spec.max_range, exclude)
        dirs_h = np.stack([np.cos(a), np.sin(a)], -1)
        t, idx = first_hit_fan(o, dirs_h, k, scene.boxes.subset(sel), max_t=spec.max_range / norm[:, None])
        e_i, a_i = np.nonzero(idx != NO_HIT)
        idx = idx[e_i, a_i]
        if len(sel):
            idx = np.where(idx >= 0, sel[np.maximum(idx, 0)], idx)
        th = t[e_i, a_i]
        kk, nn = k[e_i].astype(np.float32), norm[e_i].astype(np.float32)
        ca, sa = cs[a_i, 0], cs[a_i, 1]
        pts = np.empty((len(e_i), 6), np.float32)
        pts[:, 0], pts[:, 1], pts[:, 2] = th * ca, th * sa, th * kk
        dw = np.empty((len(e_i), 3), np.float32)
        dw[:, 0], dw[:, 1], dw[:, 2] = (c * ca - s * sa) / nn, (s * ca + c * sa) / nn, kk / nn
        pw = np.empty_like(dw)
        pw[:, 0] = c * pts[:, 0] - s * pts[:, 1] + np.float32(o[0])
        pw[:, 1] = s * pts[:, 0] + c * pts[:, 1] + np.float32(o[1])
        pw[:, 2] = pts[:, 2] + np.float32(o[2])
        pts[:, 3], pts[:, 4], pts[:, 5] = lidar_returns(scene, ground, pw, dw, idx)
        rng = np.zeros(t.shape, np.float32)
        rng[e_i, a_i] = th * nn
    padded = np.zeros((spec.max_points, 6), np.float32)
    padded[: len(pts)] = pts
    return {"points": pts, "padded": padded, "count": len(pts), "range_image": rng}


@functools.lru_cache(maxsize=32)
def _rays(spec: LidarSpec) -> tuple[np.ndarray, ...]:
    """Azimuths (A,), slopes (E,), 3D length per horizontal metre (E,), (A, 2) float32 cos/sin,
    and, ``(E, A)`` contiguous float32, the range cut as horizontal distance and the slopes."""
    az = spec.azimuths()
    k = np.tan(spec.elevations())
    cs = np.stack([np.cos(az), np.sin(az)], -1).astype(np.float32)
    norm = np.sqrt(1.0 + k * k)
    max_t = np.broadcast_to(np.asarray(spec.max_range / norm[:, None], np.float32), (len(k), len(az)))
    k32 = np.ascontiguousarray(np.broadcast_to(k[:, None], (len(k), len(az))), np.float32)
    return az, k, norm, cs, np.ascontiguousarray(max_t), k32


def blank_lidar(spec: LidarSpec) -> dict[str, np.ndarray | int]:
    """Outputs of a LiDAR with no returns (no active RSU)."""
    return {
        "points": np.zeros((0, 6), np.float32),
        "padded": np.zeros((spec.max_points, 6), np.float32),
        "count": 0,
        "range_image": np.zeros((spec.channels, spec.azimuth_steps), np.float32),
    }


__all__ = [
    "POINT_FIELDS",
    "LidarSpec",
    "blank_lidar",
    "capture_lidar",
    "ego_lidar_spec",
    "scaled_lidar_specs",
    "rsu_lidar_spec",
]
