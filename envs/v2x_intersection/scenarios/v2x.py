"""V2X-specific scenarios: hazards hidden from the ego by heavy occluders, visible from an RSU.

Every module in this package registers its scenarios with ``@register_scenario``.
"""

from __future__ import annotations

from ..classes import LARGE_VEHICLE, PEDESTRIAN
from .base import Scenario
from .placement import clear_near, lane_point, spawn_static, spawn_walker, straight_sites, truck_size
from .registry import register_scenario


@register_scenario
class DynamicObjectCrossing(Scenario):
    """A pedestrian runs across the ego's lane from behind a parked truck ("ghost probe").

    The pedestrian waits on the kerb side of the truck, hidden from the ego, and is released when
    the ego's time to the crossing point equals its own time to reach the ego's lane centre, so
    the conflict really happens unless the ego slows down in time.

    Parameters: ``speed`` (m/s) of the pedestrian; ``side`` -1 from the right, +1 from the left.
    """

    name = "DynamicObjectCrossing"
    family = "crossing"
    v2x = True
    max_actors = 2
    trigger_distance = 45.0
    defaults = {"speed": 2.0, "side": -1.0}

    @classmethod
    def find_sites(cls, town):
        return straight_sites(town, min_length=60.0)

    def spawn(self, world) -> None:
        town, rng = world.town, world.rng
        lane = self.site.lanes[self.site.key]
        w = town.index.width[lane]
        side = float(self.params["side"])
        clear_near(world, self.conflict_point, 25.0)
        truck = truck_size(rng)
        # the truck stands at the kerb, its front just before the crossing point
        s_truck = self.site.s_on_key - truck[0] / 2 - 0.3
        p, h = lane_point(town, lane, s_truck, side * (w / 2 + truck[1] / 2 + 0.3))
        spawn_static(world, self.rows[0], LARGE_VEHICLE, p, h, truck, parked=True)
        # the pedestrian waits behind the truck's front corner, on the kerb side
        self._start_lat = w / 2 + truck[1] + 1.0
        start, _ = lane_point(town, lane, self.site.s_on_key - 1.2, side * self._start_lat)
        end, _ = lane_point(town, lane, self.site.s_on_key + 0.5, -side * (w / 2 + 4.0))
        spawn_walker(world, self.rows[1], start, end, speed=float(self.params["speed"]), hold=True,
                     kind=PEDESTRIAN)
        self.hazard_rows = [int(self.rows[1])]

    def update(self, world) -> None:
        t = world.table
        row = self.rows[1]
        if not t.hold[row]:
            return
        time_ped = self._start_lat / float(self.params["speed"])
        time_ego = (self.conflict_s - self.ego_s(world)) / max(float(t.speed[0]), 1.0)
        if time_ego <= time_ped + 0.3:
            t.hold[row] = False
