"""Environment configuration: one frozen dataclass that rejects unknown keys and bad values."""

from __future__ import annotations

import dataclasses
import difflib
from dataclasses import dataclass
from typing import Any

OBS_MODES = ("objects", "sensors", "bev")
RSU_POLICIES = ("none", "share_objects")


@dataclass(frozen=True)
class EnvConfig:
    """All knobs of a V2XIntersection world. Build with :func:`make_config` (validates keys).

    Attributes:
        town: named town (``town.NAMED_TOWNS``); with ``scenario`` and no explicit town, the
            scenario's preferred town.
        scenario: run one scenario type (``v2xbench scenarios list``) on a route through it.
        suite: draw routes from a suite (``train``, ``val``, ``test50`` or a suite JSON path).
        route_index: the suite route to use (default: drawn from the reset seed).
        seed: seed of the first ``reset()`` called without one (so ``gym.make(..., seed=3)`` works).
        route_length: length of the random route drawn at reset (m).
        num_vehicles: NPC vehicles driving with IDM.
        num_parked: parked vehicles in parking lanes.
        num_pedestrians: pedestrians on sidewalks and crosswalks.
        num_bicycles: bicycles riding at the right edge of lanes.
        large_vehicle_fraction: share of NPC and parked vehicles that are trucks/vans/buses.
        jaywalk_prob: per-second probability that a walking pedestrian crosses mid-block.
        obs_mode: ``objects`` (object lists; fast, for RL), ``sensors`` (the ego's 6 cameras and
            LiDAR instead of its object list; the RSU adds its camera and LiDAR) or ``bev`` (an
            ego-centred semantic BEV raster instead of the object list).
        max_objects: object slots in the ego's and RSU's object lists.
        route_points: route points ahead in the observation (every ``route_step`` m).
        route_step: spacing of observed route points (m, a whole number: route points are 1 m apart).
        ego_range, rsu_range: sensing ranges (m).
        rsu_policy: built-in RSU message policy for the single-agent Gymnasium env.
        rsu_slots: RSU agents in the PettingZoo env (the nearest forward-facing units).
        latency_ticks, loss_prob, bandwidth_bytes_per_s, max_payload_floats, encoding: V2X channel
            (``channel.ChannelConfig``); latency >= 1: the RSU acts on tick t, the ego reads at t + latency.
        max_steps: episode cap in ticks (``None``: from the route's time budget).
        terminate_on_collision: end the episode at the first collision (for RL; off for eval).
        render_size: top-down render size in pixels.
        dt: simulation tick (s); fixed at 0.1 (10 Hz) as in the paper.
    """

    town: str = "Town01"
    scenario: str | None = None
    suite: str | None = None
    route_index: int | None = None
    seed: int | None = None
    route_length: float = 300.0
    num_vehicles: int = 30
    num_parked: int = 10
    num_pedestrians: int = 12
    num_bicycles: int = 3
    large_vehicle_fraction: float = 0.25
    jaywalk_prob: float = 0.01
    obs_mode: str = "objects"
    max_objects: int = 32
    route_points: int = 20
    route_step: int = 2
    ego_range: float = 60.0
    rsu_range: float = 75.0
    rsu_policy: str = "share_objects"
    rsu_slots: int = 1
    latency_ticks: int = 1
    loss_prob: float = 0.0
    bandwidth_bytes_per_s: float | None = None
    max_payload_floats: int = 320
    encoding: str = "float16"
    max_steps: int | None = None
    terminate_on_collision: bool = False
    render_size: int = 512
    dt: float = 0.1

    def __post_init__(self) -> None:
        from .town import NAMED_TOWNS

        def bad(name: str, why: str) -> None:
            raise ValueError(f"config: {name}={getattr(self, name)!r} {why}")

        if self.town not in NAMED_TOWNS:
            bad("town", f"is not a known town ({', '.join(NAMED_TOWNS)})")
        if self.scenario is not None:
            from .scenarios import get_scenario

            try:
                get_scenario(self.scenario)
            except ValueError as e:
                raise ValueError(f"config: scenario: {e}") from None
        if self.seed is not None and (not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0):
            bad("seed", "must be an int >= 0 or None")
        if self.route_index is not None and (not isinstance(self.route_index, int) or self.route_index < 0):
            bad("route_index", "must be an int >= 0 or None")
        for name in ("num_vehicles", "num_parked", "num_pedestrians", "num_bicycles"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= 500:
                bad(name, "must be an int in [0, 500]")
        for name in ("max_objects", "route_points", "route_step", "rsu_slots", "max_payload_floats", "render_size"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                bad(name, "must be a positive int")
        for name in ("route_length", "ego_range", "rsu_range"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not v > 0:
                bad(name, "must be a positive number")
        for name in ("large_vehicle_fraction", "jaywalk_prob", "loss_prob"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
                bad(name, "must be a probability in [0, 1]")
        if self.obs_mode not in OBS_MODES:
            bad("obs_mode", f"must be one of {OBS_MODES}")
        if self.rsu_policy not in RSU_POLICIES:
            bad("rsu_policy", f"must be one of {RSU_POLICIES}")
        if not isinstance(self.latency_ticks, int) or self.latency_ticks < 1:
            bad("latency_ticks", "must be an int >= 1 (a message made from the RSU's observation at "
                "tick t reaches the ego's observation at tick t + latency_ticks)")
        bw = self.bandwidth_bytes_per_s
        if bw is not None and (not isinstance(bw, (int, float)) or not 0 < bw < float("inf")):
            bad("bandwidth_bytes_per_s", "must be a positive finite number or None")
        if self.encoding not in ("float16", "float32"):
            bad("encoding", "must be 'float16' or 'float32'")
        if self.max_steps is not None and (not isinstance(self.max_steps, int) or self.max_steps < 1):
            bad("max_steps", "must be a positive int or None")
        if self.dt != 0.1:
            bad("dt", "is fixed at 0.1 s (10 Hz)")


CONFIG_FIELDS = tuple(f.name for f in dataclasses.fields(EnvConfig))


def make_config(config: EnvConfig | None = None, **kwargs: Any) -> EnvConfig:
    """Build an :class:`EnvConfig`, rejecting unknown keys with a suggestion.

    Raises:
        ValueError: unknown key or bad value (the message names it).
    """
    for key in kwargs:
        if key not in CONFIG_FIELDS:
            close = difflib.get_close_matches(key, CONFIG_FIELDS, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"config: unknown key {key!r}{hint}")
    base = config or EnvConfig()
    if kwargs.get("scenario") is not None and "town" not in kwargs:
        from .scenarios import get_scenario

        try:
            towns = get_scenario(kwargs["scenario"]).towns
        except ValueError as e:
            raise ValueError(f"config: scenario: {e}") from None
        if towns:
            kwargs["town"] = towns[0]
    return dataclasses.replace(base, **kwargs)
