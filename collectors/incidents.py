"""How an agent's red lights and vehicle collisions happened: ``v2xbench incidents``.

The suite summary says how many infractions a run had; this reads the per-run records of
``v2xbench eval`` folders (``routes/*.json``: the ego's speed every tick and the infraction
events) and says how each red light and vehicle collision came about:

- **red lights**, by what the ego did in the :data:`LOOKBACK_S` before it crossed the stop line:
  ``set_off`` (it stood, below :data:`STANDING_MPS`, and then went while the light was red),
  ``slowed`` (its slowest speed was below :data:`SLOW_MPS` without standing) or ``drove_through``
  (never below :data:`SLOW_MPS`); for the set-offs, how long it had stood (how many stood
  less than :data:`SHORT_STAND_S`: a rolling stop) and how many seconds it drove from rest to
  the line;
- **vehicle collisions**, by where on the ego the other vehicle was (``front``: the ego drove
  into it; ``rear``: it drove into the ego; ``side``; ``unknown`` for records written before the
  sides were recorded, ``infractions.contact_side``), whether the ego stood, and ``repeats``: the
  same vehicle registered again within :data:`REPEAT_S` (CARLA's rule registers one contact that
  lasts beyond its 5 s same-party window and 5 m place window again; ``metrics.py``).

Counts are also given per km of route completed, as the suite summary gives infractions.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from v2xbench.envs.v2x_intersection.evaluation.infractions import (
    COLLISION_VEHICLE,
    RED_LIGHT,
    SIDE_FRONT,
    SIDE_LEFT,
    SIDE_REAR,
    SIDE_RIGHT,
)

from v2xbench.files import atomic_write_text

from .jobs import all_results

LOOKBACK_S = 10.0  # s before the stop line that say how the ego came to a red light
STANDING_MPS = 0.3  # m/s: slower is standing
SLOW_MPS = 2.0  # m/s: a red light approached slower than this (without standing) "slowed"
SHORT_STAND_S = 2.0  # s: a set-off after a stand shorter than this is a rolling stop
REPEAT_S = 6.0  # s: the same vehicle registered again within this is one contact counted twice
RED_KINDS = ("set_off", "slowed", "drove_through")
SIDES = ("front", "side", "rear", "unknown")


def _side(value: float) -> str:
    v = int(value)
    return {SIDE_FRONT: "front", SIDE_LEFT: "side", SIDE_RIGHT: "side", SIDE_REAR: "rear"}.get(v, "unknown")


def red_light_approach(speed: np.ndarray, tick: int, dt: float) -> dict:
    """How the ego came to the red light it crossed at ``tick``: ``kind`` (:data:`RED_KINDS`),
    its speed at the line (m/s) and, for a set-off, the seconds it stood and the seconds from
    rest to the line."""
    t = min(int(tick), len(speed) - 1)
    back = speed[max(0, t - int(round(LOOKBACK_S / dt))):t + 1]
    out = {"tick": t, "speed": float(speed[t]), "standing_s": None, "to_line_s": None}
    if back.min() < STANDING_MPS:
        k = t
        while k > 0 and speed[k] >= STANDING_MPS:
            k -= 1
        j = k
        while j >= 0 and speed[j] < STANDING_MPS:
            j -= 1
        out.update(kind="set_off", standing_s=(k - j) * dt, to_line_s=(t - k) * dt)
    else:
        out["kind"] = "slowed" if back.min() < SLOW_MPS else "drove_through"
    return out


def vehicle_collisions(events: np.ndarray, speed: np.ndarray, dt: float) -> list[dict]:
    """Each vehicle collision of a run: tick, other vehicle, side, the ego's speed and whether it
    repeats the same vehicle's registration within :data:`REPEAT_S`."""
    out, last = [], {}
    for code, tick, other, value in events.tolist():
        if int(code) != COLLISION_VEHICLE:
            continue
        t, o = int(tick), int(other)
        repeat = o in last and (t - last[o]) * dt <= REPEAT_S + 1e-9
        last[o] = t
        out.append({"tick": t, "other": o, "side": _side(value), "speed": float(speed[min(t, len(speed) - 1)]),
                    "repeat": bool(repeat)})
    return out


def run_incidents(result: dict) -> dict:
    """Red-light approaches and vehicle collisions of one ``v2xbench eval`` result dict."""
    rec = result["record"]
    dt = float(rec.get("dt", 0.1))
    speed = np.asarray(rec["ego_speed"], float)
    events = np.asarray(rec["events"], float).reshape(-1, 4)
    if not len(speed):
        return {"red_lights": [], "collisions": []}
    reds = [red_light_approach(speed, t, dt) for c, t, _, _ in events.tolist() if int(c) == RED_LIGHT]
    return {"red_lights": reds, "collisions": vehicle_collisions(events, speed, dt)}


def _median(x: list) -> float:
    return float(np.median(x)) if x else float("nan")


def folder_incidents(folder: str | Path) -> dict:
    """The incidents of every run in an eval folder, summed: counts, per km and medians."""
    results = all_results(folder)
    km, reds, cols, failed = 0.0, [], [], 0
    for result in results:
        if result.get("record") is None:  # a run that failed (error or timeout) has no record
            failed += 1
            continue
        try:
            km += float(result["metrics"].get("km_completed", 0.0))
            inc = run_incidents(result)
        except (ValueError, KeyError, TypeError) as e:
            where = Path(folder) / "routes" / f"{result['job_id']}.json"
            raise ValueError(f"{where}: not a readable eval result ({type(e).__name__}: {e})") from None
        reds += inc["red_lights"]
        cols += inc["collisions"]
    per_km = (lambda n: n / km) if km > 0 else (lambda n: float("nan"))
    s = {"folder": str(folder), "runs": len(results) - failed, "runs_without_record": failed, "km_completed": km,
         "red_lights": len(reds),
         "red_lights_per_km": per_km(len(reds))}
    for kind in RED_KINDS:
        s[f"red_{kind}"] = sum(r["kind"] == kind for r in reds)
    setoffs = [r for r in reds if r["kind"] == "set_off"]
    s["red_set_off_stood_under_2s"] = sum(r["standing_s"] < SHORT_STAND_S for r in setoffs)
    s["red_set_off_median_standing_s"] = _median([r["standing_s"] for r in setoffs])
    s["red_set_off_median_to_line_s"] = _median([r["to_line_s"] for r in setoffs])
    s["red_median_speed_at_line"] = _median([r["speed"] for r in reds])
    s["vehicle_collisions"] = len(cols)
    s["vehicle_collisions_per_km"] = per_km(len(cols))
    for side in SIDES:
        s[f"collisions_{side}"] = sum(c["side"] == side for c in cols)
    s["collisions_ego_standing"] = sum(c["speed"] < STANDING_MPS for c in cols)
    s["collisions_repeats"] = sum(c["repeat"] for c in cols)
    s["collisions_distinct_per_km"] = per_km(len(cols) - s["collisions_repeats"])
    return s


def _f(x, nd: int = 1) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else (
        f"{x:.{nd}f}" if isinstance(x, float) else str(x))


def incidents_markdown(rows: dict[str, dict]) -> str:
    """Two tables (red lights, vehicle collisions), one row per named folder."""
    lines = ["| agent | runs | km | red lights (/km) | set off after standing (stood < 2 s) | slowed "
             "| drove through | median s stood | median s rest -> line | median m/s at line |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, s in rows.items():
        lines.append(f"| {name} | {s['runs']} | {_f(s['km_completed'])} | {s['red_lights']} "
                     f"({_f(s['red_lights_per_km'], 2)}) | {s['red_set_off']} ({s['red_set_off_stood_under_2s']}) | "
                     f"{s['red_slowed']} | "
                     f"{s['red_drove_through']} | {_f(s['red_set_off_median_standing_s'])} | "
                     f"{_f(s['red_set_off_median_to_line_s'])} | {_f(s['red_median_speed_at_line'])} |")
    lines += ["", "| agent | vehicle collisions (/km) | ego drove into it (front) | side | into the ego (rear) "
              "| side unknown | ego standing | repeats of one contact | distinct /km |",
              "|---|---|---|---|---|---|---|---|---|"]
    for name, s in rows.items():
        lines.append(f"| {name} | {s['vehicle_collisions']} ({_f(s['vehicle_collisions_per_km'], 2)}) | "
                     f"{s['collisions_front']} | {s['collisions_side']} | {s['collisions_rear']} | "
                     f"{s['collisions_unknown']} | {s['collisions_ego_standing']} | {s['collisions_repeats']} | "
                     f"{_f(s['collisions_distinct_per_km'], 2)} |")
    return "\n".join(lines) + "\n"


def build_incidents(named_folders: list[tuple[str, str | Path]], out: str | Path | None = None) -> dict[str, dict]:
    """Incidents of each ``(name, eval folder)``; with ``out``, writes ``out.json`` and ``out.md``
    (atomically). Returns the rows by name."""
    rows = {name: folder_incidents(folder) for name, folder in named_folders}
    if out is not None:
        out = Path(out)
        atomic_write_text(out.with_suffix(".json"), json.dumps(rows, indent=1) + "\n")
        atomic_write_text(out.with_suffix(".md"), incidents_markdown(rows))
    return rows
