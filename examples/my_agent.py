"""A third-party agent for V2XBench: a cautious driver that uses only its observation.

Any class with the attributes and methods below can be evaluated, without registering it or
changing V2XBench::

    v2xbench eval --agent examples/my_agent.py:CautiousDriver --suite test50 --out results/cautious

(add ``--isolate-agent`` to run it in a process of its own, apart from the simulator, and
``--agent-config cfg.json`` with ``{"use_v2x": false}`` to build it with ``use_v2x=False``: the
file's JSON object is passed to the constructor as keyword arguments).

The protocol (``v2xbench.agents.interface``):

- ``obs_mode``: the observation it needs (``"objects"``: object lists, see below).
- ``privileged``: ``False`` (it does not read the simulator; only the built-in expert and oracles
  may, and the harness refuses any other agent that declares ``True``).
- ``rsu_policy``: what the roadside unit sends it: ``"share_objects"`` (the objects the RSU sees)
  or ``"none"`` (no V2X), or an object, its own roadside policy
  (``examples/my_roadside_policy.py``).
- ``reset(route_info)``: called at the start of every route with ``route_points`` ((P, 2) world
  frame, 1 m apart) and ``commands`` ((P,) navigation codes), as CARLA gives an agent its route,
  plus ``town`` and ``seed``; nothing about the scenarios. Clear all per-route state here.
- ``act(obs) -> control``: ``(3,)`` array (throttle in [0, 1], steer in [-1, 1], brake in [0, 1])
  or, as here, ``{"waypoints": (K, 2) ego frame, "speed": m/s}``, which V2XBench's shared
  waypoint controller turns into a control. ``obs`` is exactly the Gymnasium env's observation
  (``gym.make("v2xbench:V2XIntersection-v0")``), so a model trained there runs unchanged. Write
  ``act(self, obs, info)`` to also get the step's info (the Gymnasium env's ``info``: ``tick``,
  ``route_completion``, ``v2x_bps``, event counts, ...); this driver does not need it.
- optional ``checkpoint`` (path(s) of the weights it loads) and ``fingerprint()`` (a string):
  ``eval`` keys its results by a fingerprint of the agent (this file's contents, its checkpoint,
  its config, the ``--set`` overrides) and refuses to resume into results of another one
  (``--overwrite`` starts afresh). This driver has no weights.

The observation (``obs_mode="objects"``, all float32, ego frame: x forward, y left, metres):

- ``ego (9,)``: speed, accel, yaw_rate, throttle, steer, brake, light_state (-1 none, 0 green,
  1 yellow, 2 red, 3 stop sign), dist_to_stop_line (m, -1 if none), route_completion (%).
- ``route (20, 3)``: the next route points (x, y, command), 2 m apart.
- ``objects (32, 11)``: what the ego's sensors see; columns present, class_id, x, y, yaw, length,
  width, height, vx, vy, visibility; unused rows are zero.
- ``v2x_objects (32, 11)``: what the RSU sent, moved into the ego frame (same columns).
- ``v2x_info (8,)``: received, age_ticks, num_objects, rsu_x, rsu_y, rsu_yaw, payload_length,
  payload_format; ``v2x_payload (320,)``: the received message's floats as sent (a custom
  roadside policy's message is only there: ``examples/my_roadside_policy.py``).

The driver follows the route at a modest speed, slows for curves, brakes for anything (seen by
itself or received over V2X) whose current or predicted position is within its corridor along the
route, stops for red and yellow lights and comes to a full stop at stop signs. It uses numpy only.
"""

from __future__ import annotations

import numpy as np

CRUISE = 7.0  # m/s
MAX_LAT_ACCEL = 1.5  # m/s^2 in curves
COMFORT_DECEL = 2.5  # m/s^2 when planning stops
HALF_WIDTH = 1.6  # m, corridor half-width beyond the object's own half-width
MARGIN = 5.0  # m kept to obstacles and stop lines (measured from the ego centre)
HORIZON = 2.0  # s of constant-velocity prediction of other road users
STOP_WAIT = 10  # ticks standing at a stop sign before going on
RED, YELLOW, STOP_SIGN = 2, 1, 3  # ``light_state`` codes


class CautiousDriver:
    """Observation-only cautious driver (see module docstring).

    Args:
        use_v2x: also react to objects received from the roadside unit.
    """

    obs_mode = "objects"
    privileged = False
    rsu_policy = "share_objects"

    def __init__(self, use_v2x: bool = True) -> None:
        self.use_v2x = use_v2x
        self.stop_ticks = 0
        self.stop_done = False

    def reset(self, route_info: dict) -> None:
        """Start of a route: forget the stop-sign state."""
        self.stop_ticks, self.stop_done = 0, False

    def act(self, obs: dict) -> dict:
        """Waypoints along the route and the speed to drive them at."""
        ego, path = obs["ego"], obs["route"][:, :2].astype(np.float64)
        v = float(ego[0])
        speed = min(CRUISE, self._curve_speed(path), self._object_speed(obs, path))
        speed = min(speed, self._line_speed(float(ego[6]), float(ego[7]), v))
        return {"waypoints": path, "speed": speed}

    @staticmethod
    def _stop_speed(gap: float) -> float:
        """Highest speed from which a comfortable stop within ``gap`` metres is possible."""
        return float(np.sqrt(2.0 * COMFORT_DECEL * max(gap, 0.0)))

    def _curve_speed(self, path: np.ndarray) -> float:
        d = np.diff(path[:12], axis=0)
        seg = np.linalg.norm(d, axis=1)
        if len(d) < 2 or seg.sum() < 1e-3:
            return CRUISE
        heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        kappa = np.abs(np.diff(heading)) / np.maximum(seg[1:], 1e-3)
        return float(np.sqrt(MAX_LAT_ACCEL / max(float(kappa.max()), 1e-4)))

    def _object_speed(self, obs: dict, path: np.ndarray) -> float:
        rows = [obs["objects"]] + ([obs["v2x_objects"]] if self.use_v2x else [])
        objs = np.concatenate(rows, 0)
        objs = objs[objs[:, 0] > 0.5]
        if len(objs) == 0:
            return CRUISE
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        best = np.inf
        for t in (0.0, 0.5 * HORIZON, HORIZON):  # now and along the predicted motion
            xy = objs[:, 2:4] + t * objs[:, 8:10]
            dist = np.linalg.norm(xy[:, None, :] - path[None, :, :], axis=2)  # (N, P)
            k = dist.argmin(1)
            inside = dist[np.arange(len(objs)), k] < HALF_WIDTH + objs[:, 6] / 2.0
            inside &= (k > 0) | (xy[:, 0] > 0)  # ahead of the ego
            if inside.any():
                best = min(best, float((arc[k[inside]] - objs[inside, 5] / 2.0).min()))
        return CRUISE if not np.isfinite(best) else self._stop_speed(best - MARGIN)

    def _line_speed(self, light: float, dist_line: float, v: float) -> float:
        if dist_line < 0:
            self.stop_ticks, self.stop_done = 0, False
            return CRUISE
        if light == RED or (light == YELLOW and dist_line - MARGIN > v * v / (2 * COMFORT_DECEL)):
            return self._stop_speed(dist_line - MARGIN + 2.0)
        if light == STOP_SIGN and not self.stop_done:
            if v < 0.2 and dist_line < MARGIN + 2.0:  # standing at the line: wait, then go
                self.stop_ticks += 1
                self.stop_done = self.stop_ticks >= STOP_WAIT
            return CRUISE if self.stop_done else self._stop_speed(dist_line - MARGIN)
        return CRUISE
