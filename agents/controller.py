"""Shared waypoint-following controller: pure pursuit for steering, P control for speed.

Any agent that plans waypoints (the expert, AURORA, baselines) turns them into
``(throttle, steer, brake)`` with :class:`WaypointController`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from v2xbench.envs.v2x_intersection.core.dynamics import VehicleParams


@dataclass(frozen=True)
class ControllerParams:
    """Gains and limits of the waypoint controller."""

    lookahead_min: float = 4.0  # m
    lookahead_gain: float = 0.6  # s: lookahead grows with speed
    lookahead_max: float = 15.0  # m
    speed_gain: float = 1.5  # 1/s: acceleration per m/s of speed error


class WaypointController:
    """Pure pursuit + proportional speed control for the kinematic bicycle ego."""

    def __init__(self, params: ControllerParams | None = None, vehicle: VehicleParams | None = None) -> None:
        self.p = params or ControllerParams()
        self.vehicle = vehicle or VehicleParams()

    def steer(self, path_xy: np.ndarray, speed: float) -> float:
        """Steering in [-1, 1] to follow ``path_xy (P, 2)`` given in the ego frame (m)."""
        if len(path_xy) == 0:
            return 0.0
        ld = float(np.clip(self.p.lookahead_min + self.p.lookahead_gain * speed, self.p.lookahead_min,
                           self.p.lookahead_max))
        d = np.linalg.norm(path_xy, axis=1)
        ahead = np.flatnonzero((d >= ld) & (path_xy[:, 0] > 0))
        target = path_xy[ahead[0]] if len(ahead) else path_xy[-1]
        dist = max(float(np.hypot(*target)), 1e-3)
        alpha = np.arctan2(target[1], target[0])
        delta = np.arctan2(2.0 * self.vehicle.wheelbase * np.sin(alpha), dist)
        return float(np.clip(delta / self.vehicle.max_steer, -1.0, 1.0))

    def longitudinal(self, speed: float, accel_cmd: float) -> tuple[float, float]:
        """Throttle and brake in [0, 1] realising an acceleration command (m/s^2)."""
        a = accel_cmd + self.vehicle.drag * speed
        if a >= 0:
            return float(np.clip(a / self.vehicle.max_accel, 0.0, 1.0)), 0.0
        return 0.0, float(np.clip(-a / self.vehicle.max_brake, 0.0, 1.0))

    def control(self, path_xy: np.ndarray, speed: float, target_speed: float) -> np.ndarray:
        """``(throttle, steer, brake)`` to follow a path at a target speed (m/s)."""
        throttle, brake = self.longitudinal(speed, self.p.speed_gain * (target_speed - speed))
        return np.array([throttle, self.steer(path_xy, speed), brake], np.float32)
