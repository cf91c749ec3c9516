"""Environment configuration: one frozen dataclass that rejects unknown keys and bad values."""

from __future__ import annotations

import dataclasses
import difflib
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.validation import Bool, Check, Choice, Float, Int, OrNone, Rule, Text, kind_of, show
from ..v2x.wire import NUM_OBJECT_FIELDS

OBS_MODES = ("objects", "sensors", "bev")
ACTION_MODES = ("carla", "accel_steer")  # actions.MODES: the ego's action and its mapping
RSU_POLICIES = ("none", "share_objects")
ENCODINGS = ("float16", "float32")
MAX_ACTORS_PER_KIND = 500  # num_vehicles, num_parked, ... (a town fits fewer: a warning says so)
#: the images a camera renders (``sensors.camera``), in their canonical order
CAMERA_IMAGES = ("rgb", "depth", "semantic", "instance")
MIN_CAMERA_SIDE, MAX_CAMERA_SIDE = 2, 4096  # pixels: a camera's width and height
MAX_LIDAR_SCALE = 2.0  # x the default LiDAR channels and azimuths (bounds the point arrays)
#: the fields of the one sensor configuration (``obs_mode="sensors"``): accepted by ``gym.make``,
#: ``parallel_env``, ``V2XTorchEnv``, ``v2xbench eval --set`` and ``v2xbench collect``; an agent
#: declares the values it needs as ``sensors = {...}`` (``agents/interface.py``)
SENSOR_FIELDS = ("camera_size", "camera_images", "lidar_scale")


@dataclass(frozen=True)
class EnvConfig:
    """All knobs of a V2XIntersection world. Build with :func:`make_config` (validates keys).

    Every field is checked on construction by its rule in :data:`FIELD_RULES` (type and bounds:
    ``max_objects=10**9`` is refused naming the bound), then :data:`COMBINATION_CHECKS`
    (``route_index`` needs a ``suite`` ...). A new field needs a rule there.

    Attributes:
        town: named town (``town.NAMED_TOWNS``); with ``scenario`` and no explicit town, the
            scenario's preferred town.
        scenario: run one scenario type (``v2xbench scenarios list``) on a route through it.
        suite: draw routes from a suite (``train``, ``val``, ``test50`` or a suite JSON path).
        route_index: the suite route to use (default: drawn from the reset seed).
        seed: seed of the first ``reset()`` called without one (so ``gym.make(..., seed=3)`` works).
        route_length: length of the random route drawn at reset (m; a ``ShortfallWarning`` once per
            town and value where no route that long is found).
        num_vehicles: NPC vehicles driving with IDM.
        num_parked: parked vehicles in parking lanes.
        num_pedestrians: pedestrians on sidewalks and crosswalks.
        num_bicycles: bicycles riding at the right edge of lanes.
        large_vehicle_fraction: share of NPC and parked vehicles that are trucks/vans/buses (6-11 m
            long, ``actors.SIZES``; a parked one longer than a slot takes two slots).
        jaywalk_prob: per-second probability that a walking pedestrian crosses mid-block.
        obs_mode: ``objects`` (object lists; fast, for RL), ``sensors`` (the ego's 6 cameras and
            LiDAR instead of its object list; the RSU adds its camera and LiDAR; configured by
            ``camera_size``, ``camera_images``, ``lidar_scale``) or ``bev`` (an ego-centred
            semantic BEV raster instead of the object list).
        camera_size: ``(width, height)`` of the 6 ego cameras and the RSU camera in ``sensors``
            mode (pixels; ``[256, 128]`` or ``"256x128"`` also accepted).
        camera_images: the images every camera renders and observes in ``sensors`` mode, of
            ``rgb``, ``depth``, ``semantic``, ``instance`` (stored in that order; ``()``: no
            cameras, LiDAR only). Images not asked for are neither rendered nor in the space.
        lidar_scale: density of the ego and RSU LiDARs in ``sensors`` mode, as a fraction of the
            default channels and azimuths (ego 32 x 360, RSU 64 x 240; ``sensors.lidar``).
        action_mode: the ego's action (:mod:`.actions`): ``carla`` (default; ``(3,)`` throttle,
            steer, brake) or ``accel_steer`` (``(2,)`` signed acceleration in [-1, 1] and steer;
            +-1 = +-3.5 m/s^2, 0 coasts: for RL).
        max_objects: object slots in the ego's and RSU's object lists.
        route_points: route points ahead in the observation (every ``route_step`` m).
        route_step: spacing of observed route points (m, a whole number: route points are 1 m apart).
        ego_range: ego sensing range (m).
        rsu_range: RSU sensing range and the farthest distance of an active unit (m).
        rsu_policy: built-in RSU message policy of the Gymnasium and TorchRL envs
            (``RSU_POLICIES``).
        rsu_slots: RSU agents in the PettingZoo env (the nearest forward-facing units).
        latency_ticks: V2X delivery delay (``channel.ChannelConfig``): a message the RSU sends at
            tick t is in the ego's observation at t + latency_ticks.
        loss_prob: probability that a transmitted V2X message is lost (its bytes still count).
        bandwidth_bytes_per_s: cap on V2X bytes on air per second (``None``: unlimited).
        max_payload_floats: V2X message payload capacity in floats (320 = 32 objects; the size
            of the ego's ``v2x_payload``); a longer message is an error, never cut.
        encoding: wire encoding of V2X payload floats (``float16``: 2 bytes, ``float32``: 4).
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
    camera_size: tuple[int, int] = (128, 64)
    camera_images: tuple[str, ...] = CAMERA_IMAGES
    lidar_scale: float = 1.0
    action_mode: str = "carla"
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
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for name, value in values.items():
            rule = FIELD_RULES.get(name)
            if rule is None:
                raise TypeError(f"config: field {name!r} has no rule in config.FIELD_RULES "
                                "(add one)")
            prepared = _PREPARE.get(name, _same)(value)  # [256, 128] -> (256, 128), ...
            rule.check(prepared, f"config: {name}")
            if isinstance(prepared, np.generic):  # np.int64(3) -> 3: the config holds Python values
                prepared = plain_scalar(prepared)
            if prepared is not value:
                object.__setattr__(self, name, prepared)
        for check in COMBINATION_CHECKS:
            check(self)


def plain_scalar(value: Any) -> Any:
    """A NumPy scalar as the Python value it holds (``np.int64(3)`` -> ``3``, ``np.float32`` ->
    ``float``); anything else unchanged. NumPy integers are accepted wherever ints are."""
    return value.item() if isinstance(value, np.generic) else value


def _known_town(name: Any) -> None:
    from ..town import NAMED_TOWNS, town_hint

    if name not in NAMED_TOWNS:
        raise ValueError(f"{name!r} is not a known town{town_hint(name)} "
                         f"({', '.join(NAMED_TOWNS)})")


def _known_scenario(name: Any) -> None:
    from ..scenarios import get_scenario

    if not isinstance(name, str):
        raise ValueError(f"expected a scenario name, got {type(name).__name__} {name!r}")
    get_scenario(name)


def _same(value: Any) -> Any:
    return value


def _size_value(value: Any) -> Any:
    """``[256, 128]``, ``(np.int64(256), 128)`` or ``"256x128"`` as ``(256, 128)`` (anything else
    unchanged, for the rule to refuse)."""
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value)
        return (int(m.group(1)), int(m.group(2))) if m else value
    if isinstance(value, (list, tuple, np.ndarray)):
        return tuple(plain_scalar(v) for v in value)
    return value


def _images_value(value: Any) -> Any:
    """A list (or ``"rgb,depth"``) of image names as a tuple in :data:`CAMERA_IMAGES` order
    (anything else unchanged, for the rule to refuse)."""
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",") if v.strip()]
    if isinstance(value, (list, tuple)):
        rank = {k: i for i, k in enumerate(CAMERA_IMAGES)}
        return tuple(sorted(value, key=lambda v: rank.get(v, len(rank)) if isinstance(v, str)
                            else len(rank)))
    return value


#: how a field's value is put in its stored form before its rule checks it (JSON lists as tuples)
_PREPARE: dict[str, Callable[[Any], Any]] = {"camera_size": _size_value,
                                             "camera_images": _images_value}


def _camera_size(value: Any) -> None:
    if not (isinstance(value, tuple) and len(value) == 2):
        raise ValueError(f"expected (width, height) in pixels, e.g. [128, 64] or '128x64', got "
                         f"{kind_of(value)} {show(value)}")
    side = Int(MIN_CAMERA_SIDE, MAX_CAMERA_SIDE, "pixels")
    for name, v in zip(("width", "height"), value):
        side.check(v, name)


def _camera_images(value: Any) -> None:
    if not isinstance(value, tuple):
        raise ValueError(f"expected a list of image names of {CAMERA_IMAGES}, got "
                         f"{kind_of(value)} {show(value)}")
    kind = Choice(CAMERA_IMAGES, why="the images a camera renders")
    for v in value:
        kind.check(v, "image")
    if len(set(value)) != len(value):
        raise ValueError(f"{show(list(value))} names an image twice")


_COUNT = Int(0, MAX_ACTORS_PER_KIND)
_PROB = Float(0.0, 1.0, why="a probability")

#: one rule per field: type and bounds (every value that sizes an allocation has an upper bound)
FIELD_RULES: dict[str, Rule] = {
    "town": Check(_known_town, "a named town"),
    "scenario": OrNone(Check(_known_scenario, "a registered scenario type")),
    "suite": OrNone(Text(4096, what="a suite name or a path to a suite JSON")),
    "route_index": OrNone(Int(0, 100_000)),
    "seed": OrNone(Int(0, 2**63 - 1)),
    "route_length": Float(10.0, 5000.0, "m"),
    "num_vehicles": _COUNT,
    "num_parked": _COUNT,
    "num_pedestrians": _COUNT,
    "num_bicycles": _COUNT,
    "large_vehicle_fraction": _PROB,
    "jaywalk_prob": _PROB,
    "obs_mode": Choice(OBS_MODES),
    "camera_size": Check(_camera_size, f"(width, height), ints in [{MIN_CAMERA_SIDE}, "
                         f"{MAX_CAMERA_SIDE}] pixels"),
    "camera_images": Check(_camera_images, f"a list of distinct images of {CAMERA_IMAGES}"),
    "lidar_scale": Float(0.0, MAX_LIDAR_SCALE, "x the default density", lo_open=True,
                         why="fraction of the default LiDAR channels and azimuths"),
    "action_mode": Choice(ACTION_MODES, why="the ego's action: actions.MODES"),
    "max_objects": Int(1, 256, "object slots"),
    "route_points": Int(1, 200, "points"),
    "route_step": Int(1, 50, "m"),
    "ego_range": Float(1.0, 500.0, "m"),
    "rsu_range": Float(1.0, 500.0, "m"),
    "rsu_policy": Choice(RSU_POLICIES),
    "rsu_slots": Int(1, 16, "RSU agents"),
    "latency_ticks": Int(1, 100, "ticks", why="a message made from the RSU's observation at tick t "
                         "reaches the ego's observation at tick t + latency_ticks"),
    "loss_prob": _PROB,
    "bandwidth_bytes_per_s": OrNone(Float(0.0, 1e12, "bytes/s", lo_open=True)),
    "max_payload_floats": Int(NUM_OBJECT_FIELDS, 65_535, "floats", why="a message must carry "
                              f"at least one object of {NUM_OBJECT_FIELDS} floats; the wire "
                              "header's length is a uint16"),
    "encoding": Choice(ENCODINGS),
    "max_steps": OrNone(Int(1, 100_000, "ticks")),
    "terminate_on_collision": Bool(),
    "render_size": Int(16, 4096, "pixels"),
    "dt": Choice((0.1,), why="the tick is fixed at 0.1 s (10 Hz)"),
}


def _suite_and_index(cfg: EnvConfig) -> None:
    """``route_index`` needs a ``suite`` and must index one of its routes; a suite replaces the
    ``scenario`` (so both together are a mistake). Loads (and so validates) the suite."""
    if cfg.route_index is not None and cfg.suite is None:
        raise ValueError(f"config: route_index={cfg.route_index} needs a suite (route_index picks "
                         "one of the suite's routes)")
    if cfg.suite is not None and cfg.scenario is not None:
        raise ValueError(f"config: scenario={cfg.scenario!r} and suite={cfg.suite!r} exclude each "
                         "other (the suite's routes bring their own scenarios)")
    if cfg.suite is None:
        return
    from ..suites.route_files import load_suite_cached

    try:
        n = len(load_suite_cached(cfg.suite))
    except ValueError as e:
        raise ValueError(f"config: suite: {e}") from None
    if cfg.route_index is not None and cfg.route_index >= n:
        raise ValueError(f"config: route_index: {cfg.route_index} is outside [0, {n - 1}] "
                         f"(suite {cfg.suite!r} has {n} routes)")


#: checks of field combinations, run after the per-field rules
COMBINATION_CHECKS: list[Callable[[EnvConfig], None]] = [_suite_and_index]


CONFIG_FIELDS = tuple(f.name for f in dataclasses.fields(EnvConfig))


def sensor_config(cfg: EnvConfig) -> dict[str, Any]:
    """The :data:`SENSOR_FIELDS` of ``cfg`` as JSON values (lists): what a data set's manifest
    records and what an agent's ``sensors`` declaration is compared with."""
    return {k: list(v) if isinstance(v, tuple) else v
            for k, v in ((k, getattr(cfg, k)) for k in SENSOR_FIELDS)}


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
    if isinstance(kwargs.get("scenario"), str) and "town" not in kwargs:
        from ..scenarios import get_scenario

        try:
            towns = get_scenario(kwargs["scenario"]).towns
        except ValueError as e:
            raise ValueError(f"config: scenario: {e}") from None
        if towns:
            kwargs["town"] = towns[0]
    return dataclasses.replace(base, **kwargs)
