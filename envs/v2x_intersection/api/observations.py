"""Typed observation spaces and the functions that fill them from a :class:`~.world.World`.

Three modes (``config.obs_mode``): ``objects`` (below), ``sensors`` (the ego's ``objects`` key is
replaced by ``cameras`` - 6 ego cameras, each ``rgb``/``depth``/``semantic``/``instance`` - and
``lidar`` - ``points (L, 6)`` padded + ``count``; the RSU observation adds its ``camera`` and
``lidar``) and ``bev`` (the ego's ``objects`` key is replaced by ``bev (C, H, W)`` uint8, which
draws only the actors the ego sees, as ``objects``; the raster of every actor is the privileged
``BevSpec(privileged=True)``, never an observation). Sensor layouts and defaults: :mod:`.sensors`.
The ``sensors`` mode is configured by ``config.SENSOR_FIELDS``: ``camera_size`` (every camera's
``(width, height)``), ``camera_images`` (the images a camera has: only those are rendered and in
the space; ``()`` leaves out ``cameras`` and the RSU's ``camera``) and ``lidar_scale`` (the
LiDARs' density, ``sensors.lidar.scaled_lidar_specs``).
Class ids are the observed ones (``World.object_classes``: an emergency vehicle is
``classes.EMERGENCY_VEHICLE``), in every mode and in the RSU's messages.

``objects`` mode (fast, for RL). Ego observation (all float32):

========================  ==================  ===============================================
key                       shape               content
========================  ==================  ===============================================
``ego``                   ``(9,)``            ``EGO_FEATURES``
``route``                 ``(P, 3)``          next route points in the ego frame (x, y, command)
``objects``               ``(M, 11)``         actors the ego sees (``OBJECT_FEATURES``, ego frame)
``v2x_objects``           ``(M, 11)``         objects received from the RSU, moved to the ego frame
``v2x_info``              ``(8,)``            ``V2X_INFO_FEATURES``
``v2x_payload``           ``(L,)``            the received payload as sent, zero-padded
========================  ==================  ===============================================

``L = max_payload_floats``. Every received message is in ``v2x_payload`` (its first
``v2x_info.payload_length`` floats, the rest zero; as float32 after the wire's encoding), whatever
its format; only an object list (``payload_format`` 0, ``wire.PAYLOAD_FORMATS``) is also decoded
into ``v2x_objects``. A raw payload (format 1: a custom roadside policy's own message) leaves
``v2x_objects`` empty and ``num_objects`` 0. ``age_ticks`` and the sender's pose
(``rsu_x``, ``rsu_y``, ``rsu_yaw``, in the ego frame) describe the message in both keys. The
``v2x_*`` keys are in every mode (``objects``, ``sensors``, ``bev``).

RSU observation: ``unit`` (``UNIT_FEATURES``), ``calibration`` ``(2, 4, 4)`` =
(``T_world_rsu``, ``T_ego_rsu``), ``objects`` ``(M, 11)`` in the RSU ground frame (origin at the
pole's foot, x along the unit's yaw, z up; pitch and roll are in ``T_world_rsu``).
Rows of object arrays are sorted by distance; unused rows are all zero (``present = 0``).
Received objects whose ego-frame ``x``, ``y``, ``vx`` or ``vy`` would pass ``+-BIG`` (an object
10 km away; a payload's values are within ``wire.PAYLOAD_LIMIT``) are clipped to it at decode,
so every value stays inside its box.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from gymnasium import spaces

from ..core import libm
from ..core.geometry import (
    local_to_world_2d,
    pose_matrix,
    relative_transform,
    world_to_local_2d,
    wrap_angle,
)
from ..core.jit import HAVE_JIT
from ..perception.jit_perception import OBS_BOUND
from ..perception.visibility import VISIBLE_THRESHOLD
from ..traffic.vehicles import STOP_LINE_SETBACK, stop_sign_lanes
from ..v2x.channel import message_space
from ..v2x.rsu import RSU_PITCH
from ..v2x.wire import (
    FORMAT_OBJECTS,
    NUM_OBJECT_FIELDS,
    PAYLOAD_LIMIT,
    decode_frame,
    unpack_objects,
)
from .jit_observations import ego_obs_packed_kernel

EGO_FEATURES = ("speed", "accel", "yaw_rate", "throttle", "steer", "brake", "light_state",
                "dist_to_stop_line", "route_completion")
OBJECT_FEATURES = ("present", "class_id", "x", "y", "yaw", "length", "width", "height", "vx", "vy",
                   "visibility")
V2X_INFO_FEATURES = ("received", "age_ticks", "num_objects", "rsu_x", "rsu_y", "rsu_yaw",
                     "payload_length", "payload_format")
_PAYLOAD_LENGTH = V2X_INFO_FEATURES.index("payload_length")
UNIT_FEATURES = ("unit_id", "x", "y", "z", "yaw", "pitch")
BIG = OBS_BOUND  # bound of the observation boxes (1e4; received objects are clipped to it)
#: received objects stay in the observation this many ticks after their delivery (then zeroed)
V2X_HOLD_TICKS = 5
#: ``light_state`` value for a stop sign (other values: -1 none, 0 green, 1 yellow, 2 red)
LIGHT_STOP_SIGN = 3


def _box(*shape: int, low: float = -BIG, high: float = BIG) -> spaces.Box:
    return spaces.Box(low, high, shape=shape, dtype=np.float32)


def sensor_rig(cfg):
    """The :class:`~.sensors.SensorRig` a config's observation mode needs (``None`` for
    ``objects``; for ``sensors``, configured by the config's ``SENSOR_FIELDS``)."""
    if cfg.obs_mode == "objects":
        return None
    return _rig_of(cfg)


def _rig_of(cfg):
    if cfg.obs_mode == "bev":
        return _rig("bev")
    return _rig("sensors", tuple(cfg.camera_size), tuple(cfg.camera_images), float(cfg.lidar_scale))


@functools.lru_cache(maxsize=16)
def _rig(obs_mode: str, camera_size: tuple = (), images: tuple = (), lidar_scale: float = 1.0):
    from ..sensors import SensorConfig, SensorRig
    from ..sensors.lidar import scaled_lidar_specs

    if obs_mode == "bev":
        return SensorRig(SensorConfig(ego_cameras=(), rsu_camera_size=None, ego_lidar=None, rsu_lidar=None,
                                      calibration=False, groundtruth=False))
    ego_lidar, rsu_lidar = scaled_lidar_specs(lidar_scale)
    return SensorRig(SensorConfig(camera_size=camera_size, rsu_camera_size=camera_size,
                                  ego_lidar=ego_lidar, rsu_lidar=rsu_lidar, bev=None,
                                  calibration=False, groundtruth=False, images=images))


def _sensor_spaces(cfg) -> spaces.Dict:
    return _rig_of(cfg).observation_space()


def _v2x_info_box(max_payload_floats: int) -> spaces.Box:
    """``v2x_info``'s box: ``+-BIG``, with room for the payload length when a payload holds more
    than ``BIG`` floats."""
    high = np.full(len(V2X_INFO_FEATURES), BIG, np.float32)
    high[_PAYLOAD_LENGTH] = max(BIG, max_payload_floats)
    return spaces.Box(np.float32(-BIG), high, dtype=np.float32)


def ego_space(cfg) -> spaces.Dict:
    """Observation space of the ego agent (see module docstring)."""
    m = cfg.max_objects
    d = {
        "ego": _box(len(EGO_FEATURES)),
        "route": _box(cfg.route_points, 3),
        "v2x_objects": _box(m, len(OBJECT_FEATURES)),
        "v2x_info": _v2x_info_box(cfg.max_payload_floats),
        "v2x_payload": _box(cfg.max_payload_floats, low=-PAYLOAD_LIMIT, high=PAYLOAD_LIMIT),
    }
    if cfg.obs_mode == "objects":
        d["objects"] = _box(m, len(OBJECT_FEATURES))
    elif cfg.obs_mode == "sensors":
        s = _sensor_spaces(cfg)
        if cfg.camera_images:
            d["cameras"] = spaces.Dict({k: v for k, v in s["cameras"].spaces.items()
                                        if k != "rsu_cam"})
        d["lidar"] = s["lidars"]["lidar"]
    else:
        d["bev"] = _sensor_spaces(cfg)["bev"]
    return spaces.Dict(d)


def rsu_space(cfg) -> spaces.Dict:
    """Observation space of an RSU agent (``sensors`` mode adds its camera and LiDAR)."""
    d = {
        "unit": _box(len(UNIT_FEATURES)),
        "calibration": _box(2, 4, 4),
        "objects": _box(cfg.max_objects, len(OBJECT_FEATURES)),
    }
    if cfg.obs_mode == "sensors":
        s = _sensor_spaces(cfg)
        if cfg.camera_images:
            d["camera"] = s["cameras"]["rsu_cam"]
        d["lidar"] = s["lidars"]["rsu_lidar"]
    return spaces.Dict(d)


def sensor_observation(world) -> dict:
    """The rig observation of the world's current tick (captured once per tick, then cached)."""
    key = (id(world.table), world.tick)
    cached = getattr(world, "_sensor_obs", None)
    if cached is None or cached[0] != key:
        rig = _rig_of(world.config)
        if world.config.obs_mode == "bev":
            obs = {"bev": rig.capture_bev(world)}
        else:
            obs = rig.observation(rig.capture(world))
        world._sensor_obs = cached = (key, obs)
    return cached[1]


def ego_action_space() -> spaces.Box:
    """``(throttle, steer, brake)`` in ``[0, 1] x [-1, 1] x [0, 1]``."""
    return spaces.Box(np.array([0.0, -1.0, 0.0], np.float32), np.array([1.0, 1.0, 1.0], np.float32), dtype=np.float32)


def rsu_action_space(world_or_cfg) -> spaces.Dict:
    """The RSU's action is its V2X message (``channel.message_space``)."""
    return message_space(world_or_cfg)


def validate_control(action, name: str = "ego action") -> np.ndarray:
    """Check an ego control and clip it into range.

    Out-of-range finite values are **clipped** to the action box (as most RL libraries expect);
    wrong shape, non-numeric dtype, NaN or inf raise ``ValueError`` naming the problem.
    """
    if type(action) is np.ndarray and action.shape == (3,) and action.dtype.char in "fd":
        throttle, steer, brake = action.tolist()  # the float64 values of float32 / float64
        if math.isfinite(throttle) and math.isfinite(steer) and math.isfinite(brake):
            # np.minimum(np.maximum(a, lo), hi) on Python floats (like NumPy's, a value equal to a
            # bound gives the bound: -0.0 throttle becomes 0.0)
            return np.array((_clip(throttle, 0.0, 1.0), _clip(steer, -1.0, 1.0), _clip(brake, 0.0, 1.0)))
    a = np.asarray(action)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{name}: expected a numeric array of shape (3,), got dtype {a.dtype}")
    if a.shape != (3,):
        raise ValueError(f"{name}: expected shape (3,) = (throttle, steer, brake), got {a.shape}")
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or inf: {a.tolist()}")
    return np.minimum(np.maximum(a, _CONTROL_LO), _CONTROL_HI)  # np.clip for finite values, cheaper


def _clip(x: float, lo: float, hi: float) -> float:
    x = x if x > lo else lo
    return x if x < hi else hi


_CONTROL_LO = np.array([0.0, -1.0, 0.0])
_CONTROL_HI = np.array([1.0, 1.0, 1.0])


def _rows(objs: np.ndarray, vis: np.ndarray, m: int) -> np.ndarray:
    """Pad ``(K, 10)`` channel-layout rows into ``(m, 11)`` observation rows."""
    out = np.zeros((m, len(OBJECT_FEATURES)), np.float32)
    k = min(len(objs), m)
    if k:
        out[:k, 0] = 1.0
        out[:k, 1:10] = objs[:k, :9]
        out[:k, 10] = vis[:k]
    return out


def ego_observation(world) -> dict[str, np.ndarray]:
    """Fill the ego observation (see module docstring)."""
    objects = world.config.obs_mode == "objects"
    out = _vector_observation(world, objects)
    return out if objects else _sensor_keys(world, out)


def objects_observation(world) -> dict[str, np.ndarray]:
    """The ``objects``-mode ego observation (``ego``, ``route``, ``v2x_*``, ``objects``) whatever
    the world's ``obs_mode``: what the data set records as ``obs/*`` when a sensors-mode agent
    drives the collection (``collectors/dataset/driver.py``)."""
    return _vector_observation(world, True)


def _vector_observation(world, objects: bool) -> dict[str, np.ndarray]:
    """The ego observation's vector keys, with ``objects`` when asked (no sensor keys)."""
    cfg = world.config
    if HAVE_JIT:
        m = cfg.max_objects
        out = {"ego": np.empty(len(EGO_FEATURES), np.float32), "route": np.empty((cfg.route_points, 3), np.float32),
               "v2x_objects": np.empty((m, len(OBJECT_FEATURES)), np.float32),
               "v2x_info": np.empty(len(V2X_INFO_FEATURES), np.float32),
               "v2x_payload": np.empty(cfg.max_payload_floats, np.float32)}
        if objects:
            out["objects"] = np.empty((m, len(OBJECT_FEATURES)), np.float32)
        fill_objects_observation(world, out)
        return out
    t = world.table  # NumPy path
    ego_xy, ego_yaw = t.pos[0], float(t.yaw[0])
    # route ahead
    r = world.route
    k0 = world.monitor.progress
    ks = np.minimum(k0 + np.arange(cfg.route_points) * cfg.route_step, len(r.points) - 1)
    route = np.zeros((cfg.route_points, 3), np.float32)
    route[:, :2] = world_to_local_2d(r.points[ks], ego_xy, ego_yaw)
    route[:, 2] = r.commands[ks]
    # traffic light of the current route lane
    ix = world.town.index
    lane = int(r.lane_ids[min(k0, len(r.lane_ids) - 1)])
    light = float(world.lane_signal[lane])
    jid = ix.junction_ahead[lane]
    if light < 0 and jid >= 0 and lane in world.town.junctions[jid].stop_lanes:
        light = float(LIGHT_STOP_SIGN)
    dist_line = -1.0
    if ix.stop_at_end[lane]:
        _, s_lane, _ = ix.project(ego_xy[None], point_ids=ix.lane_point_ids(lane))
        dist_line = float(ix.length[lane] - STOP_LINE_SETBACK - s_lane[0])
    # the yaw rate of the steer the dynamics applied (a scenario may perturb the command: ControlLoss)
    steer = float(world.applied_control[1])
    yaw_rate = t.speed[0] * float(libm.tan(steer * world.params.max_steer)) / world.params.wheelbase
    ego = np.array([t.speed[0], t.accel[0], yaw_rate, *world.last_control, light, dist_line,
                    world.monitor.route_completion], np.float32)
    v2x, info, raw = _v2x(world, ego_xy, ego_yaw)
    out = {"ego": ego, "route": route, "v2x_objects": v2x, "v2x_info": info, "v2x_payload": raw}
    if objects:
        from ..sim.world import object_rows  # (world imports this module)

        objs = object_rows(t, np.flatnonzero(world.ego_vis >= VISIBLE_THRESHOLD), ego_xy, ego_yaw,
                           world.object_classes())
        vis = world.ego_vis[objs[:, 9].astype(np.int64)] if len(objs) else np.zeros(0)
        out["objects"] = _rows(objs, vis, cfg.max_objects)
    return out


def _sensor_keys(world, out: dict) -> dict:
    """Add the ``sensors`` / ``bev`` mode keys to ``out``."""
    if world.config.obs_mode == "sensors":
        s = sensor_observation(world)
        if world.config.camera_images:
            out["cameras"] = {k: v for k, v in s["cameras"].items() if k != "rsu_cam"}
        out["lidar"] = s["lidars"]["lidar"]
    else:
        out["bev"] = sensor_observation(world)["bev"]
    return out


def fill_objects_observation(world, out: dict) -> None:
    """Write the ego observation's ``ego``, ``route``, ``v2x_objects``, ``v2x_info``,
    ``v2x_payload`` (and ``objects``, when ``out`` has it) into the arrays of ``out``, in one kernel
    call and a copy of the payload (numba path of :func:`ego_observation`; ``batch.WorldBatch``
    passes rows of its buffers)."""
    cfg, t, r = world.config, world.table, world.route
    k0 = world.monitor.progress
    lane = int(r.lane_ids[min(k0, len(r.lane_ids) - 1)])
    inbox = world.inbox
    has_msg = inbox is not None and world.tick - inbox[1] < cfg.latency_ticks + V2X_HOLD_TICKS
    if has_msg:
        sender, sent_tick, raw = inbox[0], inbox[1], inbox[2]
        fmt = _inbox_format(inbox)
        payload = raw if fmt == FORMAT_OBJECTS else _NO_PAYLOAD  # only object lists are decoded
        rx, ry, _, ryaw = world.rsus.pose[sender].tolist()
        age = world.tick - sent_tick
    else:
        raw, fmt, payload, rx, ry, ryaw, age = None, 0, _NO_PAYLOAD, 0.0, 0.0, 0.0, 0
    objects = out.get("objects")
    if objects is not None:
        world.object_classes()  # refreshes the class array the kernel reads (emergency vehicles)
    consts = world._obs_args.get((t, r, world.town), lambda: _obs_consts(world))
    ego_obs_packed_kernel(
        out["ego"], out["route"], out["v2x_objects"] if objects is None else objects, out["v2x_objects"],
        out["v2x_info"], objects is not None, k0, world.ego_vis, lane, has_msg, payload, rx, ry, ryaw, age,
        world.last_control, float(world.applied_control[1]), world.lane_signal, world.monitor.route_completion,
        consts)
    _fill_payload(out["v2x_payload"], out["v2x_info"], raw, fmt)


def _inbox_format(inbox: tuple) -> int:
    """The payload format of an inbox message (``channel.Delivery``; a bare ``(sender, tick,
    payload)`` is an object list)."""
    return int(inbox[3]) if len(inbox) > 3 else FORMAT_OBJECTS


def _fill_payload(buf: np.ndarray, info: np.ndarray, raw: np.ndarray | None, fmt: int) -> None:
    """Write a held message's payload into ``buf`` (zero-padded) and its length and format into
    ``info`` (``raw`` ``None``: nothing held, ``buf`` zeroed; ``info`` is then already zero)."""
    if raw is None:
        buf[:] = 0.0
        return
    n = raw.shape[0]
    buf[:n] = raw
    buf[n:] = 0.0
    info[_PAYLOAD_LENGTH] = n
    info[_PAYLOAD_LENGTH + 1] = fmt


def _obs_consts(world) -> tuple:
    """``ego_obs_packed_kernel``'s arguments that hold for the episode (its table, route, town)."""
    cfg, t, r, ix, pr = world.config, world.table, world.route, world.town.index, world.params
    return (r.points, r.commands, cfg.route_step, VISIBLE_THRESHOLD, t.pos, t.yaw, t.speed, t.accel,
            world.object_classes(), t.length,
            t.width, t.height, t.actor_id, ix.stop_at_end, ix.length, STOP_LINE_SETBACK, ix.points, ix.owner,
            ix.offset, ix.n_points, ix.gs, ix.base, pr.max_steer, pr.wheelbase, stop_sign_lanes(world.town),
            LIGHT_STOP_SIGN)

_NO_PAYLOAD = np.zeros(0, np.float32)
#: channel-layout columns of a received object that move with the frame (x, y, vx, vy)
_MOVED = [1, 2, 7, 8]


def _v2x(world, ego_xy: np.ndarray, ego_yaw: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``v2x_objects``, ``v2x_info`` and ``v2x_payload`` (NumPy path)."""
    cfg = world.config
    info = np.zeros(len(V2X_INFO_FEATURES), np.float32)
    raw_obs = np.zeros(cfg.max_payload_floats, np.float32)
    if world.inbox is None or world.tick - world.inbox[1] >= cfg.latency_ticks + V2X_HOLD_TICKS:
        return np.zeros((cfg.max_objects, len(OBJECT_FEATURES)), np.float32), info, raw_obs
    sender, sent_tick, raw = world.inbox[:3]
    fmt = _inbox_format(world.inbox)
    payload = raw if fmt == FORMAT_OBJECTS else _NO_PAYLOAD  # only object lists are decoded
    x, y, _, yaw = world.rsus.pose[sender]  # float64 scalars (a float32 row + yaw stays float64)
    n_rows = len(payload) // NUM_OBJECT_FIELDS
    rows = unpack_objects(payload, n_rows * NUM_OBJECT_FIELDS)
    if n_rows:
        xy = local_to_world_2d(rows[:, 1:3].astype(np.float64), np.array([x, y]), yaw)
        rows = rows.copy()
        rows[:, 1:3] = world_to_local_2d(xy, ego_xy, ego_yaw)
        rows[:, 3] = wrap_angle(rows[:, 3] + yaw - ego_yaw)
        c, s = np.cos(yaw - ego_yaw), np.sin(yaw - ego_yaw)
        vx, vy = rows[:, 7].copy(), rows[:, 8].copy()
        rows[:, 7], rows[:, 8] = c * vx - s * vy, s * vx + c * vy
        # a payload's values are within PAYLOAD_LIMIT in the RSU frame; in the ego frame a
        # position or velocity may pass the box bound: clip it (as the kernel does)
        rows[:, _MOVED] = np.clip(rows[:, _MOVED], -BIG, BIG)
    rows_obs = _rows(rows, np.ones(n_rows), cfg.max_objects)
    c, s = np.cos(ego_yaw), np.sin(ego_yaw)  # the unit in the ego frame (world_to_local_2d's operations)
    d0, d1 = x - ego_xy[0], y - ego_xy[1]
    info[:_PAYLOAD_LENGTH] = (1.0, world.tick - sent_tick, n_rows, c * d0 + s * d1,
                              -s * d0 + c * d1, wrap_angle(yaw - ego_yaw))
    _fill_payload(raw_obs, info, raw, fmt)
    return rows_obs, info, raw_obs


def rsu_observation(world, slot: int = 0) -> dict[str, np.ndarray]:
    """Fill the observation of the RSU agent in ``slot`` (zeros when no unit is active)."""
    cfg, t = world.config, world.table
    u = int(world.active_rsu[slot])
    # the base keys' shapes (as ``rsu_space``), without building the space every tick
    obs = {"unit": np.zeros(len(UNIT_FEATURES), np.float32),
           "calibration": np.zeros((2, 4, 4), np.float32),
           "objects": np.zeros((cfg.max_objects, len(OBJECT_FEATURES)), np.float32)}
    if cfg.obs_mode == "sensors":  # the rig captures slot 0's unit; further slots get blank sensors
        s = sensor_observation(world)
        obs["lidar"] = s["lidars"]["rsu_lidar"]
        if cfg.camera_images:
            obs["camera"] = s["cameras"]["rsu_cam"]
        if slot > 0:
            obs.update({k: {n: np.zeros_like(v) for n, v in obs[k].items()}
                        for k in ("camera", "lidar") if k in obs})
    if u < 0:
        return obs
    x, y, z, yaw = world.rsus.pose[u]
    obs["unit"][:] = (u, x, y, z, yaw, RSU_PITCH)
    t_world_rsu = world.rsus.matrix(u)
    t_world_ego = pose_matrix(t.pos[0, 0], t.pos[0, 1], 0.0, t.yaw[0])
    obs["calibration"][0] = t_world_rsu
    obs["calibration"][1] = relative_transform(t_world_ego, t_world_rsu)
    objs = world.rsu_objects(slot)
    vis = world.rsu_vis[slot][objs[:, 9].astype(np.int64)] if len(objs) else np.zeros(0)
    obs["objects"] = _rows(objs, vis, cfg.max_objects)
    return obs


def decode_inbox(data: bytes) -> np.ndarray:
    """Decode raw channel bytes into object rows (for tools that read recorded traffic); a raw
    payload (not an object list) gives no rows."""
    _, _, payload, fmt = decode_frame(data)
    if fmt != FORMAT_OBJECTS:
        return np.zeros((0, NUM_OBJECT_FIELDS), np.float32)
    return unpack_objects(payload, len(payload) - len(payload) % NUM_OBJECT_FIELDS)
