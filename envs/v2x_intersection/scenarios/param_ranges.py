"""Per-instance parameter ranges: the suites draw each scenario instance's parameters from here.

CARLA Leaderboard 2.0 routes give every scenario instance its own parameters (a flow's speed, a
pedestrian's speed, a distance); V2XBench's suite builder (``suites_build.py``) draws them
uniformly from the ranges below, once per instance, and writes them into the route file, so a
route replays identically and an agent cannot learn one fixed timing per type. A parameter that
is not listed keeps the scenario's default. Integer defaults are drawn as integers (both ends
included). The ranges are kept where the privileged expert still passes (see the leaderboard).
"""

from __future__ import annotations

import numpy as np

#: ``{type: {parameter: (low, high)}}``; every name must be in the type's ``defaults``
PARAM_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "Accident": {"offset": (0.6, 0.9)},
    "AccidentTwoWays": {"offset": (0.6, 0.9), "flow_gap": (45.0, 70.0), "flow_speed": (0.7, 0.9)},
    "BlockedIntersection": {"wait_s": (8.0, 12.0)},
    "ConstructionObstacleTwoWays": {"flow_gap": (45.0, 70.0), "flow_speed": (0.7, 0.9)},
    "CrossingBicycleFlow": {"count": (3, 5), "speed": (4.0, 6.0), "spacing": (6.0, 9.0)},
    "DynamicObjectCrossing": {"speed": (1.6, 2.6)},
    "EnterActorFlow": {"speed": (8.0, 12.0)},
    "EnterActorFlowV2": {"speed": (12.0, 16.0)},
    "HardBreakRoute": {"lead_speed": (6.5, 8.5), "decel": (5.0, 8.0), "stop_time": (3.0, 5.0)},
    "HazardAtSideLane": {"count": (1, 3), "speed": (2.5, 3.5)},
    "HazardAtSideLaneTwoWays": {"count": (1, 3), "speed": (2.5, 3.5), "flow_gap": (45.0, 70.0)},
    "HighwayCutIn": {"ramp_speed": (12.0, 16.0), "speed_after": (8.0, 12.0)},
    "HighwayExit": {"speed": (13.0, 17.0)},
    "InterurbanActorFlow": {"speed": (9.0, 13.0)},
    "InterurbanAdvancedActorFlow": {"speed": (8.0, 12.0)},
    "InvadingTurn": {"invasion": (0.7, 1.2), "speed": (6.0, 10.0), "count": (2, 3)},
    "MergerIntoSlowTraffic": {"speed": (3.0, 5.0)},
    "MergerIntoSlowTrafficV2": {"speed": (3.0, 5.0)},
    "NonSignalizedJunctionLeftTurn": {"speed": (8.0, 12.0), "spacing_min": (20.0, 30.0),
                                      "spacing_max": (55.0, 80.0), "into_junction": (1.5, 4.5)},
    "NonSignalizedJunctionRightTurn": {"speed": (8.0, 12.0), "spacing_min": (20.0, 30.0),
                                       "spacing_max": (55.0, 80.0), "truck_gap": (0.0, 2.0)},
    "OppositeVehicleRunningRedLight": {"speed": (10.0, 14.0)},
    "OppositeVehicleTakingPriority": {"speed": (10.0, 14.0)},
    "ParkedObstacle": {"offset": (0.5, 0.9)},
    "ParkedObstacleTwoWays": {"offset": (0.5, 0.9), "flow_gap": (45.0, 70.0)},
    "ParkingCrossingPedestrian": {"speed": (1.3, 2.0), "cars": (1, 2)},
    "ParkingCutIn": {"reaction_time": (1.5, 2.5), "speed": (11.0, 15.0)},
    "ParkingExit": {"flow_gap": (25.0, 40.0)},
    "PedestrianCrossing": {"count": (1, 3), "speed": (1.2, 1.7)},
    "PriorityAtJunction": {"speed": (8.0, 12.0), "source_dist": (35.0, 55.0)},
    "SignalizedJunctionLeftTurn": {"speed": (8.0, 12.0)},
    "SignalizedJunctionRightTurn": {"speed": (8.0, 12.0)},
    "StaticCutIn": {"queue": (3, 4), "reaction_time": (2.0, 2.8)},
    "VehicleOpensDoorTwoWays": {"reaction_time": (2.5, 3.5), "flow_gap": (45.0, 70.0)},
    "VehicleTurningRoute": {"speed": (3.0, 5.0), "wait": (1.0, 2.0)},
    "VehicleTurningRoutePedestrian": {"speed": (1.4, 2.2), "wait": (0.5, 1.5)},
    "YieldToEmergencyVehicle": {"speed": (17.0, 23.0)},
}


def draw_params(name: str, defaults: dict, rng: np.random.Generator) -> dict:
    """One instance's parameters for scenario type ``name`` (only the ranged ones).

    Raises:
        ValueError: a range names a parameter the type does not have, or has ``low > high``.
    """
    out: dict = {}
    for key, (lo, hi) in sorted(PARAM_RANGES.get(name, {}).items()):
        if key not in defaults:
            raise ValueError(f"PARAM_RANGES[{name!r}] names {key!r}, not a parameter of {name} "
                             f"(known: {sorted(defaults)})")
        if lo > hi:
            raise ValueError(f"PARAM_RANGES[{name!r}][{key!r}]: low {lo} > high {hi}")
        if isinstance(defaults[key], (int, np.integer)) and not isinstance(defaults[key], bool):
            out[key] = int(rng.integers(int(lo), int(hi) + 1))
        else:
            out[key] = round(float(rng.uniform(lo, hi)), 3)
    return out
