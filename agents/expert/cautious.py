"""Ego-only references for the benchmark's fairness: what a careful driver without V2X achieves.

- :class:`CautiousEgo` (``cautious_ego``): the ego-only oracle that slows to
  :attr:`CautiousEgo.cap` m/s while it passes a standing large vehicle it sees near its path
  (from :attr:`CautiousEgo.before_m` m before the vehicle's rear to its front): a hidden hazard
  stepping out from behind it meets a car that can stop. A child hidden by a parked car gives it
  no warning (:class:`~.wary.WaryEgo`, ``wary_ego``, slows past every standing vehicle).
- :class:`StopAndWaitEgo` (``stop_and_wait_ego``): the ego-only oracle that stands
  :attr:`StopAndWaitEgo.wait_s` s before every standing large vehicle it sees ahead, then drives
  on as the plain oracle. Hazards are triggered by the ego's time to arrival at its current
  speed (never by its waiting), so this gains nothing; ``tests/scenarios/test_fairness.py`` keeps it that
  way.

Both are privileged like the oracles (they read the ego state, route and visibility from the
world; the objects they react to are the ego's own view).
"""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.core.classes import LARGE_VEHICLE

from .agents import EgoOnlyOracle
from .objects import Objects

STANDING_MPS = 0.5  # m/s: a vehicle slower than this counts as standing


def standing_large(objs: Objects, st: np.ndarray, lat: np.ndarray, max_lat: float) -> np.ndarray:
    """Indices of standing large vehicles within ``max_lat`` m of the path (any station)."""
    return ((objs.kind == LARGE_VEHICLE) & (objs.speed < STANDING_MPS)
            & (np.abs(lat) < max_lat)).nonzero()[0]


class _ZoneCapEgo(EgoOnlyOracle):
    """The ego-only oracle with speed caps along its path from :meth:`_caps` (the planner's
    ``zone_caps``), set for each episode."""

    max_lat = 8.0  # m: standing vehicles this close to the path count (parked at either kerb)

    def _on_start(self) -> None:
        super()._on_start()
        self.planner.zone_caps = self._caps

    def _caps(self, stations, objs, st, lat, e_long) -> np.ndarray:
        raise NotImplementedError


class CautiousEgo(_ZoneCapEgo):
    """The ego-only oracle, slow past the standing large vehicles it sees (module docstring)."""

    cap = 3.0  # m/s while passing
    before_m = 8.0  # m before the vehicle's rear where the cap starts

    def _standing(self, objs, st, lat) -> np.ndarray:
        """Indices of the standing vehicles it slows past (here: large ones)."""
        return standing_large(objs, st, lat, self.max_lat)

    def _caps(self, stations, objs, st, lat, e_long) -> np.ndarray:
        caps = np.full(len(stations), np.inf)
        for i in self._standing(objs, st, lat):
            zone = (stations > st[i] - e_long[i] - self.before_m) & (stations < st[i] + e_long[i])
            caps[zone] = self.cap
        return caps


class StopAndWaitEgo(_ZoneCapEgo):
    """The ego-only oracle that stands ``wait_s`` s before each standing large vehicle it sees
    ahead (once per vehicle), then drives on (module docstring)."""

    wait_s = 5.0
    stop_gap_m = 10.0  # m before the vehicle's rear where it stands

    def _on_start(self) -> None:
        super()._on_start()
        self._waited: dict[tuple[int, int], float] = {}  # vehicle key -> s stood before it

    def _key(self, objs: Objects, i: int) -> tuple[int, int]:
        """A standing vehicle's identity: its id, else its position rounded to 2 m."""
        if objs.ids[i] >= 0:
            return (int(objs.ids[i]), 0)
        return (int(objs.pos[i, 0] // 2), int(objs.pos[i, 1] // 2))

    def _caps(self, stations, objs, st, lat, e_long) -> np.ndarray:
        caps = np.full(len(stations), np.inf)
        v = float(self.world.table.speed[0])
        for i in standing_large(objs, st, lat, self.max_lat):
            gap = st[i] - e_long[i] - self.stop_gap_m  # station where the ego stands
            if gap < -1.0:
                continue  # already beside or past it
            key = self._key(objs, i)
            waited = self._waited.get(key, 0.0)
            if waited >= self.wait_s:
                continue
            if gap < 2.0 and v < 0.1:
                self._waited[key] = waited + self.world.config.dt
            caps[stations > gap] = 0.0
        return caps
