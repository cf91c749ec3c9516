"""The schema of route and suite files: every field's type and bounds, checked with the field's
path in the message (``routes[3].scenarios[1].params.speed: 1000000000.0 is outside [0, 30] m/s``).

Checked, beyond types: ids safe as file names; lanes that exist and follow each other; waypoints,
triggers and conflict points on the route (within :data:`ON_ROUTE_M`); a site's lanes a stretch of
the route's lanes and its conflict point (``s_on_key``) on its key lane; ``extra`` in its
scenario's shape (:data:`EXTRA_SHAPES`: ``(lane path, arc length)`` pairs over lanes that follow
each other); scenario parameters in :data:`PARAM_RULES` (bounds in the units the scenarios use);
at most :data:`MAX_SCENARIOS` scenarios per route, in driving order, none repeated; seeds in
``[0, MAX_SEED]``. Tables of rules keep it declarative: a new scenario parameter is one new line
(``tests/sim/test_input_validation.py`` checks that every registered parameter has a rule).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..core.validation import Choice, Float, Int, Rule, Text, check_keys, join, kind_of, show

ROUTE_KEYS = (
    "format",
    "id",
    "town",
    "lanes",
    "waypoints",
    "scenarios",
    "weather",
    "time_of_day",
    "seed",
)
ROUTE_REQUIRED = ("format", "id", "town", "lanes", "waypoints", "scenarios", "seed")
SCENARIO_KEYS = ("type", "params", "site", "trigger", "conflict")
SITE_KEYS = ("lanes", "key", "s_on_key", "extra")
SUITE_KEYS = ("format", "name", "split", "routes")

MAX_LANES = 2000  # lanes per route
MAX_WAYPOINTS = 2000  # waypoints per route (every ~20 m: 40 km)
MAX_SCENARIOS = 16  # scenario instances per route
MAX_ROUTES = 10_000  # routes per suite
MAX_SEED = 2**32 - 1  # a route's world seed (jobs add 1000 per seed index)
ON_ROUTE_M = 5.0  # m: how far a waypoint, trigger or conflict point may lie from the route
DUPLICATE_M = 1.0  # m: two instances of one type on one site closer than this are the same
ID_RULE = Text(
    100, r"[A-Za-z0-9][A-Za-z0-9_.-]*", "letters, digits, '_', '.' or '-' (it names result files)"
)
SEED_RULE = Int(0, MAX_SEED)

_SPEED = Float(0.0, 30.0, "m/s")
_DIST = Float(0.0, 300.0, "m")
_TIME = Float(0.0, 120.0, "s")

#: scenario parameter -> rule (units as the scenarios read them; see each scenario's docstring)
PARAM_RULES: dict[str, Rule] = {
    "speed": _SPEED,
    "ramp_speed": _SPEED,
    "speed_after": _SPEED,
    "lead_speed": _SPEED,
    "start_speed": _SPEED,
    "flow_speed": Float(0.05, 1.5, "x speed limit"),
    "spacing_min": Float(2.0, 500.0, "m"),
    "spacing_max": Float(2.0, 500.0, "m"),
    "flow_gap": Float(5.0, 500.0, "m"),
    "spacing": Float(0.5, 200.0, "m"),
    "gap": Float(0.5, 20.0, "m"),
    "distance": _DIST,
    "source_dist": _DIST,
    "start_before": _DIST,
    "release_distance": _DIST,
    "release_gap": _DIST,
    "max_gap": _DIST,
    "brake_gap": _DIST,
    "front_gap": _DIST,
    "behind_gap": _DIST,
    "vehicle_gap": _DIST,
    "stuck_distance": _DIST,
    "exit_length": _DIST,
    "truck_gap": Float(0.0, 10.0, "m"),
    "into_junction": Float(0.0, 10.0, "m"),
    "invasion": Float(0.0, 3.0, "m"),
    "intrude": Float(0.0, 2.0, "m"),
    "wait": Float(0.0, 5.0, "m"),
    "window": Float(0.5, 20.0, "m"),
    "offset": Float(0.0, 1.0, "x half lane width"),
    "door_angle": Float(0.0, 1.6, "rad"),
    "decel": Float(0.5, 15.0, "m/s^2"),
    "reaction_time": _TIME,
    "stop_time": _TIME,
    "wait_s": _TIME,
    "stuck_time": _TIME,
    "open_time": Float(0.1, 30.0, "s"),
    "lead": Float(0.0, 10.0, "s"),
    "throttle_mean": Float(0.0, 1.0),
    "throttle_std": Float(0.0, 1.0),
    "steer_mean": Float(0.0, 1.0),
    "steer_std": Float(0.0, 1.0),
    "count": Int(1, 3),
    "cars": Int(0, 2),
    "queue": Int(0, 4),
    "side": Choice((-1.0, 1.0), why="-1 from the right, +1 from the left"),
    "direction": Choice(("right", "left", "any")),
}
#: (scenario type, parameter) -> rule, where a type reads a parameter with other bounds
PARAM_OVERRIDES: dict[tuple[str, str], Rule] = {
    ("CrossingBicycleFlow", "count"): Int(1, 5),  # up to max_actors - 1 bicycles
}
#: (low, high) parameter pairs that must be ordered
PARAM_ORDER = (("spacing_min", "spacing_max"),)

#: scenario type -> shape of ``site.extra``: ``"pair"`` one ``[lane path, s]`` (required);
#: ``(lo, hi)`` a list of ``lo..hi`` pairs (empty: recomputed from the town's sites); types not
#: listed keep no ``extra`` (it must be empty)
EXTRA_SHAPES: dict[str, str | tuple[int, int]] = {
    "CrossingBicycleFlow": "pair",
    "NonSignalizedJunctionLeftTurn": "pair",
    "NonSignalizedJunctionRightTurn": "pair",
    "HighwayCutIn": (1, 1),
    **dict.fromkeys(
        (
            "EnterActorFlow",
            "EnterActorFlowV2",
            "HighwayExit",
            "InterurbanActorFlow",
            "InterurbanAdvancedActorFlow",
            "MergerIntoSlowTraffic",
            "MergerIntoSlowTrafficV2",
            "OppositeVehicleRunningRedLight",
            "OppositeVehicleTakingPriority",
            "PriorityAtJunction",
            "SignalizedJunctionLeftTurn",
            "SignalizedJunctionRightTurn",
        ),
        (1, 4),
    ),
}


def param_rule(scenario: str, name: str) -> Rule | None:
    """The rule of parameter ``name`` of scenario type ``scenario`` (``None``: none known)."""
    return PARAM_OVERRIDES.get((scenario, name), PARAM_RULES.get(name))


def need(d: dict, key: str, types: type | tuple, path: str, what: str) -> Any:
    """``d[key]``, present and of ``types`` (bools are neither ints nor numbers here)."""
    if key not in d:
        raise ValueError(f"{join(path, key)}: missing required field")
    v = d[key]
    if not isinstance(v, types) or (isinstance(v, bool) and bool not in _tuple(types)):
        raise ValueError(f"{join(path, key)}: expected {what}, got {kind_of(v)} {show(v)}")
    return v


def _tuple(t) -> tuple:
    return t if isinstance(t, tuple) else (t,)


def int_list(v: Any, path: str, lo: int, hi: int, n_max: int, what: str) -> list[int]:
    """A non-empty list of at most ``n_max`` ints in ``[lo, hi)``."""
    if not isinstance(v, list) or not v:
        raise ValueError(f"{path}: expected a non-empty list of {what}, got {show(v)}")
    if len(v) > n_max:
        raise ValueError(f"{path}: {len(v)} {what} is more than the {n_max} allowed")
    for k, x in enumerate(v):
        if not isinstance(x, int) or isinstance(x, bool):
            raise ValueError(f"{path}[{k}]: expected a lane id (int), got {kind_of(x)} {show(x)}")
        if not lo <= x < hi:
            raise ValueError(f"{path}[{k}]: lane {x} is outside [{lo}, {hi - 1}] ({what})")
    return v


def point(v: Any, path: str) -> tuple[float, float]:
    """A finite ``[x, y]`` pair (m)."""
    ok = (
        isinstance(v, list)
        and len(v) == 2
        and all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in v)
    )
    if not ok:
        raise ValueError(f"{path}: expected an [x, y] pair of numbers, got {kind_of(v)} {show(v)}")
    if not all(math.isfinite(c) for c in v):
        raise ValueError(f"{path}: {v} is not finite")
    return float(v[0]), float(v[1])


def check_on_route(points: np.ndarray, route_points: np.ndarray, path: str, label: str) -> None:
    """Every row of ``points (K, 2)`` within :data:`ON_ROUTE_M` m of a route point (the route's
    points lie ``ROUTE_STEP`` = 1 m apart)."""
    for k0 in range(0, len(points), 256):
        chunk = points[k0 : k0 + 256]
        d = np.sqrt(((chunk[:, None, :] - route_points[None, :, :]) ** 2).sum(-1).min(1))
        bad = np.flatnonzero(d > ON_ROUTE_M + 0.5)
        if len(bad):
            k = k0 + int(bad[0])
            where = f"{path}[{k}]" if label == "waypoint" else path
            raise ValueError(
                f"{where}: {label} {np.round(points[k], 3).tolist()} is {d[bad[0]]:.1f} m "
                f"from the route (at most {ON_ROUTE_M:g} m)"
            )


def lane_chain(town, lanes: list[int], path: str) -> None:
    """Each lane of ``lanes`` follows the previous one (a successor, or a neighbour: a lane
    change)."""
    for k, (a, b) in enumerate(zip(lanes[:-1], lanes[1:])):
        ln = town.lanes[a]
        if b not in ln.successors and b not in (ln.left, ln.right):
            raise ValueError(f"{path}[{k + 1}]: lane {b} does not follow lane {a}")


def check_params(scenario: str, params: Any, defaults: dict, path: str) -> dict:
    """``params`` of a scenario instance: known keys, each within its rule, ordered pairs in
    order."""
    if not isinstance(params, dict):
        raise ValueError(f"{path}: expected an object, got {kind_of(params)} {show(params)}")
    check_keys(params, sorted(defaults), path)
    for name, value in params.items():
        rule = param_rule(scenario, name)
        if rule is None:
            raise ValueError(
                f"{join(path, name)}: no rule for parameter {name!r} "
                "(add one to route_schema.PARAM_RULES)"
            )
        rule.check(value, join(path, name))
    merged = {**defaults, **params}
    for lo, hi in PARAM_ORDER:
        if lo in merged and hi in merged and merged[lo] > merged[hi]:
            at = join(path, lo if lo in params else hi)
            raise ValueError(f"{at}: {lo}={merged[lo]!r} is above {hi}={merged[hi]!r}")
    return dict(params)


def check_extra(scenario: str, extra: Any, town, path: str) -> None:
    """``site.extra`` in the shape :data:`EXTRA_SHAPES` gives for ``scenario`` (empty: recomputed
    from the town, except a required pair). A pair is ``[lane path, s]``: lanes that follow each
    other, ``s`` (m) along them."""
    if not isinstance(extra, list):
        raise ValueError(f"{path}: expected a list, got {kind_of(extra)} {show(extra)}")
    shape = EXTRA_SHAPES.get(scenario)
    if not extra:
        if shape == "pair":  # read as is (``v2x_junction``), never recomputed from the town
            raise ValueError(f"{path}: {scenario} needs its [lane path, s] pair, got []")
        return
    if shape is None:
        raise ValueError(f"{path}: {scenario} takes no extra data, got {show(extra)}")
    if shape == "pair":
        _pair(extra, town, path)
        return
    lo, hi = shape
    if not lo <= len(extra) <= hi:
        n = f"{lo} to {hi}" if lo < hi else str(lo)
        raise ValueError(
            f"{path}: {scenario} takes {n} [lane path, s] pair{'s' if hi > 1 else ''}, "
            f"got {len(extra)}"
        )
    for k, p in enumerate(extra):
        _pair(p, town, f"{path}[{k}]")


def _pair(p: Any, town, path: str) -> None:
    if not (isinstance(p, list) and len(p) == 2 and isinstance(p[0], list)):
        raise ValueError(f"{path}: expected a [lane path, s] pair, got {show(p)}")
    lanes = int_list(p[0], f"{path}[0]", 0, len(town.lanes), 64, f"lane ids of {town.name}")
    lane_chain(town, lanes, f"{path}[0]")
    length = float(sum(town.index.length[x] for x in lanes))
    hi = math.ceil(length * 1000.0) / 1000.0
    Float(0.0, hi, "m", why="the length of the lane path").check(p[1], f"{path}[1]")
