"""Closed-loop metrics: the one home of their definitions (``/work/shared/METRICS.md`` restated).

Every metric is a pure function of a :class:`RouteRecord` (what an evaluation run logs per route)
and is registered by name (:func:`register_metric`, :data:`METRICS`, :func:`compute_metrics`).
Suites are summarised by :func:`aggregate`. Open-loop and perception metrics live in
``metrics_perception.py``.

==================  =========================================================================
metric              definition
==================  =========================================================================
route_completion    RC, percent (0-100) of the route length passed (``EventMonitor``).
infraction_score    IS, product of one factor per infraction (:data:`INFRACTION_FACTORS`) times
                    ``1 - pct_outside_lanes / 100``; ``pct_outside_lanes = 100 * outside_lanes_m
                    / driven_m`` (CARLA ``OutsideRouteLanesTest``: distance driven outside the
                    route's lanes over distance driven; off the drivable lanes, or outside
                    junctions on a lane the route does not take, the opposite lane included).
                    A bicycle hit is a vehicle collision (CARLA's bicycles are vehicles).
                    ``EventMonitor`` already applies CARLA's collision filter (the last
                    registered party is ignored for 5 s, any contact within 3 m of a registered
                    collision's place until the ego is 5 m from it), so every collision row
                    counts once here.
collision sides     ``n_collision_vehicle_{front,side,rear}``: vehicle collisions by where on
                    the ego the other vehicle was (the event's ``SIDE_*`` value: its centre
                    within 45 degrees of the ego's heading, of its reverse, or between); the
                    ego driving into a car ahead is ``front``, a car driving into the ego from
                    behind ``rear``. Not part of IS. Records from before the sides were recorded
                    give no such counts.
driving_score       DS = RC x IS (0-100).
efficiency          Bench2Drive: the route is cut into :data:`NUM_CHECKPOINTS` equal-length
                    checkpoints by route arc length; in each, over the ticks with at least one
                    surrounding background vehicle, ``100 * mean(ego speed) / mean(background
                    mean speed)``. Checkpoints without such ticks (or with 0/0) are skipped,
                    values above :data:`EFFICIENCY_MAX` (1000, including +inf when traffic
                    stands still) are discarded; the route value is the mean of the rest, NaN
                    when none is left.
comfortness         100 x comfortable segments / segments; segments of :data:`SEGMENT_TICKS`
                    (20) ticks, a last partial one dropped, an episode of <= 20 ticks is one
                    segment; Savitzky-Golay (window 7, order 2, delta 0.1 s) derivatives; a
                    segment is comfortable when every quantity of :data:`COMFORT_BOUNDS` stays
                    strictly inside its bounds at every tick. NaN for an empty trajectory.
bps / peak_bps      bytes the RSU sent (channel ``bytes_sent_total``: payload plus the
                    ``channel.HEADER_SIZE`` = 16 byte header per message) / simulated seconds;
                    peak = channel ``peak_bps`` (max bytes in any 1 s window).
==================  =========================================================================

"Surrounding background vehicles" (Efficiency) are the active NPC vehicles (class car or large
vehicle, behaviour ``DRIVER``; parked cars, cyclists and the ego excluded) whose centre is within
:data:`SURROUNDING_RADIUS_M` (50 m) of the ego centre; see :func:`surrounding_mean_speed`.

Suites (:func:`aggregate`): DS and RC are means over *all* expected runs (routes x seeds), a route
that was not run or crashed (``ended_by == ENDED_ERROR``) counting 0; IS, BPS are means over the
runs that finished; Efficiency and Comfortness are means over the runs whose value is not NaN
(NaN when none is). Infractions are reported per km of route completed (CARLA convention,
``sum(route_length * RC / 100) / 1000``). The DS 95% CI is a percentile bootstrap over runs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from math import factorial

import numpy as np

from ..core.actors import DRIVER
from ..core.classes import CAR, LARGE_VEHICLE
from .infractions import (
    COLLISION_PEDESTRIAN,
    COLLISION_STATIC,
    COLLISION_VEHICLE,
    EVENT_NAMES,
    RED_LIGHT,
    SIDE_FRONT,
    SIDE_LEFT,
    SIDE_REAR,
    SIDE_RIGHT,
    STOP_SIGN,
)

# ------------------------------------------------------------------------------------ constants

#: IS factor per occurrence, keyed by event name (``infractions.EVENT_NAMES`` where a code exists).
INFRACTION_FACTORS: dict[str, float] = {
    "collision_pedestrian": 0.50,
    "collision_vehicle": 0.60,
    "collision_static": 0.65,
    "red_light": 0.70,
    "stop_sign": 0.80,
    "scenario_timeout": 0.70,
    "yield_emergency": 0.70,
}
#: Event codes with a factor (scenario timeout / yield-to-emergency come from RouteRecord fields,
#: plus events with those names once ``EVENT_NAMES`` defines them).
FACTOR_CODES: dict[int, str] = {
    COLLISION_PEDESTRIAN: "collision_pedestrian",
    COLLISION_VEHICLE: "collision_vehicle",
    COLLISION_STATIC: "collision_static",
    RED_LIGHT: "red_light",
    STOP_SIGN: "stop_sign",
}
for _name in ("scenario_timeout", "yield_emergency"):
    if _name in EVENT_NAMES:
        FACTOR_CODES[EVENT_NAMES.index(_name)] = _name

SURROUNDING_RADIUS_M = 50.0  # m: background vehicles closer than this to the ego count (Efficiency)
NUM_CHECKPOINTS = 5  # equal-length Efficiency checkpoints per route
EFFICIENCY_MAX = 1000.0  # checkpoint values above this are discarded as outliers

SEGMENT_TICKS = 20  # ticks per Comfortness segment (2 s at 10 Hz)
SG_WINDOW = 7  # Savitzky-Golay window (samples)
SG_ORDER = 2  # Savitzky-Golay polynomial order
SG_DELTA = 0.1  # s, sample spacing for SG derivatives
#: Open (lower, upper) bounds per comfort quantity (nuPlan): m/s^2, m/s^3, rad/s^2, rad/s.
COMFORT_BOUNDS: dict[str, tuple[float, float]] = {
    "lon_accel": (-4.05, 2.40),
    "lat_accel": (-4.89, 4.89),
    "jerk": (-8.37, 8.37),
    "lon_jerk": (-4.13, 4.13),
    "yaw_accel": (-1.93, 1.93),
    "yaw_rate": (-0.95, 0.95),
}

#: ``RouteRecord.ended_by`` codes.
(
    ENDED_COMPLETED,
    ENDED_ROUTE_DEVIATION,
    ENDED_BLOCKED,
    ENDED_TIMEOUT,
    ENDED_COLLISION,
    ENDED_ERROR,
) = range(6)
ENDED_BY_NAMES = ("completed", "route_deviation", "blocked", "timeout", "collision", "error")


# ------------------------------------------------------------------------------------ record


@dataclass
class RouteRecord:
    """Everything an evaluation run logs for one route (one seed); ``T`` ticks of ``dt`` s.

    Attributes:
        route_length: route length (m).
        route_completion: RC reached, percent 0-100 (``EventMonitor.route_completion``).
        ego_xy: ``(T, 2)`` ego centre per tick (m, world frame).
        ego_yaw: ``(T,)`` ego heading (rad, any wrapping).
        ego_speed: ``(T,)`` ego speed along its heading (m/s).
        background_speed: ``(T,)`` mean speed (m/s) of the surrounding background vehicles
            (:func:`surrounding_mean_speed`), NaN at ticks with none.
        route_s: ``(T,)`` route arc length reached at each tick (m; ``route.s[monitor.progress]``).
        events: ``(E, 4)`` rows ``(code, tick, other_id, value)`` of ``EventMonitor.events``
            (codes ``infractions.EVENT_NAMES``).
        outside_lanes_m, driven_m: metres driven outside the route's lanes / in total.
        bytes_sent: channel ``bytes_sent_total`` (bytes). peak_bps: channel ``peak_bps`` (B/s).
        sim_seconds: simulated time of the route (s).
        ended_by: ``ENDED_*`` code (``ENDED_BY_NAMES``).
        scenario_timeouts, yield_emergency_failures: counts not (yet) in the event list.
        dt: tick (s). route_id, seed: identification only.
    """

    route_length: float
    route_completion: float
    ego_xy: np.ndarray
    ego_yaw: np.ndarray
    ego_speed: np.ndarray
    background_speed: np.ndarray
    route_s: np.ndarray
    events: np.ndarray
    outside_lanes_m: float
    driven_m: float
    bytes_sent: int
    peak_bps: float
    sim_seconds: float
    ended_by: int
    scenario_timeouts: int = 0
    yield_emergency_failures: int = 0
    dt: float = 0.1
    route_id: str = ""
    seed: int = 0

    def __post_init__(self) -> None:
        self.ego_xy = np.asarray(self.ego_xy, np.float64).reshape(-1, 2)
        t = len(self.ego_xy)
        for name in ("ego_yaw", "ego_speed", "background_speed", "route_s"):
            arr = np.asarray(getattr(self, name), np.float64).reshape(-1)
            if len(arr) != t:
                raise ValueError(f"RouteRecord: {name} has {len(arr)} ticks, ego_xy has {t}")
            setattr(self, name, arr)
        self.events = np.asarray(self.events, np.float64).reshape(-1, 4)
        for name in (
            "route_length",
            "route_completion",
            "outside_lanes_m",
            "driven_m",
            "peak_bps",
            "sim_seconds",
            "dt",
        ):
            setattr(self, name, float(getattr(self, name)))
        for name in (
            "bytes_sent",
            "ended_by",
            "scenario_timeouts",
            "yield_emergency_failures",
            "seed",
        ):
            setattr(self, name, int(getattr(self, name)))
        if not 0.0 <= self.route_completion <= 100.0 + 1e-6:
            raise ValueError(
                f"RouteRecord: route_completion {self.route_completion} not in [0, 100]"
            )

    def to_dict(self) -> dict:
        """JSON-ready dict (arrays as nested lists)."""
        return {
            k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self).items()
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> RouteRecord:
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        known = {f.name for f in fields(cls)}
        bad = set(d) - known
        if bad:
            raise ValueError(f"RouteRecord: unknown keys {sorted(bad)}; known: {sorted(known)}")
        return cls(**d)


def surrounding_mean_speed(table, radius: float = SURROUNDING_RADIUS_M) -> float:
    """Mean ``|speed|`` (m/s) of active NPC vehicles (car / large vehicle, behaviour ``DRIVER``)
    within ``radius`` m of the ego (row 0) of an ``ActorTable``; NaN when there is none."""
    sel = table.active & ((table.kind == CAR) | (table.kind == LARGE_VEHICLE)) & (table.behaviour == DRIVER)
    sel[0] = False
    sel &= np.linalg.norm(table.pos - table.pos[0], axis=1) < radius
    return float(np.abs(table.speed[sel]).mean()) if sel.any() else float("nan")


# ------------------------------------------------------------------------------------ registry

MetricFn = Callable[[RouteRecord], "float | Mapping[str, float]"]
#: name -> function of a RouteRecord returning a float (or a mapping of several named floats).
METRICS: dict[str, MetricFn] = {}


def register_metric(name: str) -> Callable[[MetricFn], MetricFn]:
    """Decorator registering a per-route metric under ``name`` (names are unique)."""

    def deco(fn: MetricFn) -> MetricFn:
        if name in METRICS:
            raise ValueError(f"metric {name!r} is already registered")
        METRICS[name] = fn
        return fn

    return deco


def compute_metrics(record: RouteRecord, names: Iterable[str] | None = None) -> dict[str, float]:
    """Evaluate registered metrics (all by default) on one record; mapping results are merged."""
    out: dict[str, float] = {}
    for name in list(METRICS) if names is None else names:
        if name not in METRICS:
            raise KeyError(f"unknown metric {name!r}; known: {', '.join(METRICS)}")
        v = METRICS[name](record)
        if isinstance(v, Mapping):
            out.update({k: float(x) for k, x in v.items()})
        else:
            out[name] = float(v)
    return out


# ------------------------------------------------------------------------------------ RC, IS, DS


@register_metric("route_completion")
def route_completion(r: RouteRecord) -> float:
    """RC, percent 0-100."""
    return float(np.clip(r.route_completion, 0.0, 100.0))


@register_metric("infraction_counts")
def infraction_counts(r: RouteRecord) -> dict[str, float]:
    """``n_<event name>`` for every ``EVENT_NAMES`` code, plus ``n_scenario_timeout`` and
    ``n_yield_emergency`` (record fields added to events of those names, if such codes exist)."""
    codes = r.events[:, 0].astype(np.int64)
    out = {f"n_{name}": float(np.sum(codes == c)) for c, name in enumerate(EVENT_NAMES)}
    out["n_scenario_timeout"] = out.get("n_scenario_timeout", 0.0) + r.scenario_timeouts
    out["n_yield_emergency"] = out.get("n_yield_emergency", 0.0) + r.yield_emergency_failures
    return out


@register_metric("collision_sides")
def collision_sides(r: RouteRecord) -> dict[str, float]:
    """``n_collision_vehicle_front`` / ``_side`` / ``_rear``: vehicle collisions by where on the
    ego the other vehicle was (empty for records written before sides were recorded)."""
    veh = r.events[r.events[:, 0].astype(np.int64) == COLLISION_VEHICLE]
    side = veh[:, 3].astype(np.int64)
    if not len(side) or not np.all(side > 0):  # an older record: its collisions carry no side
        return {}
    return {"n_collision_vehicle_front": float(np.sum(side == SIDE_FRONT)),
            "n_collision_vehicle_side": float(np.sum((side == SIDE_LEFT) | (side == SIDE_RIGHT))),
            "n_collision_vehicle_rear": float(np.sum(side == SIDE_REAR))}


def outside_lanes_percent(r: RouteRecord) -> float:
    """Percent (0-100) of the distance driven that was outside the route's lanes."""
    return (
        float(np.clip(100.0 * r.outside_lanes_m / r.driven_m, 0.0, 100.0))
        if r.driven_m > 0
        else 0.0
    )


@register_metric("infraction_score")
def infraction_score(r: RouteRecord) -> float:
    """IS in [0, 1]: product of :data:`INFRACTION_FACTORS` per occurrence x outside-lanes factor."""
    counts = infraction_counts(r)
    score = 1.0
    for name, factor in INFRACTION_FACTORS.items():
        score *= factor ** counts[f"n_{name}"]
    return score * (1.0 - outside_lanes_percent(r) / 100.0)


@register_metric("driving_score")
def driving_score(r: RouteRecord) -> float:
    """DS = RC x IS (0-100)."""
    return route_completion(r) * infraction_score(r)


@register_metric("km_completed")
def km_completed(r: RouteRecord) -> float:
    """Route kilometres completed: ``route_length * RC / 100 / 1000``."""
    return r.route_length * route_completion(r) / 1e5


@register_metric("ended_by")
def ended_by(r: RouteRecord) -> float:
    """The ``ENDED_*`` code, as a float."""
    return float(r.ended_by)


# ------------------------------------------------------------------------------------ efficiency


def efficiency_checkpoints(r: RouteRecord, n: int = NUM_CHECKPOINTS) -> np.ndarray:
    """``(n,)`` checkpoint values (percent), NaN where skipped (no background) or discarded."""
    edges = max(r.route_length, 1e-9) / n
    idx = np.clip(np.floor(r.route_s / edges).astype(np.int64), 0, n - 1)
    has_bg = np.isfinite(r.background_speed)
    out = np.full(n, np.nan)
    for k in range(n):
        sel = (idx == k) & has_bg
        if not sel.any():
            continue
        ego, bg = float(np.mean(r.ego_speed[sel])), float(np.mean(r.background_speed[sel]))
        if bg > 0:
            v = 100.0 * ego / bg
        else:
            v = np.inf if ego > 0 else np.nan  # traffic standing still: outlier or undefined
        out[k] = v if v <= EFFICIENCY_MAX else np.nan
    return out


@register_metric("efficiency")
def efficiency(r: RouteRecord) -> float:
    """Mean of the valid checkpoint values (percent; 100 = as fast as traffic); NaN if none."""
    v = efficiency_checkpoints(r)
    return float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")


# ------------------------------------------------------------------------------------ comfort


@lru_cache(maxsize=64)
def _sg_matrix(n: int, window: int, order: int, deriv: int, delta: float) -> np.ndarray:
    """``(n, n)`` linear operator of a Savitzky-Golay filter (scipy ``mode="interp"``).

    Interior samples use the centred window; the first/last ``window // 2`` samples use the
    polynomial fitted to the first/last ``window`` samples. With fewer than ``window`` samples
    the window is all of them and the order drops to ``n - 1`` if needed.
    """
    w = min(window, n)
    p = min(order, w - 1)
    m = np.zeros((n, n))
    if deriv > p:
        return m  # the fitted polynomial's derivative of that order is 0
    for i in range(n):
        a = min(max(i - window // 2, 0), n - w)
        t = np.arange(w, dtype=np.float64) - (i - a)  # sample positions relative to i
        coef = np.linalg.pinv(t[:, None] ** np.arange(p + 1))  # (p + 1, w) least-squares fit
        m[i, a : a + w] = coef[deriv] * factorial(deriv) / delta**deriv
    m.setflags(write=False)
    return m


def savgol(
    x: np.ndarray,
    deriv: int = 0,
    window: int = SG_WINDOW,
    order: int = SG_ORDER,
    delta: float = SG_DELTA,
) -> np.ndarray:
    """Savitzky-Golay smoothing / derivative along axis 0 of ``x (n, ...)`` (numpy only; equals
    ``scipy.signal.savgol_filter(x, window, order, deriv, delta, axis=0, mode="interp")``)."""
    x = np.asarray(x, np.float64)
    if len(x) == 0:
        return x.copy()
    return np.tensordot(_sg_matrix(len(x), window, order, deriv, float(delta)), x, axes=1)


def comfort_signals(
    speed: np.ndarray, yaw: np.ndarray, dt: float = SG_DELTA
) -> dict[str, np.ndarray]:
    """Comfort quantities ``(n,)`` of one segment.

    The acceleration vector is the SG derivative of the velocity vector ``speed * (cos, sin)(yaw)``,
    projected on the forward (``lon_accel``) and right (``lat_accel``) vectors; ``jerk`` is the SG
    derivative of its magnitude, ``lon_jerk`` that of ``lon_accel``; ``yaw_rate`` / ``yaw_accel``
    are the first / second SG derivatives of the unwrapped yaw.
    """
    yaw = np.unwrap(np.asarray(yaw, np.float64))
    fwd = np.stack([np.cos(yaw), np.sin(yaw)], -1)
    right = np.stack([np.sin(yaw), -np.cos(yaw)], -1)
    acc = savgol(np.asarray(speed, np.float64)[:, None] * fwd, 1, delta=dt)
    lon = np.sum(acc * fwd, -1)
    return {
        "lon_accel": lon,
        "lat_accel": np.sum(acc * right, -1),
        "jerk": savgol(np.linalg.norm(acc, axis=-1), 1, delta=dt),
        "lon_jerk": savgol(lon, 1, delta=dt),
        "yaw_accel": savgol(yaw, 2, delta=dt),
        "yaw_rate": savgol(yaw, 1, delta=dt),
    }


def comfort_segments(r: RouteRecord) -> list[tuple[int, int]]:
    """``[start, stop)`` tick ranges of the Comfortness segments (see module docstring)."""
    t = len(r.ego_speed)
    if t == 0:
        return []
    if t <= SEGMENT_TICKS:
        return [(0, t)]
    return [(k * SEGMENT_TICKS, (k + 1) * SEGMENT_TICKS) for k in range(t // SEGMENT_TICKS)]


def comfort_breakdown(r: RouteRecord) -> list[dict[str, bool]]:
    """Per segment, whether each :data:`COMFORT_BOUNDS` quantity stayed strictly within bounds."""
    out = []
    for a, b in comfort_segments(r):
        sig = comfort_signals(r.ego_speed[a:b], r.ego_yaw[a:b], r.dt)
        out.append(
            {
                k: bool(np.all((lo < sig[k]) & (sig[k] < hi)))
                for k, (lo, hi) in COMFORT_BOUNDS.items()
            }
        )
    return out


@register_metric("comfortness")
def comfortness(r: RouteRecord) -> float:
    """100 x comfortable segments / segments (NaN without ticks)."""
    seg = comfort_breakdown(r)
    return 100.0 * float(np.mean([all(s.values()) for s in seg])) if seg else float("nan")


# ------------------------------------------------------------------------------------ bandwidth


@register_metric("bps")
def bps(r: RouteRecord) -> float:
    """Mean bytes per second the RSU sent: ``bytes_sent / sim_seconds`` (NaN for 0 s)."""
    return r.bytes_sent / r.sim_seconds if r.sim_seconds > 0 else float("nan")


@register_metric("peak_bps")
def peak_bps(r: RouteRecord) -> float:
    """Peak bytes in any one-second window (channel ``peak_bps``)."""
    return float(r.peak_bps)


# ------------------------------------------------------------------------------------ suites


def bootstrap_ci(
    values, n_boot: int = 2000, seed: int = 0, level: float = 0.95
) -> tuple[float, float]:
    """Percentile-bootstrap CI of the mean of ``values (n,)`` (seeded ``numpy`` Generator)."""
    v = np.asarray(values, np.float64).reshape(-1)
    if len(v) == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, len(v), size=(n_boot, len(v)))].mean(1)
    q = 100.0 * (1.0 - level) / 2.0
    lo, hi = np.percentile(means, [q, 100.0 - q])
    return float(lo), float(hi)


def _nanmean(x: list[float]) -> float:
    a = np.asarray(x, np.float64)
    return float(np.nanmean(a)) if np.isfinite(a).any() else float("nan")


def aggregate(
    records: Iterable[RouteRecord | Mapping[str, float]],
    n_routes_in_suite: int,
    n_seeds: int = 1,
    n_boot: int = 2000,
    seed: int = 0,
) -> dict[str, float]:
    """Suite summary of per-run records (RouteRecords or :func:`compute_metrics` dicts).

    Args:
        records: one per (route, seed) that ran; missing runs are simply absent.
        n_routes_in_suite, n_seeds: the suite has ``n_routes_in_suite * n_seeds`` expected runs.

    Returns:
        ``driving_score`` (+ ``_ci_low``/``_ci_high``), ``route_completion`` (both over expected
        runs, missing/crashed = 0), ``infraction_score``, ``efficiency``, ``comfortness``, ``bps``
        (means over finished runs, NaN-aware for the two Bench2Drive metrics), ``peak_bps`` (max),
        ``km_completed``, ``<infraction>_per_km``, ``n_expected``, ``n_finished``, ``n_crashed``.
    """
    dicts = [compute_metrics(r) if isinstance(r, RouteRecord) else dict(r) for r in records]
    n_exp = n_routes_in_suite * n_seeds
    if len(dicts) > n_exp:
        raise ValueError(f"aggregate: {len(dicts)} records for a suite of {n_exp} runs")
    crashed = [d for d in dicts if int(d.get("ended_by", ENDED_COMPLETED)) == ENDED_ERROR]
    ok = [d for d in dicts if int(d.get("ended_by", ENDED_COMPLETED)) != ENDED_ERROR]
    ds = np.zeros(n_exp)
    ds[: len(ok)] = [d["driving_score"] for d in ok]
    lo, hi = bootstrap_ci(ds, n_boot, seed)
    km = float(sum(d.get("km_completed", 0.0) for d in ok))
    out = {
        "driving_score": float(ds.mean()) if n_exp else float("nan"),
        "driving_score_ci_low": lo,
        "driving_score_ci_high": hi,
        "route_completion": float(sum(d["route_completion"] for d in ok) / n_exp)
        if n_exp
        else float("nan"),
        "infraction_score": _nanmean([d["infraction_score"] for d in ok]),
        "efficiency": _nanmean([d.get("efficiency", np.nan) for d in ok]),
        "comfortness": _nanmean([d.get("comfortness", np.nan) for d in ok]),
        "bps": _nanmean([d.get("bps", np.nan) for d in ok]),
        "peak_bps": float(max((d.get("peak_bps", 0.0) for d in ok), default=float("nan"))),
        "km_completed": km,
        "n_expected": float(n_exp),
        "n_finished": float(len(ok)),
        "n_crashed": float(len(crashed)),
    }
    names = sorted({k[2:] for d in ok for k in d if k.startswith("n_")})
    for name in names:
        total = sum(d.get(f"n_{name}", 0.0) for d in ok)
        out[f"{name}_per_km"] = total / km if km > 0 else float("nan")
    return out
