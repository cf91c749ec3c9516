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
"""

from __future__ import annotations

import dataclasses
import functools
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .routes import Route, route_from_lanes
from .town import NAMED_TOWNS, get_town

ROUTE_FORMAT = "v2xbench-route/1"
SUITE_FORMAT = "v2xbench-suite/1"
WEATHERS = ("clear", "cloudy", "rain", "fog")
TIMES_OF_DAY = ("day", "dusk", "night")
SUITE_DIR = Path(__file__).parent / "suites"


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


def _need(d: dict, key: str, types, where: str):
    """``d[key]``, checked to be present and of ``types`` (bools are not numbers here)."""
    if key not in d:
        raise ValueError(f"{where}: missing field {key!r}")
    v = d[key]
    if not isinstance(v, types) or isinstance(v, bool):
        names = " or ".join(t.__name__ for t in (types if isinstance(types, tuple) else (types,)))
        raise ValueError(f"{where}: field {key!r} has type {type(v).__name__}, expected {names}")
    return v


def parse_route(d: dict, where: str = "route") -> RouteSpec:
    """Validate a route dict and build a :class:`RouteSpec`.

    Raises:
        ValueError: naming the bad field (missing, wrong type, unknown town / scenario / lane, ...).
    """
    from .scenarios import get_scenario

    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected a JSON object, got {type(d).__name__}")
    if d.get("format") != ROUTE_FORMAT:
        raise ValueError(f"{where}: field 'format' is {d.get('format')!r}, expected {ROUTE_FORMAT!r}")
    rid = _need(d, "id", str, where)
    where = f"{where} {rid!r}"
    town_name = _need(d, "town", str, where)
    if town_name not in NAMED_TOWNS:
        raise ValueError(f"{where}: field 'town' = {town_name!r} is not a known town ({', '.join(NAMED_TOWNS)})")
    town = get_town(town_name)
    lanes = _need(d, "lanes", list, where)
    if not lanes or not all(isinstance(x, int) and 0 <= x < len(town.lanes) for x in lanes):
        raise ValueError(f"{where}: field 'lanes' must be a non-empty list of lane ids of {town_name}")
    for a, b in zip(lanes[:-1], lanes[1:]):
        ln = town.lanes[a]
        if b not in ln.successors and b not in (ln.left, ln.right):
            raise ValueError(f"{where}: field 'lanes': lane {b} does not follow lane {a}")
    wps = np.asarray(_need(d, "waypoints", list, where), dtype=float)
    if wps.ndim != 2 or wps.shape[1] != 2 or len(wps) < 2 or not np.all(np.isfinite(wps)):
        raise ValueError(f"{where}: field 'waypoints' must be a list of >= 2 finite [x, y] pairs")
    scen = []
    for k, s in enumerate(_need(d, "scenarios", list, where)):
        w = f"{where}: scenarios[{k}]"
        if not isinstance(s, dict):
            raise ValueError(f"{w}: expected an object")
        typ = _need(s, "type", str, w)
        try:
            cls = get_scenario(typ)
        except ValueError as e:
            raise ValueError(f"{w}: field 'type': {e}") from None
        params = s.get("params", {})
        if not isinstance(params, dict) or set(params) - set(cls.defaults):
            raise ValueError(f"{w}: field 'params' has unknown keys {sorted(set(params) - set(cls.defaults))}; "
                             f"known: {sorted(cls.defaults)}")
        site = _need(s, "site", dict, w)
        sl = _need(site, "lanes", list, f"{w}.site")
        if not sl or not all(isinstance(x, int) and x in lanes for x in sl):
            raise ValueError(f"{w}: field 'site.lanes' must be lanes of the route")
        key = _need(site, "key", int, f"{w}.site")
        if not 0 <= key < len(sl):
            raise ValueError(f"{w}: field 'site.key' = {key} out of range for {len(sl)} site lanes")
        s_on = float(_need(site, "s_on_key", (int, float), f"{w}.site"))
        extra = _to_tuple(site.get("extra", []))
        scen.append(ScenarioInstance(typ, tuple(sl), key, s_on, extra, dict(params),
                                     tuple(s.get("trigger", (0.0, 0.0))), tuple(s.get("conflict", (0.0, 0.0)))))
    weather = d.get("weather", "clear")
    if weather not in WEATHERS:
        raise ValueError(f"{where}: field 'weather' = {weather!r}, expected one of {WEATHERS}")
    tod = d.get("time_of_day", "day")
    if tod not in TIMES_OF_DAY:
        raise ValueError(f"{where}: field 'time_of_day' = {tod!r}, expected one of {TIMES_OF_DAY}")
    seed = _need(d, "seed", int, where)
    return RouteSpec(rid, town_name, list(lanes), wps, scen, weather, tod, seed)


def build_episode_from_spec(spec: RouteSpec) -> tuple[Route, list]:
    """The route and placed scenario instances of a route file."""
    from .scenarios import Site, get_scenario

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


def load_route_file(path: str | Path) -> RouteSpec:
    """Read and validate one route JSON file."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"route file {path}: not valid JSON ({e})") from None
    return parse_route(d, f"route file {path}")


def save_json_atomic(obj: dict, path: str | Path) -> Path:
    """Write JSON to ``path`` atomically (temporary file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    tmp.replace(path)
    return path


@functools.lru_cache(maxsize=8)
def load_suite_cached(name_or_path: str) -> tuple[RouteSpec, ...]:
    """:func:`load_suite`'s routes, parsed once per process."""
    return tuple(load_suite(name_or_path)[1])


def load_suite(name_or_path: str | Path) -> tuple[str, list[RouteSpec]]:
    """A suite by name (``train``, ``val``, ``test50``) or path; returns ``(split, routes)``."""
    p = Path(name_or_path)
    if not p.suffix:
        p = SUITE_DIR / f"{name_or_path}.json"
        if not p.exists():
            known = sorted(x.stem for x in SUITE_DIR.glob("*.json"))
            raise ValueError(f"unknown suite {str(name_or_path)!r}; known: {', '.join(known)}")
    d = json.loads(p.read_text())
    if d.get("format") != SUITE_FORMAT:
        raise ValueError(f"suite {p}: field 'format' is {d.get('format')!r}, expected {SUITE_FORMAT!r}")
    routes = [parse_route(r, f"suite {p.name} route[{k}]") for k, r in enumerate(d["routes"])]
    ids = [r.id for r in routes]
    if len(set(ids)) != len(ids):
        raise ValueError(f"suite {p}: duplicate route ids")
    return d.get("split", p.stem), routes
