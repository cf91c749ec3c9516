"""Roadside policies that agents bring to ``v2xbench eval``: the harness's side of the contract.

An agent's ``rsu_policy`` (``agents/interface.py``) is either the name of a built-in RSU policy
(``"share_objects"`` or ``"none"``, ``config.RSU_POLICIES``) or an object, the agent's own
roadside policy::

    class MyRoadside:
        def reset(self, route_info: dict) -> None: ...    # optional: at every route's start
        def act(self, rsu_obs: dict) -> message: ...      # every tick a unit serves the route

The harness runs it in the roadside unit's place (:class:`RoadsideRunner`): every tick at which a
unit serves the ego (``World.active_rsu[0] >= 0``) it calls ``act`` with that unit's observation,
the PettingZoo ``rsu`` agent's (``observations.rsu_observation``: ``unit``, ``calibration``,
``objects``, and in ``sensors`` mode its ``camera`` and ``lidar``), and sends the message it
returns over the V2X channel, which counts its bytes (BPS), delays, loses and rate-limits it as
any message. No unit, no call and no message. A message (:func:`message_values`) is:

- a 1-D array of floats (list, tuple or NumPy array): a raw payload (``wire.FORMAT_RAW``), which
  the ego receives as its ``v2x_payload`` observation (``v2x_info``: ``payload_length``, its age
  and the sender's pose); an empty array sends nothing;
- ``None``: send nothing this tick;
- a mapping in the PettingZoo RSU action's layout, ``{"length", "payload", "format"}``
  (``channel.message_space``), e.g. an object list made with ``channel.pack_objects`` and
  ``"format": wire.FORMAT_OBJECTS``, which the ego also gets decoded in ``v2x_objects``.

Every value must be finite and within ``+-wire.PAYLOAD_LIMIT`` (1e4); a message longer than
``max_payload_floats`` (``--set max_payload_floats=N`` raises it) is an error that fails the
route, never cut. Results and the summary name the policy ``custom:<ClassName>``
(:func:`policy_label`), and the run's fingerprint holds its code, declared ``checkpoint`` and
``fingerprint()`` (:func:`roadside_component`), as for the agent.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from v2xbench.envs.v2x_intersection.sim.config import RSU_POLICIES
from v2xbench.envs.v2x_intersection.v2x.channel import ChannelConfig
from v2xbench.envs.v2x_intersection.v2x.wire import (
    FORMAT_OBJECTS,
    FORMAT_RAW,
    _check_used,
    _is_int,
    check_format,
)

#: prefix of a custom roadside policy's label (``custom:<ClassName>``)
CUSTOM_PREFIX = "custom:"
#: an agent's RSU policy when it declares none (``interface._DEFAULTS``)
DEFAULT_POLICY = "share_objects"


def roadside_policy(agent: Any) -> Any | None:
    """The roadside policy object an agent brings (``None`` when its ``rsu_policy`` names a
    built-in policy or is absent).

    Raises:
        ValueError: ``rsu_policy`` is neither a known policy name nor an object with ``act``.
    """
    rp = getattr(agent, "rsu_policy", DEFAULT_POLICY)
    if isinstance(rp, str):
        if rp not in RSU_POLICIES:
            raise ValueError(f"agent {type(agent).__name__}: rsu_policy={rp!r} must be one of "
                             f"{RSU_POLICIES} or a roadside policy object with "
                             "act(rsu_observation) -> message (see agents/interface.py)")
        return None
    if not callable(getattr(rp, "act", None)):
        raise ValueError(f"agent {type(agent).__name__}: rsu_policy is a {type(rp).__name__} "
                         "without an act(rsu_observation) method; give a policy name "
                         f"{RSU_POLICIES} or a roadside policy object (see agents/interface.py)")
    return rp


def policy_label(agent: Any) -> str:
    """What results and the summary call an agent's RSU policy: the built-in policy's name, or
    ``custom:<ClassName>`` for a roadside policy object.

    Raises:
        ValueError: as :func:`roadside_policy`.
    """
    rp = roadside_policy(agent)
    if rp is None:
        return str(getattr(agent, "rsu_policy", DEFAULT_POLICY))
    from .agent_process import RemoteRoadside

    if isinstance(rp, RemoteRoadside):  # the agent's process named it
        return rp.label
    return f"{CUSTOM_PREFIX}{type(rp).__name__}"


def roadside_component(agent: Any, label: str | None = None) -> dict | None:
    """The roadside policy's part of the run's fingerprint (``agent_fingerprint.py``): its label,
    the source file of its class (SHA-256) and what it declares (``checkpoint``,
    ``fingerprint()``: ``agent_fingerprint.declared``); ``None`` for a built-in policy."""
    rp = roadside_policy(agent)
    if rp is None:
        return None
    from .agent_fingerprint import declared, factory_code_digests

    name = policy_label(agent)
    return {"policy": name, "code": factory_code_digests(type(rp)),
            **declared(rp, label or name)}


def message_values(output: Any, label: str) -> tuple[np.ndarray, int] | None:
    """``(values, format)`` of a roadside policy's output (module docstring): the payload as a
    1-D float64 array and its format code; ``None`` when it sends nothing.

    Raises:
        ValueError: naming the policy and the problem: bytes or text, not 1-D, not numbers, a
            mapping without ``length`` / ``payload``, a length the payload does not hold, an
            unknown format.
    """
    if output is None:
        return None
    if isinstance(output, (bytes, bytearray, memoryview, str)):
        raise ValueError(f"roadside policy {label}: act() returned {type(output).__name__}; a "
                         "message is a 1-D array of floats (the payload), a message dict or None")
    if isinstance(output, Mapping):
        missing = [k for k in ("length", "payload") if k not in output]
        if missing:
            raise ValueError(f"roadside policy {label}: message dict is missing {missing} "
                             "(keys: length, payload, format)")
        n = output["length"]
        if isinstance(n, np.ndarray) and n.ndim == 0:
            n = n.item()
        if not _is_int(n) or n < 0:
            raise ValueError(f"roadside policy {label}: message length must be an integer >= 0, "
                             f"got {n!r}")
        fmt = check_format(output.get("format", FORMAT_OBJECTS))
        values = _floats(output["payload"], label)
        if values.shape[0] < n:
            raise ValueError(f"roadside policy {label}: message length {n} but its payload holds "
                             f"{values.shape[0]} floats")
        return (values[:n], fmt) if n else None
    values = _floats(output, label)
    return (values, FORMAT_RAW) if values.shape[0] else None


def _floats(x: Any, label: str) -> np.ndarray:
    a = np.asarray(x)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"roadside policy {label}: a message payload holds numbers, got dtype "
                         f"{a.dtype}")
    if a.ndim != 1:
        raise ValueError(f"roadside policy {label}: a message payload is 1-D, got shape {a.shape}")
    return a.astype(np.float64)


def build_message(values: np.ndarray, fmt: int, config: ChannelConfig, label: str) -> dict:
    """The RSU message action (``channel.message_space``) carrying ``values`` in format ``fmt``.

    Raises:
        ValueError: more floats than ``max_payload_floats`` (named; a message is never cut),
            NaN/inf or a value beyond ``+-PAYLOAD_LIMIT`` (named with its index or value).
    """
    n, m = values.shape[0], config.max_payload_floats
    if n > m:
        raise ValueError(f"roadside policy {label}: oversized message of {n} floats exceeds the "
                         f"limit of max_payload_floats={m} (messages are never cut; raise the "
                         "limit with --set max_payload_floats=N)")
    try:
        _check_used(values, n)
    except ValueError as e:
        raise ValueError(f"roadside policy {label}: {e}") from None
    payload = np.zeros(m, np.float32)
    payload[:n] = values
    return {"length": n, "payload": payload, "format": fmt}


def to_message(output: Any, config: ChannelConfig, label: str) -> dict | None:
    """The RSU message action of a roadside policy's output (``None``: send nothing)."""
    v = message_values(output, label)
    return None if v is None else build_message(*v, config, label)


class RoadsideRunner:
    """Runs an agent's roadside policy in the active roadside unit's place (module docstring).

    Args:
        policy: the roadside policy object (``act``, optional ``reset``).
        label: its name in results (:func:`policy_label`).
    """

    def __init__(self, policy: Any, label: str) -> None:
        self.policy, self.label = policy, label

    def reset(self, route_info: dict) -> None:
        """The policy's ``reset(route_info)``, when it has one (at every route's start)."""
        fn = getattr(self.policy, "reset", None)
        if callable(fn):
            fn(route_info)

    def message(self, world) -> dict | None:
        """The message of this tick: the policy's ``act`` on the slot-0 unit's observation, as an
        RSU action; ``None`` (nothing sent) when no unit serves the ego.

        Raises:
            ValueError: a malformed or oversized message (:func:`to_message`).
        """
        if world.active_rsu[0] < 0:
            return None
        from v2xbench.envs.v2x_intersection.api.observations import rsu_observation

        out = self.policy.act(rsu_observation(world, 0))
        return to_message(out, world.channel_config, self.label)


def roadside_runner(agent: Any) -> RoadsideRunner | None:
    """A :class:`RoadsideRunner` for the agent's roadside policy (``None`` for a built-in one)."""
    rp = roadside_policy(agent)
    return None if rp is None else RoadsideRunner(rp, policy_label(agent))


def world_rsu_policy(agent: Any, overrides: Mapping[str, Any]) -> str:
    """The env's ``rsu_policy`` for an agent: ``"none"`` when it brings its own (the built-in
    policy stays off; its runner sends instead), else the override or the agent's choice.

    Raises:
        ValueError: an ``rsu_policy`` override next to an agent's own roadside policy.
    """
    if roadside_policy(agent) is None:
        return str(overrides.get("rsu_policy", getattr(agent, "rsu_policy", DEFAULT_POLICY)))
    if "rsu_policy" in overrides:
        raise ValueError(f"--set rsu_policy={overrides['rsu_policy']!r} conflicts with the "
                         f"agent's own roadside policy ({policy_label(agent)}); drop the override")
    return "none"
