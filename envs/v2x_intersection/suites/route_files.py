"""Route files and route suites: JSON routes with scenario instances, validated on load.

A route file (``format: "v2xbench-route/1"``) holds one route::

    {
      "format": "v2xbench-route/1",
      "id": "test50_007",                 # unique within its suite
      "town": "Town12",                   # a named town
      "lanes": [12, 240, 57, ...],        # the exact lane sequence (the planner's output)
      "waypoints": [[x, y], ...],         # route points every ~20 m (for people and other tools)
      "scenarios": [                      # scenario instances along the route, in driving order
        {"type": "PedestrianCrossing", "params": {},
         "site": {"lanes": [57, 301], "key": 1, "s_on_key": 8.4},
         "trigger": [x, y], "conflict": [x, y]}
      ],
      "weather": "clear", "time_of_day": "day",
      "seed": 7                           # seeds the world at reset
    }

A suite file (``format: "v2xbench-suite/1"``) is ``{"name", "split", "routes": [route, ...]}``.
Suites ship with the package in ``suites/`` (``train``, ``val``, ``test50``).

Loading validates every field against :mod:`.route_schema` (types, bounds, lanes, positions on the
route, scenario parameters, ``extra`` shapes, unknown keys) and raises ``ValueError`` naming the
file and the field path, so a bad file fails before any episode or evaluation job starts.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.validation import Choice, Float, Int
from ..town import NAMED_TOWNS, get_town
from ..town.routes import Route, route_from_lanes
from . import route_schema as S

ROUTE_FORMAT = "v2xbench-route/1"
SUITE_FORMAT = "v2xbench-suite/1"
WEATHERS = ("clear", "cloudy", "rain", "fog")
TIMES_OF_DAY = ("day", "dusk", "night")
SUITE_DIR = Path(__file__).parent


@dataclass
class ScenarioInstance:
    """One scenario placed on a route (see module docstring)."""

    type: str
    site_lanes: tuple[int, ...]
    key: int
    s_on_key: float
    extra: tuple = ()
    params: dict = field(default_factory=dict)
    trigger: tuple[float, float] = (0.0, 0.0)
    conflict: tuple[float, float] = (0.0, 0.0)


@dataclass
class RouteSpec:
    """A validated route file (see module docstring)."""

    id: str
    town: str
    lanes: list[int]
    waypoints: np.ndarray
    scenarios: list[ScenarioInstance]
    weather: str = "clear"
    time_of_day: str = "day"
    seed: int = 0

    def to_dict(self) -> dict:
        """JSON-compatible dict (inverse of :func:`parse_route`)."""
        return {
            "format": ROUTE_FORMAT, "id": self.id, "town": self.town, "lanes": [int(x) for x in self.lanes],
            "waypoints": np.round(np.asarray(self.waypoints, float), 3).tolist(),
            "scenarios": [
                {"type": s.type, "params": dict(s.params),
                 "site": {"lanes": [int(x) for x in s.site_lanes], "key": int(s.key), "s_on_key": float(s.s_on_key),
                          "extra": _to_json(s.extra)},
                 "trigger": [round(float(v), 3) for v in s.trigger],
                 "conflict": [round(float(v), 3) for v in s.conflict]}
                for s in self.scenarios
            ],
            "weather": self.weather, "time_of_day": self.time_of_day, "seed": int(self.seed),
        }


def _to_json(x):
    """Site ``extra`` data (nested tuples of numbers) as JSON lists."""
    if isinstance(x, (tuple, list)):
        return [_to_json(v) for v in x]
    if isinstance(x, (np.integer, int)) and not isinstance(x, bool):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x)
    return x


def _to_tuple(x):
    """Inverse of :func:`_to_json`: lists back to (nested) tuples."""
    return tuple(_to_tuple(v) for v in x) if isinstance(x, list) else x


def parse_route(d: dict, where: str = "route", path: str = "") -> RouteSpec:
    """Validate a route dict against the schema (:mod:`.route_schema`); build a :class:`RouteSpec`.

    Args:
        d: the route, as read from JSON.
        where: what holds it (``"route file r.json"``, ``"suite s.json"``), first in messages.
        path: the route's path within ``where`` (``"routes[3]"``; empty for a route file).

    Raises:
        ValueError: ``"{where}: {field path}: {problem}"``, e.g. ``suite s.json:
            routes[3].scenarios[1].params.speed: 1000000000.0 is outside [0, 30] m/s``.
    """
    try:
        return _parse_route(d, path)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None


def _parse_route(d: Any, path: str) -> RouteSpec:
    if not isinstance(d, dict):
        raise ValueError(f"{path or 'route'}: expected a JSON object, got {type(d).__name__}")
    S.check_keys(d, S.ROUTE_KEYS, path, S.ROUTE_REQUIRED)
    if d["format"] != ROUTE_FORMAT:
        raise ValueError(f"{S.join(path, 'format')}: {d['format']!r} is not {ROUTE_FORMAT!r}")
    S.ID_RULE.check(d["id"], S.join(path, "id"))
    Choice(tuple(NAMED_TOWNS)).check(d["town"], S.join(path, "town"))
    town_name = d["town"]
    town = get_town(town_name)
    lanes = S.int_list(d["lanes"], S.join(path, "lanes"), 0, len(town.lanes), S.MAX_LANES,
                       f"lane ids of {town_name}")
    S.lane_chain(town, lanes, S.join(path, "lanes"))
    try:
        route = _route_of(town_name, tuple(lanes))
    except ValueError as e:
        raise ValueError(f"{S.join(path, 'lanes')}: {e}") from None
    wpath = S.join(path, "waypoints")
    raw = d["waypoints"]
    if not isinstance(raw, list) or not 2 <= len(raw) <= S.MAX_WAYPOINTS:
        n = len(raw) if isinstance(raw, list) else type(raw).__name__
        raise ValueError(f"{wpath}: expected a list of 2 to {S.MAX_WAYPOINTS} [x, y] pairs, "
                         f"got {n}")
    wps = np.array([S.point(w, f"{wpath}[{k}]") for k, w in enumerate(raw)], float)
    S.check_on_route(wps, route.points, wpath, "waypoint")
    spath = S.join(path, "scenarios")
    raw = d["scenarios"]
    if not isinstance(raw, list) or len(raw) > S.MAX_SCENARIOS:
        got = f"{len(raw)} scenarios" if isinstance(raw, list) else type(raw).__name__
        raise ValueError(f"{spath}: expected a list of at most {S.MAX_SCENARIOS} scenarios, "
                         f"got {got}")
    scen, seen, last = [], [], -1.0
    for k, s in enumerate(raw):
        w = f"{spath}[{k}]"
        inst, conflict_s = _parse_scenario(s, w, town, lanes, route)
        for j, other in enumerate(seen):
            same_site = (other.type, other.site_lanes, other.key) == (inst.type, inst.site_lanes,
                                                                       inst.key)
            if same_site and abs(other.s_on_key - inst.s_on_key) < S.DUPLICATE_M:
                raise ValueError(f"{w}: repeats {spath}[{j}] (same type, site and conflict point)")
        if k > 0 and _starts_route(inst.type):
            raise ValueError(f"{w}: {inst.type} starts the route at its site (the ego starts "
                             "there), so it can only be the route's first scenario")
        if conflict_s < last:
            raise ValueError(f"{w}: its conflict point ({conflict_s:.1f} m along the route) comes "
                             f"before the previous scenario's ({last:.1f} m); list scenarios in "
                             "driving order")
        seen.append(inst)
        last = conflict_s
        scen.append(inst)
    weather = d.get("weather", "clear")
    Choice(WEATHERS).check(weather, S.join(path, "weather"))
    tod = d.get("time_of_day", "day")
    Choice(TIMES_OF_DAY).check(tod, S.join(path, "time_of_day"))
    S.SEED_RULE.check(d["seed"], S.join(path, "seed"))
    return RouteSpec(d["id"], town_name, list(lanes), wps, scen, weather, tod, int(d["seed"]))


def _starts_route(name: str) -> bool:
    from ..scenarios import get_scenario

    return get_scenario(name).starts_route


def _parse_scenario(s: Any, path: str, town, lanes: list[int],
                    route: Route) -> tuple[ScenarioInstance, float]:
    """One scenario instance of a route and its conflict point's arc length along the route (m)."""
    from ..scenarios import get_scenario

    if not isinstance(s, dict):
        raise ValueError(f"{path}: expected an object, got {type(s).__name__}")
    S.check_keys(s, S.SCENARIO_KEYS, path, ("type", "site"))
    typ = S.need(s, "type", str, path, "a scenario type name")
    try:
        cls = get_scenario(typ)
    except ValueError as e:
        raise ValueError(f"{S.join(path, 'type')}: {e}") from None
    params = S.check_params(typ, s.get("params", {}), cls.defaults, S.join(path, "params"))
    site = S.need(s, "site", dict, path, "an object")
    sp = S.join(path, "site")
    S.check_keys(site, S.SITE_KEYS, sp, ("lanes", "key", "s_on_key"))
    sl = S.int_list(site["lanes"], S.join(sp, "lanes"), 0, len(town.lanes), 64,
                    f"lane ids of {town.name}")
    n = len(sl)
    if not any(lanes[i:i + n] == sl for i in range(len(lanes) - n + 1)):
        raise ValueError(f"{S.join(sp, 'lanes')}: {sl} is not a stretch of the route's lanes")
    Int(0, n - 1, why=f"an index into the site's {n} lanes").check(site["key"], S.join(sp, "key"))
    key_lane = sl[site["key"]]
    length = float(town.index.length[key_lane])
    s_path = S.join(sp, "s_on_key")
    s_rule = Float(0.0, math.ceil(length * 1000.0) / 1000.0, "m",
                   why=f"the length of key lane {key_lane}")
    s_rule.check(site["s_on_key"], s_path)
    s_on = float(site["s_on_key"])
    hits = np.flatnonzero(route.lane_ids == key_lane)
    if not len(hits):
        raise ValueError(f"{S.join(sp, 'key')}: key lane {key_lane} is not driven on the route")
    conflict_s = float(route.s[hits[0]] + s_on)
    if conflict_s > route.length + 1e-6:
        past = conflict_s - route.length
        raise ValueError(f"{s_path}: {s_on!r} puts the conflict point {past:.1f} m past the "
                         "route's end")
    extra = site.get("extra", [])
    S.check_extra(typ, extra, town, S.join(sp, "extra"))
    ends = []
    for key in ("trigger", "conflict"):
        xy = S.point(s[key], S.join(path, key)) if key in s else (0.0, 0.0)
        if key in s:
            S.check_on_route(np.array([xy]), route.points, S.join(path, key), key)
        ends.append(xy)
    inst = ScenarioInstance(typ, tuple(sl), int(site["key"]), s_on, _to_tuple(extra), params,
                            ends[0], ends[1])
    return inst, conflict_s


def build_episode_from_spec(spec: RouteSpec) -> tuple[Route, list]:
    """The route and placed scenario instances of a route file."""
    from ..scenarios import Site, get_scenario

    route = _route_of(spec.town, tuple(spec.lanes))
    route = dataclasses.replace(route, lanes=list(route.lanes))  # scenarios may replace fields
    out = []
    for inst in spec.scenarios:
        cls = get_scenario(inst.type)
        site = Site(tuple(inst.site_lanes), inst.key, inst.s_on_key, inst.extra)
        key_lane = inst.site_lanes[inst.key]
        hits = np.flatnonzero(route.lane_ids == key_lane)
        conflict_s = float(route.s[hits[0]] + inst.s_on_key)
        out.append(cls(route, site, conflict_s, inst.params))
    return route, out


@functools.lru_cache(maxsize=64)
def _route_of(town_name: str, lanes: tuple[int, ...]) -> Route:
    """The dense route along ``lanes`` (deterministic; built once per process, arrays read-only:
    every episode of a route file starts from it)."""
    route = route_from_lanes(get_town(town_name), list(lanes))
    for a in (route.points, route.headings, route.lane_ids, route.commands, route.s):
        a.setflags(write=False)
    return route


def _read_json(path: Path, what: str) -> Any:
    """The JSON in ``path``; errors name the file (``what``: ``"suite"``, ``"route file"``)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{what} {path}: cannot be read ({e})") from None
    try:
        return json.loads(text)
    except (json.JSONDecodeError, RecursionError) as e:
        raise ValueError(f"{what} {path}: not valid JSON ({e})") from None


def load_route_file(path: str | Path) -> RouteSpec:
    """Read and validate one route JSON file."""
    path = Path(path)
    return parse_route(_read_json(path, "route file"), f"route file {path}")


def save_json_atomic(obj: dict, path: str | Path) -> Path:
    """Write JSON to ``path`` atomically (``v2xbench.files.atomic_write_json``; parents made)."""
    from v2xbench.files import atomic_write_json

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_json(path, obj, indent=1)


@functools.lru_cache(maxsize=8)
def load_suite_cached(name_or_path: str) -> tuple[RouteSpec, ...]:
    """:func:`load_suite`'s routes, parsed once per process."""
    return tuple(load_suite(name_or_path)[1])


def load_suite(name_or_path: str | Path) -> tuple[str, list[RouteSpec]]:
    """A suite by name (``train``, ``val``, ``test50``) or path; returns ``(split, routes)``.

    Raises:
        ValueError: unknown name, unreadable file, or any schema violation (the message names
            the file and the field path, ``routes[3].scenarios[1].params.speed: ...``).
        FileNotFoundError: no file at the path.
    """
    p = Path(name_or_path)
    if not p.suffix:
        p = SUITE_DIR / f"{name_or_path}.json"
        if not p.exists():
            known = sorted(x.stem for x in SUITE_DIR.glob("*.json"))
            raise ValueError(f"unknown suite {str(name_or_path)!r}; known: {', '.join(known)}")
    return parse_suite(_read_json(p, "suite"), f"suite {p}", p.stem)


def parse_suite(d: Any, where: str = "suite",
                default_split: str = "suite") -> tuple[str, list[RouteSpec]]:
    """Validate a suite dict (``{"format", "name", "split", "routes"}``); returns
    ``(split, routes)``. ``where`` names the suite in messages."""
    try:
        if not isinstance(d, dict):
            raise ValueError(f"expected a JSON object, got {type(d).__name__}")
        S.check_keys(d, S.SUITE_KEYS, "", ("format", "routes"))
        if d["format"] != SUITE_FORMAT:
            raise ValueError(f"format: {d['format']!r} is not {SUITE_FORMAT!r}")
        for key in ("name", "split"):
            if key in d:
                S.ID_RULE.check(d[key], key)
        routes = d["routes"]
        if not isinstance(routes, list):
            raise ValueError(f"routes: expected a list of routes, got {type(routes).__name__}")
        if not routes:
            raise ValueError("routes: the suite has no routes")
        if len(routes) > S.MAX_ROUTES:
            raise ValueError(f"routes: {len(routes)} routes is more than the {S.MAX_ROUTES} "
                             "allowed")
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
    specs = [parse_route(r, where, f"routes[{k}]") for k, r in enumerate(routes)]
    first: dict[str, int] = {}
    for k, r in enumerate(specs):
        if r.id in first:
            raise ValueError(f"{where}: routes[{k}].id: {r.id!r} repeats routes[{first[r.id]}].id "
                             "(route ids name result files)")
        first[r.id] = k
    return d.get("split", default_split), specs
