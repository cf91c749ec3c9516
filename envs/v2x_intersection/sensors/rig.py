"""The sensor rig: every ego and RSU sensor of a world, captured in one call.

:class:`SensorRig` holds a :class:`SensorConfig` (which sensors, at what resolution) and captures
a frame from a :class:`~..world.World` after ``reset`` or ``step``::

    rig = SensorRig()                      # defaults: 6 + 1 cameras 128 x 64, 2 LiDARs, BEV, GT
    frame = rig.capture(world)
    frame["cameras"]["cam_front"]["rgb"]   # (64, 128, 3) uint8
    frame["lidars"]["rsu_lidar"]["padded"] # (15360, 6) float32, frame["lidars"][...]["count"]

Frame layout (:meth:`SensorRig.capture`)::

    {
      "tick": int, "rsu_unit": int (-1: no active RSU),
      "cameras": {name: {"rgb", "depth", "semantic", "instance"}}  (ego cameras + "rsu_cam";
                  the images of ``SensorConfig.images``, no cameras when it is empty),
      "lidars": {"lidar": {...}, "rsu_lidar": {...}}  (:mod:`.lidar`),
      "bev": (C, H, W) uint8  (:mod:`.bev`),
      "calibration": {...}  (:mod:`.calibration`; absent with ``calibration=False``),
      "gt": {"boxes", "ego", "rsu", "fused", "joint"}  (:mod:`.groundtruth`),
    }

Sensors switched off in the config are absent from the frame, and so are images not in
``SensorConfig.images`` (they are not rendered either: ``camera.render_camera_jobs``). Every
capture method can be called
alone (for per-sensor timing); each takes an optional :class:`.scene.Scene` so that one capture
builds the scene once. The RSU sensors use the active unit of slot 0 (``world.active_rsu[0]``);
without one they return blank outputs of the same shapes. :meth:`SensorRig.observation_space` and
:meth:`SensorRig.observation` give the fixed Gymnasium layout (padded point arrays + counts).

Defaults (chosen for CPU training): cameras 128 x 64 (2:1 as the paper's 1024 x 512; enough to
read lanes, vehicles and pedestrians to ~40 m and a signal lamp: >= 4 lamp pixels from 6 to 20 m
ahead, visible to ~25 m), far clip 150 m; ego LiDAR 32 x 360 (1 deg) to 70 m; RSU LiDAR 64 x 240
(0.5 deg over 120 deg) to 75 m; BEV 128 x 128 at 0.5 m.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.actors import EGO_LENGTH, EGO_WIDTH
from ..sim.config import MAX_CAMERA_SIDE, MIN_CAMERA_SIDE
from .bev import BEV_CHANNELS, BevSpec, capture_bev
from .calibration import active_unit, calibration, ego_pose, rsu_lidar_pose, rsu_pose
from .camera import (
    DEFAULT_FAR,
    DEFAULT_SIZE,
    EGO_CAMERA_NAMES,
    IMAGES,
    CameraSpec,
    blank_camera,
    ego_camera_specs,
    render_camera,
    render_camera_jobs,
    render_cameras,
    rsu_camera_spec,
)
from .fan import unoccluded_pixels_many
from .ground import GROUND_MPP, ground_raster
from .groundtruth import ground_truth
from .lidar import LidarSpec, blank_lidar, capture_lidar, ego_lidar_spec, rsu_lidar_spec
from .scene import Scene, build_scene
from .semantics import NUM_SEMANTIC

_EGO = np.array([0])  # the ego's own box: ego sensors look through it


@dataclass(frozen=True)
class SensorConfig:
    """Which sensors a :class:`SensorRig` captures and how.

    Attributes:
        camera_size: ``(width, height)`` of the ego cameras (pixels).
        ego_cameras: names of the ego cameras to capture (subset of ``EGO_CAMERA_NAMES``).
        rsu_camera_size: ``(width, height)`` of the RSU camera; ``None`` switches it off.
        rsu_oversample: virtual-fan density of the pitched RSU camera (:mod:`.camera`).
        far: far clip of all cameras (m).
        ego_lidar, rsu_lidar: LiDAR specs; ``None`` switches one off.
        bev: BEV spec; ``None`` switches it off.
        calibration: put the sensors' calibration in the frame.
        groundtruth: compute the three box sets.
        ground_mpp: ground raster resolution (m per pixel).
        images: the images every camera renders (subset of ``camera.IMAGES``; ``()``: no
            camera is rendered). ``groundtruth`` needs ``instance``.
    """

    camera_size: tuple[int, int] = DEFAULT_SIZE
    ego_cameras: tuple[str, ...] = EGO_CAMERA_NAMES
    rsu_camera_size: tuple[int, int] | None = DEFAULT_SIZE
    rsu_oversample: float = 1.0
    far: float = DEFAULT_FAR
    ego_lidar: LidarSpec | None = field(default_factory=ego_lidar_spec)
    rsu_lidar: LidarSpec | None = field(default_factory=rsu_lidar_spec)
    bev: BevSpec | None = field(default_factory=BevSpec)
    calibration: bool = True
    groundtruth: bool = True
    ground_mpp: float = GROUND_MPP
    images: tuple[str, ...] = IMAGES

    def __post_init__(self) -> None:
        unknown = set(self.ego_cameras) - set(EGO_CAMERA_NAMES)
        if unknown:
            raise ValueError(
                f"SensorConfig: unknown ego cameras {sorted(unknown)}; known: {EGO_CAMERA_NAMES}"
            )
        for name in ("camera_size", "rsu_camera_size"):
            v = getattr(self, name)
            ok = isinstance(v, (tuple, list)) and len(v) == 2 and all(
                isinstance(x, (int, np.integer)) and not isinstance(x, bool)
                and MIN_CAMERA_SIDE <= x <= MAX_CAMERA_SIDE for x in v)
            if v is not None and not ok:
                raise ValueError(f"SensorConfig: {name}={v!r} must be (width, height), "
                                 f"ints in [{MIN_CAMERA_SIDE}, {MAX_CAMERA_SIDE}] pixels")
        bad = [k for k in self.images if k not in IMAGES]
        if isinstance(self.images, str) or bad or len(set(self.images)) != len(self.images):
            raise ValueError(f"SensorConfig: images={self.images!r} must be distinct names of "
                             f"{IMAGES}")
        if self.groundtruth and "instance" not in self.images:
            raise ValueError("SensorConfig: groundtruth needs the cameras' instance images; add "
                             "'instance' to images or set groundtruth=False")


class SensorRig:
    """Captures the sensors of :class:`SensorConfig` from a world (module docstring)."""

    def __init__(self, config: SensorConfig | None = None) -> None:
        self.config = config or SensorConfig()
        c = self.config
        w, h = c.camera_size
        every = {s.name: s for s in ego_camera_specs(w, h, EGO_LENGTH, EGO_WIDTH, c.far)}
        self.ego_cameras: tuple[CameraSpec, ...] = tuple(every[n] for n in c.ego_cameras)
        self.rsu_camera: CameraSpec | None = (
            None if c.rsu_camera_size is None else rsu_camera_spec(*c.rsu_camera_size, far=c.far)
        )

    # ----------------------------------------------------------------- shared inputs
    def scene(self, world) -> Scene:
        """The render scene of the world's current state."""
        return build_scene(world)

    def ground(self, world):
        """The world town's ground raster (cached per town)."""
        return ground_raster(world.town, self.config.ground_mpp)

    # ----------------------------------------------------------------- single sensors
    def capture_camera(self, world, name: str, scene: Scene | None = None) -> dict:
        """One camera (an ego camera name or ``"rsu_cam"``): its images (``config.images``)."""
        scene = scene or self.scene(world)
        images = self.config.images
        if self.rsu_camera is not None and name == self.rsu_camera.name:
            unit = active_unit(world)
            if unit < 0:
                return blank_camera(self.rsu_camera, images)
            pose = rsu_pose(world, unit) @ self.rsu_camera.T_parent_body()
            return render_camera(
                scene,
                self.ground(world),
                self.rsu_camera,
                pose,
                oversample=self.config.rsu_oversample,
                images=images,
            )
        spec = {s.name: s for s in self.ego_cameras}.get(name)
        if spec is None:
            raise KeyError(f"capture_camera: no camera {name!r} in this rig")
        pose = ego_pose(world) @ spec.T_parent_body()
        return render_camera(scene, self.ground(world), spec, pose, exclude=_EGO, images=images)

    def capture_ego_cameras(self, world, scene: Scene | None = None) -> dict[str, dict]:
        """All configured ego cameras (shaded in one batch)."""
        scene = scene or self.scene(world)
        t_we = ego_pose(world)
        poses = [t_we @ s.T_parent_body() for s in self.ego_cameras]
        outs = render_cameras(scene, self.ground(world), list(self.ego_cameras), poses, _EGO,
                              images=self.config.images)
        return {s.name: o for s, o in zip(self.ego_cameras, outs)}

    def capture_rsu_camera(self, world, scene: Scene | None = None) -> dict:
        """The active RSU's camera (blank without one)."""
        if self.rsu_camera is None:
            raise ValueError("capture_rsu_camera: the RSU camera is off in this config")
        return self.capture_camera(world, self.rsu_camera.name, scene)

    def capture_ego_lidar(self, world, scene: Scene | None = None) -> dict:
        """The ego LiDAR sweep."""
        spec = self.config.ego_lidar
        if spec is None:
            raise ValueError("capture_ego_lidar: the ego LiDAR is off in this config")
        pose = ego_pose(world) @ spec.T_parent_sensor()
        return capture_lidar(scene or self.scene(world), self.ground(world), spec, pose, _EGO)

    def capture_rsu_lidar(self, world, scene: Scene | None = None) -> dict:
        """The active RSU's LiDAR sweep (blank without one)."""
        spec = self.config.rsu_lidar
        if spec is None:
            raise ValueError("capture_rsu_lidar: the RSU LiDAR is off in this config")
        unit = active_unit(world)
        if unit < 0:
            return blank_lidar(spec)
        pose = rsu_lidar_pose(world, unit, spec)
        return capture_lidar(scene or self.scene(world), self.ground(world), spec, pose)

    def capture_bev(self, world) -> np.ndarray:
        """The ego-centred BEV raster ``(C, H, W)`` uint8."""
        if self.config.bev is None:
            raise ValueError("capture_bev: the BEV is off in this config")
        return capture_bev(world, self.ground(world), self.config.bev)

    def calibration(self, world) -> dict:
        """Intrinsics / extrinsics of every configured sensor (:mod:`.calibration`)."""
        c = self.config
        return calibration(world, self.ego_cameras, c.ego_lidar, self.rsu_camera, c.rsu_lidar)

    def groundtruth(self, world, frame: dict, scene: Scene | None = None) -> dict:
        """The three box sets, from the LiDAR points and camera images of ``frame``."""
        scene = scene or self.scene(world)
        lid = {}
        for g in ("ego", "rsu"):
            spec = getattr(self.config, f"{g}_lidar")
            if spec is not None and spec.name in frame["lidars"]:
                lid[g] = frame["lidars"][spec.name]["points"][:, 5]
        cams, requests = [], []
        t_we = ego_pose(world)
        for spec in self.ego_cameras:
            if spec.name in frame["cameras"]:
                cams.append(("ego", frame["cameras"][spec.name]["instance"]))
                requests.append((spec, t_we @ spec.T_parent_body(), 1.0))
        unit = active_unit(world)
        rc = self.rsu_camera
        if rc is not None and unit >= 0 and rc.name in frame["cameras"]:
            cams.append(("rsu", frame["cameras"][rc.name]["instance"]))
            requests.append(
                (rc, rsu_pose(world, unit) @ rc.T_parent_body(), self.config.rsu_oversample)
            )

        def unoccluded(instances: list) -> list:
            return unoccluded_pixels_many(scene, [(*r, i) for r, i in zip(requests, instances)])

        return ground_truth(world, lid, cams, unoccluded)

    # ----------------------------------------------------------------- observation spaces
    def observation_space(self):
        """Typed, fixed Gymnasium space of :meth:`observation` (for a ``sensors`` obs mode).

        ``Dict(cameras: Dict(name: Dict(rgb, depth, semantic, instance)), lidars: Dict(name:
        Dict(points (L, 6) padded, count ())), bev (C, H, W))``; a camera's ``Dict`` has only
        the images of ``config.images`` (no camera at all when it is empty).
        """
        from gymnasium import spaces

        cams = {}
        images = self.config.images
        for spec in self.ego_cameras + ((self.rsu_camera,) if self.rsu_camera else ()):
            if not images:
                break
            h, w = spec.height, spec.width
            every = {
                "rgb": spaces.Box(0, 255, (h, w, 3), np.uint8),
                "depth": spaces.Box(0.0, spec.far, (h, w), np.float32),
                "semantic": spaces.Box(0, NUM_SEMANTIC - 1, (h, w), np.uint8),
                "instance": spaces.Box(0, 2**24 - 1, (h, w), np.int32),
            }
            cams[spec.name] = spaces.Dict({k: every[k] for k in images})
        lidars = {}
        for spec in (self.config.ego_lidar, self.config.rsu_lidar):
            if spec is not None:
                r = spec.max_range
                lo = np.array([-r, -r, -r, 0.0, 0.0, 0.0], np.float32)
                hi = np.array([r, r, r, 1.0, NUM_SEMANTIC - 1, 2**24 - 1], np.float32)
                lidars[spec.name] = spaces.Dict(
                    {
                        "points": spaces.Box(
                            np.tile(lo, (spec.max_points, 1)),
                            np.tile(hi, (spec.max_points, 1)),
                            dtype=np.float32,
                        ),
                        "count": spaces.Box(0, spec.max_points, (), np.int64),
                    }
                )
        out = {"cameras": spaces.Dict(cams), "lidars": spaces.Dict(lidars)}
        if self.config.bev is not None:
            n = self.config.bev.size
            out["bev"] = spaces.Box(0, 1, (len(BEV_CHANNELS), n, n), np.uint8)
        return spaces.Dict(out)

    def observation(self, frame: dict) -> dict:
        """The arrays of a captured frame laid out as :meth:`observation_space`."""
        cams = {n: {k: c[k] for k in self.config.images} for n, c in frame["cameras"].items()}
        lidars = {
            n: {"points": d["padded"], "count": np.array(d["count"], np.int64)}
            for n, d in frame["lidars"].items()
        }
        out = {"cameras": cams, "lidars": lidars}
        if "bev" in frame:
            out["bev"] = frame["bev"]
        return out

    # ----------------------------------------------------------------- everything
    def capture(self, world) -> dict:
        """Every configured sensor, calibration and ground truth (frame layout: module doc)."""
        scene = self.scene(world)
        unit = active_unit(world)
        frame: dict = {"tick": int(world.tick), "rsu_unit": unit}
        t_we = ego_pose(world)
        images = self.config.images
        jobs = [(s, t_we @ s.T_parent_body(), _EGO, 1.0) for s in self.ego_cameras]
        rc = self.rsu_camera
        if rc is not None and unit >= 0:  # shaded in the ego cameras' batch
            jobs.append((rc, rsu_pose(world, unit) @ rc.T_parent_body(), None, self.config.rsu_oversample))
        if not images:  # no image asked for: no camera is rendered
            jobs = []
        shots = render_camera_jobs(scene, self.ground(world), jobs, images)
        cams = {job[0].name: shot for job, shot in zip(jobs, shots)}
        if rc is not None and unit < 0 and images:
            cams[rc.name] = blank_camera(rc, images)
        frame["cameras"] = cams
        lidars = {}
        if self.config.ego_lidar is not None:
            lidars[self.config.ego_lidar.name] = self.capture_ego_lidar(world, scene)
        if self.config.rsu_lidar is not None:
            lidars[self.config.rsu_lidar.name] = self.capture_rsu_lidar(world, scene)
        frame["lidars"] = lidars
        if self.config.bev is not None:
            frame["bev"] = self.capture_bev(world)
        if self.config.calibration:
            frame["calibration"] = self.calibration(world)
        if self.config.groundtruth:
            frame["gt"] = self.groundtruth(world, frame, scene)
        return frame


__all__ = ["SensorConfig", "SensorRig"]
