"""The agent interface every driver implements: the expert, oracles, AURORA, baselines, yours.

An agent is any object with::

    obs_mode: str                 # observation mode it needs ("objects", "sensors", "bev")
    rsu_policy: str | object      # what the RSU sends it: "share_objects", "none", or its
                                  # own roadside policy object (see "Roadside policy" below)
    privileged: bool              # optional, informative only (see below)
    def reset(self, route_info: dict) -> None: ...
    def act(self, obs: dict) -> np.ndarray: ...   # (3,) throttle, steer, brake   -- or --
                                                  # (2,) accel, steer (action_mode="accel_steer")
                                                  # {"waypoints": (K, 2) ego frame, "speed": m/s}
    def act(self, obs: dict, info: dict) -> ...   # the same, with the step's info (see below)
    checkpoint: str | list[str]   # optional: weight files / folders it loads (hashed, see below)
    def fingerprint(self) -> str  # optional: anything else its behaviour depends on
    sensors: dict                 # optional: the sensor configuration it needs (see below)
    channel: dict                 # optional: {"max_payload_floats": N} its messages need

**One observation contract.** ``obs`` is exactly the observation the Gymnasium env
(``gym.make("v2xbench:V2XIntersection-v0", obs_mode=...)``) returns for the agent's
``obs_mode``: the keys of ``observations.ego_space`` and nothing more, every value inside that
space, so a model trained on the gym id (Stable-Baselines3, say) runs unchanged. Anything else the
harness hands over goes in ``info``: the Gymnasium env's ``info`` dict of the same tick
(``episode.EpisodeTracker.info``: ``tick``, ``route_completion`` (%), ``v2x_bps``, event counts,
reward terms, channel statistics; at the first ``act`` of a route the reset's info). ``act``
receives it when its signature asks for it (:func:`act_takes_info`): a parameter named ``info``
(passed by keyword), or a second positional parameter without a default (passed positionally);
otherwise ``act(obs)`` is called, as before.

``route_info`` is what CARLA's leaderboard gives an agent: the route and its commands, nothing
about the scenarios on it. Keys: ``route_points`` ((P, 2) world frame, 1 m apart), ``commands``
((P,) ``COMMAND_NAMES`` codes), ``town`` (the map's name, public like CARLA's HD map) and
``seed`` (the job's world seed; the ``random`` baseline seeds its generator with it). It has no
route id, scenario list, weather or time of day (:data:`ROUTE_INFO_KEYS`).

**Roadside policy** (bring your own; ``docs/evaluation.md``, ``examples/my_roadside_policy.py``).
``rsu_policy`` names a built-in policy of the roadside unit (``"share_objects"``: it sends the
objects it sees; ``"none"``: silence) or is an object with::

    def act(self, rsu_obs: dict) -> np.ndarray | dict | None: ...   # the message of this tick
    def reset(self, route_info: dict) -> None: ...                   # optional, every route

which the harness runs in the roadside unit's place (``collectors/roadside.py``): every tick a
unit serves the ego, ``act`` gets that unit's observation (the PettingZoo ``rsu`` agent's:
``observations.rsu_space``) and returns its message: a 1-D array of at most
``max_payload_floats`` floats, each finite and within +-1e4 (a raw payload: the ego reads it from
``obs["v2x_payload"][:int(obs["v2x_info"][6])]``, ``v2x_info`` giving its age and the sender's
pose too), ``None`` (say nothing), or a PettingZoo RSU action dict ``{"length", "payload",
"format"}`` (an object list made with ``channel.pack_objects``, ``"format": 0``, is also decoded
into the ego's ``v2x_objects``). Not bytes: the channel serializes the floats in the run's
``encoding`` (float16 by default, 2 bytes each, after a 16-byte header) and counts every byte in
the run's BPS. A longer message fails the route naming the limit; it is never cut. Results and the
summary name the policy ``custom:<ClassName>``; its code, ``checkpoint`` and ``fingerprint()``
join the run's fingerprint. With ``--isolate-agent`` it runs in the agent's process.

**Configuration** (``v2xbench eval --agent-config FILE``): the file's JSON object is passed to the
agent's constructor as keyword arguments (``Class(**config)``; CARLA passes a path to
``setup(path_to_conf_file)`` instead: an agent that wants a file of its own takes a path argument,
``{"conf_file": "my.yaml"}``). A key the constructor does not take is refused before any route
runs (:func:`build_agent`).

**Sensors** (``obs_mode="sensors"``). An agent trained on one camera resolution, set of images
or LiDAR density declares it, e.g. ``sensors = {"camera_size": (128, 64), "camera_images":
("rgb",), "lidar_scale": 0.5}``: keys of ``config.SENSOR_FIELDS``, values as ``EnvConfig``
takes them (checked when the agent is built, :func:`declared_sensors`). ``eval`` configures the
env from the declaration (a field it leaves out keeps the env's default or ``--set``), so the
agent gets exactly those images and only those are rendered; a ``--set`` of a declared field
with another value is refused before any route runs, naming both values (an agent fed other
images than it was trained on would fail silently). The declaration is part of the run's env
overrides: the fingerprint, the summary and the leaderboard's sensors column record it.

**Channel**. An agent whose own roadside policy sends larger messages than the env's default
payload limit declares the limit it needs, ``channel = {"max_payload_floats": N}`` (the only
key; a positive int within the field's bound in ``config.FIELD_RULES``; checked when the agent
is built, :func:`declared_channel`). ``eval`` sets the env's ``max_payload_floats`` from it, and
refuses a ``--set max_payload_floats`` with another value before any route runs, naming both.

**Fingerprint** (what ``eval`` keys its results by, ``collectors/agent_fingerprint.py``): the
agent's code, its configuration, and what it declares: ``checkpoint`` (a path or a list of paths;
each file, or every file under a folder, is hashed with SHA-256; one inside the installed package
is keyed by its path there, any other by the path given) and ``fingerprint()`` (a string,
for anything else, e.g. a model registry id). Declare the weights the agent loads, so that results
of other weights are never mixed with its own.

Privilege is the harness's decision, never the agent's: only the built-in agents named in
:data:`PRIVILEGED_AGENTS` are given the simulator (``bind(world)`` after every reset) and marked
privileged in results and on the leaderboard (:func:`granted_privilege`). Any other agent (a
``path/to/file.py:Class`` or a registered non-built-in name) that declares ``privileged = True``
is refused by :func:`load_agent` with a ``ValueError``: it would otherwise run without the world
it expects and be scored as if it were an ego-only driver.

Waypoint outputs are turned into controls by the shared :class:`~.controller.WaypointController`
(:func:`to_control`). Agents register by name with :func:`register_agent` so that
``v2xbench eval --agent NAME`` finds them; any class following the protocol also runs with
``--agent path/to/file.py:ClassName``.
"""

from __future__ import annotations

import importlib.util
import inspect
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .controller import WaypointController


@runtime_checkable
class Agent(Protocol):
    """Structural type of a driving agent (see module docstring)."""

    obs_mode: str
    rsu_policy: Any  # a built-in policy's name or a roadside policy object (module docstring)

    def reset(self, route_info: dict) -> None: ...

    def act(self, obs: dict) -> Any: ...


AGENTS: dict[str, Callable[[], Any]] = {}


def register_agent(name: str) -> Callable:
    """Decorator registering an agent factory (usually the class) under ``name``."""

    def deco(factory):
        if name in AGENTS:
            raise ValueError(f"agent {name!r} registered twice")
        AGENTS[name] = factory
        return factory

    return deco


PRIVILEGED_AGENTS: frozenset[str] = frozenset(
    {"expert", "oracle_ego", "oracle_v2x", "cautious_ego", "stop_and_wait_ego", "wary_ego"}
)
"""Registered names of the built-in agents that the harness gives the simulator (``bind``)."""

ROUTE_INFO_KEYS: tuple[str, ...] = ("town", "seed", "route_points", "commands")
"""The keys of ``route_info`` (see module docstring)."""

_DEFAULTS = (("obs_mode", "objects"), ("privileged", False), ("rsu_policy", "share_objects"))


def register_builtins() -> None:
    """Import the modules that register the built-in agents (idempotent)."""
    from . import builtin  # noqa: F401

    try:  # the expert package registers expert / oracle_ego / oracle_v2x on import
        from . import expert  # noqa: F401
    except ImportError:
        pass


def _is_builtin(factory: Any) -> bool:
    return getattr(factory, "__module__", "").startswith(__name__.rsplit(".", 1)[0] + ".")


def granted_privilege(agent: str | Callable[[], Any]) -> bool:
    """Whether the harness gives ``agent`` the simulator: a name in :data:`PRIVILEGED_AGENTS`
    registered by V2XBench itself, or that built-in class (or a ``functools.partial`` of it)
    passed as a factory. The agent object's own ``privileged`` attribute plays no part."""
    import functools

    register_builtins()
    if isinstance(agent, str):
        return agent in PRIVILEGED_AGENTS and agent in AGENTS and _is_builtin(AGENTS[agent])
    while isinstance(agent, functools.partial):
        agent = agent.func
    return any(AGENTS.get(n) is agent and _is_builtin(agent) for n in PRIVILEGED_AGENTS)


def complete_agent(agent: Any, label: str, privileged: bool) -> Any:
    """Fill the optional members' defaults and check the protocol of an agent instance.

    Raises:
        ValueError: ``reset`` or ``act`` missing, an ``rsu_policy`` that is neither a built-in
            policy's name nor an object with ``act``, or ``privileged = True`` declared by an agent
            the harness does not grant it to (see module docstring).
    """
    for attr, default in _DEFAULTS:
        if not hasattr(agent, attr):
            setattr(agent, attr, default)
    missing = [m for m in ("reset", "act") if not callable(getattr(agent, m, None))]
    if missing:
        raise ValueError(f"agent {label!r} lacks method(s) {', '.join(missing)} (see agents/interface.py)")
    _check_rsu_policy(agent.rsu_policy, label)
    declared_sensors(agent, label)
    declared_channel(agent, label)
    if getattr(agent, "privileged", False) and not privileged:
        raise ValueError(
            f"agent {label!r} declares privileged = True, but only the built-in agents "
            f"{', '.join(sorted(PRIVILEGED_AGENTS))} may read the simulator; set privileged = False "
            "and drive from the observation")
    if privileged and not callable(getattr(agent, "bind", None)):
        raise ValueError(f"privileged agent {label!r} has no bind(world) method")
    return agent


def _declaration(agent: Any, attr: str, fields: tuple[str, ...], shape: str, label: str) -> dict:
    """An agent's optional declaration dict ``attr`` (``{}`` when absent), its keys checked against
    ``fields``; the messages name the agent, the attribute and the known keys."""
    decl = getattr(agent, attr, None)
    if decl is None:
        return {}
    if not isinstance(decl, dict):
        raise ValueError(f"agent {label!r}: {attr} must be {shape}, got {type(decl).__name__}")
    unknown = sorted(str(k) for k in decl if k not in fields)
    if unknown:
        raise ValueError(f"agent {label!r}: {attr} has unknown key(s) {unknown}; known: "
                         f"{', '.join(fields)}")
    return decl


def declared_sensors(agent: Any, label: str = "agent") -> dict[str, Any]:
    """The sensor configuration ``agent`` declares it needs (its optional ``sensors`` dict; module
    docstring, "Sensors") as ``config.sensor_config`` values (JSON: lists; ``camera_images`` in
    ``config.CAMERA_IMAGES`` order); ``{}`` when it declares none.

    Raises:
        ValueError: ``sensors`` is not a dict, names a key outside ``config.SENSOR_FIELDS``, or
            holds a value the field's rule refuses (the message names the agent and the field).
    """
    from v2xbench.envs.v2x_intersection.sim.config import SENSOR_FIELDS, make_config, sensor_config

    decl = _declaration(agent, "sensors", SENSOR_FIELDS, f"a dict of {', '.join(SENSOR_FIELDS)}",
                        label)
    if not decl:
        return {}
    try:
        values = sensor_config(make_config(**decl))
    except ValueError as e:
        raise ValueError(f"agent {label!r}: sensors: {e}") from None
    return {k: values[k] for k in SENSOR_FIELDS if k in decl}


#: The keys an agent's ``channel`` declaration may hold (module docstring, "Channel").
CHANNEL_FIELDS = ("max_payload_floats",)


def declared_channel(agent: Any, label: str = "agent") -> dict[str, int]:
    """The channel settings ``agent`` declares it needs (its optional ``channel`` dict; module
    docstring, "Channel"); ``{}`` when it declares none.

    Raises:
        ValueError: ``channel`` is not a dict, names a key other than ``max_payload_floats``, or
            holds a value outside the field's rule (the message names the agent and the bound).
    """
    from v2xbench.envs.v2x_intersection.sim.config import FIELD_RULES

    decl = _declaration(agent, "channel", CHANNEL_FIELDS, "a dict like {'max_payload_floats': N}",
                        label)
    out = {}
    for key in CHANNEL_FIELDS:
        if key in decl:
            FIELD_RULES[key].check(decl[key], f"agent {label!r}: channel {key}")
            out[key] = int(decl[key])
    return out


def _check_rsu_policy(policy: Any, label: str) -> None:
    """Raise ``ValueError`` unless ``policy`` names a built-in RSU policy or is a roadside
    policy object (one with a callable ``act``; module docstring)."""
    from v2xbench.envs.v2x_intersection.sim.config import RSU_POLICIES

    if isinstance(policy, str):
        if policy not in RSU_POLICIES:
            raise ValueError(f"agent {label!r}: rsu_policy={policy!r} must be one of "
                             f"{RSU_POLICIES} or a roadside policy object with "
                             "act(rsu_observation) -> message (see agents/interface.py)")
    elif not callable(getattr(policy, "act", None)):
        raise ValueError(f"agent {label!r}: rsu_policy is a {type(policy).__name__} without an "
                         f"act(rsu_observation) method; give one of {RSU_POLICIES} or a roadside "
                         "policy object (see agents/interface.py)")


def agent_file(spec: str) -> Path | None:
    """The file of a ``path/to/file.py:ClassName`` spec (``None`` for a registered name).

    Raises:
        ValueError: neither a registered name nor an existing ``file.py:Class``.
    """
    register_builtins()
    if spec in AGENTS:
        return None
    if ":" in spec:
        path = spec.rsplit(":", 1)[0]
        if not Path(path).is_file():
            raise ValueError(f"agent file {path!r} not found")
        return Path(path)
    import difflib

    close = difflib.get_close_matches(spec, AGENTS, n=1)
    hint = f" Did you mean {close[0]!r}?" if close else ""
    raise ValueError(f"unknown agent {spec!r}.{hint} Registered: {', '.join(sorted(AGENTS))}; "
                     "or give path/to/file.py:ClassName")


def agent_factory(spec: str) -> Callable[..., Any]:
    """The factory (usually the class) of a registered name or ``path/to/file.py:ClassName``;
    a file is imported (executed) to find its class.

    Raises:
        ValueError: see :func:`agent_file`; the file has no such class.
    """
    path = agent_file(spec)
    if path is None:
        return AGENTS[spec]
    cls_name = spec.rsplit(":", 1)[1]
    mod_name = f"v2xbench_user_agent_{abs(hash(path.resolve()))}"
    module_spec = importlib.util.spec_from_file_location(mod_name, path)
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[mod_name] = module
    module_spec.loader.exec_module(module)
    if not hasattr(module, cls_name):
        raise ValueError(f"agent file {str(path)!r} has no class {cls_name!r}")
    return getattr(module, cls_name)


def build_agent(factory: Callable[..., Any], label: str, config: dict | None = None) -> Any:
    """``factory(**config)`` (``factory()`` without a config; see "Configuration" above).

    Raises:
        ValueError: ``config`` is not a dict with string keys, or the constructor does not take
            its keys (the message names them and what it takes).
    """
    if not config:
        return factory()
    if not isinstance(config, dict) or not all(isinstance(k, str) for k in config):
        raise ValueError(f"agent config of {label!r} must be an object of keyword arguments, got "
                         f"{type(config).__name__}")
    try:
        sig = inspect.signature(factory)
    except (TypeError, ValueError):  # not introspectable: let the call say
        sig = None
    if sig is not None:
        try:
            sig.bind(**config)
        except TypeError as e:
            takes = [n for n, p in sig.parameters.items()
                     if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
            raise ValueError(f"agent {label!r} does not take the agent config {sorted(config)} "
                             f"({e}); its constructor takes: {', '.join(takes) or 'no arguments'}"
                             ) from None
    return factory(**config)


def load_agent(spec: str, config: dict | None = None) -> Any:
    """An agent instance from a registered name or ``path/to/file.py:ClassName``, built with
    ``config`` as keyword arguments (:func:`build_agent`).

    Raises:
        ValueError: unknown name, missing file or class, a config the constructor does not take,
            an object lacking the protocol, or a non-built-in agent declaring ``privileged = True``.
    """
    agent = build_agent(agent_factory(spec), spec, config)
    return complete_agent(agent, spec, granted_privilege(spec))


def act_info_style(agent: Any) -> str | None:
    """How ``agent.act`` takes the step's ``info`` (module docstring): ``"keyword"`` (a parameter
    named ``info``), ``"positional"`` (a second positional parameter without a default) or
    ``None`` (it does not: ``act(obs)``)."""
    try:
        params = list(inspect.signature(agent.act).parameters.values())
    except (TypeError, ValueError):
        return None
    P = inspect.Parameter
    if any(p.name == "info" and p.kind in (P.POSITIONAL_OR_KEYWORD, P.KEYWORD_ONLY) for p in params):
        return "keyword"
    positional = [p for p in params if p.kind in (P.POSITIONAL_ONLY, P.POSITIONAL_OR_KEYWORD)]
    if len(positional) >= 2 and positional[1].default is inspect.Parameter.empty:
        return "positional"
    return None


def act_takes_info(agent: Any) -> bool:
    """Whether ``agent.act`` asks for the step's ``info`` (:func:`act_info_style`)."""
    return act_info_style(agent) is not None


_UNSET = object()


def call_act(agent: Any, obs: dict, info: dict | None, style: str | None | object = _UNSET) -> Any:
    """``agent.act(obs)``, ``agent.act(obs, info=info)`` or ``agent.act(obs, info)`` as the agent
    asks (``style`` from :func:`act_info_style`, computed when not given)."""
    if style is _UNSET:
        style = act_info_style(agent)
    if style == "keyword":
        return agent.act(obs, info=info)
    if style == "positional":
        return agent.act(obs, info)
    return agent.act(obs)


_CONTROLLER = WaypointController()


def to_control(output: Any, obs: dict, action_mode: str = "carla") -> np.ndarray:
    """Turn an agent's output into a ``(3,)`` control (waypoints go through the shared controller;
    an array is an action of the env's ``action_mode``, ``envs.v2x_intersection.actions``:
    ``(3,)`` throttle, steer, brake for ``carla``, ``(2,)`` accel, steer for ``accel_steer``).

    Raises:
        ValueError: output is neither an action of ``action_mode`` (the message names the mode and
            its shape) nor a waypoint dict; NaN or inf.
    """
    if isinstance(output, dict):
        if "waypoints" not in output:
            raise ValueError("agent output dict must have 'waypoints' ((K, 2) ego frame) and 'speed'")
        wps = np.asarray(output["waypoints"], dtype=np.float64).reshape(-1, 2)
        speed = float(output.get("speed", np.linalg.norm(wps[0]) / 0.5 if len(wps) else 0.0))
        return _CONTROLLER.control(wps, float(obs["ego"][0]), speed)
    from v2xbench.envs.v2x_intersection.api.actions import get_mode, validate_action

    a = np.asarray(output, dtype=np.float32)
    if a.shape != get_mode(action_mode).shape:
        raise ValueError(f"agent output must be an action of shape {get_mode(action_mode).describe()} "
                         f"or a waypoint dict, got shape {a.shape}")
    return validate_action(a, action_mode, "agent output")
