"""An agent's declared sensors and channel against the evaluation's env overrides
(``v2xbench eval``).

An agent declares the sensor configuration it needs as ``sensors = {...}``
(``agents/interface.py``, "Sensors"; keys of ``config.SENSOR_FIELDS``). The evaluation takes the
declared values as env overrides (so the env renders exactly the images the agent needs, at its
resolution) and refuses a ``--set`` of a declared field with another value: an agent fed other
images than it was trained on fails silently, so the mismatch is an error before any route runs.
"""

from __future__ import annotations

from typing import Any

from v2xbench.envs.v2x_intersection.sim.config import make_config, sensor_config


def apply_agent_sensors(overrides: dict[str, Any], declared: dict[str, Any],
                        label: str) -> dict[str, Any]:
    """``overrides`` with the agent's ``declared`` sensor fields (``interface.declared_sensors``)
    filled in, as JSON values.

    Args:
        overrides: the run's env overrides (``--set``).
        declared: what the agent declares (already checked: JSON values of ``sensor_config``).
        label: the agent's spec, for messages.

    Raises:
        ValueError: an override of a declared field differs from the declaration (the message
            names the field, both values and what to do), or is no valid value of the field.
    """
    out = dict(overrides)
    for key, need in declared.items():
        if key in overrides:
            try:
                have = sensor_config(make_config(**{key: overrides[key]}))[key]
            except ValueError as e:
                raise ValueError(f"--set {key}: {e}") from None
            if have != need:
                raise ValueError(
                    f"agent {label!r} declares sensors {key}={need!r} (what it was trained on), "
                    f"but the env is configured with {key}={have!r} (--set); the agent would get "
                    f"observations it does not expect. Drop --set {key} (the env then takes the "
                    "agent's value) or change the agent's sensors declaration")
        out[key] = need
    return out


def apply_agent_channel(overrides: dict[str, Any], declared: dict[str, int],
                        label: str) -> dict[str, Any]:
    """``overrides`` with the agent's declared channel settings (``interface.declared_channel``,
    e.g. ``max_payload_floats``) filled in.

    Raises:
        ValueError: a ``--set`` of a declared field has another value (naming both).
    """
    out = dict(overrides)
    for key, need in declared.items():
        if key in overrides and overrides[key] != need:
            raise ValueError(
                f"agent {label!r} declares channel {key}={need!r} (what its messages need), "
                f"but --set {key}={overrides[key]!r}; drop the --set (the env then takes the "
                "agent's value) or set the same value")
        out[key] = need
    return out


def agent_env_overrides(agent: Any, label: str,
                        overrides: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The env overrides of a run driven by ``agent``: ``(recorded, world)``. ``recorded``:
    ``overrides`` with the agent's declared sensors and channel filled in (what results and the
    fingerprint report); ``world``: those plus the agent's ``obs_mode`` (unless overridden) and the
    world's ``rsu_policy`` (``roadside.world_rsu_policy``), what the agent's world is made with.

    Raises:
        ValueError: as :func:`apply_agent_sensors`, :func:`apply_agent_channel` and
            ``world_rsu_policy``.
    """
    from v2xbench.agents.interface import declared_channel, declared_sensors

    from .roadside import world_rsu_policy

    recorded = apply_agent_sensors(dict(overrides), declared_sensors(agent, label), label)
    recorded = apply_agent_channel(recorded, declared_channel(agent, label), label)
    world = dict(recorded)
    world.setdefault("obs_mode", agent.obs_mode)
    world["rsu_policy"] = world_rsu_policy(agent, world)
    return recorded, world


__all__ = ["agent_env_overrides", "apply_agent_channel", "apply_agent_sensors"]
