"""Keyframe facts: the privileged state a Chat-V2XBench keyframe's answers are computed from.

Collection (:mod:`..dataset.collect`) calls :func:`keyframe_facts` every ``KEYFRAME_EVERY``
ticks and stores the result (plain JSON) in the shard's ``keyframes.jsonl``; the QA generator
(:mod:`.generate`) turns facts into questions and answers without the simulator, so answers can
be re-phrased or re-generated without re-collecting. Frames: ego frame = x forward, y left, z up,
origin at the ego box centre on the ground (metres); ``rsu_cam`` = the roadside camera's optical
frame (x right, y down, z forward).

Definitions (exact, tested):

- ``light``: the signal of the ego's current route lane as in the ego observation
  (``EGO_FEATURES.light_state``); it *affects* the ego when it is green/yellow/red and the stop
  line is at most ``record.LIGHT_RANGE`` (40 m) ahead.
- ``ego.speed_trend``: ``speed(t) - speed(t - 1 s)`` > ``TREND_EPS`` accelerating, <
  ``-TREND_EPS`` decelerating, else unchanged (speeds as logged in the shard, ``ego_speed``).
- ``ego.prev_command``: the logged navigation command of the previous frame (tick - 1).
- ``alignment``: jointly visible objects (>= 10 LiDAR returns from both the ego and the RSU);
  ``xyz_cam`` their box centre in the RSU camera frame rounded to 1 cm, ``xyz_ego`` the exact
  rigid transform (``geometry.relative_transform(T_world_ego, T_world_cam)``) of ``xyz_cam``.
- ``critical``: up to two fused-set objects ranked by a risk score from the closest approach of
  constant-velocity motion relative to the ego (within ``HORIZON_S``) and from standing in the
  expert's planned path (module constants below).
- ``plan``: the expert's speed decision (stop / accelerate / decelerate / keep, from its planned
  speeds), path decision (route command ahead, or a nudge when its waypoints leave the lane centre)
  and binding reason (``Plan.reason``).
"""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.core.classes import (
    BICYCLE,
    CAR,
    CLASS_NAMES,
    LARGE_VEHICLE,
    PEDESTRIAN,
    STATIC_OBSTACLE,
    TRAFFIC_CONE,
    TRAFFIC_LIGHT,
    TRAFFIC_SIGN,
)
from v2xbench.envs.v2x_intersection.core.geometry import (
    invert_transform,
    relative_transform,
    transform_points,
    world_to_local_2d,
)
from v2xbench.envs.v2x_intersection.sensors import boxes_in_frame
from v2xbench.envs.v2x_intersection.town.model import COMMAND_NAMES, CONTROL_NAMES, FOLLOW_LANE

from ..dataset.record import light_info, nav_command

KEYFRAME_EVERY = 10  # ticks (1 s at 10 Hz), as the paper
TREND_EPS = 0.2  # m/s over 1 s
HINT_RANGE, MAX_HINTS = 50.0, 10  # m, objects listed in every prompt
HORIZON_S = 5.0  # s of constant-velocity relative motion for the closest approach
RISK_MIN = 0.1  # objects below this risk are not critical
LIGHT_NAMES = {-1: "none", 0: "green", 1: "yellow", 2: "red", 3: "stop_sign"}
SPEED_EPS = 0.5  # m/s: planned change over 1 s that counts as accelerating / decelerating
STOP_SPEED = 0.3  # m/s
NUDGE_M = 0.8  # m: waypoints this far from the lane centre are a nudge
DYNAMIC = (CAR, LARGE_VEHICLE, PEDESTRIAN, BICYCLE)
POLES = (TRAFFIC_LIGHT, TRAFFIC_SIGN)


def _r(x, nd: int = 2) -> float:
    return round(float(x), nd)


def _seen_by(b: dict, i: int) -> str:
    e, r = bool(b["in_ego"][i]), bool(b["in_rsu"][i])
    return "both" if e and r else ("ego" if e else "rsu")


def object_hints(fused_ego: dict) -> list[dict]:
    """Nearest fused-set objects (not poles) within ``HINT_RANGE``: the prompt's GT hints."""
    c = fused_ego["center"]
    d = np.linalg.norm(c[:, :2], axis=1)
    keep = np.flatnonzero((d <= HINT_RANGE) & ~np.isin(fused_ego["class"], POLES))
    keep = keep[np.argsort(d[keep])][:MAX_HINTS]
    return [{"id": int(fused_ego["id"][i]), "class": CLASS_NAMES[int(fused_ego["class"][i])],
             "x": _r(c[i, 0]), "y": _r(c[i, 1]),
             "speed": _r(np.linalg.norm(fused_ego["velocity"][i, :2]), 1),
             "seen_by": _seen_by(fused_ego, i)} for i in keep]


def _motion(vel: np.ndarray, yaw: float) -> str:
    """Motion of an object relative to the ego's heading (ego-frame velocity and yaw)."""
    if np.linalg.norm(vel[:2]) < STOP_SPEED:
        return "stationary"
    h = abs((yaw + np.pi) % (2 * np.pi) - np.pi)
    if h < np.deg2rad(30):
        return "same_direction"
    if h > np.deg2rad(150):
        return "oncoming"
    return "crossing_right" if vel[1] < 0 else "crossing_left"


def _path_gap(path_ego: np.ndarray, xy: np.ndarray, half_width: np.ndarray) -> np.ndarray:
    """Distance along the planned path to each object standing in it (inf where not in it)."""
    if len(path_ego) < 2 or len(xy) == 0:
        return np.full(len(xy), np.inf)
    seg = np.linalg.norm(np.diff(path_ego, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    d = np.linalg.norm(xy[:, None, :] - path_ego[None], axis=2)
    j = np.argmin(d, axis=1)
    inside = (d[np.arange(len(xy)), j] < half_width + 1.2) & (path_ego[j, 0] > 0.0)
    return np.where(inside, s[j], np.inf)


def critical_objects(fused_ego: dict, ego_speed: float, path_ego: np.ndarray) -> list[dict]:
    """Up to two most critical fused objects (risk score in the module docstring)."""
    cls = fused_ego["class"]
    sel = np.flatnonzero(np.isin(cls, (*DYNAMIC, TRAFFIC_CONE, STATIC_OBSTACLE)))
    if len(sel) == 0:
        return []
    p = fused_ego["center"][sel, :2]
    v = fused_ego["velocity"][sel, :2]
    vrel = v - np.array([ego_speed, 0.0])
    vv = np.maximum((vrel**2).sum(1), 1e-9)
    t_star = np.clip(-(p * vrel).sum(1) / vv, 0.0, HORIZON_S)
    d_star = np.linalg.norm(p + vrel * t_star[:, None], axis=1)
    half = 0.5 * fused_ego["size"][sel, 1]
    r_near = np.exp(-np.maximum(d_star - half - 1.5, 0.0) / 3.0) * np.exp(-t_star / 2.5)
    gap = _path_gap(path_ego, p, half)
    r_path = np.where(np.isfinite(gap), np.exp(-np.nan_to_num(gap, posinf=1e3) / 20.0), 0.0)
    risk = np.maximum(r_near, r_path)
    order = np.argsort(-risk)[:2]
    out = []
    for k in order:
        if risk[k] < RISK_MIN:
            break
        i = sel[k]
        if t_star[k] < 4.0 and d_star[k] < half[k] + 2.5:
            impact = "collision_risk"
        elif np.isfinite(gap[k]):
            impact = "in_path"
        else:
            impact = "monitor"
        out.append({
            "id": int(fused_ego["id"][i]), "class": CLASS_NAMES[int(cls[i])],
            "x": _r(p[k, 0]), "y": _r(p[k, 1]), "vx": _r(v[k, 0]), "vy": _r(v[k, 1]),
            "speed": _r(np.linalg.norm(v[k]), 1), "motion": _motion(v[k], float(fused_ego["yaw"][i])),
            "distance": _r(np.linalg.norm(p[k]), 1), "closest_m": _r(d_star[k], 1),
            "closest_s": _r(t_star[k], 1), "path_gap": None if not np.isfinite(gap[k]) else _r(gap[k], 1),
            "impact": impact, "risk": _r(risk[k], 3), "seen_by": _seen_by(fused_ego, i),
        })
    return out


def alignment_targets(joint: dict, t_world_ego: np.ndarray, t_world_cam: np.ndarray) -> list[dict]:
    """Jointly visible objects with their RSU-camera and ego-frame box centres (docstring)."""
    t_cam_world = invert_transform(t_world_cam)
    t_ego_cam = relative_transform(t_world_ego, t_world_cam)
    out = []
    for i in range(len(joint["id"])):
        cam = np.round(transform_points(t_cam_world, joint["center"][i]), 2)
        ego = transform_points(t_ego_cam, cam)
        out.append({"id": int(joint["id"][i]), "class": CLASS_NAMES[int(joint["class"][i])],
                    "xyz_cam": [float(v) for v in cam], "xyz_ego": [round(float(v), 4) for v in ego],
                    "points": [int(joint["ego_lidar_points"][i]), int(joint["rsu_lidar_points"][i])]})
    return out


def rsu_relative(cal: dict) -> dict | None:
    """Position (m) and heading / pitch (deg) of the RSU camera in the ego frame."""
    if cal["rsu_unit"] < 0 or "rsu_cam" not in cal:
        return None
    t = cal["rsu_cam"]["T_ego_sensor"]
    z_axis = t[:3, 2]  # optical axis
    return {"unit": int(cal["rsu_unit"]), "x": _r(t[0, 3]), "y": _r(t[1, 3]), "z": _r(t[2, 3]),
            "heading_deg": _r(np.rad2deg(np.arctan2(z_axis[1], z_axis[0])), 1),
            "pitch_deg": _r(np.rad2deg(np.arcsin(-z_axis[2])), 1)}


def speed_decision(v: float, speeds: np.ndarray) -> str:
    """``stop`` / ``accelerate`` / ``decelerate`` / ``keep`` from the expert's planned speeds
    (``speeds[k]`` at ``0.5 (k + 1)`` s)."""
    if speeds[2] < STOP_SPEED:
        return "stop"
    dv = float(speeds[1]) - v
    return "accelerate" if dv > SPEED_EPS else ("decelerate" if dv < -SPEED_EPS else "keep")


def path_decision(world, waypoints: np.ndarray, route_ego: np.ndarray) -> str:
    """Route command ahead (``turn_left`` ...), a nudge around something, or ``follow_lane``."""
    r, k0, v = world.route, world.monitor.progress, float(world.table.speed[0])
    ahead = r.commands[k0: k0 + int(max(25.0, 3.0 * v))]
    turns = ahead[ahead != FOLLOW_LANE]
    if len(turns):
        return {"left": "turn_left", "right": "turn_right", "straight": "go_straight",
                "change_lane_left": "change_lane_left",
                "change_lane_right": "change_lane_right"}[COMMAND_NAMES[int(turns[0])]]
    if len(route_ego) >= 2 and len(waypoints):
        n = len(route_ego)
        d = np.linalg.norm(waypoints[:, None, :] - route_ego[None, :, :2], axis=2)
        j = np.argmin(d, axis=1)
        tan = route_ego[np.minimum(j + 1, n - 1), :2] - route_ego[np.maximum(j - 1, 0), :2]
        tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-9)
        rel = waypoints - route_ego[j, :2]
        lat = tan[:, 0] * rel[:, 1] - tan[:, 1] * rel[:, 0]  # signed, left positive
        k = int(np.argmax(np.abs(lat)))
        if abs(lat[k]) > NUDGE_M:
            return "nudge_left" if lat[k] > 0 else "nudge_right"
    return "follow_lane"


def scene_facts(world, fused_world: dict) -> dict:
    """Weather, time of day, traffic density, road conditions and the signal ahead."""
    t = world.table
    spec = world.spec
    ego = t.pos[0]
    act = np.flatnonzero(t.active)
    act = act[act > 0]
    d = np.linalg.norm(t.pos[act] - ego, axis=1)
    kinds = t.kind[act]
    n_veh = int(((kinds == CAR) | (kinds == LARGE_VEHICLE))[d < 50.0].sum())
    n_ped = int((kinds == PEDESTRIAN)[d < 30.0].sum())
    n_bike = int((kinds == BICYCLE)[d < 30.0].sum())
    level = "light" if n_veh <= 3 else ("moderate" if n_veh <= 8 else "heavy")
    obst = np.isin(fused_world["class"], (TRAFFIC_CONE, STATIC_OBSTACLE))
    loc = world_to_local_2d(fused_world["center"][:, :2], ego, float(t.yaw[0]))
    ahead = obst & (loc[:, 0] > 0) & (loc[:, 0] < 60.0) & (np.abs(loc[:, 1]) < 8.0)
    obstacles = [{"class": CLASS_NAMES[int(fused_world["class"][i])], "x": _r(loc[i, 0]),
                  "y": _r(loc[i, 1])} for i in np.flatnonzero(ahead)[:6]]
    lane = int(world.route.lane_ids[min(world.monitor.progress, len(world.route.lane_ids) - 1)])
    jid = int(world.town.index.junction_ahead[lane])
    junction = None
    if jid >= 0:
        j = world.town.junctions[jid]
        junction = {"control": CONTROL_NAMES[j.control],
                    "distance": _r(np.linalg.norm(np.asarray(j.center) - ego), 1)}
    return {"weather": spec.weather if spec else "clear",
            "time_of_day": spec.time_of_day if spec else "day",
            "density": {"vehicles": n_veh, "pedestrians": n_ped, "bicycles": n_bike, "level": level},
            "obstacles": obstacles, "construction": any(o["class"] == "traffic_cone" for o in obstacles),
            "junction": junction}


def keyframe_facts(world, frame: dict, expert, history: dict, images: dict, episode: dict) -> dict:
    """The facts of the current keyframe (module docstring).

    Args:
        world: the world at the keyframe tick. frame: ``SensorRig.capture(world)`` (with GT).
        expert: the bound expert after ``act`` on this tick (``last_plan``).
        history: ``{"speed": {tick: m/s}, "command": {tick: code}}`` of the episode so far.
        images: ``{camera name: image path relative to the data set root}``.
        episode: ``{"episode", "route_id", "town", "scenarios"}`` of the shard.
    """
    t = world.table
    cal = frame["calibration"]
    tick = int(world.tick)
    t_world_ego = cal["T_world_ego"]
    fused_ego = boxes_in_frame(frame["gt"]["fused"], invert_transform(t_world_ego))
    plan = expert.last_plan
    v = float(t.speed[0])
    state, affects, line = light_info(world)
    prev_tick = max(tick - KEYFRAME_EVERY, min(history["speed"]))
    v_prev = float(history["speed"][prev_tick])
    dv = v - v_prev
    trend = "accelerating" if dv > TREND_EPS else ("decelerating" if dv < -TREND_EPS else "unchanged")
    cmd_prev = history["command"].get(tick - 1, nav_command(world))
    k0 = world.monitor.progress
    route_ego = world_to_local_2d(world.route.points[max(k0 - 10, 0): k0 + 60], t.pos[0], float(t.yaw[0]))
    path_ego = world_to_local_2d(plan.path, t.pos[0], float(t.yaw[0])) if len(plan.path) else route_ego
    crit = critical_objects(fused_ego, v, path_ego)
    align = []
    if cal["rsu_unit"] >= 0 and "rsu_cam" in cal:
        align = alignment_targets(frame["gt"]["joint"], t_world_ego, cal["rsu_cam"]["T_world_sensor"])
    facts = {
        **episode, "tick": tick, "time_s": round(tick * world.config.dt, 1), "images": images,
        **scene_facts(world, frame["gt"]["fused"]),
        "ego": {"speed": _r(v), "speed_prev_1s": _r(v_prev), "prev_tick": int(prev_tick),
                "speed_trend": trend, "command": COMMAND_NAMES[nav_command(world)],
                "prev_command": COMMAND_NAMES[int(cmd_prev)],
                "speed_limit": _r(world.town.index.speed_limit[int(world.route.lane_ids[
                    min(world.monitor.progress, len(world.route.lane_ids) - 1)])], 1)},
        "light": {"state": LIGHT_NAMES[state], "affects_ego": affects,
                  "distance": _r(line, 1) if line >= 0 else None},
        "objects": object_hints(fused_ego),
        "rsu": rsu_relative(cal),
        "critical": crit,
        "alignment": align,
        "plan": {"reason": plan.reason, "speed_decision": speed_decision(v, plan.speeds),
                 "path_decision": path_decision(world, plan.waypoints, route_ego),
                 "target_speed_1s": _r(plan.speeds[1]), "accel": _r(plan.accel)},
    }
    if cal["rsu_unit"] >= 0 and "rsu_cam" in cal:
        facts["T_ego_rsu_cam"] = [round(float(x), 9) for x in relative_transform(
            t_world_ego, cal["rsu_cam"]["T_world_sensor"]).ravel()]
    return facts


__all__ = ["KEYFRAME_EVERY", "TREND_EPS", "alignment_targets", "critical_objects", "keyframe_facts",
           "object_hints", "path_decision", "rsu_relative", "scene_facts", "speed_decision"]
