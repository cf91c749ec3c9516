"""Bring your own roadside policy: an ego agent plus the message its roadside unit sends it.

::

    v2xbench eval --agent examples/my_roadside_policy.py:PedestrianAlertDriver --suite test50 \\
        --max-routes 2 --out results/ped_alert

The agent's ``rsu_policy`` is an object (here :class:`NearestPedestrianRoadside`), not the name of
a built-in policy (``"share_objects"``, ``"none"``). ``eval`` runs it in the roadside unit's
place: every tick a unit serves the ego, its ``act`` gets that unit's observation (what the
PettingZoo ``rsu`` agent observes, ``observations.rsu_space``: ``unit`` (id, x, y, z, yaw,
pitch), ``calibration`` ``(2, 4, 4)`` = (``T_world_rsu``, ``T_ego_rsu``) and ``objects``
``(32, 11)``, what the unit sees, in its ground frame: origin at the pole's foot, x along its yaw)
and returns the message to send: a 1-D array of at most ``max_payload_floats`` (320) floats, each
finite and within +-1e4, or ``None`` to say nothing. The V2X channel serializes it (16-byte header
+ 2 bytes a float in float16: this 3-float message is 22 bytes on air), counts its bytes in the
run's BPS, and delivers it ``latency_ticks`` (1) later. Results and the summary name the policy
``custom:NearestPedestrianRoadside``.

The message here: the position ``(x, y)`` in the unit's ground frame and the speed of the
pedestrian nearest the ego among those the unit sees (one the ego may not see, hidden behind a
parked van, say): 3 floats. The ego finds it in its observation as a raw payload:

- ``v2x_payload (320,)``: the received floats, zero-padded (as float32 after float16 on the wire);
- ``v2x_info (8,)``: received, age_ticks, num_objects (0: a raw payload is not an object list),
  rsu_x, rsu_y, rsu_yaw (the sender's pose in the ego frame), payload_length (3),
  payload_format (1 = raw; 0 would be an object list, also decoded into ``v2x_objects``).

:class:`PedestrianAlertDriver` drives with the built-in ``RouteFollower`` on its own sensors and
brakes when the received pedestrian stands in its corridor ahead. It uses numpy only.
"""

from __future__ import annotations

import numpy as np
from v2xbench.agents.route_follower import RouteFollower

PEDESTRIAN = 2  # ``classes.PEDESTRIAN``
#: ``v2x_info`` columns (``observations.V2X_INFO_FEATURES``)
RECEIVED, AGE, RSU_X, RSU_Y, RSU_YAW, LENGTH, FORMAT = 0, 1, 3, 4, 5, 6, 7
FORMAT_RAW = 1  # ``wire.FORMAT_RAW``
MAX_AGE = 3  # ticks: older alerts are ignored
CORRIDOR = 2.5  # m either side of the route
LOOKAHEAD = 30.0  # m ahead of the ego
STOP_MARGIN = 6.0  # m kept to the pedestrian (from the ego's centre)


class NearestPedestrianRoadside:
    """Roadside policy: the pedestrian nearest the ego, as ``[x, y, speed]`` in the unit's frame."""

    def reset(self, route_info: dict) -> None:
        """Nothing to forget between routes (optional method)."""

    def act(self, rsu_obs: dict) -> np.ndarray | None:
        """The 3-float message of this tick, or ``None`` when the unit sees no pedestrian."""
        objs = rsu_obs["objects"]
        peds = objs[(objs[:, 0] > 0.5) & (objs[:, 1] == PEDESTRIAN)]
        if len(peds) == 0:
            return None
        # the ego's position: world frame from the calibration, then the unit's ground frame
        t_world_rsu, t_ego_rsu = rsu_obs["calibration"].astype(np.float64)
        ego_world = (t_world_rsu @ np.linalg.inv(t_ego_rsu))[:2, 3]
        _, ux, uy, _, uyaw, _ = rsu_obs["unit"].astype(np.float64)
        d = ego_world - (ux, uy)
        ego = np.array([np.cos(uyaw) * d[0] + np.sin(uyaw) * d[1],
                        -np.sin(uyaw) * d[0] + np.cos(uyaw) * d[1]])
        k = int(np.argmin(np.hypot(*(peds[:, 2:4] - ego).T)))
        x, y, vx, vy = peds[k, [2, 3, 8, 9]]
        return np.array([x, y, np.hypot(vx, vy)], np.float32)


def received_pedestrian(obs: dict) -> np.ndarray | None:
    """The alerted pedestrian's ``(x, y)`` in the ego frame, from the raw payload (``None``: no
    fresh alert)."""
    info = obs["v2x_info"]
    if info[RECEIVED] < 0.5 or info[AGE] > MAX_AGE or info[FORMAT] != FORMAT_RAW:
        return None
    if int(info[LENGTH]) != 3:
        return None
    x, y, _speed = obs["v2x_payload"][:3].astype(np.float64)
    c, s = np.cos(info[RSU_YAW]), np.sin(info[RSU_YAW])  # the unit's frame -> the ego's
    return np.array([info[RSU_X] + c * x - s * y, info[RSU_Y] + s * x + c * y])


class PedestrianAlertDriver:
    """Ego agent that brings :class:`NearestPedestrianRoadside` (module docstring)."""

    obs_mode = "objects"
    privileged = False

    def __init__(self) -> None:
        self.rsu_policy = NearestPedestrianRoadside()  # an object: the harness runs it
        self.driver = RouteFollower(use_v2x=False)  # v2x_objects stay empty: no object list
        self.alerts = 0  # ticks on which a received pedestrian made it brake

    def reset(self, route_info: dict) -> None:
        """Start of a route."""
        self.driver.reset(route_info)

    def act(self, obs: dict) -> np.ndarray:
        """``(throttle, steer, brake)``: the route follower's, braking for an alerted pedestrian."""
        control = self.driver.act(obs)
        ped = received_pedestrian(obs)
        if ped is None or ped[0] <= 0.0 or ped[0] > LOOKAHEAD:
            return control
        path = obs["route"][:, :2].astype(np.float64)
        if np.min(np.hypot(*(path - ped).T)) > CORRIDOR:
            return control
        gap = float(ped[0]) - STOP_MARGIN
        v = float(obs["ego"][0])
        need = v * v / (2.0 * max(gap, 0.5))  # deceleration that stops before it, m/s^2
        if need > 0.5 or gap < 0.0:
            self.alerts += 1
            control = control.copy()
            control[0], control[2] = 0.0, float(np.clip(need / 6.0, 0.2, 1.0))
        return control
