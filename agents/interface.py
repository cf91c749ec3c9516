"""The agent interface every driver implements: the expert, oracles, AURORA, baselines, yours.

An agent is any object with::

    obs_mode: str                 # observation mode it needs ("objects", "sensors", "bev")
    rsu_policy: str               # what the RSU sends it: "share_objects" or "none"
    privileged: bool              # optional, informative only (see below)
    def reset(self, route_info: dict) -> None: ...
    def act(self, obs: dict) -> np.ndarray: ...   # (3,) throttle, steer, brake   -- or --
                                                  # {"waypoints": (K, 2) ego frame, "speed": m/s}

``route_info`` is what CARLA's leaderboard gives an agent: the route and its commands, nothing
about the scenarios on it. Keys: ``route_points`` ((P, 2) world frame, 1 m apart), ``commands``
((P,) ``COMMAND_NAMES`` codes), ``town`` (the map's name, public like CARLA's HD map) and
``seed`` (the job's world seed; the ``random`` baseline seeds its generator with it). It has no
route id, scenario list, weather or time of day (:data:`ROUTE_INFO_KEYS`).

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
    rsu_policy: str

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
    {"expert", "oracle_ego", "oracle_v2x", "cautious_ego", "stop_and_wait_ego"}
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
        ValueError: ``reset`` or ``act`` missing, or ``privileged = True`` declared by an agent
            the harness does not grant it to (see module docstring).
    """
    for attr, default in _DEFAULTS:
        if not hasattr(agent, attr):
            setattr(agent, attr, default)
    missing = [m for m in ("reset", "act") if not callable(getattr(agent, m, None))]
    if missing:
        raise ValueError(f"agent {label!r} lacks method(s) {', '.join(missing)} (see agents/interface.py)")
    if getattr(agent, "privileged", False) and not privileged:
        raise ValueError(
            f"agent {label!r} declares privileged = True, but only the built-in agents "
            f"{', '.join(sorted(PRIVILEGED_AGENTS))} may read the simulator; set privileged = False "
            "and drive from the observation")
    if privileged and not callable(getattr(agent, "bind", None)):
        raise ValueError(f"privileged agent {label!r} has no bind(world) method")
    return agent


def load_agent(spec: str) -> Any:
    """An agent instance from a registered name or ``path/to/file.py:ClassName``.

    Raises:
        ValueError: unknown name, missing file or class, an object lacking the protocol, or a
            non-built-in agent declaring ``privileged = True``.
    """
    register_builtins()
    if spec in AGENTS:
        agent = AGENTS[spec]()
    elif ":" in spec:
        path, cls_name = spec.rsplit(":", 1)
        p = Path(path)
        if not p.is_file():
            raise ValueError(f"agent file {path!r} not found")
        mod_name = f"v2xbench_user_agent_{abs(hash(p.resolve()))}"
        module_spec = importlib.util.spec_from_file_location(mod_name, p)
        module = importlib.util.module_from_spec(module_spec)
        sys.modules[mod_name] = module
        module_spec.loader.exec_module(module)
        if not hasattr(module, cls_name):
            raise ValueError(f"agent file {path!r} has no class {cls_name!r}")
        agent = getattr(module, cls_name)()
    else:
        raise ValueError(f"unknown agent {spec!r}; registered: {', '.join(sorted(AGENTS))}; "
                         "or give path/to/file.py:ClassName")
    return complete_agent(agent, spec, granted_privilege(spec))


_CONTROLLER = WaypointController()


def to_control(output: Any, obs: dict) -> np.ndarray:
    """Turn an agent's output into a ``(3,)`` control (waypoints go through the shared controller).

    Raises:
        ValueError: output is neither a (3,) control nor a waypoint dict.
    """
    if isinstance(output, dict):
        if "waypoints" not in output:
            raise ValueError("agent output dict must have 'waypoints' ((K, 2) ego frame) and 'speed'")
        wps = np.asarray(output["waypoints"], dtype=np.float64).reshape(-1, 2)
        speed = float(output.get("speed", np.linalg.norm(wps[0]) / 0.5 if len(wps) else 0.0))
        return _CONTROLLER.control(wps, float(obs["ego"][0]), speed)
    a = np.asarray(output, dtype=np.float32)
    if a.shape != (3,):
        raise ValueError(f"agent output must be a (3,) control or a waypoint dict, got shape {a.shape}")
    return a
