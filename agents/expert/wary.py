"""``wary_ego``: the careful ego-only driver taken to its end, for the benchmark's fairness table.

:class:`WaryEgo` is :class:`~.cautious.CautiousEgo` (the ego-only oracle, capped at
``cap`` m/s while it passes a standing vehicle it sees near its path) keyed on *every* standing
vehicle it sees, parked cars included, not only on trucks and vans: the driver who also expects
a child between parked cars. It shows what caution alone can buy without V2X and what it costs
in time (Efficiency), beside ``cautious_ego`` (trucks only) and the V2X oracle.
"""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.core.classes import CAR, LARGE_VEHICLE

from .cautious import STANDING_MPS, CautiousEgo
from .objects import Objects


def standing_vehicles(objs: Objects, lat: np.ndarray, max_lat: float) -> np.ndarray:
    """Indices of standing cars and large vehicles within ``max_lat`` m of the path."""
    vehicle = (objs.kind == CAR) | (objs.kind == LARGE_VEHICLE)
    return (vehicle & (objs.speed < STANDING_MPS) & (np.abs(lat) < max_lat)).nonzero()[0]


class WaryEgo(CautiousEgo):
    """The ego-only oracle, slow past every standing vehicle it sees (module docstring)."""

    def _standing(self, objs, st, lat) -> np.ndarray:
        return standing_vehicles(objs, lat, self.max_lat)
