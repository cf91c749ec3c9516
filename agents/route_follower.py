"""A simple built-in driver that uses only the ego's observation (no privileged state).

It follows the observed route with :class:`~.controller.WaypointController`, slows for curves,
keeps an IDM gap to objects in its corridor (seen by the ego or received over V2X) and stops at
red and yellow lights. It is the README's default driver and a baseline, not the expert.
"""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.api.observations import LIGHT_STOP_SIGN as STOP_SIGN
from v2xbench.envs.v2x_intersection.core.dynamics import IDMParams, idm_accel
from v2xbench.envs.v2x_intersection.traffic.signals import RED, YELLOW

from .controller import WaypointController

CRUISE_SPEED = 9.0  # m/s
MAX_LAT_ACCEL = 2.0  # m/s^2 in curves
CORRIDOR_HALF_WIDTH = 1.8  # m


class RouteFollower:
    """Observation -> control driver (see module docstring).

    Args:
        use_v2x: also brake for objects received from the RSU.
    """

    def __init__(self, use_v2x: bool = True) -> None:
        self.use_v2x = use_v2x
        self.controller = WaypointController()
        self.idm = IDMParams(time_headway=1.2, min_gap=3.0)
        self._stopped = False

    def reset(self, route_info: dict | None = None) -> None:
        """Forget the stop-sign state (call at every episode start)."""
        self._stopped = False

    def act(self, obs: dict) -> np.ndarray:
        """``(throttle, steer, brake)`` for one ego observation."""
        ego, route = obs["ego"], obs["route"]
        v = float(ego[0])
        path = route[:, :2]
        target = min(CRUISE_SPEED, self._curve_speed(path))
        gap, dv = self._leader(obs, v)
        accel = float(idm_accel(np.float64(v), np.float64(target), np.float64(gap), np.float64(dv), self.idm))
        light, dist_line = ego[6], ego[7]
        if light == STOP_SIGN and dist_line > -2.0:
            self._stopped = self._stopped or (v < 0.3 and dist_line < 8.0)
            if not self._stopped:
                light = RED
        elif light != STOP_SIGN:
            self._stopped = False
        if light in (RED, YELLOW) and dist_line > -1.0:
            stop_gap = max(dist_line - 2.5, 0.0)  # front bumper ~2.4 m ahead of the centre
            if light == RED or stop_gap > v * v / 6.0:
                accel = min(accel, float(idm_accel(np.float64(v), np.float64(target), np.float64(stop_gap),
                                                   np.float64(v), self.idm)))
        throttle, brake = self.controller.longitudinal(v, accel)
        return np.array([throttle, self.controller.steer(path, v), brake], np.float32)

    def _curve_speed(self, path: np.ndarray) -> float:
        d = np.diff(path[:12], axis=0)
        h = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        seg = np.linalg.norm(d, axis=1)
        if len(h) < 2 or seg.sum() < 1e-3:
            return CRUISE_SPEED
        kappa = np.abs(np.diff(h)) / np.maximum(seg[1:], 1e-3)
        return float(np.sqrt(MAX_LAT_ACCEL / max(kappa.max(), 1e-4)))

    def _leader(self, obs: dict, v: float) -> tuple[float, float]:
        rows = [obs["objects"]]
        if self.use_v2x:
            rows.append(obs["v2x_objects"])
        objs = np.concatenate(rows, 0)
        objs = objs[objs[:, 0] > 0.5]
        if len(objs) == 0:
            return np.inf, 0.0
        x, y = objs[:, 2], objs[:, 3]
        # predict 1.5 s ahead so crossing actors about to enter the corridor count
        xp, yp = x + 1.5 * objs[:, 8], y + 1.5 * objs[:, 9]
        inside = (x > 0) & ((np.abs(y) < CORRIDOR_HALF_WIDTH + objs[:, 6] / 2) |
                            (np.abs(yp) < CORRIDOR_HALF_WIDTH + objs[:, 6] / 2) & (xp > 0))
        if not np.any(inside):
            return np.inf, 0.0
        gap = x[inside] - objs[inside, 5] / 2 - 2.4
        k = int(np.argmin(gap))
        return float(max(gap[k], 0.0)), float(v - objs[inside][k, 8])  # vx: leader speed along ego x
