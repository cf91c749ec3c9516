"""The LB2.0 / Bench2Drive scoring rules of issue 29 on constructed cases, each of which the
previous rules scored differently: distance on lanes that are not the route's counts as outside
the route lanes; a bicycle is a vehicle; CARLA's collision filter (the same party within 5 s, any
contact within 3 m of a registered one until the ego is 5 m away); "held by a red light" only
near the stop line; a pedestrian or cyclist hit by the ego leaves the world instead of waiting
for it for good."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.actors import EGO, WALKER, ActorTable
from v2xbench.envs.v2x_intersection.core.classes import BICYCLE, CAR, PEDESTRIAN
from v2xbench.envs.v2x_intersection.evaluation import infractions
from v2xbench.envs.v2x_intersection.evaluation import metrics as M
from v2xbench.envs.v2x_intersection.evaluation.infractions import (
    BLOCKED,
    BLOCKED_S,
    COLLISION_FORGET_M,
    COLLISION_NEAR_M,
    COLLISION_PEDESTRIAN,
    COLLISION_VEHICLE,
    HELD_BY_RED_M,
    HIT_VRU_LEAVES_S,
    OUTSIDE_LANES,
    SIDE_FRONT,
    SIDE_LEFT,
    SIDE_REAR,
    SIDE_RIGHT,
    EventMonitor,
    contact_side,
)
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.model import DRIVING, SIGNAL
from v2xbench.envs.v2x_intersection.town.routes import route_from_lanes
from v2xbench.envs.v2x_intersection.traffic.signals import NO_SIGNAL, RED
from v2xbench.envs.v2x_intersection.traffic.vehicles import STOP_LINE_SETBACK

DT = 0.1
NONE = np.zeros(0, np.int64)


@pytest.fixture(params=["numba", "numpy"])
def monitor_path(request, monkeypatch):
    """Run a test on the kernel path of ``EventMonitor`` and on its NumPy path."""
    if request.param == "numba" and not infractions.HAVE_JIT:
        pytest.skip("numba not installed")
    if request.param == "numpy":
        monkeypatch.setattr(infractions, "HAVE_JIT", False)
    return request.param


def table(n: int, kinds=()) -> ActorTable:
    t = ActorTable.empty(n)
    t.active[:] = True
    t.kind[:] = CAR
    t.kind[1:1 + len(kinds)] = kinds
    t.behaviour[0] = EGO
    t.length[:], t.width[:] = 4.7, 1.9
    return t


def drive_on(mon: EventMonitor, town, t: ActorTable, lane: int, s_values, v: float = 5.0,
             signal: np.ndarray | None = None, tick0: int = 1) -> list:
    """Put the ego on ``lane``'s centre at each arc length of ``s_values`` in turn, heading along
    the lane, moving ``v * DT`` a tick; returns the events."""
    signal = np.full(len(town.lanes), NO_SIGNAL) if signal is None else signal
    out = []
    for k, s in enumerate(s_values):
        p, h = town.index.pose_at(np.array([lane]), np.array([float(s)]))
        t.pos[0], t.yaw[0], t.speed[0] = p[0], h[0], v
        out += mon.update(tick0 + k, t, NONE, signal, v * DT)
    return out


# ------------------------------------------------------------------------------ outside route lanes


def _town04_route():
    """Town04's lane 0 (road 0) into connector 20 and lane 6; lane 1 is lane 0's same-direction
    neighbour, lane 3 its opposite lane."""
    town = get_town("Town04")
    ln = town.lanes[0]
    assert ln.right == 1 and ln.opposite == 3 and town.lanes[3].opposite == 0
    return town, route_from_lanes(town, [0, 20, 6])


@pytest.mark.parametrize("lane", [3, 1], ids=["opposite_lane", "neighbour_lane"])
def test_distance_on_a_lane_off_the_route_counts_as_outside(lane, monitor_path):
    """10 m on the route's lane, then 10 m on a lane that is not the route's (the opposite lane,
    the same-direction neighbour): the second 10 m are outside, IS x 0.5 (before: 1.0, since
    the ego was inside *a* lane)."""
    town, route = _town04_route()
    mon = EventMonitor(town, route, DT)
    t = table(1)
    ev = drive_on(mon, town, t, 0, np.arange(50.0, 60.0, 0.5))
    assert mon.outside_m == 0.0 and not any(e[0] == OUTSIDE_LANES for e in ev)
    L = town.index.length[lane]
    # the opposite lane runs the other way: its arc length at the same place is L - s
    s_other = L - np.arange(60.0, 70.0, 0.5) if lane == 3 else np.arange(60.0, 70.0, 0.5)
    ev = drive_on(mon, town, t, lane, s_other, tick0=100)
    assert sum(e[0] == OUTSIDE_LANES for e in ev) == 1  # on entering
    assert mon.outside_m == pytest.approx(10.0) and mon.driven_m == pytest.approx(20.0)
    rec = _record(mon)
    assert M.outside_lanes_percent(rec) == pytest.approx(50.0)
    assert M.infraction_score(rec) == pytest.approx(0.5)


def test_outside_route_lanes_switch_and_junctions(monitor_path):
    """With ``route_lanes_test`` off (a scenario that needs the ego in the opposite lane, as
    CARLA's ``SwitchWrongDirectionTest``) the opposite lane does not count, leaving the drivable
    lanes still does; a junction's connectors never count (they overlap)."""
    town, route = _town04_route()
    mon = EventMonitor(town, route, DT)
    t = table(1)
    mon.route_lanes_test = False
    assert mon.route_lanes_test is False
    L = town.index.length[3]
    drive_on(mon, town, t, 3, L - np.arange(60.0, 70.0, 0.5))
    assert mon.outside_m == 0.0
    # 4 m right of the outer lane 2's centre, off the road: off the lanes, counted
    assert town.lanes[2].right < 0
    p, h = town.index.pose_at(np.array([2]), np.array([80.0]))
    t.pos[0] = p[0] - 4.0 * np.array([-np.sin(h[0]), np.cos(h[0])])
    mon.update(50, t, NONE, np.full(len(town.lanes), NO_SIGNAL), 0.5)
    assert mon.outside_m == pytest.approx(0.5)
    mon.route_lanes_test = True
    # connector 21 runs beside the route's connector 20 in the same junction: not counted
    drive_on(mon, town, t, 21, np.arange(10.0, 20.0, 0.5), tick0=60)
    assert town.lanes[21].kind != DRIVING and 21 not in route.lanes
    assert mon.outside_m == pytest.approx(0.5)


def _record(mon: EventMonitor) -> M.RouteRecord:
    z = np.zeros(2)
    return M.RouteRecord(route_length=100.0, route_completion=100.0, ego_xy=np.zeros((2, 2)), ego_yaw=z,
                         ego_speed=z, background_speed=z, route_s=z,
                         events=np.asarray(mon.events, float).reshape(-1, 4), outside_lanes_m=mon.outside_m,
                         driven_m=mon.driven_m, bytes_sent=0, peak_bps=0.0, sim_seconds=0.2,
                         ended_by=M.ENDED_COMPLETED)


# ------------------------------------------------------------------------------ collisions


def _stand(mon: EventMonitor, t: ActorTable, x: float, tick: int, contacts=()) -> list:
    """The ego stands at ``(x, 0)`` at ``tick`` touching the rows ``contacts``."""
    t.pos[0], t.speed[0] = (x, 0.0), 0.0
    return mon.update(tick, t, np.asarray(contacts, np.int64), np.full(len(mon.town.lanes), NO_SIGNAL), 0.0)


def _collision_monitor():
    town = get_town("Town04")
    return EventMonitor(town, route_from_lanes(town, [0, 20, 6]), DT)


@pytest.mark.parametrize("kind, code", [(BICYCLE, COLLISION_VEHICLE), (PEDESTRIAN, COLLISION_PEDESTRIAN),
                                        (CAR, COLLISION_VEHICLE)])
def test_a_bicycle_is_a_vehicle(kind, code, monitor_path):
    """Hitting a bicycle is a vehicle collision (IS 0.60, as CARLA's bicycles are vehicles;
    before: a pedestrian collision, 0.50)."""
    mon = _collision_monitor()
    t = table(2, [kind])
    ev = _stand(mon, t, 0.0, 1, [1])
    assert [e[0] for e in ev] == [code] and ev[0][2] == 1
    assert M.infraction_score(_record(mon)) == pytest.approx(M.INFRACTION_FACTORS[infractions.EVENT_NAMES[code]])
    assert M.infraction_score(_record(mon)) == pytest.approx(0.5 if kind == PEDESTRIAN else 0.6)


@pytest.mark.parametrize("yaw", [0.0, 2.0])
def test_collision_side_is_where_the_other_party_was(yaw, monitor_path):
    """A collision's value says where on the ego the other vehicle was, in the ego's frame (its
    heading ``yaw``): ahead, behind, left, right; the metric counts vehicle collisions by side."""
    c, s = np.cos(yaw), np.sin(yaw)
    sides = []
    for ahead, left, tick in [(4.0, 0.5, 1), (-4.5, -0.3, 100), (1.0, 2.0, 200), (-1.0, -2.0, 300)]:
        mon = _collision_monitor()
        t = table(2)
        t.yaw[0] = yaw
        t.pos[1] = (c * ahead - s * left, s * ahead + c * left)
        ev = _stand(mon, t, 0.0, tick, [1])
        assert [e[0] for e in ev] == [COLLISION_VEHICLE]
        sides.append(int(ev[0][3]))
    assert sides == [SIDE_FRONT, SIDE_REAR, SIDE_LEFT, SIDE_RIGHT]
    assert contact_side(1.0, 0.99, 0.0) == SIDE_FRONT and contact_side(1.0, 1.01, 0.0) == SIDE_LEFT
    assert contact_side(-1.0, -0.99, 0.0) == SIDE_REAR and contact_side(-0.99, -1.0, 0.0) == SIDE_RIGHT
    rec = _record(mon)
    rec.events = np.asarray([(COLLISION_VEHICLE, k, k, side) for k, side in enumerate(sides + [SIDE_FRONT])], float)
    assert M.collision_sides(rec) == {"n_collision_vehicle_front": 2.0, "n_collision_vehicle_side": 2.0,
                                      "n_collision_vehicle_rear": 1.0}
    agg = M.aggregate([M.compute_metrics(rec)], 1)
    km = M.km_completed(rec)
    assert agg["collision_vehicle_front_per_km"] == pytest.approx(2.0 / km)
    assert agg["collision_vehicle_rear_per_km"] == pytest.approx(1.0 / km)
    rec.events[:, 3] = 0.0  # a record from before the sides were recorded: no side counts
    assert M.collision_sides(rec) == {}


def test_same_actor_ignored_for_5_s_after_its_registration(monitor_path):
    """Contact with actor 1, the ego backs off 20 m (the place is forgotten) and touches it again
    4 s later: ignored (before: counted, 3 s after the last contact); again 5.5 s after the
    registration: counted."""
    mon = _collision_monitor()
    t = table(2)
    assert len(_stand(mon, t, 0.0, 1, [1])) == 1
    _stand(mon, t, 20.0, 2)  # moved away: the registered place is forgotten
    assert _stand(mon, t, 20.0, 41, [1]) == []  # 4 s later: the same actor, ignored
    assert _stand(mon, t, 20.0, 51, [1]) == []  # exactly 5 s: still ignored
    _stand(mon, t, 40.0, 52)
    ev = _stand(mon, t, 40.0, 56, [1])  # 5.5 s after the registration
    assert [e[0] for e in ev] == [COLLISION_VEHICLE]
    assert mon.counts[COLLISION_VEHICLE] == 2


def test_contacts_near_a_registered_collision_are_ignored_until_5_m_away(monitor_path):
    """After a collision with actor 1 at x = 0: a contact with actor 2 with the ego 2 m from
    there is ignored (before: counted, another actor), also 10 s later; at 4 m (more than 3,
    not yet 5) a contact counts; once the ego has been more than 5 m away, a contact back at 2 m
    counts."""
    mon = _collision_monitor()
    t = table(4)
    assert len(_stand(mon, t, 0.0, 1, [1])) == 1
    assert _stand(mon, t, 2.0, 5, [2]) == []
    assert _stand(mon, t, 2.0, 105, [2]) == []  # the place stays while the ego is within 5 m
    ev = _stand(mon, t, COLLISION_NEAR_M + 1.0, 106, [3])  # 4 m from the first place: counts...
    assert [e[2] for e in ev] == [3]
    assert _stand(mon, t, COLLISION_NEAR_M + 1.0, 107, [2]) == []  # ...and registers its own place
    _stand(mon, t, COLLISION_FORGET_M + COLLISION_NEAR_M + 1.5, 108)  # > 5 m from both places
    ev = _stand(mon, t, 2.0, 109, [2])
    assert [e[2] for e in ev] == [2]
    assert mon.counts[COLLISION_VEHICLE] == 3


def test_two_contacts_in_one_tick_register_once(monitor_path):
    """Two parties touched in the same tick: the second is within 3 m of the first's place."""
    mon = _collision_monitor()
    t = table(3, [PEDESTRIAN, CAR])
    ev = _stand(mon, t, 0.0, 1, [1, 2])
    assert [e[0] for e in ev] == [COLLISION_PEDESTRIAN]


# ------------------------------------------------------------------------------ held by a red light


def _red_approach(town):
    for ln in town.lanes:
        if (ln.kind == DRIVING and ln.stop_at_end and ln.length > 80
                and town.junctions[ln.junction_ahead].control == SIGNAL):
            conn = ln.successors[0]
            return ln.id, route_from_lanes(town, [ln.id, conn, town.lanes[conn].successors[0]])
    raise AssertionError("no approach")


@pytest.mark.parametrize("front_gap, held", [(57.0, False), (HELD_BY_RED_M + 1.0, False),
                                             (HELD_BY_RED_M - 1.0, True), (3.0, True), (-1.0, True)])
def test_held_by_red_only_near_the_stop_line(front_gap, held, monitor_path):
    """Standing in a lane that ends at a red light holds the ego only with its front at most
    ``HELD_BY_RED_M`` before the stop line (before: anywhere in the lane, 57 m included)."""
    town = get_town("Town01")
    lane, route = _red_approach(town)
    signal = np.full(len(town.lanes), NO_SIGNAL)
    signal[lane] = RED
    mon = EventMonitor(town, route, DT)
    t = table(1)
    line = town.index.length[lane] - STOP_LINE_SETBACK
    drive_on(mon, town, t, lane, [line - front_gap - 0.5 * 4.7] * 3, v=0.0, signal=signal)
    assert mon.held_by_red is held
    assert mon.still_s == pytest.approx(0.0 if held else 0.3)  # held: the blocked clock stands


def test_far_from_a_red_stop_line_the_blocked_clock_runs(monitor_path):
    """Standing 57 m before a red stop line for 180 s ends the route as blocked (before: never,
    a red light was 'ahead'); 5 m before it, it does not, and the clock stands meanwhile."""
    town = get_town("Town01")
    lane, route = _red_approach(town)
    signal = np.full(len(town.lanes), NO_SIGNAL)
    signal[lane] = RED
    line = town.index.length[lane] - STOP_LINE_SETBACK
    n = int(BLOCKED_S / DT) + 5
    for gap, blocked in ((57.0, 1), (5.0, 0)):
        mon = EventMonitor(town, route, DT)
        t = table(1)
        p, h = town.index.pose_at(np.array([lane]), np.array([line - gap - 2.35]))
        t.pos[0], t.yaw[0], t.speed[0] = p[0], h[0], 0.0
        for k in range(n):
            mon.update(k + 1, t, NONE, signal, 0.0)
        assert mon.counts[BLOCKED] == blocked, gap


# ------------------------------------------------------------------------------ no deadlock after a hit


@pytest.mark.parametrize("kind", [PEDESTRIAN, BICYCLE])
def test_a_hit_walker_leaves_instead_of_waiting_for_the_ego(kind, monitor_path):
    """A crossing walker (or a cyclist moved as one, as scenario cyclists are) that the ego hits
    and then stands in the way of waits for the ego for good (walkers do not walk into a
    standing car) while a driver waits for it: a permanent deadlock. Now it leaves the world
    ``HIT_VRU_LEAVES_S`` after the collision, and the collision counts once."""
    w = World(make_config(town="Town03", num_vehicles=0, num_parked=0, num_pedestrians=1, num_bicycles=0))
    w.reset(seed=0)
    t = w.table
    assert t.behaviour[1] == WALKER
    t.kind[1] = kind
    u = np.array([np.cos(t.yaw[0]), np.sin(t.yaw[0])])
    t.path[1] = -1  # crossing in front of the ego, through its body
    t.cross_from[1], t.cross_to[1] = t.pos[0] + 1.0 * u, t.pos[0] + 12.0 * u
    t.pos[1], t.speed[1] = t.pos[0] + 1.0 * u, 1.4
    brake = np.array([0.0, 0.0, 1.0])
    w.step(brake)
    code = COLLISION_PEDESTRIAN if kind == PEDESTRIAN else COLLISION_VEHICLE
    assert w.monitor.counts[code] == 1
    start = t.pos[1].copy()
    leave = int(round(HIT_VRU_LEAVES_S / DT))
    for _ in range(leave - 2):
        w.step(brake)
    assert t.active[1] and np.allclose(t.pos[1], start)  # it waits for the standing ego
    for _ in range(3):
        w.step(brake)
    assert not t.active[1]
    for _ in range(100):
        w.step(brake)
    assert not t.active[1] and w.monitor.counts[code] == 1 and w.monitor.counts.sum() == 1
