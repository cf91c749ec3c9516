"""One recorded frame: the world, its sensors and the expert turned into fixed-shape arrays.

:func:`frame_record` returns a nested dict of NumPy arrays (one TensorDict row of a shard,
:mod:`.shards`). Keys, shapes and dtypes (``M = RecordConfig.max_boxes``, ``R`` route points,
``C`` cameras selected in ``RecordConfig.cameras``, ``H x W`` their size: the manifest's
``sensor_config["camera_size"]``, the ``EnvConfig`` field an agent's env takes; poses and
calibration in float64 so that frames compose exactly):

==============================  ================  ===========================================
key                             shape, dtype      content
==============================  ================  ===========================================
``tick``                        () int64          simulation tick (10 Hz)
``ego_pose``                    (3,) float64      world x, y (m), yaw (rad)
``ego_speed``, ``ego_accel``    () float32        m/s, m/s^2
``control``                     (3,) float32      executed throttle, steer, brake (perturbed)
``expert_control``              (3,) float32      the expert's control for this state (label)
``perturbed``                   () bool           the executed control carried injected noise
``expert_waypoints``            (8, 2) float32    expert's future positions, ego frame, every 0.5 s
``expert_speeds``               (8,) float32      planned speeds there (m/s)
``expert_reason``               () int64          index in :data:`REASONS` (binding constraint)
``command``                     () int64          navigation command (``town.model.COMMAND_NAMES``)
``route``                       (R, 3) float32    route ahead: ego-frame x, y and command
``light_state``                 () int64          -1 none, 0 green, 1 yellow, 2 red, 3 stop sign
``light_affects_ego``           () bool           a light governs the ego's lane within 40 m
``stop_line_distance``          () float32        m to the stop line of the lane (-1: none)
``calib/T_world_ego``           (4, 4) float64    ego pose
``calib/T_world_rsu``           (4, 4) float64    active RSU unit pose (identity without one)
``calib/T_ego_rsu``             (4, 4) float64    ``geometry.relative_transform``
``calib/rsu_unit``              () int64          active unit (-1: none)
``calib/cam_intrinsics``        (7, 3, 3) f64     6 ego cameras (``EGO_CAMERA_NAMES``) + RSU
``calib/T_ego_cam``             (7, 4, 4) f64     camera optical frame -> ego frame
``calib/T_world_cam``           (7, 4, 4) f64     camera optical frame -> world
``calib/T_ego_lidar``           (2, 4, 4) f64     ego LiDAR, RSU LiDAR -> ego frame
``gt/<set>/boxes``              (M, 9) float32    ego frame x, y, z, length, width, height,
                                                  yaw, vx, vy (set: ego, rsu, fused)
``gt/<set>/class``, ``id``      (M,) int64        ``classes`` id, actor id (static: 1e6 + j)
``gt/<set>/lidar_points``       (M, 2) int64      returns in the ego and the RSU LiDAR
``gt/<set>/mask``               (M,) bool         valid rows (the nearest ``M`` of the set)
``gt/<set>/count``              () int64          size of the set before truncation
``gt/fused/joint``              (M,) bool         jointly visible (>= 10 points in both LiDARs)
``cameras/<cam>/rgb``           (H, W, 3) uint8   sensor ``rgb`` (cam in the 6 + ``rsu_cam``)
``cameras/<cam>/depth``         (H, W) float32    sensor ``depth`` (optical-axis m)
``cameras/<cam>/semantic``      (H, W) uint8      sensor ``semantic``
``lidar/<ego|rsu>/points``      (L, 6) float32    sensor ``lidar``: padded points, sensor frame
``lidar/<ego|rsu>/count``       () int64          valid points
``bev_bits``                    (2, S, S) uint8   sensor ``bev``: the 14 binary channels packed
                                                  along axis 0 (:func:`unpack_bev`)
``channel``                     (K,) float64      :data:`CHANNEL_FIELDS` of ``Channel.stats``
``obs/<key>``                   float32           the ego's objects-mode observation (keys
                                                  :data:`OBS_KEYS`, shapes of
                                                  ``observations.ego_space``): what a
                                                  behaviour-cloned ``obs_mode="objects"`` agent
                                                  sees, the received V2X message decoded in
                                                  ``v2x_objects``, as sent in ``v2x_payload``,
                                                  its sender and age in ``v2x_info``
                                                  (``RecordConfig.objects_obs``)
==============================  ================  ===========================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from v2xbench.envs.v2x_intersection.api.observations import (
    EGO_FEATURES,
    OBJECT_FEATURES,
    V2X_INFO_FEATURES,
    objects_observation,
)
from v2xbench.envs.v2x_intersection.core.geometry import invert_transform
from v2xbench.envs.v2x_intersection.sensors import BEV_CHANNELS, EGO_CAMERA_NAMES, boxes_in_frame

SENSORS = ("rgb", "depth", "semantic", "lidar", "bev")
DEFAULT_SENSORS = ("rgb", "bev")
CAMERAS = (*EGO_CAMERA_NAMES, "rsu_cam")
REASONS = ("free", "leader", "red", "yellow", "stop_sign", "yield", "conflict", "other")
CHANNEL_FIELDS = ("bytes_sent_total", "messages_sent", "messages_lost", "messages_delivered",
                  "bytes_delivered_total", "messages_dropped_bandwidth", "last_message_bytes", "bps")
BOX_SETS = ("ego", "rsu", "fused")
MAX_BOXES = 4096  # rows per box set: bounds the per-frame record size
LIGHT_RANGE = 40.0  # m: a light farther than this from its stop line does not yet affect the ego
_LIGHT = EGO_FEATURES.index("light_state")
_LINE = EGO_FEATURES.index("dist_to_stop_line")


@dataclass(frozen=True)
class RecordConfig:
    """What a frame record holds.

    Attributes:
        sensors: subset of :data:`SENSORS` stored every tick (``rgb``/``depth``/``semantic`` of
            the 7 cameras, both LiDARs, the BEV).
        max_boxes: rows per ground-truth box set (the nearest ones are kept).
        objects_obs: also store the ego's objects-mode observation (``obs/*``: exactly what an
            agent with ``obs_mode="objects"`` receives, including the received V2X message
            decoded in ``obs/v2x_objects``, as sent in ``obs/v2x_payload``, and its sender pose
            and age in ``obs/v2x_info``).
            Data sets collected before this field existed lack it (their manifests say false).
    """

    sensors: tuple[str, ...] = DEFAULT_SENSORS
    max_boxes: int = 96
    objects_obs: bool = True

    def __post_init__(self) -> None:
        bad = set(self.sensors) - set(SENSORS)
        if bad:
            raise ValueError(f"RecordConfig: unknown sensors {sorted(bad)}; known: {SENSORS}")
        m = self.max_boxes
        if isinstance(m, bool) or not isinstance(m, int) or not 1 <= m <= MAX_BOXES:
            raise ValueError(f"RecordConfig: max_boxes={m!r} must be an int in [1, {MAX_BOXES}]")
        if not isinstance(self.objects_obs, bool):
            raise ValueError(f"RecordConfig: objects_obs={self.objects_obs!r} must be true or false")


def record_schema(config: RecordConfig, camera_size: tuple[int, int], route_points: int,
                  lidar_points: tuple[int, int], bev_size: int,
                  max_objects: int = 32, max_payload_floats: int = 320
                  ) -> dict[tuple[str, ...], tuple]:
    """Every leaf of a :func:`frame_record` as ``{key path: (dtype name, per-frame shape)}``.

    This is the whole schema of a shard's memmap (module docstring): a loader accepts these keys,
    dtypes and shapes and nothing else.

    Args:
        config: what the record holds (sensors, box rows).
        camera_size: ``(width, height)`` of the 7 cameras.
        route_points: ``EnvConfig.route_points`` (rows of ``route``).
        lidar_points: padded rows of the ego and the RSU LiDAR (``LidarSpec.max_points``).
        bev_size: BEV raster side (``BevSpec.size``).
        max_objects: ``EnvConfig.max_objects`` (rows of ``obs/objects``, ``obs/v2x_objects``).
        max_payload_floats: ``EnvConfig.max_payload_floats`` (size of ``obs/v2x_payload``).
    """
    from v2xbench.agents.expert.planner import N_WAYPOINTS

    w, h = (int(v) for v in camera_size)
    m = config.max_boxes
    cams = len(CAMERAS)
    schema: dict[tuple[str, ...], tuple] = {
        ("tick",): ("int64", ()), ("ego_pose",): ("float64", (3,)),
        ("ego_speed",): ("float32", ()), ("ego_accel",): ("float32", ()),
        ("control",): ("float32", (3,)), ("expert_control",): ("float32", (3,)),
        ("perturbed",): ("bool", ()), ("expert_waypoints",): ("float32", (N_WAYPOINTS, 2)),
        ("expert_speeds",): ("float32", (N_WAYPOINTS,)), ("expert_reason",): ("int64", ()),
        ("command",): ("int64", ()), ("route",): ("float32", (int(route_points), 3)),
        ("light_state",): ("int64", ()), ("light_affects_ego",): ("bool", ()),
        ("stop_line_distance",): ("float32", ()),
        ("calib", "T_world_ego"): ("float64", (4, 4)), ("calib", "T_world_rsu"): ("float64", (4, 4)),
        ("calib", "T_ego_rsu"): ("float64", (4, 4)), ("calib", "rsu_unit"): ("int64", ()),
        ("calib", "cam_intrinsics"): ("float64", (cams, 3, 3)),
        ("calib", "T_ego_cam"): ("float64", (cams, 4, 4)),
        ("calib", "T_world_cam"): ("float64", (cams, 4, 4)),
        ("calib", "T_ego_lidar"): ("float64", (2, 4, 4)),
        ("channel",): ("float64", (len(CHANNEL_FIELDS),)),
    }
    for s in BOX_SETS:
        schema.update({("gt", s, "boxes"): ("float32", (m, 9)), ("gt", s, "class"): ("int64", (m,)),
                       ("gt", s, "id"): ("int64", (m,)),
                       ("gt", s, "lidar_points"): ("int64", (m, 2)),
                       ("gt", s, "mask"): ("bool", (m,)), ("gt", s, "count"): ("int64", ())})
    schema[("gt", "fused", "joint")] = ("bool", (m,))
    kinds = {"rgb": ("uint8", (h, w, 3)), "depth": ("float32", (h, w)),
             "semantic": ("uint8", (h, w))}
    for c in CAMERAS:
        schema.update({("cameras", c, k): v for k, v in kinds.items() if k in config.sensors})
    if "lidar" in config.sensors:
        for g, n in zip(("ego", "rsu"), lidar_points):
            schema[("lidar", g, "points")] = ("float32", (int(n), 6))
            schema[("lidar", g, "count")] = ("int64", ())
    if config.objects_obs:
        schema.update(_objects_obs_schema(route_points, max_objects, max_payload_floats))
    if "bev" in config.sensors:
        schema[("bev_bits",)] = ("uint8", (-(-len(BEV_CHANNELS) // 8), bev_size, bev_size))
    return schema


#: keys of the stored objects-mode observation (``obs/<key>``)
OBS_KEYS = ("ego", "route", "objects", "v2x_objects", "v2x_info", "v2x_payload")


def _objects_obs_schema(route_points: int, max_objects: int,
                        max_payload_floats: int = 320) -> dict[tuple[str, ...], tuple]:
    """``obs/*`` leaves: the objects-mode observation (``observations.ego_space``)."""
    n_obj, m, r = len(OBJECT_FEATURES), int(max_objects), int(route_points)
    shapes = {"ego": (len(EGO_FEATURES),), "route": (r, 3), "objects": (m, n_obj),
              "v2x_objects": (m, n_obj), "v2x_info": (len(V2X_INFO_FEATURES),),
              "v2x_payload": (int(max_payload_floats),)}
    return {("obs", k): ("float32", v) for k, v in shapes.items()}


def unpack_bev(bits: np.ndarray, channels: int = len(BEV_CHANNELS)) -> np.ndarray:
    """``(..., C, S, S)`` uint8 0/1 BEV from :func:`frame_record`'s ``bev_bits`` ``(..., 2, S, S)``."""
    bits = np.asarray(bits)
    return np.unpackbits(bits, axis=-3)[..., :channels, :, :]


def reason_code(reason: str) -> int:
    """Index of an expert reason in :data:`REASONS` (unknown reasons map to ``other``)."""
    return REASONS.index(reason) if reason in REASONS else REASONS.index("other")


def light_info(world, obs: dict | None = None) -> tuple[int, bool, float]:
    """``(light_state, affects_ego, stop-line distance)`` as the ego observation computes them
    (``obs``: that observation when already computed)."""
    ego = (obs if obs is not None else objects_observation(world))["ego"]
    state, line = int(ego[_LIGHT]), float(ego[_LINE])
    return state, bool(0 <= state <= 2 and 0.0 <= line <= LIGHT_RANGE), line


def nav_command(world) -> int:
    """Navigation command at the ego's current route point."""
    r = world.route
    return int(r.commands[min(world.monitor.progress, len(r.commands) - 1)])


def _box_set(boxes: dict, t_ego_world: np.ndarray, m: int, joint: bool) -> dict:
    b = boxes_in_frame(boxes, t_ego_world)
    n = len(b["id"])
    order = np.argsort(np.linalg.norm(b["center"][:, :2], axis=1))[:m]
    k = len(order)
    rows = np.zeros((m, 9), np.float32)
    if k:
        c = b["center"][order]
        rows[:k] = np.c_[c, b["size"][order], b["yaw"][order], b["velocity"][order, :2]]
    out = {"boxes": rows, "class": np.zeros(m, np.int64), "id": np.zeros(m, np.int64),
           "lidar_points": np.zeros((m, 2), np.int64), "mask": np.arange(m) < k,
           "count": np.array(n, np.int64)}
    out["class"][:k] = b["class"][order]
    out["id"][:k] = b["id"][order]
    out["lidar_points"][:k] = np.c_[b["ego_lidar_points"][order], b["rsu_lidar_points"][order]]
    if joint:
        out["joint"] = np.zeros(m, bool)
        out["joint"][:k] = b["joint"][order]
    return out


def _calibration(cal: dict) -> dict:
    k = np.zeros((len(CAMERAS), 3, 3))
    t_ego = np.zeros((len(CAMERAS), 4, 4))
    t_world = np.zeros((len(CAMERAS), 4, 4))
    for i, name in enumerate(CAMERAS):
        if name in cal:
            k[i], t_ego[i], t_world[i] = (cal[name]["intrinsics"], cal[name]["T_ego_sensor"],
                                          cal[name]["T_world_sensor"])
    lid = np.stack([cal[n]["T_ego_sensor"] if n in cal else np.eye(4) for n in ("lidar", "rsu_lidar")])
    return {"T_world_ego": cal["T_world_ego"], "T_world_rsu": cal["T_world_rsu"],
            "T_ego_rsu": cal["T_ego_rsu"], "rsu_unit": np.array(cal["rsu_unit"], np.int64),
            "cam_intrinsics": k, "T_ego_cam": t_ego, "T_world_cam": t_world, "T_ego_lidar": lid}


def frame_record(world, frame: dict, expert, control: np.ndarray, perturbed: bool,
                 config: RecordConfig) -> dict:
    """The record of the current tick (module docstring).

    Args:
        world: the world after ``reset`` / ``step``.
        frame: ``SensorRig.capture(world)`` of this tick (with ground truth).
        expert: the bound :class:`~v2xbench.agents.expert.Expert` after ``act`` on this tick.
        control: ``(3,)`` control executed on this tick (the expert's, possibly perturbed).
        perturbed: whether ``control`` carries injected noise.
        config: what to store.
    """
    t = world.table
    cal = frame["calibration"]
    t_ego_world = invert_transform(cal["T_world_ego"])
    obs = objects_observation(world)  # obs/* is the objects mode whatever the world's mode
    state, affects, line = light_info(world, obs)
    obs_route = obs["route"]
    plan = expert.last_plan
    rec: dict = {
        "tick": np.array(world.tick, np.int64),
        "ego_pose": np.array([t.pos[0, 0], t.pos[0, 1], t.yaw[0]], np.float64),
        "ego_speed": np.array(t.speed[0], np.float32),
        "ego_accel": np.array(t.accel[0], np.float32),
        "control": np.asarray(control, np.float32).reshape(3),
        "expert_control": np.asarray(plan.control, np.float32).reshape(3),
        "perturbed": np.array(bool(perturbed)),
        "expert_waypoints": np.asarray(plan.waypoints, np.float32),
        "expert_speeds": np.asarray(plan.speeds, np.float32),
        "expert_reason": np.array(reason_code(plan.reason), np.int64),
        "command": np.array(nav_command(world), np.int64),
        "route": obs_route.astype(np.float32),
        "light_state": np.array(state, np.int64),
        "light_affects_ego": np.array(affects),
        "stop_line_distance": np.array(line, np.float32),
        "calib": _calibration(cal),
        "gt": {s: _box_set(frame["gt"][s], t_ego_world, config.max_boxes, s == "fused")
               for s in BOX_SETS},
    }
    stats = world.channel.stats()
    rec["channel"] = np.array([float(stats[k]) for k in CHANNEL_FIELDS], np.float64)
    kinds = [k for k in ("rgb", "depth", "semantic") if k in config.sensors]
    if kinds:
        rec["cameras"] = {c: {k: frame["cameras"][c][k] for k in kinds} for c in CAMERAS}
    if "lidar" in config.sensors:
        rec["lidar"] = {g: {"points": frame["lidars"][n]["padded"],
                            "count": np.array(frame["lidars"][n]["count"], np.int64)}
                        for g, n in (("ego", "lidar"), ("rsu", "rsu_lidar"))}
    if "bev" in config.sensors:
        rec["bev_bits"] = np.packbits(frame["bev"].astype(bool), axis=0)
    if config.objects_obs:
        rec["obs"] = {k: np.asarray(obs[k], np.float32) for k in OBS_KEYS}
    return rec


__all__ = ["BOX_SETS", "CAMERAS", "CHANNEL_FIELDS", "DEFAULT_SENSORS", "MAX_BOXES", "OBS_KEYS", "REASONS",
           "SENSORS", "RecordConfig", "frame_record", "light_info", "nav_command", "reason_code",
           "record_schema", "unpack_bev"]
