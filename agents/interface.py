"""The agent interface every driver implements: the expert, oracles, AURORA, baselines, yours.

An agent is any object with::

    obs_mode: str                 # observation mode it needs ("objects"; "sensors"/"bev" later)
    privileged: bool              # True: it reads the simulator state (expert, oracles) through
                                  # bind(world); evaluation on the leaderboard marks it as such
    rsu_policy: str               # what the RSU sends it: "share_objects" or "none"
    def reset(self, route_info: dict) -> None: ...
    def act(self, obs: dict) -> np.ndarray: ...   # (3,) throttle, steer, brake   -- or --
                                                  # {"waypoints": (K, 2) ego frame, "speed": m/s}

``route_info`` has ``town``, ``route_id``, ``seed``, ``route_points`` ((P, 2) world frame) and
``commands`` ((P,) ``COMMAND_NAMES`` codes). Waypoint outputs are turned into controls by the
shared :class:`~.controller.WaypointController` (:func:`to_control`). Agents register by name with
:func:`register_agent` so that ``v2xbench eval --agent NAME`` finds them; any class following the
protocol also runs with ``--agent path/to/file.py:ClassName``.
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
    privileged: bool
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


def load_agent(spec: str) -> Any:
    """An agent instance from a registered name or ``path/to/file.py:ClassName``.

    Raises:
        ValueError: unknown name, missing file or class, or an object lacking the protocol.
    """
    from . import builtin  # noqa: F401  (registers the built-in agents)

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
    for attr, default in (("obs_mode", "objects"), ("privileged", False), ("rsu_policy", "share_objects")):
        if not hasattr(agent, attr):
            setattr(agent, attr, default)
    missing = [m for m in ("reset", "act") if not callable(getattr(agent, m, None))]
    if missing:
        raise ValueError(f"agent {spec!r} lacks method(s) {', '.join(missing)} (see agents/interface.py)")
    return agent


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
