"""Longitudinal planning: IDM against a set of constraints, and speed-profile rollouts.

A *constraint* is a target the ego centre must not pass: ``(gap, v_target, s0, headway)`` with
``gap`` the distance (m) from the ego centre to where the centre may go at most (behind a
leader's tail, before a stop line, before a predicted conflict), ``v_target`` how fast that
point moves along the path (m/s; 0 for stop points), ``s0`` the standstill distance kept to it
and ``headway`` the desired time gap (s). The acceleration is the IDM minimum over constraints,
with the free-road term towards the speed envelope (speed limits and curves ahead, approached
at a comfortable deceleration).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ENVELOPE_STEP = 2.0  # m between envelope samples


@dataclass(frozen=True)
class LonParams:
    """IDM constants of the ego (comfortable, as Bench2Drive's comfort bounds require)."""

    accel: float = 2.0  # m/s^2, maximum acceleration
    decel: float = 3.0  # m/s^2, comfortable deceleration
    max_brake: float = 8.0  # m/s^2
    delta: float = 4.0
    curve_decel: float = 1.8  # m/s^2 when slowing for a speed limit or curve ahead


def idm(
    v: float, v0: float, gap: float, v_target: float, s0: float, headway: float, p: LonParams
) -> float:
    """IDM acceleration (m/s^2) behind one constraint (``gap`` inf: free road)."""
    v0 = max(v0, 0.1)
    free = 1.0 - (v / v0) ** p.delta if v < 3.0 * v0 else -10.0
    if gap == np.inf:
        return p.accel * free
    s_star = s0 + max(0.0, v * headway + v * (v - v_target) / (2.0 * (p.accel * p.decel) ** 0.5))
    return p.accel * (free - (s_star / max(gap, 0.05)) ** 2)


def envelope(
    st: np.ndarray, vlim: np.ndarray, front: float, p: LonParams
) -> tuple[float, np.ndarray]:
    """Speed envelope on a station grid: the highest speed from which every limit ahead can be
    reached at ``p.curve_decel``.

    Args:
        st: ``(P,)`` path stations (m). vlim: ``(P,)`` limits (m/s). front: ego half length (m).

    Returns:
        ``(st0, env)``: the grid starts at station ``st0`` with ``ENVELOPE_STEP`` spacing.
    """
    st0 = float(st[0])
    grid = np.arange(st0, float(st[-1]) + 1e-9, ENVELOPE_STEP)
    vmax = float(vlim.max())
    slow = (vlim < vmax - 0.05).nonzero()[0]
    if len(slow) == 0:
        return st0, np.full(len(grid), vmax)
    slow = slow[:: max(1, len(slow) // 60)]
    ds = st[slow][None, :] - front - grid[:, None]
    cap = np.sqrt(vlim[slow][None, :] ** 2 + 2.0 * p.curve_decel * np.maximum(ds, 0.0))
    cap = np.where(st[slow][None, :] + front >= grid[:, None], cap, np.inf)
    return st0, np.minimum(cap.min(1), vmax)


def accel_now(
    v: float, v0: float, constraints: list[tuple[float, float, float, float]], p: LonParams
) -> tuple[float, int]:
    """Acceleration (m/s^2) and the index of the binding constraint (-1: free road)."""
    a, which = idm(v, v0, np.inf, 0.0, 0.0, 0.0, p), -1
    for k, (gap, vt, s0, hw) in enumerate(constraints):
        ak = idm(v, v0, gap, vt, s0, hw, p)
        if ak < a:
            a, which = ak, k
    return max(a, -p.max_brake), which


def rollout(
    v: float,
    env: tuple[float, np.ndarray],
    constraints: list[tuple[float, float, float, float]],
    dt: float,
    steps: int,
    p: LonParams,
    a_first: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Integrate the IDM speed profile: constraint targets move at their ``v_target``.

    Args:
        v: speed now (m/s).
        env: the speed envelope (:func:`envelope`).
        constraints: see module docstring (gaps at time 0).
        dt: step (s). steps: number of steps.
        a_first: acceleration to apply on the first step (default: the IDM one).

    Returns:
        ``(s (steps,), v (steps,))`` station (m, from the ego now) and speed after each step.
    """
    st0, ev = env
    ev = ev.tolist()
    last = len(ev) - 1
    acc, max_b, sq = p.accel, p.max_brake, 2.0 * (p.accel * p.decel) ** 0.5
    inv = 1.0 / ENVELOPE_STEP
    cons = [(float(g), float(vt), float(s0), float(hw)) for g, vt, s0, hw in constraints]
    s = t = 0.0
    out_s, out_v = [0.0] * steps, [0.0] * steps
    for k in range(steps):
        if k == 0 and a_first is not None:
            a = a_first
        else:
            i = int((s - st0) * inv)
            v0 = ev[0 if i < 0 else (last if i > last else i)]
            v0 = v0 if v0 > 0.1 else 0.1
            r = v / v0
            free = 1.0 - r * r * r * r if r < 3.0 else -10.0
            a = acc * free
            for g, vt, s0, hw in cons:
                gap = g + vt * t - s
                dyn = v * hw + v * (v - vt) / sq
                x = (s0 + (dyn if dyn > 0.0 else 0.0)) / (gap if gap > 0.05 else 0.05)
                ak = acc * (free - x * x)
                if ak < a:
                    a = ak
            if a < -max_b:
                a = -max_b
        v = v + a * dt
        if v < 0.0:
            v = 0.0
        s += v * dt
        t += dt
        out_s[k], out_v[k] = s, v
    return np.array(out_s), np.array(out_v)
