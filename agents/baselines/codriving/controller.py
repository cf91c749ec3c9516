"""CoDriving's "native controller" (ours; the paper drives its planned waypoints with its own
controller rather than a shared one): two PID loops on the model's waypoints.

- **Steering**: the aim point is the mean of the first two waypoints (ego frame, ``x`` ahead,
  ``y`` left); its bearing ``atan2(y, x) / (pi / 2)`` is the error of a PID whose output,
  clipped to ``[-1, 1]``, is the steer (positive: left, as the env's).
- **Speed**: the target speed (AURORA's rule on the waypoints, the same every baseline gets) minus
  the current speed, clipped to ``[0, max_delta]`` m/s, is the error of a PID whose output,
  clipped to ``[0, max_throttle]``, is the throttle; the ego brakes fully when the target is
  below ``stop_speed`` or the speed exceeds the target by ``brake_ratio``.

**Traffic-light brake** (:class:`LightBrake`, off by default; ``{"light_brake": true}`` in the
agent's config): the published CoDriving predicts a traffic-light hazard from a front camera and
brakes fully while it is predicted (V2Xverse's ``traffic_light_brake``). Our CoDriving sees only
LiDAR, which carries no light colour, so instead it reads the light of its lane from the ego
vector every agent observes (``obs["ego"]``: ``light_state``, ``dist_to_stop_line``;
docs/environment.md) and brakes while a red light's stop line is within its stopping distance
(``v^2 / (2 decel) + margin``), and on yellow only where it can still stop comfortably. Stop signs
stay the planner's.

Both PIDs keep the last ``window`` errors for their integral and derivative terms (TransFuser's
and InterFuser's controller form); :meth:`NativeController.reset` clears them at a new route.
The gains and limits are TransFuser's (turn 1.25 / 0.75 / 0.3, speed 5 / 0.5 / 1, window 20,
``max_delta`` 0.25, ``max_throttle`` 0.75), not tuned on our ego.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PIDGains:
    """Gains of one PID loop over a window of errors (the integral and derivative per tick)."""

    kp: float
    ki: float
    kd: float
    window: int = 20


class PID:
    """A PID over the last ``window`` errors."""

    def __init__(self, gains: PIDGains) -> None:
        self.g = gains
        self.errors: deque[float] = deque([0.0, 0.0], maxlen=gains.window)

    def reset(self) -> None:
        """Forget the errors."""
        self.errors = deque([0.0, 0.0], maxlen=self.g.window)

    def step(self, error: float) -> float:
        """The control for this tick's ``error``."""
        self.errors.append(float(error))
        e = np.asarray(self.errors)
        return self.g.kp * e[-1] + self.g.ki * float(e.mean()) + self.g.kd * float(e[-1] - e[-2])


@dataclass(frozen=True)
class LightBrake:
    """Whether to brake for the light of the ego's lane (module docstring).

    Attributes:
        decel: m/s^2 the stop envelope assumes. margin: m before the stop line to stop at.
        yellow_decel: on yellow, brake only if stopping before the line needs at most this.
    """

    decel: float = 4.0
    margin: float = 2.5
    yellow_decel: float = 3.0

    def __call__(self, light_state: float, dist_to_line: float, speed: float) -> bool:
        """``light_state`` / ``dist_to_stop_line`` as in the ego vector (the ego's centre to its
        lane's stop line, the line red-light infractions are counted at; ``-1``: none),
        ``speed`` m/s: brake this tick?"""
        from v2xbench.envs.v2x_intersection.traffic.signals import RED, YELLOW

        if dist_to_line < 0 or int(light_state) not in (RED, YELLOW):
            return False
        to_line, v = float(dist_to_line), max(float(speed), 0.0)
        if to_line > v * v / (2 * self.decel) + self.margin:
            return False  # not yet near the line
        return int(light_state) == RED or to_line >= v * v / (2 * self.yellow_decel)


class NativeController:
    """Waypoints + target speed -> ``(throttle, steer, brake)`` (module docstring)."""

    def __init__(self, turn: PIDGains = PIDGains(1.25, 0.75, 0.3),
                 speed: PIDGains = PIDGains(5.0, 0.5, 1.0), max_throttle: float = 0.75,
                 max_delta: float = 0.25, stop_speed: float = 0.4, brake_ratio: float = 1.1
                 ) -> None:
        self.turn, self.speed = PID(turn), PID(speed)
        self.max_throttle, self.max_delta = max_throttle, max_delta
        self.stop_speed, self.brake_ratio = stop_speed, brake_ratio

    def reset(self) -> None:
        """A new route: clear both PIDs."""
        self.turn.reset()
        self.speed.reset()

    def control(self, waypoints: np.ndarray, speed: float, target_speed: float) -> np.ndarray:
        """``(3,)`` float32 throttle, steer, brake for ``waypoints`` ``(T >= 1, 2)`` (ego frame),
        the current ``speed`` and the ``target_speed`` (m/s).

        Raises:
            ValueError: no waypoints, or non-finite input.
        """
        w = np.asarray(waypoints, np.float64).reshape(-1, 2)
        if len(w) == 0 or not np.isfinite(w).all() or not np.isfinite([speed, target_speed]).all():
            raise ValueError(f"CoDriving NativeController: waypoints {w.shape} and speeds "
                             f"({speed}, {target_speed}) must be finite, T >= 1")
        aim = w[:2].mean(0)
        angle = float(np.arctan2(aim[1], aim[0])) / (np.pi / 2) if np.hypot(*aim) > 1e-3 else 0.0
        steer = float(np.clip(self.turn.step(angle), -1.0, 1.0))
        brake = target_speed < self.stop_speed or speed > self.brake_ratio * target_speed
        delta = float(np.clip(target_speed - speed, 0.0, self.max_delta))
        throttle = float(np.clip(self.speed.step(delta), 0.0, self.max_throttle))
        if brake:
            throttle = 0.0
        return np.array([throttle, steer, 1.0 if brake else 0.0], np.float32)


__all__ = ["LightBrake", "NativeController", "PID", "PIDGains"]
