"""Semantic ids, instance-id encoding and ground materials shared by every sensor.

Semantic ids (``uint8`` in images, float in LiDAR point rows) are the object class ids of
:mod:`..classes` (0-8) followed by the ground and sky categories:

====  ===============  ===========================================================
id    name             what
====  ===============  ===========================================================
0-8   object classes   car, large_vehicle, pedestrian, bicycle, traffic_light,
                       traffic_sign, traffic_cone, static_obstacle (incl. buildings),
                       emergency_vehicle (siren on; ``World.object_classes``)
9     road             drivable asphalt (lanes and junction areas)
10    lane_marking     painted lines: lane boundaries, stop lines, parking-slot lines
11    crosswalk        the whole zebra-crossing area (stripes and the asphalt between)
12    sidewalk         sidewalks, paved junction corners and curbs
13    parking          parking lanes
14    terrain          grass and everything else on the ground (also distant ground)
15    sky              nothing hit within the sensor's range, looking up
====  ===============  ===========================================================

(Before issue 29 there were 8 object classes and the ground / sky ids were one lower.)

Instance ids (``int32``): :data:`INSTANCE_NONE` (0) for ground and sky; actor row ``r`` of
``world.table`` is ``r + 1`` (the ego, row 0, is 1); static box ``j`` of ``world.static_boxes`` is
``STATIC_INSTANCE_OFFSET + j`` (1,000,000 + j). Every id is below 2**24, so it survives a
round trip through float32 (the LiDAR point rows) exactly.

Ground materials are the codes of the per-town ground raster (:mod:`.ground`); bit 7
(:data:`CENTRE_BIT`) flags a lane centre line, which has no look of its own (BEV only). Lookup
tables indexed by the full 8-bit code map a material to its semantic id, colour, LiDAR
reflectivity and BEV channels.
"""

from __future__ import annotations

import numpy as np

from ..core.classes import (
    BICYCLE,
    CAR,
    CLASS_NAMES,
    EMERGENCY_VEHICLE,
    LARGE_VEHICLE,
    NUM_CLASSES,
    PEDESTRIAN,
    STATIC_OBSTACLE,
    TRAFFIC_CONE,
    TRAFFIC_LIGHT,
    TRAFFIC_SIGN,
)

# ----------------------------------------------------------------------------- semantic ids
ROAD = NUM_CLASSES  # 9
LANE_MARKING = NUM_CLASSES + 1
CROSSWALK = NUM_CLASSES + 2
SIDEWALK = NUM_CLASSES + 3
PARKING = NUM_CLASSES + 4
TERRAIN = NUM_CLASSES + 5
SKY = NUM_CLASSES + 6
SEMANTIC_NAMES: tuple[str, ...] = CLASS_NAMES + (
    "road",
    "lane_marking",
    "crosswalk",
    "sidewalk",
    "parking",
    "terrain",
    "sky",
)
NUM_SEMANTIC = len(SEMANTIC_NAMES)

#: Display colours of the semantic ids (Cityscapes-like), ``(NUM_SEMANTIC, 3)`` uint8.
SEMANTIC_COLORS = np.array(
    [
        (0, 0, 142),  # car
        (0, 60, 100),  # large vehicle
        (220, 20, 60),  # pedestrian
        (119, 11, 32),  # bicycle
        (250, 170, 30),  # traffic light
        (220, 220, 0),  # traffic sign
        (255, 120, 0),  # traffic cone
        (70, 70, 70),  # static obstacle / building
        (255, 0, 255),  # emergency vehicle
        (128, 64, 128),  # road
        (157, 234, 50),  # lane marking
        (200, 200, 255),  # crosswalk
        (244, 35, 232),  # sidewalk
        (250, 170, 160),  # parking
        (107, 142, 35),  # terrain
        (70, 130, 180),  # sky
    ],
    np.uint8,
)

# ----------------------------------------------------------------------------- instance ids
INSTANCE_NONE = 0
STATIC_INSTANCE_OFFSET = 1_000_000


def actor_instance(rows: np.ndarray | int) -> np.ndarray:
    """Instance ids of actor rows (``row + 1``)."""
    return np.asarray(rows, dtype=np.int64) + 1


def static_instance(idx: np.ndarray | int) -> np.ndarray:
    """Instance ids of static boxes (``STATIC_INSTANCE_OFFSET + index``)."""
    return np.asarray(idx, dtype=np.int64) + STATIC_INSTANCE_OFFSET


def decode_instance(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split instance ids into ``(is_static, index)``.

    Returns:
        ``is_static`` bool and ``index`` int64 (actor row or static box index; -1 for
        :data:`INSTANCE_NONE`), both shaped like ``ids``.
    """
    ids = np.asarray(ids, dtype=np.int64)
    static = ids >= STATIC_INSTANCE_OFFSET
    index = np.where(static, ids - STATIC_INSTANCE_OFFSET, ids - 1)
    return static, np.where(ids == INSTANCE_NONE, -1, index)


# ----------------------------------------------------------------------------- ground materials
M_TERRAIN, M_ROAD, M_PARKING, M_SIDEWALK, M_CURB = 0, 1, 2, 3, 4
M_MARK_WHITE, M_MARK_YELLOW, M_STOP_LINE, M_PARK_LINE = 5, 6, 7, 8
M_CROSS_STRIPE, M_CROSS_GAP = 9, 10
NUM_MATERIALS = 11
CENTRE_BIT = 128

_MAT_SEM = [TERRAIN, ROAD, PARKING, SIDEWALK, SIDEWALK] + [LANE_MARKING] * 4 + [CROSSWALK] * 2
_MAT_RGB = [
    (96, 128, 70),  # terrain: grass
    (84, 86, 92),  # road asphalt
    (104, 106, 112),  # parking
    (188, 180, 164),  # sidewalk
    (150, 146, 138),  # curb
    (232, 232, 228),  # white marking
    (236, 190, 40),  # yellow marking
    (238, 238, 234),  # stop line
    (214, 214, 210),  # parking-slot line
    (236, 236, 232),  # crosswalk stripe
    (84, 86, 92),  # asphalt between stripes
]
#: Texture noise amplitude per material (relative brightness jitter).
_MAT_NOISE = [0.16, 0.07, 0.07, 0.06, 0.05, 0.03, 0.03, 0.03, 0.03, 0.03, 0.07]
#: LiDAR reflectivity per material (paint is retro-reflective).
_MAT_REFL = [0.22, 0.18, 0.2, 0.32, 0.3, 0.8, 0.75, 0.8, 0.7, 0.8, 0.18]


def _lut(values: list, dtype, shape=()) -> np.ndarray:
    base = np.asarray(values, dtype=dtype).reshape((len(values),) + shape)
    out = np.zeros((256,) + shape, dtype=dtype)
    out[:] = base[0]
    out[:NUM_MATERIALS] = base
    out[CENTRE_BIT : CENTRE_BIT + NUM_MATERIALS] = base  # centre-line flag: same look
    return out


#: ``(256,)`` uint8 semantic id of a ground code.
MATERIAL_SEMANTIC = _lut(_MAT_SEM, np.uint8)
#: ``(256, 3)`` float32 RGB (0-255) of a ground code.
MATERIAL_RGB = _lut(_MAT_RGB, np.float32, (3,))
#: ``(256,)`` float32 texture-noise amplitude of a ground code.
MATERIAL_NOISE = _lut(_MAT_NOISE, np.float32)
#: ``(256,)`` float32 LiDAR reflectivity of a ground code.
MATERIAL_REFLECTIVITY = _lut(_MAT_REFL, np.float32)

#: LiDAR reflectivity of the object classes (signs and cones are retro-reflective).
CLASS_REFLECTIVITY = np.zeros(NUM_SEMANTIC, np.float32)
CLASS_REFLECTIVITY[[CAR, LARGE_VEHICLE, PEDESTRIAN, BICYCLE, EMERGENCY_VEHICLE]] = (0.55, 0.5, 0.3, 0.4, 0.6)
CLASS_REFLECTIVITY[[TRAFFIC_LIGHT, TRAFFIC_SIGN, TRAFFIC_CONE, STATIC_OBSTACLE]] = (
    0.45,
    0.9,
    0.85,
    0.4,
)

__all__ = [
    "CENTRE_BIT",
    "CLASS_REFLECTIVITY",
    "CROSSWALK",
    "INSTANCE_NONE",
    "LANE_MARKING",
    "MATERIAL_REFLECTIVITY",
    "MATERIAL_RGB",
    "MATERIAL_SEMANTIC",
    "NUM_SEMANTIC",
    "PARKING",
    "ROAD",
    "SEMANTIC_COLORS",
    "SEMANTIC_NAMES",
    "SIDEWALK",
    "SKY",
    "STATIC_INSTANCE_OFFSET",
    "TERRAIN",
    "actor_instance",
    "decode_instance",
    "static_instance",
]
