"""The top-down renderer's colours (RGB) and the small drawing helpers its modules share."""

from __future__ import annotations

import numpy as np

from ..core.classes import BICYCLE, CAR, LARGE_VEHICLE, PEDESTRIAN
from ..traffic.signals import GREEN, NO_SIGNAL, RED, YELLOW

BACKGROUND = (221, 226, 214)
SIDEWALK = (226, 212, 182)
ROAD = (92, 95, 102)
PARKING_FILL = (122, 124, 130)
CENTRE_LINE = (112, 115, 123)
MARK_WHITE = (236, 236, 236)
MARK_YELLOW = (242, 196, 44)
CROSSWALK = (238, 238, 238)
BUILDING_LOW = (204, 202, 197)
BUILDING_HIGH = (134, 132, 140)
BUILDING_EDGE = (98, 98, 104)
STOP_SIGN = (204, 24, 34)
EGO_COLOR = (255, 136, 0)
CLASS_COLORS: dict[int, tuple[int, int, int]] = {
    CAR: (52, 104, 196),
    LARGE_VEHICLE: (118, 64, 170),
    PEDESTRIAN: (232, 58, 140),
    BICYCLE: (0, 150, 136),
}
OTHER_COLOR = (90, 90, 90)
ACTOR_EDGE = (24, 24, 28)
EGO_SEEN_COLOR = (0, 229, 255)
RSU_SEEN_COLOR = (255, 0, 255)
RSU_COLOR = (248, 248, 248)
RSU_ACTIVE_COLOR = (255, 0, 255)
RSU_FOV_RGB, RSU_FOV_ALPHA = (236, 64, 255), 0.12
RSU_FOV_EDGE = (206, 92, 226)
ROUTE_COLOR = (30, 112, 255)
PARKED_TINT = (150, 152, 158)
LIGHT_HOUSING = (28, 28, 32)
LIGHT_COLORS: dict[int, tuple[int, int, int]] = {
    GREEN: (36, 204, 72),
    YELLOW: (255, 204, 0),
    RED: (232, 28, 28),
    NO_SIGNAL: (150, 150, 150),
}


def box_quads(center: np.ndarray, yaw: np.ndarray, x0, x1, y0, y1) -> np.ndarray:
    """World corners ``(N, 4, 2)`` of local rectangles ``[x0, x1] x [y0, y1]`` (arrays ``(N,)``)."""
    lx = np.stack([x1, x0, x0, x1], -1)
    ly = np.stack([y1, y1, y0, y0], -1)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    return np.stack([center[:, :1] + c * lx - s * ly, center[:, 1:] + s * lx + c * ly], -1)


def mix_rgb(a: tuple, b: tuple, t: float) -> tuple[int, int, int]:
    """Linear blend of two RGB colours (``t = 0``: ``a``)."""
    return tuple(int(round(x + (y - x) * t)) for x, y in zip(a, b))  # type: ignore[return-value]


