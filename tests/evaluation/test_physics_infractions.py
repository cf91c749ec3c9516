"""Tests of collision queries (separating-axis kernel and pymunk reference) and of the infraction / route-progress monitor."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.actors import EGO, PARKED, WALKER, ActorTable
from v2xbench.envs.v2x_intersection.core.classes import CAR, PEDESTRIAN
from v2xbench.envs.v2x_intersection.core.geometry import box_corners_2d
from v2xbench.envs.v2x_intersection.evaluation import infractions, jit_events
from v2xbench.envs.v2x_intersection.evaluation.infractions import (
    COLLISION_PEDESTRIAN,
    COLLISION_SAME_ACTOR_S,
    COLLISION_STATIC,
    COLLISION_VEHICLE,
    NUM_EVENTS,
    RED_LIGHT,
    ROUTE_DEVIATION,
    SCENARIO_TIMEOUT,
    STOP_SIGN,
    EventMonitor,
)
from v2xbench.envs.v2x_intersection.evaluation.physics import CollisionWorld
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.model import DRIVING, SIGNAL, STOP
from v2xbench.envs.v2x_intersection.town.routes import random_route, route_from_lanes
from v2xbench.envs.v2x_intersection.traffic.signals import GREEN, NO_SIGNAL, RED
from v2xbench.envs.v2x_intersection.traffic.vehicles import STOP_LINE_SETBACK

BRAKE = np.array([0.0, 0.0, 1.0])


@pytest.fixture(params=["numba", "numpy"])
def monitor_path(request, monkeypatch):
    """Run a monitor test on the kernel path (``jit_events.monitor_kernel``) and on the NumPy
    path of ``EventMonitor`` (the kernel path only where numba is installed)."""
    if request.param == "numba" and not infractions.HAVE_JIT:
        pytest.skip("numba not installed")
    if request.param == "numpy":
        monkeypatch.setattr(infractions, "HAVE_JIT", False)
    return request.param


def table(n: int) -> ActorTable:
    t = ActorTable.empty(n)
    t.active[:] = True
    t.kind[:] = CAR
    t.behaviour[0] = EGO
    t.length[:], t.width[:] = 4.7, 1.9
    return t


# ------------------------------------------------------------------------------ CollisionWorld


def test_collision_world_npc_and_static_contacts():
    t = table(3)
    t.pos[1] = [3.0, 0.5]  # overlaps the ego's front
    t.pos[2] = [4.7 + 5.0, 0.0]  # 5 m gap ahead
    statics = np.array(
        [
            [0.0, 30.0, 10.0, 4.0, 0.0],  # k = 0: far away
            [0.0, -3.0, 10.0, 4.5, 0.0],  # k = 1: its edge y = -0.75 overlaps the ego (y >= -0.95)
        ]
    )
    cw = CollisionWorld(t, statics)
    np.testing.assert_array_equal(cw.ego_contacts(t), [-2, 1])
    # move things: the NPC leaves, the far one comes close, the static stays
    t.pos[1] = [0.0, 8.0]
    t.pos[2] = [-4.0, 0.0]
    np.testing.assert_array_equal(cw.ego_contacts(t), [-2, 2])
    # inactive actors are never reported
    t.active[2] = False
    np.testing.assert_array_equal(cw.ego_contacts(t), [-2])


def test_collision_world_lateral_gap():
    t = table(2)
    t.pos[1] = [0.0, 1.9 + 5.0]  # side by side, 5 m apart
    cw = CollisionWorld(t, np.zeros((0, 5)))
    assert len(cw.ego_contacts(t)) == 0
    t.pos[1] = [0.0, 1.8]  # 10 cm overlap
    np.testing.assert_array_equal(cw.ego_contacts(t), [1])


def test_collision_world_follows_the_ego_and_rotation():
    t = table(2)
    t.pos[1] = [20.0, 0.0]
    cw = CollisionWorld(t, np.zeros((0, 5)))
    assert len(cw.ego_contacts(t)) == 0
    t.pos[0] = [17.0, 0.0]
    np.testing.assert_array_equal(cw.ego_contacts(t), [1])
    # crossed at 90 deg: the NPC's 2.35 m half length reaches y = +-2.35 around x = 20
    t.pos[0] = [20.0, 3.35]
    t.yaw[1] = np.pi / 2
    assert len(cw.ego_contacts(t)) == 0  # the ego spans y >= 3.35 - 0.95 = 2.4: 5 cm gap
    t.pos[0] = [20.0, 3.2]  # y >= 2.25: 10 cm overlap
    np.testing.assert_array_equal(cw.ego_contacts(t), [1])


def _sat_depth(c0: np.ndarray, c1: np.ndarray) -> float:
    depth = np.inf
    for c in (c0, c1):
        for k in range(2):
            e = c[k + 1] - c[k]
            n = np.array([-e[1], e[0]]) / np.linalg.norm(e)
            p0, p1 = c0 @ n, c1 @ n
            depth = min(depth, min(p0.max(), p1.max()) - max(p0.min(), p1.min()))
    return depth


@pytest.mark.parametrize("jit", [True, False], ids=["kernel", "pymunk"])
def test_collision_world_matches_separating_axis_test(monkeypatch, jit):
    from v2xbench.envs.v2x_intersection.evaluation import physics

    if jit and not physics.HAVE_JIT:
        pytest.skip("numba not installed")
    monkeypatch.setattr(physics, "HAVE_JIT", jit)
    rng = np.random.default_rng(0)
    n = 25
    t = table(n)
    t.length[1:], t.width[1:] = rng.uniform(0.5, 8.0, n - 1), rng.uniform(0.5, 2.5, n - 1)
    t.active[-3:] = False  # inactive rows never touch
    total = static_total = 0
    for _ in range(60):
        statics = np.column_stack([rng.uniform(-9, 9, (12, 2)), rng.uniform(0.3, 9.0, 12),
                                   rng.uniform(0.3, 4.0, 12), rng.uniform(-4, 4, 12)])
        cs = box_corners_2d(statics[:, :2], statics[:, 2], statics[:, 3], statics[:, 4])
        cw = CollisionWorld(t, statics)
        t.pos[0] = rng.uniform(-1, 1, 2)
        t.pos[1:] = rng.uniform(-8, 8, (n - 1, 2))
        t.yaw[:] = rng.uniform(-4, 4, n)
        c = box_corners_2d(t.pos, t.length, t.width, t.yaw)
        depth = np.array([_sat_depth(c[0], c[i]) for i in range(n)])
        sdepth = np.array([_sat_depth(c[0], b) for b in cs])
        got = cw.ego_contacts(t).tolist()
        assert got == sorted(got)
        clear = np.abs(depth) > 1e-6
        expected = {i for i in range(1, n) if depth[i] > 0 and t.active[i]}
        assert {i for i in got if i > 0 and clear[i]} == {i for i in expected if clear[i]}
        expected_static = {-1 - k for k in range(len(cs)) if sdepth[k] > 0}
        sclear = {-1 - k for k in range(len(cs)) if abs(sdepth[k]) > 1e-6}
        assert {i for i in got if i < 0 and i in sclear} == expected_static & sclear
        total += len(expected)
        static_total += len(expected_static)
    assert total > 100 and static_total > 50


# ------------------------------------------------------------------------------ collisions in a world


def test_ego_into_parked_vehicle_carla_collision_filter(monitor_path):
    """CARLA's CollisionTest in a world: one long contact counts once (the ego stays within 3 m
    of where it registered), a new contact after the ego backed off > 5 m counts again once 5 s
    have passed since the registration, not before (the old rule, 3 s since the last contact,
    gave 1 and 3 here)."""
    w = World(
        make_config(town="Town03", num_vehicles=0, num_parked=1, num_pedestrians=0, num_bicycles=0)
    )
    w.reset(seed=0)
    t = w.table
    assert t.behaviour[1] == PARKED
    u = np.array([np.cos(t.yaw[1]), np.sin(t.yaw[1])])
    touching = t.pos[1] - 3.0 * u  # ego's front overlaps the parked car's rear by ~1.5 m
    away = t.pos[1] - 20.0 * u

    def hold(pos, ticks):
        for _ in range(ticks):
            t.pos[0], t.yaw[0], t.speed[0] = pos, t.yaw[1], 0.0
            w.step(BRAKE)

    hold(touching, 1)
    assert w.monitor.counts[COLLISION_VEHICLE] == 1
    ev = [e for e in w.monitor.events if e[0] == COLLISION_VEHICLE]
    assert ev[0][1] == 1 and ev[0][2] == int(t.actor_id[1])
    hold(touching, 80)  # 8 s of continuous contact: the ego stays at the registered place
    assert w.monitor.counts[COLLISION_VEHICLE] == 1
    hold(away, 10)  # back off 1 s (20 m: the place is forgotten); 9 s since the registration
    hold(touching, 3)
    assert w.monitor.counts[COLLISION_VEHICLE] == 2
    hold(away, 10)  # again, but only 1.3 s after that registration: the same actor is ignored
    hold(touching, 3)
    assert w.monitor.counts[COLLISION_VEHICLE] == 2
    hold(away, int(COLLISION_SAME_ACTOR_S / 0.1) + 5)  # away longer than the window
    hold(touching, 3)
    assert w.monitor.counts[COLLISION_VEHICLE] == 3
    assert w.monitor.counts[COLLISION_PEDESTRIAN] == 0


def test_ego_into_pedestrian(monitor_path):
    w = World(
        make_config(town="Town03", num_vehicles=0, num_parked=0, num_pedestrians=1, num_bicycles=0)
    )
    w.reset(seed=0)
    t = w.table
    assert t.behaviour[1] == WALKER and t.kind[1] == PEDESTRIAN
    for _ in range(5):
        w.step(BRAKE)
    t.pos[0], t.yaw[0], t.speed[0] = t.pos[1], t.yaw[1], 0.0
    events = w.step(BRAKE)
    assert (COLLISION_PEDESTRIAN, w.tick, int(t.actor_id[1])) in [e[:3] for e in events]
    assert w.monitor.counts[COLLISION_PEDESTRIAN] == 1
    assert w.monitor.counts[COLLISION_VEHICLE] == 0


def test_ego_into_building_is_static_collision(monitor_path):
    w = World(
        make_config(town="Town01", num_vehicles=0, num_parked=0, num_pedestrians=0, num_bicycles=0)
    )
    w.reset(seed=0)
    t = w.table
    b = w.town.buildings[0]
    t.pos[0], t.yaw[0], t.speed[0] = b[:2], b[4], 0.0
    w.step(BRAKE)
    ev = [e for e in w.monitor.events if e[0] == COLLISION_STATIC]
    assert len(ev) == 1 and ev[0][2] == -1  # building 0 is static box 0, encoded -1 - 0


# ------------------------------------------------------------------------------ EventMonitor


def _approach(town, control: int):
    """A route over a lane ending at a junction of ``control`` (lane, route)."""
    for ln in town.lanes:
        if (
            ln.kind == DRIVING
            and ln.stop_at_end
            and ln.length > 40
            and town.junctions[ln.junction_ahead].control == control
            and (control != STOP or ln.id in town.junctions[ln.junction_ahead].stop_lanes)
        ):
            conn = ln.successors[0]
            return ln.id, route_from_lanes(town, [ln.id, conn, town.lanes[conn].successors[0]])
    raise AssertionError("no approach")


def _drive(monitor, town, t, lane, s_values, v, signal):
    out = []
    for k, s in enumerate(s_values):
        p, h = town.index.pose_at(np.array([lane]), np.array([s]))
        t.pos[0], t.yaw[0], t.speed[0] = p[0], h[0], v
        out += monitor.update(k + 1, t, np.zeros(0, np.int64), signal, 0.1 * v)
    return out


@pytest.mark.parametrize("state, expected", [(RED, 1), (GREEN, 0)])
def test_red_light_when_crossing_the_stop_line(state, expected, monitor_path):
    town = get_town("Town01")
    lane, route = _approach(town, SIGNAL)
    signal = np.full(len(town.lanes), NO_SIGNAL)
    signal[lane] = state
    mon = EventMonitor(town, route, 0.1)
    t = table(1)
    line = town.index.length[lane] - STOP_LINE_SETBACK
    ev = _drive(mon, town, t, lane, np.arange(line - 10.0, line - 0.1, 0.5), 5.0, signal)
    assert not any(e[0] == RED_LIGHT for e in ev)  # stopping before the line is fine
    ev = _drive(mon, town, t, lane, [line + 0.5, line + 1.0], 5.0, signal)
    red = [e for e in ev if e[0] == RED_LIGHT]
    assert len(red) == expected
    if expected:
        assert red[0][3] == float(lane)
    assert mon.counts[RED_LIGHT] == expected


def test_scenario_clock_stops_while_a_red_light_holds_the_ego(monitor_path):
    from types import SimpleNamespace

    from v2xbench.envs.v2x_intersection.scenarios.base import Scenario, Site

    class Waiting(Scenario):
        name = "Waiting"
        trigger_distance = 1e3  # triggers at once
        timeout_s = 2.0

        def spawn(self, world) -> None:
            pass

    town = get_town("Town01")
    lane, route = _approach(town, SIGNAL)
    sc = Waiting(route, Site((lane,), 0, 0.0), route.length - 5.0)
    mon = EventMonitor(town, route, 0.1)
    world = SimpleNamespace(monitor=mon, route=route, config=SimpleNamespace(dt=0.1), tick=0)
    t = table(1)
    line = town.index.length[lane] - STOP_LINE_SETBACK
    signal = np.full(len(town.lanes), NO_SIGNAL)

    def stand(state: int, ticks: int) -> None:
        signal[lane] = state
        for _ in range(ticks):
            _drive(mon, town, t, lane, [line - 3.0], 0.0, signal)
            sc.tick(world)
            world.tick += 1

    stand(RED, 50)  # 5 s at a red light: the scenario clock does not run
    assert mon.held_by_red and sc.triggered and not sc.passed
    assert sc.elapsed_s < 0.2 and mon.counts[SCENARIO_TIMEOUT] == 0
    stand(GREEN, 25)  # 2.5 s standing at green: out of time
    assert not mon.held_by_red
    assert sc.timed_out and mon.counts[SCENARIO_TIMEOUT] == 1


@pytest.mark.parametrize("stop_first, expected", [(False, 1), (True, 0)])
def test_stop_sign(stop_first, expected, monitor_path):
    town = get_town("Town01")
    lane, route = _approach(town, STOP)
    signal = np.full(len(town.lanes), NO_SIGNAL)
    mon = EventMonitor(town, route, 0.1)
    t = table(1)
    line = town.index.length[lane] - STOP_LINE_SETBACK
    _drive(mon, town, t, lane, np.arange(line - 20.0, line - 2.0, 1.0), 5.0, signal)
    if stop_first:
        _drive(mon, town, t, lane, [line - 1.5] * 5, 0.0, signal)
    ev = _drive(mon, town, t, lane, [line + 0.5, line + 1.5], 3.0, signal)
    assert sum(e[0] == STOP_SIGN for e in ev) == expected


def test_route_deviation(monitor_path):
    town = get_town("Town04")  # straight lane: distances are easy
    route = route_from_lanes(town, [0, 20, 6])
    mon = EventMonitor(town, route, 0.1)
    t = table(1)
    k = 30
    h = route.headings[k]
    left = np.array([-np.sin(h), np.cos(h)])
    for off in (0.0, 10.0, 20.0):
        t.pos[0] = route.points[k] + off * left
        mon.update(1, t, np.zeros(0, np.int64), np.full(len(town.lanes), NO_SIGNAL), 0.0)
    assert mon.counts[ROUTE_DEVIATION] == 0
    t.pos[0] = route.points[k] + 40.0 * left
    ev = mon.update(2, t, np.zeros(0, np.int64), np.full(len(town.lanes), NO_SIGNAL), 0.0)
    dev = [e for e in ev if e[0] == ROUTE_DEVIATION]
    assert len(dev) == 1 and dev[0][3] == pytest.approx(40.0, abs=0.05)
    assert mon.counts.shape == (NUM_EVENTS,)


def test_route_completion_increases_to_100(monitor_path):
    town = get_town("Town01")
    route = random_route(town, np.random.default_rng(5), 300.0)
    mon = EventMonitor(town, route, 0.1)
    t = table(1)
    signal = np.full(len(town.lanes), GREEN)
    assert mon.route_completion == 0.0
    rc = []
    n = len(route.points)
    for k in range(0, n, 2):
        t.pos[0], t.yaw[0], t.speed[0] = route.points[k], route.headings[k], 10.0
        mon.update(k + 1, t, np.zeros(0, np.int64), signal, 2.0)
        rc.append(mon.route_completion)
        # progress tracks the ego: the furthest route point within 3 m of it
        s_done = mon.route_completion / 100.0 * route.length
        assert route.s[k] <= s_done <= route.s[k] + 3.5  # (3 m straight line, a bit more on arcs)
    t.pos[0] = route.points[-1]
    mon.update(n + 1, t, np.zeros(0, np.int64), signal, 2.0)
    rc.append(mon.route_completion)
    assert np.all(np.diff(rc) >= 0.0)
    assert rc[len(rc) // 2] == pytest.approx(50.0, abs=2.0)
    assert rc[-1] == pytest.approx(100.0)
    assert mon.counts[ROUTE_DEVIATION] == 0


def test_route_completion_does_not_jump_ahead_when_far(monitor_path):
    town = get_town("Town01")
    route = random_route(town, np.random.default_rng(5), 300.0)
    mon = EventMonitor(town, route, 0.1)
    t = table(1)
    t.pos[0] = route.points[-1]  # teleported to the goal: not within the 40-point window
    mon.update(1, t, np.zeros(0, np.int64), np.full(len(town.lanes), NO_SIGNAL), 0.0)
    assert mon.route_completion == 0.0


def test_kernel_constants_match_the_monitor():
    """jit_events repeats the event codes, limits and kinds it needs (infractions imports it)."""
    from v2xbench.envs.v2x_intersection.town import model
    from v2xbench.envs.v2x_intersection.traffic import signals

    for name in ("RED_LIGHT", "STOP_SIGN", "OUTSIDE_LANES", "OFF_ROAD", "WRONG_WAY", "ROUTE_DEVIATION", "BLOCKED",
                 "ROUTE_DEVIATION_M", "BLOCKED_S", "STOP_SPEED", "STOP_CHECK_M", "HELD_SPEED", "HELD_BY_RED_M"):
        assert getattr(jit_events, "_" + name) == getattr(infractions, name), name
    assert jit_events._RED == signals.RED and jit_events._CONNECTOR == model.CONNECTOR


def _monitor_trace(monkeypatch, jit: bool, town, route, dt: float, seed: int):
    """A monitor driven over random poses near (and off) the route, with random speeds, headings
    (wrong way included), lane states and contacts, with a long stand in the middle; returns its
    events, state bytes, counts and progress."""
    rng = np.random.default_rng(seed)
    with monkeypatch.context() as m:
        m.setattr(infractions, "HAVE_JIT", jit)
        mon = EventMonitor(town, route, dt)
        t = table(3)
        t.kind[1], t.kind[2] = PEDESTRIAN, CAR
        n = len(route.points)
        k = 0
        for tick in range(1, 400):
            k = min(k + int(rng.integers(0, 3)), n - 1) if not 150 <= tick < 340 else k
            h = route.headings[k] + (np.pi if rng.random() < 0.1 else rng.normal(0.0, 0.2))
            left = np.array([-np.sin(route.headings[k]), np.cos(route.headings[k])])
            t.pos[0] = route.points[k] + rng.choice([0.0, 0.0, 0.0, 1.5, 2.5, 3.5, 4.0, 7.0, 40.0]) * left
            t.length[0] = rng.uniform(3.0, 6.0)
            if rng.random() < 0.05:
                mon.route_lanes_test = not mon.route_lanes_test
            t.yaw[0] = h
            standing = 150 <= tick < 340  # long enough for the blocked clock (180 s)
            t.speed[0] = 0.0 if standing or rng.random() < 0.3 else rng.uniform(0.0, 12.0)
            signal = rng.integers(-1, 3, len(town.lanes))
            contacts = rng.choice([-2, 1, 2], int(rng.integers(0, 3)), replace=False)
            mon.update(tick, t, np.sort(contacts).astype(np.int64), signal, float(rng.uniform(0.0, 1.2)))
    return mon.events, mon._state.tobytes(), mon.counts.tobytes(), mon.progress


@pytest.mark.skipif(not infractions.HAVE_JIT, reason="numba not installed")
@pytest.mark.parametrize("town_name, seed", [("Town01", 0), ("Town03", 1), ("Town02", 2)])
def test_monitor_kernel_matches_numpy(monkeypatch, town_name, seed):
    """Both paths of the monitor emit the same events (values included) and end in the same
    state, over a trace that visits every lane event (dt = 1 s, so that the 180 s blocked clock
    runs out within it)."""
    town = get_town(town_name)
    route = random_route(town, np.random.default_rng(seed), 400.0)
    a = _monitor_trace(monkeypatch, True, town, route, 1.0, seed)
    b = _monitor_trace(monkeypatch, False, town, route, 1.0, seed)
    assert a == b
    assert all(type(e[3]) is float for e in a[0])


@pytest.mark.skipif(not infractions.HAVE_JIT, reason="numba not installed")
def test_monitor_kernel_trace_covers_the_lane_events(monkeypatch):
    """The trace of the test above reaches the events the kernel repeats (else it compares little)."""
    from v2xbench.envs.v2x_intersection.evaluation.infractions import (
        BLOCKED,
        OFF_ROAD,
        OUTSIDE_LANES,
        WRONG_WAY,
    )

    seen = set()
    for town_name, seed in [("Town01", 0), ("Town03", 1), ("Town02", 2)]:
        town = get_town(town_name)
        route = random_route(town, np.random.default_rng(seed), 400.0)
        seen |= {e[0] for e in _monitor_trace(monkeypatch, True, town, route, 1.0, seed)[0]}
    assert {OUTSIDE_LANES, OFF_ROAD, WRONG_WAY, ROUTE_DEVIATION, BLOCKED, COLLISION_STATIC,
            COLLISION_PEDESTRIAN, COLLISION_VEHICLE} <= seen


def test_monitor_state_attributes(monitor_path):
    """The float attributes kept in the state array read and write as floats."""
    town = get_town("Town01")
    route = random_route(town, np.random.default_rng(5), 300.0)
    mon = EventMonitor(town, route, 0.1)
    t = table(1)
    t.pos[0], t.yaw[0], t.speed[0] = route.points[0], route.headings[0], 0.0
    mon.update(1, t, np.zeros(0, np.int64), np.full(len(town.lanes), NO_SIGNAL), 0.25)
    assert mon.driven_m == 0.25 and type(mon.driven_m) is float
    assert mon.still_s == pytest.approx(0.1) and mon.held_by_red is False
    mon.outside_m = 3.0  # a scenario may hold it (scenarios/parking.py)
    assert mon.outside_m == 3.0
