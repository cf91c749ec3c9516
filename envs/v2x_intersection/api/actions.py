"""Ego action modes: how an agent's action becomes the ``(throttle, steer, brake)`` control.

``config.action_mode`` picks the ego's action in every API (Gymnasium ``action_space``,
PettingZoo ``action_space("ego")``, ``V2XTorchEnv.action_spec``, ``v2xbench eval --set
action_mode=...``). The world itself always applies a CARLA-style control (:mod:`.dynamics`), so
the ego observation's throttle / steer / brake columns show the mapped control in either mode.

=================  =======  ===================================================================
mode               shape    action
=================  =======  ===================================================================
``carla``          ``(3,)``  throttle in [0, 1], steer in [-1, 1], brake in [0, 1] (default;
                            full brake, 8 m/s^2, is stronger than full throttle, 3.5 m/s^2)
``accel_steer``    ``(2,)``  accel in [-1, 1], steer in [-1, 1]: ``accel > 0`` is throttle
                            ``accel``, ``accel < 0`` is brake ``-accel * BRAKE_PER_ACCEL``, so
                            +1 and -1 are +-3.5 m/s^2 (symmetric, as highway-env's
                            ``ContinuousAction``), 0 coasts (drag only); for RL
=================  =======  ===================================================================

Finite out-of-range values are clipped into the box; a wrong shape, a non-numeric dtype, NaN or
inf raise ``ValueError`` naming the mode and the expected shape.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from ..core.dynamics import VehicleParams
from ..sim.config import ACTION_MODES
from .observations import validate_control

#: brake per unit of negative accel: -1 brakes at ``max_accel`` m/s^2 (3.5 / 8 = 0.4375 brake)
BRAKE_PER_ACCEL = VehicleParams().max_accel / VehicleParams().max_brake


def _clip(x: float, lo: float, hi: float) -> float:
    x = x if x > lo else lo
    return x if x < hi else hi


def _carla_one(a: np.ndarray, name: str) -> np.ndarray:
    return validate_control(a, name)


def _accel_steer_one(a: np.ndarray, name: str) -> np.ndarray:
    accel, steer = a.tolist()
    if not (math.isfinite(accel) and math.isfinite(steer)):
        raise ValueError(f"{name}: contains NaN or inf: {[accel, steer]} "
                         "(action_mode='accel_steer')")
    accel, steer = _clip(accel, -1.0, 1.0), _clip(steer, -1.0, 1.0)
    throttle = accel if accel > 0.0 else 0.0
    brake = -accel * BRAKE_PER_ACCEL if accel < 0.0 else 0.0
    return np.array((throttle, steer, brake))


def _carla_many(a: np.ndarray) -> np.ndarray:
    return a


def _accel_steer_many(a: np.ndarray) -> np.ndarray:
    out = np.zeros((len(a), 3))
    out[:, 0] = np.maximum(a[:, 0], 0.0)
    out[:, 1] = a[:, 1]
    out[:, 2] = np.maximum(-a[:, 0], 0.0) * BRAKE_PER_ACCEL
    return out


@dataclass(frozen=True)
class ActionMode:
    """One ego action mode.

    Attributes:
        name: the ``config.action_mode`` value.
        fields: the action's components in order (their count is the action's length).
        low, high: ``(D,)`` bounds of the action box.
        to_control: checks one ``(D,)`` numeric array (NaN/inf raise; out of range clipped) and
            returns the ``(3,)`` float64 control ``(throttle, steer, brake)``.
        to_controls: ``(N, D)`` finite actions already clipped into the box -> ``(N, 3)`` controls.
    """

    name: str
    fields: tuple[str, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    to_control: Callable[[np.ndarray, str], np.ndarray]
    to_controls: Callable[[np.ndarray], np.ndarray]

    @property
    def shape(self) -> tuple[int]:
        """The action's shape, ``(D,)``."""
        return (len(self.fields),)

    def describe(self) -> str:
        """``"(3,) = (throttle, steer, brake) for action_mode='carla'"`` (for error messages)."""
        return f"({len(self.fields)},) = ({', '.join(self.fields)}) for action_mode={self.name!r}"


#: the action modes by name (``config.ACTION_MODES``)
MODES: dict[str, ActionMode] = {
    "carla": ActionMode("carla", ("throttle", "steer", "brake"), (0.0, -1.0, 0.0), (1.0, 1.0, 1.0),
                        _carla_one, _carla_many),
    "accel_steer": ActionMode("accel_steer", ("accel", "steer"), (-1.0, -1.0), (1.0, 1.0),
                              _accel_steer_one, _accel_steer_many),
}
assert tuple(MODES) == ACTION_MODES, "actions.MODES and config.ACTION_MODES disagree"


def get_mode(mode: str) -> ActionMode:
    """The :class:`ActionMode` named ``mode``.

    Raises:
        ValueError: an unknown mode (naming the known ones).
    """
    try:
        return MODES[mode]
    except (KeyError, TypeError):
        raise ValueError(f"action_mode: {mode!r} is not one of {', '.join(MODES)}") from None


def action_space(mode: str = "carla") -> spaces.Box:
    """The ego's ``Box`` action space of ``mode`` (float32)."""
    m = get_mode(mode)
    return spaces.Box(np.array(m.low, np.float32), np.array(m.high, np.float32), dtype=np.float32)


def validate_action(action, mode: str = "carla", name: str = "ego action") -> np.ndarray:
    """Check one ego action of ``mode`` and map it to the ``(3,)`` float64 control.

    Raises:
        ValueError: non-numeric dtype, wrong shape (the message names the mode and the expected
            shape), NaN or inf.
    """
    m = MODES[mode]
    a = action if type(action) is np.ndarray else np.asarray(action)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{name}: expected a numeric array of shape {m.describe()}, got dtype "
                         f"{a.dtype}")
    if a.shape != m.shape:
        raise ValueError(f"{name}: expected shape {m.describe()}, got {a.shape}")
    return m.to_control(a, name)


def validate_actions(actions, n: int, mode: str = "carla") -> np.ndarray:
    """Check ``(n, D)`` ego actions of ``mode``, clip them into the box and map them to ``(n, 3)``
    controls (:func:`validate_action` row by row, in one go).

    Raises:
        ValueError: non-numeric dtype, wrong shape (naming the mode and the expected shape),
            a row with NaN or inf (naming the row).
    """
    m = MODES[mode]
    a = np.asarray(actions)
    d = len(m.fields)
    what = f"({n}, {d}) = ({', '.join(m.fields)}) per world for action_mode={mode!r}"
    if a.dtype.kind not in "fiu":
        raise ValueError(f"actions: expected a numeric array of shape {what}, got dtype {a.dtype}")
    if a.shape != (n, d):
        raise ValueError(f"actions: expected shape {what}, got {a.shape}")
    a = a.astype(np.float64)
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"action[{i}]: contains NaN or inf: {a[i].tolist()}")
    return m.to_controls(np.clip(a, m.low, m.high))


__all__ = ["BRAKE_PER_ACCEL", "MODES", "ActionMode", "action_space", "get_mode", "validate_action",
           "validate_actions"]
