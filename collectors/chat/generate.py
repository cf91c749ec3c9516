"""Chat-V2XBench QA pairs from keyframe facts: four levels, exact and descriptive answers.

:func:`keyframe_qa` turns one keyframe's facts (:mod:`.facts`) into QA items; the phrasing of
every question and answer is drawn from :mod:`.templates` with a generator seeded by
``(seed, crc32(keyframe id))``, so a data set is reproducible and ``--seed`` re-phrases it.

=========== =================== ============ ===============================================
level       type                kind         answer from
=========== =================== ============ ===============================================
scene       scene_description   descriptive  weather, time of day, density, obstacles, signal
scene       traffic_light       closed       logged signal state + affects-ego flag
perception  critical_objects    descriptive  up to two fused objects by risk (facts)
alignment   rsu_to_ego          coordinate   exact rigid transform RSU camera -> ego
planning    speed_decision      closed       expert's planned speeds
planning    path_decision       closed       route command ahead / nudge
planning    behavior            descriptive  speed + path decision + the reason that explains
                                             it (:func:`effective_reason` of the expert's
                                             binding constraint)
planning    previous_command    closed       logged navigation command at tick - 1
planning    speed_trend         closed       logged speeds at tick and tick - 10
=========== =================== ============ ===============================================

An item (our schema, one JSON line each)::

    {"id", "keyframe", "episode", "route_id", "town", "scenarios", "tick", "level", "type",
     "kind", "question", "answer", "label", "context", "hints", "split", "images"}

(:func:`keyframe_qa` gives all but ``context`` and ``split``, which the export adds.)

``label`` is the machine-readable answer: a canonical string (closed), ``[x, y, z]`` metres
(coordinate) or a dict of slots (descriptive). :func:`keyframe_qa` gives every item ``hints``:
the auto-labelling annotation (the ego's speed and navigation command, the nearby ground-truth
objects in the ego frame and the RSU camera's exact pose relative to the ego; the paper
conditions its prompts on it). It is not a prompt: the export (:mod:`.export`) adds the
hint-free ``context`` (only what the car has at run time) that prompts carry by default.
"""

from __future__ import annotations

import zlib

import numpy as np

from . import templates as T

LEVELS = ("scene", "perception", "alignment", "planning")
TYPES = {
    "scene_description": ("scene", "descriptive"), "traffic_light": ("scene", "closed"),
    "critical_objects": ("perception", "descriptive"), "rsu_to_ego": ("alignment", "coordinate"),
    "speed_decision": ("planning", "closed"), "path_decision": ("planning", "closed"),
    "behavior": ("planning", "descriptive"), "previous_command": ("planning", "closed"),
    "speed_trend": ("planning", "closed"),
}
CAMERA_ORDER = ("cam_front", "cam_front_right", "cam_back_right", "cam_back", "cam_back_left",
                "cam_front_left", "rsu_cam")
MAX_ALIGN = 2


def keyframe_id(facts: dict) -> str:
    """``<episode>_t<tick>``."""
    return f"{facts['episode']}_t{facts['tick']:05d}"


def context_text(f: dict) -> str:
    """The ``hints`` annotation: ego state, GT object hints (ego frame), the RSU camera pose."""
    e = f["ego"]
    lines = [f"Ego speed: {e['speed']:.1f} m/s; navigation command: {T.COMMAND[e['command']]}.",
             "Nearby objects (ground truth, ego frame: x forward, y left, metres):"]
    if f["objects"]:
        for o in f["objects"]:
            lines.append(f"- {T.CLASS.get(o['class'], o['class'])} #{o['id']} at ({o['x']:.2f}, {o['y']:.2f}), "
                         f"{o['speed']:.1f} m/s, {T.SEEN[o['seen_by']]}")
    else:
        lines.append("- none within 50 m")
    r = f.get("rsu")
    if r is None:
        lines.append("Roadside camera: no roadside unit is active.")
    else:
        lines.append(f"Roadside camera relative to the ego: position ({r['x']:.2f}, {r['y']:.2f}, {r['z']:.2f}) m, "
                     f"heading {r['heading_deg']:.1f} deg, pitch {r['pitch_deg']:.1f} deg down.")
    return "\n".join(lines)


def _pick(rng: np.random.Generator, options):
    return options[int(rng.integers(len(options)))]


def _cap(s: str) -> str:
    return s[:1].upper() + s[1:]


def _scene(f: dict, rng) -> tuple[str, dict]:
    d = f["density"]
    obst = f["obstacles"]
    if obst:
        what = ", ".join(f"{T.CLASS[o['class']]} at {o['x']:.0f} m" for o in obst)
        road = _pick(rng, T.ROAD_OBST).format(n=len(obst), what=what)
        if f["construction"]:
            road += T.CONSTRUCTION
    else:
        road = _pick(rng, T.ROAD_CLEAR)
    li, j = f["light"], f.get("junction")
    if li["affects_ego"]:
        signal = f"The traffic light for the ego's lane is {li['state']}."
    elif li["state"] == "stop_sign":
        signal = "The ego's lane has a stop sign at the junction ahead."
    elif j is not None and j["control"] == "signal":
        signal = f"A signalized junction is {j['distance']:.0f} m away; its light does not yet affect the ego."
    else:
        signal = "No traffic signal affects the ego."
    text = _pick(rng, T.SCENE).format(time=T.TIME[f["time_of_day"]], weather=T.WEATHER[f["weather"]],
                                      density=T.DENSITY[d["level"]], nv=d["vehicles"], np=d["pedestrians"],
                                      road=road, signal=signal)
    slots = {"weather": f["weather"], "time_of_day": f["time_of_day"], "density": d["level"],
             "light": li["state"] if li["affects_ego"] else "none", "obstacles": len(obst),
             "construction": bool(f["construction"])}
    return " ".join(text.split()), slots


def _light(f: dict, rng) -> tuple[str, str]:
    li = f["light"]
    if li["affects_ego"]:
        return _pick(rng, T.LIGHT_YES).format(c=li["state"], d=li["distance"]), li["state"]
    return _pick(rng, T.LIGHT_NO), "no"


def _critical(f: dict, rng) -> tuple[str, dict]:
    crit = f["critical"]
    if not crit:
        return _pick(rng, T.CRIT_NONE), {"objects": []}
    parts = []
    for k, o in enumerate(crit):
        key = "collision_risk_behind" if o["impact"] == "collision_risk" and o["x"] < 0 else o["impact"]
        impact = T.IMPACT[key].format(m=o["closest_m"], s=o["closest_s"], gap=o["path_gap"] or 0.0)
        if k == 0 and o["impact"] != "monitor":
            impact += T.RESPONSE.get(f["plan"]["speed_decision"], "")
        cls = T.CLASS[o["class"]]
        parts.append(_pick(rng, T.CRIT_ONE).format(cls=cls, Cls=_cap(cls), id=o["id"], x=o["x"], y=o["y"],
                                                   motion=T.MOTION[o["motion"]], v=o["speed"],
                                                   seen=T.SEEN[o["seen_by"]], impact=impact))
    slots = {"objects": [{k: o[k] for k in ("id", "class", "x", "y", "motion", "impact", "seen_by")}
                         for o in crit]}
    return " ".join(parts), slots


def effective_reason(decision: str, constraint: str) -> str:
    """The reason that explains a speed decision (the expert's binding constraint, re-read).

    A stop-type constraint (light, sign, yield, conflict) explains decelerating or stopping; while
    the ego still accelerates or keeps its speed it only bounds how far the way is clear
    (``clear_until``). A leader explains slowing down; otherwise the ego follows it (``follow``).
    A free road explains accelerating or keeping; slowing on a free road is a ``slow_zone``.
    """
    slowing = decision in ("decelerate", "stop")
    if constraint in T.STOP_THINGS:
        return constraint if slowing else "clear_until"
    if constraint == "leader":
        return "leader" if slowing else "follow"
    if constraint == "free":
        return "slow_zone" if slowing else "free"
    return "other"


def _behavior(f: dict, rng) -> tuple[str, dict]:
    p = f["plan"]
    top = f["critical"][0] if f["critical"] else None
    cls = T.CLASS[top["class"]] if top else ("vehicle" if p["reason"] == "leader" else "road user")
    why = effective_reason(p["speed_decision"], p["reason"])
    reason = T.REASON[why].format(cls=cls, what=T.STOP_THINGS.get(p["reason"], ""))
    speed, path = T.SPEED[p["speed_decision"]], T.PATH[p["path_decision"]]
    text = _pick(rng, T.BEHAVIOR).format(speed=speed, Speed=_cap(speed), path=path, reason=reason)
    return text, {"speed_decision": p["speed_decision"], "path_decision": p["path_decision"],
                  "reason": why, "constraint": p["reason"]}


def _closed(kind: str, value: str, rng) -> str:
    return _pick(rng, T.CLOSED[kind]).format(v=value, V=_cap(value))


def keyframe_qa(f: dict, seed: int = 0) -> list[dict]:
    """All QA items of one keyframe (module docstring)."""
    kid = keyframe_id(f)
    rng = np.random.default_rng([int(seed), zlib.crc32(kid.encode())])
    items: list[tuple[str, str, str, object]] = []  # (type, question, answer, label)

    def add(kind: str, answer: str, label, **fmt) -> None:
        items.append((kind, _pick(rng, T.QUESTIONS[kind]).format(**fmt), answer, label))

    add("scene_description", *_scene(f, rng))
    add("traffic_light", *_light(f, rng))
    add("critical_objects", *_critical(f, rng))
    align = list(f.get("alignment", []))
    if align:
        for k in sorted(rng.choice(len(align), size=min(MAX_ALIGN, len(align)), replace=False)):
            a = align[int(k)]
            x, y, z = a["xyz_cam"]
            ex, ey, ez = a["xyz_ego"]
            cls = T.CLASS.get(a["class"], a["class"].replace("_", " "))
            ans = _pick(rng, T.ALIGN).format(cls=cls, x=ex, y=ey, z=ez)
            add("rsu_to_ego", ans, [round(ex, 2), round(ey, 2), round(ez, 2)], cls=cls, x=x, y=y, z=z)
    p, e = f["plan"], f["ego"]
    add("speed_decision", _closed("speed_decision", T.SPEED[p["speed_decision"]], rng), p["speed_decision"])
    add("path_decision", _closed("path_decision", T.PATH[p["path_decision"]], rng), p["path_decision"])
    add("behavior", *_behavior(f, rng))
    add("previous_command", _closed("previous_command", T.COMMAND[e["prev_command"]], rng), e["prev_command"])
    add("speed_trend", _closed("speed_trend", T.TREND[e["speed_trend"]], rng), e["speed_trend"])
    ctx = context_text(f)
    images = [f["images"][c] for c in CAMERA_ORDER if c in f.get("images", {})]
    base = {"keyframe": kid, "episode": f["episode"], "route_id": f["route_id"], "town": f["town"],
            "scenarios": f["scenarios"], "tick": f["tick"], "hints": ctx, "images": images}
    out = []
    for i, (kind, q, a, label) in enumerate(items):
        level, qkind = TYPES[kind]
        out.append({**base, "id": f"{kid}_{i:02d}", "level": level, "type": kind, "kind": qkind,
                    "question": q, "answer": a, "label": label})
    return out


__all__ = ["CAMERA_ORDER", "LEVELS", "TYPES", "context_text", "effective_reason", "keyframe_id",
           "keyframe_qa"]
