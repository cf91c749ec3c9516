"""Pure dynamics functions: the ego's kinematic bicycle model (with its inverse) and IDM.

All functions are vectorized over leading dimensions and keep no state: ``(state, action, dt) ->
state``. Units: m, s, rad, m/s, m/s^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import libm
from .jit import HAVE_JIT, _njit, _njit_inline


@dataclass(frozen=True)
class VehicleParams:
    """Physical limits of the ego vehicle (a mid-size car)."""

    wheelbase: float = 2.8  # m
    max_steer: float = 0.61  # rad (35 deg) road-wheel angle at steer = +-1
    max_accel: float = 3.5  # m/s^2 at throttle = 1
    max_brake: float = 8.0  # m/s^2 at brake = 1
    max_speed: float = 25.0  # m/s
    drag: float = 0.02  # 1/s, rolling + air resistance (a = -drag * v)


def bicycle_step(
    x: np.ndarray, y: np.ndarray, yaw: np.ndarray, v: np.ndarray,
    throttle: np.ndarray, steer: np.ndarray, brake: np.ndarray,
    params: VehicleParams, dt: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One step of the kinematic bicycle model (rear-axle reference, semi-implicit Euler).

    Args:
        x, y, yaw, v: state (m, m, rad, m/s), any matching shapes.
        throttle in [0, 1], steer in [-1, 1] (positive = left), brake in [0, 1].
        params: vehicle limits.
        dt: time step (s).

    Returns:
        ``(x, y, yaw, v, accel)`` after ``dt``; speed never goes negative (no reverse gear).
    """
    accel = throttle * params.max_accel - brake * params.max_brake - params.drag * v
    v_new = np.clip(v + accel * dt, 0.0, params.max_speed)
    accel = (v_new - v) / dt
    delta = steer * params.max_steer
    yaw_rate = v_new * libm.tan(delta) / params.wheelbase
    yaw_new = yaw + yaw_rate * dt
    yaw_new = (yaw_new + np.pi) % (2 * np.pi) - np.pi
    x_new = x + v_new * np.cos(yaw_new) * dt
    y_new = y + v_new * np.sin(yaw_new) * dt
    return x_new, y_new, yaw_new, v_new, accel


@_njit
def bicycle_step_scalar(x, y, yaw, v, throttle, steer, brake, max_accel, max_brake, drag, max_speed, max_steer,
                        wheelbase, dt):  # pragma: no cover
    """:func:`bicycle_step` for one vehicle (float64 scalars, the same operations in the same order)."""
    accel = throttle * max_accel - brake * max_brake - drag * v
    v_new = v + accel * dt  # np.clip: NaN kept, else (v > lo ? v : lo), then (v < hi ? v : hi)
    if v_new == v_new:
        v_new = v_new if v_new > 0.0 else 0.0
        v_new = v_new if v_new < max_speed else max_speed
    accel = (v_new - v) / dt
    delta = steer * max_steer
    yaw_rate = v_new * np.tan(delta) / wheelbase
    yaw_new = yaw + yaw_rate * dt
    yaw_new = (yaw_new + np.pi) % (2 * np.pi) - np.pi
    x_new = x + v_new * np.cos(yaw_new) * dt
    y_new = y + v_new * np.sin(yaw_new) * dt
    return x_new, y_new, yaw_new, v_new, accel


def bicycle_inverse(
    yaw: np.ndarray, v: np.ndarray, yaw_next: np.ndarray, v_next: np.ndarray,
    params: VehicleParams, dt: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Controls that take ``(yaw, v)`` to ``(yaw_next, v_next)`` in one :func:`bicycle_step`.

    Exact inverse inside the actuator limits (results are clipped to the valid ranges).

    Returns:
        ``(throttle, steer, brake)``.
    """
    accel = (v_next - v) / dt + params.drag * v
    throttle = np.clip(accel / params.max_accel, 0.0, 1.0)
    brake = np.clip(-accel / params.max_brake, 0.0, 1.0)
    dyaw = (yaw_next - yaw + np.pi) % (2 * np.pi) - np.pi
    with np.errstate(divide="ignore", invalid="ignore"):
        tan_delta = np.where(v_next > 1e-6, dyaw * params.wheelbase / (np.maximum(v_next, 1e-6) * dt), 0.0)
    steer = np.clip(np.arctan(tan_delta) / params.max_steer, -1.0, 1.0)
    return throttle, steer, brake


@dataclass(frozen=True)
class IDMParams:
    """Intelligent Driver Model constants (Treiber et al. 2000)."""

    time_headway: float = 1.5  # s
    min_gap: float = 2.5  # m (jam distance)
    accel: float = 2.0  # m/s^2 (maximum acceleration)
    decel: float = 3.0  # m/s^2 (comfortable deceleration)
    delta: float = 4.0  # acceleration exponent
    max_brake: float = 8.0  # m/s^2 (emergency limit)


def idm_accel(v: np.ndarray, v0: np.ndarray, gap: np.ndarray, dv: np.ndarray, p: IDMParams) -> np.ndarray:
    """IDM acceleration (m/s^2), clipped to ``[-max_brake, accel]``.

    Args:
        v: own speed (m/s).
        v0: desired speed (m/s).
        gap: bumper-to-bumper distance to the leader (m); ``inf`` for a free road.
        dv: approach rate ``v - v_leader`` (m/s).
    """
    if (HAVE_JIT and isinstance(v, np.ndarray) and v.ndim == 1 and isinstance(v0, np.ndarray)
            and isinstance(gap, np.ndarray) and isinstance(dv, np.ndarray)
            and v.shape == v0.shape == gap.shape == dv.shape and v.dtype == v0.dtype == gap.dtype == dv.dtype == np.float64):
        return idm_kernel(v, v0, gap, dv, p.min_gap, p.time_headway, float(np.sqrt(p.accel * p.decel)), p.accel,
                          p.delta, p.max_brake)
    v0 = np.maximum(v0, 0.1)
    s_star = p.min_gap + np.maximum(0.0, v * p.time_headway + v * dv / (2.0 * np.sqrt(p.accel * p.decel)))
    free = 1.0 - libm.power(v / v0, p.delta)
    with np.errstate(divide="ignore", invalid="ignore"):
        inter = np.where(np.isfinite(gap), (s_star / np.maximum(gap, 0.1)) ** 2, 0.0)
    return np.clip(p.accel * (free - inter), -p.max_brake, p.accel)


@_njit_inline
def idm_one(v, v0, gap, dv, min_gap, headway, sqrt_ab, a_max, delta, max_brake):  # pragma: no cover
    """``dynamics.idm_accel`` for one follower (``sqrt_ab = np.sqrt(accel * decel)``)."""
    w0 = max(v0, 0.1)
    s_star = min_gap + max(0.0, v * headway + v * dv / (2.0 * sqrt_ab))
    free = 1.0 - np.power(v / w0, delta)
    if np.isfinite(gap):
        r = s_star / max(gap, 0.1)
        inter = r * r
    else:
        inter = 0.0
    return min(max(a_max * (free - inter), -max_brake), a_max)


@_njit
def idm_kernel(v, v0, gap, dv, min_gap, headway, sqrt_ab, a_max, delta, max_brake):  # pragma: no cover
    """``dynamics.idm_accel`` element by element (:func:`idm_one`)."""
    out = np.empty(v.shape[0])
    for i in range(v.shape[0]):
        out[i] = idm_one(v[i], v0[i], gap[i], dv[i], min_gap, headway, sqrt_ab, a_max, delta, max_brake)
    return out
