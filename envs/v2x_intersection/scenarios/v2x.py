"""V2X-specific scenarios: hazards hidden from the ego by heavy occluders, visible from an RSU.

This module holds the crossing family (a pedestrian steps out in front of the ego from behind a
truck or a row of parked vehicles) and the helpers shared with :mod:`.v2x_junction` (junction and
turning families). Every hazard waits hidden until a CARLA-style trigger fires (the ego's time to
arrival at the conflict point at its current speed, or its distance to it), then moves on its
own, whatever the ego does: the conflict really happens unless the ego reacts in time (for an
ego that cannot see the hazard, typically only possible at low speed or with the roadside unit's
view). See :class:`~.timed.TimedScenario`.

Every module in this package registers its scenarios with ``@register_scenario``.
"""

from __future__ import annotations

import numpy as np

from ..core.actors import DRIVER, child_size
from ..core.classes import CAR, LARGE_VEHICLE, PEDESTRIAN
from ..core.geometry import row_norms, world_to_local_2d
from ..core.jit import HAVE_JIT
from ..core.raycast import END_TOLERANCES, Boxes, segments_blocked
from ..town.model import DRIVING, MERGE, PARKING, Town
from ..traffic.vehicles import STOP_LINE_SETBACK
from ..v2x.rsu import deploy, select_active
from .base import Site
from .jit_sight import KEEP_RADIUS_M, sight_fraction_kernel
from .placement import (
    car_size,
    clear_lanes,
    clear_near,
    lane_point,
    spawn_driver,
    spawn_static,
    spawn_walker,
    straight_sites,
    truck_size,
)
from .registry import register_scenario
from .timed import TimedScenario

#: m, half width of a junction crosswalk (its centre is this far before the lane end)
CROSSWALK_HALF = 2.0
PARKING_LANE_WIDTH = 2.5  # m
EGO_EYE_Z = 1.8  # m, ego sensor height (as ``world.EGO_SENSOR_Z``)
#: probability that DynamicObjectCrossing's occluder is a car hiding a child (else a truck, an adult)
CHILD_OCCLUDER_P = 0.5


# ---------------------------------------------------------------------------------------------
# geometry helpers (shared with v2x_junction)
def carriageway_edge(town: Town, lane: int, side: float) -> float:
    """Lateral distance (m) from ``lane``'s centre line to the outer edge of the driving lanes on
    ``side`` (-1 right, +1 left; on the left of a two-way road this includes the opposite lanes).
    Parking lanes are not included."""
    ln = town.lanes[lane]
    edge = ln.width / 2.0
    if side < 0:
        k = ln.right
        while k >= 0:
            edge += town.lanes[k].width
            k = town.lanes[k].right
        return edge
    k, leftmost = ln.left, ln
    while k >= 0:
        edge += town.lanes[k].width
        leftmost = town.lanes[k]
        k = leftmost.left
    k = leftmost.opposite  # the opposite lanes border the leftmost same-direction lane
    while k >= 0:
        edge += town.lanes[k].width
        k = town.lanes[k].right
    return edge


def has_parking(town: Town, lane: int, side: float) -> bool:
    """Whether the road of ``lane`` has a parking lane on ``side`` (-1 right, +1 left)."""
    ln = town.lanes[lane]
    if ln.road < 0:
        return False
    h = np.arctan2(*(ln.points[-1] - ln.points[0])[::-1])
    for p in town.lanes:
        if p.kind != PARKING or p.road != ln.road:
            continue
        loc = world_to_local_2d(p.points.mean(0), ln.points.mean(0), h)
        if loc[1] * side > 0:
            return True
    return False


def kerb_offset(town: Town, lane: int, side: float) -> float:
    """Lateral distance (m) from ``lane``'s centre line to the kerb on ``side`` (driving lanes plus
    a parking lane if the road has one there)."""
    return carriageway_edge(town, lane, side) + (
        PARKING_LANE_WIDTH if has_parking(town, lane, side) else 0.0
    )


def away_from_crosswalks(
    town: Town, sites: list[Site], behind: float = 20.0, ahead: float = 6.0
) -> list[Site]:
    """Move each straight site's conflict point (default 60 % of the lane) to the first of 60, 70,
    45, 80 % of the lane with no mid-block crosswalk from ``behind`` m before it to ``ahead`` m
    after it (parked rows and trucks do not stand on zebra crossings); sites with no such point
    are dropped."""
    out = []
    for site in sites:
        lane = site.lanes[site.key]
        road, length = town.lanes[lane].road, town.index.length[lane]
        marks = [c.corners.mean(0) for c in town.crosswalks if c.road == road and c.junction < 0]
        s_marks = []
        if marks:
            _, s_m, d_m = town.index.project(np.array(marks), np.array([lane]))
            s_marks = s_m[d_m < 15.0]
        for f in (0.6, 0.7, 0.45, 0.8):
            if all(not -behind - 3.0 < sm - f * length < ahead + 3.0 for sm in s_marks):
                out.append(Site(site.lanes, site.key, f * length, site.extra))
                break
    return out


def eta(distance: float, speed: float, accel: float = 1.5, v_max: float = 8.0) -> float:
    """Time (s) to cover ``distance`` m from ``speed`` accelerating at ``accel`` up to ``v_max``
    (a rough model of a vehicle driving off or cruising)."""
    d, v = max(distance, 0.0), max(speed, 0.0)
    v_max = max(v_max, v, 0.5)
    t_acc = (v_max - v) / accel
    d_acc = v * t_acc + 0.5 * accel * t_acc**2
    if d <= d_acc:
        return float((-v + np.sqrt(v * v + 2.0 * accel * d)) / accel)
    return float(t_acc + (d - d_acc) / v_max)


def has_sidewalk(town: Town, lane: int) -> bool:
    """Whether the road of ``lane`` has sidewalks (no pedestrians cross highways)."""
    road = town.lanes[lane].road
    return road >= 0 and any(sw.road == road for sw in town.sidewalks)


def has_crosswalk(town: Town, lane: int, junction: int) -> bool:
    """Whether the road of ``lane`` has a crosswalk at junction ``junction``."""
    road = town.lanes[lane].road
    return junction >= 0 and any(c.junction == junction and c.road == road for c in town.crosswalks)


def park_vehicle(
    world,
    row: int,
    lane: int,
    s_front: float,
    lateral: float,
    size: tuple[float, float, float] | None = None,
    kind: int = LARGE_VEHICLE,
) -> tuple[float, float, float]:
    """A parked vehicle (default: a truck / van) whose front is at arc length ``s_front`` of
    ``lane``, its centre ``lateral`` m left of the lane centre (negative: right). Returns its
    size."""
    size = size or truck_size(world.rng)
    p, h = lane_point(world.town, lane, s_front - size[0] / 2.0, lateral)
    spawn_static(world, row, kind, p, h, size, parked=True)
    return size


def make_child(world, row: int) -> None:
    """Turn the freshly spawned walker ``row`` into a child (its own size draw mapped onto the
    child range, :func:`~..core.actors.child_size`: no new random draws)."""
    t = world.table
    size = child_size(t.length[row], t.width[row], t.height[row])
    t.length[row], t.width[row], t.height[row] = (float(v) for v in size)


def sight_blocked(world, eyes: np.ndarray, targets: np.ndarray, extra: list[tuple] = ()) -> float:
    """Fraction of the sight lines from ``eyes (E, 3)`` to ``targets (T, 3)`` blocked by the town's
    buildings and the ``extra`` boxes ``(x, y, length, width, yaw, height)`` (e.g. a truck just
    placed); used to pick hazard positions hidden from the ego. With numba, in one kernel
    (``jit_sight``, the same floats)."""
    sb, sh = world.static_boxes, world.static_heights
    if HAVE_JIT:
        ex = np.array([e[:6] for e in extra], float).reshape(-1, 6)
        return sight_fraction_kernel(np.ascontiguousarray(eyes, float), np.ascontiguousarray(targets, float), sb,
                                     sh, *world.static_trig, ex, np.cos(ex[:, 4]), np.sin(ex[:, 4]), KEEP_RADIUS_M,
                                     *END_TOLERANCES)
    keep = row_norms(sb[:, :2] - targets[:, :2].mean(0)) < KEEP_RADIUS_M
    rows = np.concatenate([sb[keep], np.array([e[:5] for e in extra], float).reshape(-1, 5)])
    heights = np.concatenate([sh[keep], np.array([e[5] for e in extra], float)])
    # fresh float64 arrays of finite values: wrapped without Boxes' checks and copies
    boxes = Boxes.trusted(np.ascontiguousarray(rows[:, :2]), rows[:, 2].copy(), rows[:, 3].copy(),
                          rows[:, 4].copy(), np.zeros(len(rows)), heights)
    starts = np.repeat(eyes, len(targets), axis=0)
    ends = np.tile(targets, (len(eyes), 1))
    return float(segments_blocked(starts, ends, boxes).mean())


def route_eyes(world, route, s_values) -> np.ndarray:
    """Ego sensor positions ``(E, 3)`` at route arc lengths ``s_values``."""
    k = np.clip(np.searchsorted(route.s, np.asarray(s_values, float)), 0, len(route.points) - 1)
    return np.concatenate([route.points[k], np.full((len(k), 1), EGO_EYE_Z)], 1)


def route_rsu_eye(world, route, conflict_s: float, before_m: float = 12.0) -> np.ndarray:
    """Position ``(3,)`` of the roadside unit that serves the ego ``before_m`` m before route arc
    length ``conflict_s`` (the route's own deployment, :func:`~..rsu.deploy`, which knows
    nothing of scenarios; the nearest unit if none faces the ego there): a scenario may pick
    where its hazard waits so that the infrastructure can see it, never the other way round."""
    units = deploy(world.town, route)
    if len(units) == 0:
        return np.array([np.nan, np.nan, np.nan])
    k = min(max(int(np.searchsorted(route.s, conflict_s - before_m)), 0), len(route.points) - 1)
    u = select_active(units, route.points[k], float(route.headings[k]), world.config.rsu_range)[0]
    return units.pose[u, :3]


def box_points(center: np.ndarray, yaw: float, length: float, heights=(0.4, 1.0)) -> np.ndarray:
    """Sample points ``(6, 3)`` along a box's axis (rear, centre, front) at ``heights``."""
    u = np.array([np.cos(yaw), np.sin(yaw)])
    xy = [center + f * 0.35 * length * u for f in (-1.0, 0.0, 1.0)]
    return np.array([[p[0], p[1], z] for p in xy for z in heights])


# ---------------------------------------------------------------------------------------------
@register_scenario
class DynamicObjectCrossing(TimedScenario):
    """A pedestrian runs across the ego's lane from behind a vehicle parked at the kerb ("ghost
    probe").

    CARLA LB2.0's DynamicObjectCrossing: a walker crosses from behind a static object. **V2X
    addition**: the object is a vehicle standing at the kerb, drawn per instance: a truck or van
    hiding an adult, or (with probability :data:`CHILD_OCCLUDER_P`) a car hiding a child
    (:func:`~..core.actors.child_size`), lower than its roof. The walker waits close in front of
    the vehicle's front, on its kerb half, hidden from the ego but seen by the roadside unit's
    raised camera, and is released so that it steps into the ego's path just after the ego's
    front gets there: the conflict really happens unless the ego slows down in time, which its
    own sensors (seeing the walker only as it passes the vehicle's side) do not allow at urban
    speed.

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
        sites = [s for s in straight_sites(town, min_length=60.0) if has_sidewalk(town, s.lanes[0])]
        return away_from_crosswalks(town, sites, behind=10.0, ahead=3.0)

    def spawn(self, world) -> None:
        town, rng = world.town, world.rng
        lane = self.site.lanes[self.site.key]
        w = town.index.width[lane]
        side = float(self.params["side"])
        clear_near(world, self.conflict_point, 25.0)
        self.child = bool(rng.random() < CHILD_OCCLUDER_P)
        truck = car_size(rng, 1.45) if self.child else truck_size(rng)
        # the vehicle stands at the kerb, its front just before the crossing point
        park_vehicle(
            world,
            self.rows[0],
            lane,
            self.site.s_on_key - 0.3,
            side * (w / 2 + truck[1] / 2 + 0.3),
            truck,
            CAR if self.child else LARGE_VEHICLE,
        )
        # the pedestrian waits close in front of the truck's front, on its kerb half: the truck
        # hides it from the approaching ego until it steps past the truck's side, while the
        # roadside unit (past the crossing, looking back) sees it all the time
        self._start_lat = w / 2 + 0.3 + truck[1] - 0.5
        s_walk = self.site.s_on_key + 0.2 + max(self.position_jitter, -0.1)  # not beside the truck
        start, _ = lane_point(town, lane, s_walk, side * self._start_lat)
        # ... to the far sidewalk (past every lane: on a wider road a fixed offset left it
        # standing in a lane the route may use later)
        end, _ = lane_point(
            town, lane, s_walk + 0.3, -side * (kerb_offset(town, lane, -side) + 1.0)
        )
        spawn_walker(world, self.rows[1], start, end, speed=self.hazard_speed(), kind=PEDESTRIAN)
        if self.child:
            make_child(world, int(self.rows[1]))
        self.hold_walker(world, self.rows[1])
        self.hazard_rows = [int(self.rows[1])]

    def update(self, world) -> None:
        self.step_one_walker(world, int(self.rows[1]), self._start_lat)


@register_scenario
class ParkingCrossingPedestrian(TimedScenario):
    """A child steps out from between parked cars and crosses the ego's lane.

    CARLA LB2.0's ParkingCrossingPedestrian: a pedestrian emerges from behind parked vehicles. On
    a road with a parking lane beside the ego's lane, a row of parked cars stands at the conflict
    point: one whose front ends just before it, one or two behind it and one after a narrow gap.
    **V2X addition**: the walker is a child (:func:`~..core.actors.child_size`, 1.0-1.35 m), who
    waits on the sidewalk behind the front car, lower than the cars' roofs and so hidden from the
    ego's camera; the roadside unit's pole-mounted camera looks down over the cars. The child
    walks through the gap and across the ego's lane when the trigger fires (see
    :class:`TimedScenario`). Nothing here is large: a driver who slows only past trucks and vans
    gets no warning (children also walk the sidewalks in background traffic,
    :data:`~..core.actors.CHILD_SHARE`).

    Parameters: ``speed`` (m/s) of the child; ``gap`` (m) between the front car and the next
    car; ``cars`` parked cars behind the front car.
    """

    name = "ParkingCrossingPedestrian"
    family = "crossing"
    v2x = True
    max_actors = 5
    towns = ("Town03", "Town01", "Town06")
    trigger_distance = 45.0
    defaults = {"speed": 1.6, "gap": 1.4, "cars": 2}

    @classmethod
    def find_sites(cls, town):
        sites = straight_sites(town, min_length=50.0, parking=True)
        sites = [
            s
            for s in sites
            if has_parking(town, s.lanes[0], -1.0) and has_sidewalk(town, s.lanes[0])
        ]
        return away_from_crosswalks(town, sites)

    def spawn(self, world) -> None:
        town, rng = world.town, world.rng
        lane = self.site.lanes[self.site.key]
        w = town.index.width[lane]
        s_c = self.site.s_on_key
        clear_near(world, self.conflict_point, 30.0)
        park_lat = -(w / 2 + PARKING_LANE_WIDTH / 2)
        gap = float(self.params["gap"])
        front = car_size(rng, 1.45)
        s_front = s_c - gap / 2
        park_vehicle(world, self.rows[0], lane, s_front, park_lat, front, CAR)
        # parked cars: one after the gap, ``cars`` behind the front car
        s = s_c + gap / 2
        car = car_size(rng)
        park_vehicle(world, self.rows[1], lane, s + car[0], park_lat, car, CAR)
        s = s_front - front[0] - 1.0
        n_cars = int(np.clip(self.params["cars"], 0, 2))
        for k in range(2):
            row = self.rows[2 + k]
            if k >= n_cars:
                continue
            car = car_size(rng)
            park_vehicle(world, row, lane, s, park_lat, car, CAR)
            s -= car[0] + float(rng.uniform(0.8, 1.5))
        # the child waits on the sidewalk beside the front car's front, facing the gap
        self._start_lat = kerb_offset(town, lane, -1.0) + 0.8
        s_walk = s_c - 0.25 + 0.25 * self.position_jitter  # inside the gap
        start, _ = lane_point(town, lane, s_walk, -self._start_lat)
        end, _ = lane_point(town, lane, s_walk + 0.65, kerb_offset(town, lane, 1.0) + 1.0)
        spawn_walker(world, self.rows[4], start, end, speed=self.hazard_speed())
        make_child(world, int(self.rows[4]))
        self.hold_walker(world, self.rows[4])
        self.hazard_rows = [int(self.rows[4])]

    def update(self, world) -> None:
        self.step_one_walker(world, int(self.rows[4]), self._start_lat)


@register_scenario
class PedestrianCrossing(TimedScenario):
    """A group of pedestrians crosses the junction-entry crosswalk in front of the ego.

    The ego approaches a junction (any control; it may go straight or turn). A truck hides the
    right-hand corner: on a multi-lane approach it waits at the stop line of the lane to the
    ego's right, otherwise it is parked at the kerb just before the crosswalk. The pedestrians
    wait on the corner behind the truck's front and cross the whole road on the crosswalk; the
    first starts once the trigger fires (see :class:`TimedScenario`), the others follow after
    short, random delays (as CARLA's idle times).

    Parameters: ``count`` pedestrians (1-3); ``speed`` (m/s) range low end (each walks at
    ``speed`` to ``speed + 0.5``).
    """

    name = "PedestrianCrossing"
    family = "crossing"
    v2x = True
    max_actors = 4
    towns = ("Town01", "Town05", "Town03")
    trigger_distance = 45.0
    defaults = {"count": 3, "speed": 1.4}

    @classmethod
    def find_sites(cls, town):
        sites = []
        for j in town.junctions:
            if j.control == MERGE:
                continue
            for cid in j.connectors:
                c = town.lanes[cid]
                if not c.predecessors:
                    continue
                inc = c.predecessors[0]
                if (
                    town.index.length[inc] < 40
                    or town.lanes[inc].kind != DRIVING
                    or not has_crosswalk(town, inc, j.id)
                ):
                    continue
                sites.append(Site((inc, cid), 0, town.index.length[inc] - CROSSWALK_HALF))
        return sites

    def spawn(self, world) -> None:
        town, rng = world.town, world.rng
        lane = self.site.lanes[0]
        ix = town.index
        w, length = ix.width[lane], ix.length[lane]
        s_c = self.site.s_on_key
        clear_near(world, self.conflict_point, 20.0)
        right = ix.right[lane]
        if right >= 0:  # a truck waits at the stop line of the lane to the right
            size = truck_size(rng)
            clear_lanes(world, [right])
            s_front = ix.length[right] - STOP_LINE_SETBACK - 0.3
            spawn_driver(
                world,
                self.rows[0],
                int(right),
                s_front - size[0] / 2,
                kind=LARGE_VEHICLE,
                hold=True,
                size=size,
            )
            s_front = s_front * length / max(ix.length[right], 1e-6)
            outer = w / 2 + ix.width[right] / 2 + size[1] / 2  # the truck's outer side
        else:  # parked at the kerb just before the crosswalk
            size = truck_size(rng)
            s_front = length - 2 * CROSSWALK_HALF - 0.3
            park_vehicle(world, self.rows[0], lane, s_front, -(w / 2 + size[1] / 2 + 0.3), size)
            outer = w / 2 + size[1] + 0.3
        self._truck_row = int(self.rows[0])
        n = int(np.clip(self.params["count"], 1, 3))
        far = kerb_offset(town, lane, 1.0) + 1.0
        self._times, self._delays = [], []
        for k in range(n):
            lat0 = outer + 0.6  # close behind the truck's side: hidden from afar too
            start, _ = lane_point(town, lane, s_front - 0.5 - 0.8 * k, -lat0)
            end, _ = lane_point(town, lane, s_c - 1.0 + 0.9 * k + self.position_jitter, far)
            speed = (float(self.params["speed"]) + float(rng.uniform(0.0, 0.5))) * self.speed_scale
            spawn_walker(world, self.rows[1 + k], start, end, speed=speed)
            self.hold_walker(world, self.rows[1 + k])
            to_path = max(lat0 - self.path_half_width, 0.0) / (lat0 + far)  # of the diagonal
            self._times.append(np.linalg.norm(end - start) * to_path / speed)
            self._delays.append(0.0 if k == 0 else float(rng.uniform(0.3, 1.5)))
        self.hazard_rows = [int(r) for r in self.rows[1 : 1 + n]]

    def update(self, world) -> None:
        t = world.table
        if self.started(world, self._times[0]):
            waited = self.since_trigger(world) - self.start_delay
            for row, delay in zip(self.hazard_rows, self._delays):
                if row not in self._walking and waited >= delay:
                    self.release_walker(world, row)
        self.walkers_yield(world)
        if self.passed and t.behaviour[self._truck_row] == DRIVER:  # the waiting truck drives on
            t.hold[self._truck_row] = False


# the junction and turning families live in their own module (it imports the helpers above)
from . import v2x_junction  # noqa: E402, F401
