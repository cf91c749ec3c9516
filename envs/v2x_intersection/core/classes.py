"""Object classes and the class groups used by metrics.

Class ids are stable integers (they appear in observations, datasets and messages).

:data:`EMERGENCY_VEHICLE` is an observed class only: the actor table keeps such a vehicle's
physical class (a large vehicle, so that it drives and collides like one), and every observation
of it - the object lists, the RSU's messages, the BEV and the camera / LiDAR semantics - reports
class 8 while its siren and lights are on (``World.object_classes``).
"""

from __future__ import annotations

import numpy as np

CAR = 0
LARGE_VEHICLE = 1  # truck / van / bus: tall enough to hide what is behind it
PEDESTRIAN = 2
BICYCLE = 3
TRAFFIC_LIGHT = 4
TRAFFIC_SIGN = 5
TRAFFIC_CONE = 6
STATIC_OBSTACLE = 7  # buildings, walls, barriers, debris
EMERGENCY_VEHICLE = 8  # an ambulance / fire engine with its siren and lights on (observed class)

CLASS_NAMES: tuple[str, ...] = (
    "car",
    "large_vehicle",
    "pedestrian",
    "bicycle",
    "traffic_light",
    "traffic_sign",
    "traffic_cone",
    "static_obstacle",
    "emergency_vehicle",
)
NUM_CLASSES = len(CLASS_NAMES)

#: Metric groups (as the paper's perception table): vehicle, VRU, traffic light, traffic sign.
GROUPS: dict[str, tuple[int, ...]] = {
    "vehicle": (CAR, LARGE_VEHICLE, EMERGENCY_VEHICLE),
    "vru": (PEDESTRIAN, BICYCLE),
    "traffic_light": (TRAFFIC_LIGHT,),
    "traffic_sign": (TRAFFIC_SIGN,),
}

VEHICLE_CLASSES = np.array([CAR, LARGE_VEHICLE, EMERGENCY_VEHICLE])
VRU_CLASSES = np.array([PEDESTRIAN, BICYCLE])


def class_id(name: str) -> int:
    """Return the integer id of a class name, raising ``ValueError`` for unknown names."""
    try:
        return CLASS_NAMES.index(name)
    except ValueError:
        raise ValueError(f"unknown object class {name!r}; known: {', '.join(CLASS_NAMES)}") from None
