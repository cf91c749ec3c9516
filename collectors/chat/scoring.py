"""Scoring answers to Chat-V2XBench: accuracy, coordinate error and slot/keyword F1.

- *closed* questions (traffic light, speed / path decision, previous command, speed trend): the
  prediction is mapped to a canonical label with :data:`VOCAB` (first value whose synonyms occur
  in it; for the traffic light, a leading "no" without a colour is ``no``); accuracy = label equal.
- *coordinate* questions (spatial alignment): the first three numbers of the prediction are
  ``(x, y, z)``; the error is the Euclidean distance (m) to the label; a prediction without three
  numbers counts as a miss (``inf``, excluded from the mean, included in ``within_*``).
- *descriptive* questions: the set of ``(slot, value)`` keywords found (:func:`slots`) in the
  prediction against the set found in the reference answer; precision, recall, F1 per item,
  averaged (an item whose reference has no keywords scores 1 when the prediction has none too).

:func:`score` takes reference items (our schema) and ``{item id: predicted answer text}``;
:func:`load_predictions` reads them from a JSONL file of ``{"id", "answer"}`` lines (both
strings; an error names the file and the line).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

VOCAB: dict[str, dict[str, tuple[str, ...]]] = {
    "weather": {"clear": ("clear", "sunny"), "cloudy": ("cloudy", "overcast"),
                "rain": ("rain", "rainy", "raining"), "fog": ("fog", "foggy", "mist", "misty")},
    "time_of_day": {"day": ("daytime", "day"), "dusk": ("dusk", "twilight"), "night": ("night",)},
    "density": {"light": ("light traffic", "sparse traffic"), "moderate": ("moderate traffic",),
                "heavy": ("heavy traffic", "dense traffic", "congested")},
    "light": {"red": ("red",), "yellow": ("yellow", "amber"), "green": ("green",)},
    "class": {"car": ("car", "cars"), "large_vehicle": ("large vehicle", "truck", "bus", "van"),
              "pedestrian": ("pedestrian", "pedestrians"), "bicycle": ("cyclist", "bicycle", "bike"),
              "traffic_cone": ("traffic cone", "cone", "cones"), "static_obstacle": ("static obstacle",)},
    "speed": {"accelerate": ("accelerate", "speed up"), "decelerate": ("decelerate", "slow down"),
              "keep": ("keep the current speed", "keep its speed", "maintain", "keep speed", "keep"),
              "stop": ("stop",)},
    "path": {"turn_left": ("turn left",), "turn_right": ("turn right",), "go_straight": ("go straight",),
             "change_lane_left": ("change lane to the left", "change to the left lane"),
             "change_lane_right": ("change lane to the right", "change to the right lane"),
             "nudge_left": ("nudge to the left", "nudge left"), "nudge_right": ("nudge to the right", "nudge right"),
             "follow_lane": ("follow the lane", "follow lane", "lane following")},
    "command": {"left": ("turn left",), "right": ("turn right",), "straight": ("go straight",),
                "change_lane_left": ("change lane to the left",), "change_lane_right": ("change lane to the right",),
                "follow_lane": ("follow the lane", "follow lane")},
    "trend": {"accelerating": ("accelerating", "speeding up"), "decelerating": ("decelerating", "slowing down"),
              "unchanged": ("keeping its speed", "unchanged", "constant", "holding")},
    "reason": {"free": ("road ahead is clear",), "leader": ("slower",), "follow": ("safe gap",),
               "red": ("light ahead is red",), "yellow": ("light ahead is yellow",),
               "stop_sign": ("stop sign at the junction",), "yield": ("yield",),
               "conflict": ("cross the ego's path", "crossing the ego's path"),
               "clear_until": ("clear up to",), "slow_zone": ("lower speed limit", "curve"),
               "other": ("current traffic situation",)},
    "impact": {"collision_risk": ("collision risk",), "in_path": ("in the ego's path",),
               "monitor": ("no immediate conflict",)},
    "seen": {"rsu_only": ("only by the roadside", "only the roadside"), "ego_only": ("by the ego only",)},
}
CLOSED_SLOT = {"traffic_light": "light", "speed_decision": "speed", "path_decision": "path",
               "previous_command": "command", "speed_trend": "trend"}
_NUM = re.compile(r"[-+]?\d+(?:\.\d+)?")


def _has(text: str, phrase: str) -> bool:
    return re.search(r"(?<![\w-])" + re.escape(phrase) + r"(?![\w-])", text) is not None


def slots(text: str, groups=None) -> set[tuple[str, str]]:
    """``(slot, value)`` keywords found in ``text`` (lower-cased, whole words)."""
    t = " ".join(text.lower().split())
    out = set()
    for g, values in VOCAB.items():
        if groups is not None and g not in groups:
            continue
        for v, syn in values.items():
            if any(_has(t, s) for s in syn):
                out.add((g, v))
    return out


def closed_label(qtype: str, text: str) -> str | None:
    """Canonical label of a closed-form answer (``None``: not recognised)."""
    t = " ".join(text.lower().split())
    group = CLOSED_SLOT[qtype]
    if qtype == "traffic_light" and re.match(r"^\W*no\b", t):
        return "no"
    best, pos = None, math.inf
    for v, syn in VOCAB[group].items():
        for s in syn:
            m = re.search(r"(?<![\w-])" + re.escape(s) + r"(?![\w-])", t)
            if m and m.start() < pos:
                best, pos = v, m.start()
    return best


def coordinates(text: str) -> np.ndarray | None:
    """The first three numbers of ``text`` as ``(3,)`` (``None`` if fewer)."""
    nums = _NUM.findall(text)
    return np.array([float(x) for x in nums[:3]]) if len(nums) >= 3 else None


def f1(pred: set, ref: set) -> float:
    """Set F1 (1.0 when both are empty)."""
    if not pred and not ref:
        return 1.0
    tp = len(pred & ref)
    if tp == 0:
        return 0.0
    p, r = tp / len(pred), tp / len(ref)
    return 2 * p * r / (p + r)


def load_predictions(path: str | Path) -> dict[str, str]:
    """``{id: answer}`` from a JSONL file with one ``{"id": str, "answer": str}`` per line.

    Raises:
        FileNotFoundError: no such file. ValueError: a line that is not valid JSON, not an
            object, without a string ``id`` or ``answer``, or repeating an id (file and line
            named).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"predictions file {path} not found")
    preds: dict[str, str] = {}
    lines: dict[str, int] = {}
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            where = f"{path}:{n}"
            try:
                d = json.loads(line)
            except ValueError as e:
                raise ValueError(f"{where}: not valid JSON: {e}") from None
            if not isinstance(d, dict):
                raise ValueError(f"{where}: expected a JSON object {{\"id\", \"answer\"}}")
            for key in ("id", "answer"):
                if not isinstance(d.get(key), str):
                    got = "missing" if key not in d else f"{type(d[key]).__name__} {d[key]!r}"
                    raise ValueError(f"{where}: {key!r} must be a string, got {got}")
            if d["id"] in lines:
                raise ValueError(f"{where}: id {d['id']!r} repeats line {lines[d['id']]}")
            lines[d["id"]] = n
            preds[d["id"]] = d["answer"]
    return preds


def score(items: list[dict], predictions: dict[str, str]) -> dict:
    """Score ``predictions`` (``{id: answer}``) against reference ``items``.

    Returns:
        ``{"answered": n, "missing": n, "closed": {"accuracy", "n", "per_type"},
        "coordinate": {"mean_error_m", "median_error_m", "within_0.5m", "n"},
        "descriptive": {"f1", "n", "per_type"}, "per_level": {level: {"n", "closed",
        "coordinate", "descriptive"}}}`` (``per_level``: the same three groups over the items of
        each level, e.g. ``scene``, ``perception``, ``alignment``, ``planning``); missing
        predictions score as wrong answers.

    Raises:
        ValueError: a prediction that is not a string (its id named).
    """
    for k, v in predictions.items():
        if not isinstance(v, str):
            raise ValueError(f"score: the answer for {k!r} is {type(v).__name__} {v!r}, "
                             "not a string")
    scored = []  # (item, value): accuracy, F1 or error (m)
    missing = 0
    for it in items:
        pred = predictions.get(it["id"])
        if pred is None:
            missing += 1
            pred = ""
        if it["kind"] == "closed":
            v = float(closed_label(it["type"], pred) == it["label"])
        elif it["kind"] == "coordinate":
            xyz = coordinates(pred)
            v = math.inf if xyz is None else float(np.linalg.norm(xyz - np.asarray(it["label"])))
        else:  # an empty answer says nothing: it scores 0 even where the reference has no slots
            v = f1(slots(pred), slots(it["answer"])) if pred.strip() else 0.0
        scored.append((it, v))
    levels = dict.fromkeys(it["level"] for it in items)
    return {"answered": len(items) - missing, "missing": missing, **_groups(scored),
            "per_level": {lv: {"n": sum(it["level"] == lv for it, _ in scored),
                               **_groups([(it, v) for it, v in scored if it["level"] == lv])}
                          for lv in levels}}


def _groups(scored: list[tuple[dict, float]]) -> dict:
    """The closed / coordinate / descriptive summaries of scored items."""
    acc: dict[str, list[float]] = {}
    desc: dict[str, list[float]] = {}
    errs: list[float] = []
    for it, v in scored:
        if it["kind"] == "closed":
            acc.setdefault(it["type"], []).append(v)
        elif it["kind"] == "coordinate":
            errs.append(v)
        else:
            desc.setdefault(it["type"], []).append(v)
    all_acc = [x for v in acc.values() for x in v]
    all_f1 = [x for v in desc.values() for x in v]
    finite = [e for e in errs if math.isfinite(e)]
    return {
        "closed": {"accuracy": float(np.mean(all_acc)) if all_acc else None, "n": len(all_acc),
                   "per_type": {k: float(np.mean(v)) for k, v in sorted(acc.items())}},
        "coordinate": {"mean_error_m": float(np.mean(finite)) if finite else None,
                       "median_error_m": float(np.median(finite)) if finite else None,
                       "within_0.5m": float(np.mean([e <= 0.5 for e in errs])) if errs else None,
                       "n": len(errs)},
        "descriptive": {"f1": float(np.mean(all_f1)) if all_f1 else None, "n": len(all_f1),
                        "per_type": {k: float(np.mean(v)) for k, v in sorted(desc.items())}},
    }


__all__ = ["VOCAB", "closed_label", "coordinates", "f1", "load_predictions", "score", "slots"]
