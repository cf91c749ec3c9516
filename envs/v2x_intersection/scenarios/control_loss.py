"""ControlLoss: the ego loses control for short moments at a few points along a straight.

**The CARLA type** (Leaderboard 2.0's ``ControlLoss``, "Control Loss Vehicle", traffic scenario
01): three dirt-debris props lie on the route 10-80 m after the scenario's trigger point (14, 48
and 74 m unless randomized), with their physics off: the ego drives over them. While the ego's
centre is within 2 m of a piece, every tick noise is added to the control the agent sent: throttle
``N(+-0.03, 0.01)`` and steer ``N(+-0.055, 0.015)`` (CARLA steer units, +-1 = the default 70 deg
wheel angle), the sign of each mean drawn once per piece. Brake is left alone.

**Here**: the same mechanism, applied where the world applies the ego's action, so it perturbs
whatever agent drives (the agent's output is its command, ``World.last_control``; the dynamics
get ``World.applied_control``). Every tick after its trigger the scenario checks the ego's
position (after the previous move) against its points and, inside a window, sets
``World.control_noise`` for the ego's next move (``World._take_control`` adds it and clips to the
action ranges; that is the one place every stepping path goes through: the NumPy and numba single
world and the batched world, ``batch.WorldBatch``). Drawn per instance from the world's generator
(``world.rng``) at spawn:

- ``points = 3`` points on one straight driving lane, in ``[conflict, conflict + span]`` of the
  route (``span = 40`` m, a class constant: sites are found before parameters are known; the
  trigger lies ``trigger_distance = 10`` m before, so the points lie 12-48 m after it where
  CARLA's lie 10-80 m): point ``k`` uniform in the ``k``-th third of the span, ``window`` m inside
  its edges, so windows never overlap;
- per point, the signs of the throttle and steer means (each +1 or -1 with probability 1/2);
- a child generator (seeded from ``world.rng``) for the per-tick noise, so the number of ticks the
  ego spends in windows does not shift the world's other draws.

Per tick inside a window (the ego's centre within ``window = 2`` m of a point, CARLA's trigger
distance): throttle noise ``sign * N(throttle_mean = 0.03, throttle_std = 0.01)`` and steer noise
``sign * N(steer_mean = 0.11, steer_std = 0.03)``, each clipped to ``mean +- 3 std``: ``|throttle
noise|`` in ``[0, 0.06]``, ``|steer noise|`` in ``[0.02, 0.20]``. Our steer's +-1 is a 35 deg wheel
angle (``VehicleParams.max_steer``), so CARLA's 0.055 / 0.015 of 70 deg are 0.11 / 0.03 here (about
3.9 deg of wheel angle); throttle keeps CARLA's numbers. Outside the windows the applied control is
the command. CARLA clips the perturbed steer to ``[0, 1]`` (dropping any left steer inside a
window); we clip to the action range ``[-1, 1]``.

**Not kept**: the debris. CARLA's pieces are dirt props on the road surface that the ego drives
over (the noise starts within 2 m of them); in this world every actor collides and occludes (there
is no drive-over prop), so a piece would be an obstacle to steer around or a collision, which is
what the old version of this scenario was (three boxes in the lane that a planner avoided, so the
expert never lost control). The points are therefore unmarked: no observation shows where control
will be lost. The scenario has no actors.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..town.model import Town
from .base import Scenario, Site, completing_s
from .obstacles import lane_sites
from .registry import register_scenario

#: a site's lane turns by at most this much (rad) over the span: the points lie along a straight
STRAIGHT_MAX_TURN = 0.15
NOISE_CLIP_STD = 3.0  # per-tick noise is clipped to mean +- this many standard deviations


def _straight_sites(town: Town, span: float) -> list[Site]:
    """:func:`~.obstacles.lane_sites` whose lane keeps its heading (within
    :data:`STRAIGHT_MAX_TURN`) from the conflict point to ``span`` m after it."""
    out = []
    for site in lane_sites(town, span):
        lane = site.lanes[site.key]
        s = site.s_on_key + np.array([0.0, 0.5 * span, span])
        _, h = town.index.pose_at(np.full(3, lane), s)
        turn = np.abs((h - h[0] + np.pi) % (2 * np.pi) - np.pi)
        if turn.max() <= STRAIGHT_MAX_TURN:
            out.append(site)
    return out


@register_scenario
class ControlLoss(Scenario):
    """The ego loses control at three points along a straight: inside a short window around each,
    noise is added to the throttle and steering the agent sends (see the module docstring for
    CARLA's version, the ranges and what differs).

    Parameters: ``window`` (m, radius of a window around a point), ``throttle_mean``,
    ``throttle_std``, ``steer_mean``, ``steer_std`` (per-tick noise, action units; the means'
    signs are drawn per point).

    Attributes (after spawn): ``points`` ``(3, 2)`` window centres; ``offsets`` (m after the
    conflict point, route arc length); ``throttle_sign``, ``steer_sign`` ``(3,)``; ``noisy_ticks``
    ticks whose next move was perturbed.
    """

    name = "ControlLoss"
    family = "obstacle"
    max_actors = 0
    n_points: ClassVar[int] = 3
    span: ClassVar[float] = 40.0
    trigger_distance = 10.0
    towns = ("Town02", "Town06", "Town01", "Town05", "Town03")
    defaults = {
        "window": 2.0,
        "throttle_mean": 0.03,
        "throttle_std": 0.01,
        "steer_mean": 0.11,
        "steer_std": 0.03,
    }

    @classmethod
    def find_sites(cls, town):
        return _straight_sites(town, cls.span)

    def __init__(self, route, site, conflict_s, params=None) -> None:
        super().__init__(route, site, conflict_s, params)
        span, window = self.span, float(self.params["window"])
        if not (span > 0.0 and 0.0 < window < span / (2 * self.n_points)):
            raise ValueError(
                f"ControlLoss: need span > 0 and 0 < window < span / {2 * self.n_points} "
                f"(windows inside their thirds of the span), got span={span}, window={window}"
            )
        route_end = completing_s(route)
        self.span_m = max(
            min(span, route_end - self.conflict_s - window), 2 * window * self.n_points
        )
        self.end_s = min(self.conflict_s + self.span_m + window + 3.0, route_end)
        self.points = np.zeros((0, 2))
        self.offsets = self.throttle_sign = self.steer_sign = np.zeros(0)
        self.noisy_ticks = 0
        self._centres: list[tuple[float, float]] = []  # the points as Python floats (spawn)
        self._window2 = window * window

    def spawn(self, world) -> None:
        rng = world.rng
        n, window = self.n_points, float(self.params["window"])
        third = self.span_m / n
        lo = np.arange(n) * third + window
        self.offsets = lo + rng.uniform(0.0, 1.0, n) * (third - 2 * window)
        self.throttle_sign = np.where(rng.random(n) < 0.5, -1.0, 1.0)
        self.steer_sign = np.where(rng.random(n) < 0.5, -1.0, 1.0)
        self._noise = np.random.default_rng(int(rng.integers(2**63)))
        r, s = self.route, self.conflict_s + self.offsets
        self.points = np.stack(
            [np.interp(s, r.s, r.points[:, 0]), np.interp(s, r.s, r.points[:, 1])], -1
        )
        self._centres = [tuple(p) for p in self.points.tolist()]
        p = self.params
        self._throttle = (float(p["throttle_mean"]), float(p["throttle_std"]))
        self._steer = (float(p["steer_mean"]), float(p["steer_std"]))

    def window_at(self, xy) -> int:
        """The index of the window that holds position ``xy`` (m), or -1."""
        x, y = (float(v) for v in xy)
        for k, (px, py) in enumerate(self._centres):
            if (x - px) ** 2 + (y - py) ** 2 < self._window2:
                return k
        return -1

    def _draw(self, mean: float, std: float) -> float:
        lim = NOISE_CLIP_STD * std
        return mean + min(max(float(self._noise.normal(0.0, std)), -lim), lim)

    def update(self, world) -> None:
        k = self.window_at(world.table.pos[0].tolist())
        if k < 0:
            return
        throttle = float(self.throttle_sign[k]) * self._draw(*self._throttle)
        steer = float(self.steer_sign[k]) * self._draw(*self._steer)
        world.control_noise = (throttle, steer, 0.0)
        self.noisy_ticks += 1


__all__ = ["ControlLoss", "STRAIGHT_MAX_TURN"]
