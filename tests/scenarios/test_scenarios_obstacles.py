"""Obstacle, parking and cut-in scenarios: each one spawns, triggers, and its hazard really happens.

Everything is measured on the world state recorded tick by tick (:func:`trace`): box geometry in
the route frame, positions and speeds; never on flags the scenarios set themselves. Seeds are
picked for short run-ups (fast tests); ``robustness`` runs the same checks over more seeds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import v2xbench.envs.v2x_intersection.scenarios.obstacles  # noqa: F401  (registers)
import v2xbench.envs.v2x_intersection.scenarios.parking  # noqa: F401  (registers)
from v2xbench.agents.route_follower import RouteFollower
from v2xbench.envs.v2x_intersection.api.observations import ego_observation
from v2xbench.envs.v2x_intersection.core.actors import PARKED
from v2xbench.envs.v2x_intersection.core.geometry import box_corners_2d
from v2xbench.envs.v2x_intersection.scenarios import build_episode, get_scenario
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import EGO_WIDTH, World
from v2xbench.envs.v2x_intersection.town import get_town

SMALL = {"num_vehicles": 6, "num_parked": 4, "num_pedestrians": 4, "num_bicycles": 1}
MARGIN = 0.5  # m: a lane is blocked when its widest free strip is narrower than the ego + this


@dataclass
class Trace:
    """Per-tick world state of one scenario run (``T`` ticks, ``N`` actor rows)."""

    pos: np.ndarray  # (T, N, 2)
    yaw: np.ndarray  # (T, N)
    speed: np.ndarray  # (T, N)
    active: np.ndarray  # (T, N)
    ego_s: np.ndarray  # (T,)
    triggered: np.ndarray  # (T,)
    command: np.ndarray  # (T, 3) the driver's control (World.last_control)
    applied: np.ndarray  # (T, 3) the control the ego's dynamics applied (World.applied_control)
    world: World
    sc: object


def trace(
    name: str,
    seed: int,
    town: str | None = None,
    ticks: int = 400,
    until_passed: bool = True,
    until=None,
) -> Trace:
    """Run scenario ``name`` with the route follower and record the actor table every tick, until
    ``ticks``, the route's end, the scenario passed (``until_passed``) or ``until(world, sc)``."""
    cls = get_scenario(name)
    town = town or cls.towns[0]
    world = World(make_config(town=town, **SMALL))
    route, scs = build_episode(name, get_town(town), np.random.default_rng(seed))
    world.reset(seed=seed, route=route, scenarios=scs)
    sc, driver, t = scs[0], RouteFollower(), world.table
    keys = ("pos", "yaw", "speed", "active", "ego_s", "triggered", "command", "applied")
    log: dict[str, list] = {k: [] for k in keys}
    for _ in range(ticks):
        world.step(driver.act(ego_observation(world)), world.default_rsu_message())
        for key, val in (("pos", t.pos), ("yaw", t.yaw), ("speed", t.speed), ("active", t.active)):
            log[key].append(val.copy())
        log["ego_s"].append(sc.ego_s(world))
        log["triggered"].append(sc.triggered)
        log["command"].append(world.last_control.copy())
        log["applied"].append(world.applied_control.copy())
        if (
            (until_passed and sc.passed)
            or world.is_route_complete()
            or (until and until(world, sc))
        ):
            break
    return Trace(**{k: np.array(v) for k, v in log.items()}, world=world, sc=sc)


def route_frame(route, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Route arc length and signed lateral offset (m, left positive) of points ``(K, 2)``."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    j = np.linalg.norm(route.points[None] - xy[:, None], axis=2).argmin(1)
    h, v = route.headings[j], xy - route.points[j]
    return route.s[j], -np.sin(h) * v[:, 0] + np.cos(h) * v[:, 1]


def box_in_route(tr: Trace, row: int, k: int = -1) -> tuple[float, float, float, float]:
    """``(s_min, s_max, lat_min, lat_max)`` of actor ``row``'s box at tick ``k`` in the route frame."""
    t = tr.world.table
    c = box_corners_2d(tr.pos[k, row], t.length[row], t.width[row], tr.yaw[k, row])[0]
    s, lat = route_frame(tr.world.route, c)
    return s.min(), s.max(), lat.min(), lat.max()


def free_width(tr: Trace, rows: list[int], half_lane: float, k: int = -1) -> float:
    """Narrowest (over the stretch the boxes cover) widest free strip of the ego lane (m)."""
    boxes = [box_in_route(tr, r, k) for r in rows if tr.active[k, r]]
    worst = np.inf
    for s in np.arange(min(b[0] for b in boxes), max(b[1] for b in boxes), 0.25):
        cover = sorted(
            (max(b[2], -half_lane), min(b[3], half_lane))
            for b in boxes
            if b[0] <= s <= b[1] and b[3] > -half_lane and b[2] < half_lane
        )
        edge, best = -half_lane, 0.0
        for a, b in cover:
            best, edge = max(best, a - edge), max(edge, b)
        worst = min(worst, max(best, half_lane - edge))
    return float(worst)


def half_lane(tr: Trace) -> float:
    sc = tr.sc
    return float(tr.world.town.index.width[sc.site.lanes[sc.site.key]]) / 2


def flow_rows(tr: Trace) -> list[int]:
    """Rows the scenario owns beyond its hazard rows that ever drove (its traffic flow)."""
    t = tr.world.table
    own = np.flatnonzero(t.scenario == 0)
    return [int(r) for r in own if r not in tr.sc.hazard_rows and tr.speed[:, r].max() > 1.0]


def passes_near(tr: Trace, rows: list[int], point: np.ndarray, radius: float = 20.0) -> int:
    """How many of ``rows`` come within ``radius`` m of ``point`` while moving (> 2 m/s)."""
    near = (np.linalg.norm(tr.pos[:, rows] - point, axis=2) < radius) & (tr.speed[:, rows] > 2.0)
    return int(np.sum(near.any(0) & tr.active[:, rows].any(0)))


# ---------------------------------------------------------------------------------------- checks
def stopped_after_trigger(world, sc) -> bool:
    """The ego has come to a stop after the trigger (in front of a blockage)."""
    return sc.triggered and world.table.speed[0] < 0.05 and world.tick - sc.trigger_tick > 20


def check_lane_block(tr: Trace, two_way: bool) -> None:
    """The boxes leave no room to pass inside the ego lane; on a multi-lane road they stay out of
    the neighbour lane; on a two-way road an oncoming flow passes beside them."""
    assert tr.triggered.any()
    hl = half_lane(tr)
    rows = tr.sc.hazard_rows
    assert free_width(tr, rows, hl) < EGO_WIDTH + MARGIN
    ahead = [box_in_route(tr, r) for r in rows]
    assert min(b[0] for b in ahead) > tr.ego_s[0]
    if two_way:
        assert passes_near(tr, flow_rows(tr), tr.sc.conflict_point, 25.0) >= 1
    else:
        free = tr.sc.free
        assert all(free * (b[3] if free > 0 else b[2]) < hl + 0.05 for b in ahead)
    # the route follower, which keeps its lane, is stopped in front of the blockage
    assert tr.speed[:, 0][tr.triggered].min() < 0.1
    assert tr.ego_s[-1] < min(b[0] for b in ahead)


def hazard_moving_for(seconds: float):
    """Stop condition: the first hazard actor has been moving for ``seconds`` s."""

    def until(world, sc) -> bool:
        until.ticks += int(world.table.speed[sc.hazard_rows[0]] > 0.1)
        return until.ticks > seconds / world.config.dt

    until.ticks = 0
    return until


def check_cut_in(tr: Trace) -> None:
    """The vehicle starts beside the ego lane and ends up in it, ahead of the ego and close."""
    row = tr.sc.hazard_rows[0]
    moving = np.flatnonzero(tr.speed[:, row] > 0.1)
    assert len(moving), "the cut-in vehicle never moved"
    k0 = moving[0]
    s0, lat0 = route_frame(tr.world.route, tr.pos[k0 - 1, row])
    assert abs(lat0[0]) > 2.5 and tr.triggered[k0]
    s, lat = route_frame(tr.world.route, tr.pos[k0:, row])
    ahead = s - tr.ego_s[k0:]
    inside = np.flatnonzero((np.abs(lat) < 0.5) & (ahead > 0.0) & (ahead < 25.0))
    assert len(inside) and inside[0] < 45, "no cut-in in front of the ego within 4.5 s"


# --------------------------------------------------------------------------- per-scenario checks
def check_multi_lane(tr: Trace) -> None:
    check_lane_block(tr, two_way=False)


def check_two_way(tr: Trace) -> None:
    check_lane_block(tr, two_way=True)


def door_open_for(seconds: float):
    """Stop condition: the scenario's door (its second hazard row) has been open ``seconds`` s."""

    def until(world, sc) -> bool:
        door = sc.hazard_rows[1]
        until.ticks = until.ticks + 1 if world.table.active[door] else 0
        return until.ticks > seconds / world.config.dt

    until.ticks = 0
    return until


def check_door(tr: Trace) -> None:
    """The door opens close in front of the ego and then blocks the ego lane (closed, it did not)."""
    car, door = tr.sc.hazard_rows
    assert not tr.active[0, door] and tr.active[-1, door]
    k = int(np.flatnonzero(tr.active[:, door])[0])
    assert tr.triggered[k] and 5.0 < tr.sc.conflict_s - tr.ego_s[k] < 35.0
    assert tr.world.table.behaviour[car] == PARKED
    assert free_width(tr, [car, door], half_lane(tr)) < EGO_WIDTH + MARGIN
    assert free_width(tr, [car, door], half_lane(tr), k=k - 1) > EGO_WIDTH + MARGIN
    assert passes_near(tr, flow_rows(tr), tr.sc.conflict_point, 50.0) >= 1


def check_control_loss(tr: Trace) -> None:
    """The three loss points lie ahead on the route, in order, at least two windows apart. A tick's
    applied control differs from the command exactly when the ego's centre was within ``window``
    m of a point before that tick's move (after the trigger): steer by 0.02-0.20 with one sign per
    window, throttle by at most 0.06, brake never; elsewhere it is the command, bit for bit. The
    ego's heading moves by the applied steer (kinematic bicycle), not by the command."""
    sc, world = tr.sc, tr.world
    w = float(sc.params["window"])
    s_pts, lat = route_frame(world.route, sc.points)
    assert np.all(np.abs(lat) < 0.3) and s_pts[0] > tr.ego_s[0]
    assert np.all(np.diff(s_pts) >= 2 * w - 0.6)  # route points are ROUTE_STEP apart
    before = np.concatenate([world.route.points[:1], tr.pos[:-1, 0]])  # ego before each move
    armed = np.concatenate([[False], tr.triggered[:-1]])  # the hooks ran on the previous tick
    near = armed[:, None] & (np.linalg.norm(before[:, None] - sc.points[None], axis=2) < w)
    inside = near.any(1)
    assert near.any(0).all(), "the ego did not pass through every window"
    diff = tr.applied - tr.command
    np.testing.assert_array_equal(tr.applied[~inside], tr.command[~inside])
    assert np.all(diff[:, 2] == 0.0)
    assert np.all(np.abs(tr.command[inside, 1]) < 0.8)  # no clipping at the steer limits here
    ds = np.abs(diff[inside, 1])
    assert ds.min() >= 0.02 - 1e-12 and ds.max() <= 0.20 + 1e-12
    assert np.abs(diff[inside, 0]).max() <= 0.06 + 1e-12
    for k in range(len(sc.points)):
        assert len(set(np.sign(diff[near[:, k], 1]))) == 1
    p, dt = world.params, world.config.dt
    j = np.flatnonzero(inside)
    j = j[j > 0]
    dyaw = (tr.yaw[j, 0] - tr.yaw[j - 1, 0] + np.pi) % (2 * np.pi) - np.pi
    rate = tr.speed[j, 0] * dt / p.wheelbase
    np.testing.assert_allclose(dyaw, rate * np.tan(tr.applied[j, 1] * p.max_steer), atol=1e-9)
    assert np.abs(dyaw - rate * np.tan(tr.command[j, 1] * p.max_steer)).max() > 1e-3


def check_bicycles(tr: Trace) -> None:
    """The bicycles start after the trigger and ride slowly on the ego's path just ahead of it."""
    rows = tr.sc.hazard_rows
    k = int(np.flatnonzero(tr.triggered)[0])
    assert tr.speed[:k, rows].max() == 0.0 and tr.speed[k:, rows].max() > 2.0
    hits = 0
    for j in range(k, len(tr.ego_s)):
        for r in rows:
            s0, _, lo, hi = box_in_route(tr, r, j)
            if (
                0 < s0 - tr.ego_s[j] < 30
                and lo < EGO_WIDTH / 2
                and hi > -EGO_WIDTH / 2
                and tr.speed[j, r] < 3.6
            ):
                hits += 1
    assert hits > 10, "the ego never caught up with slow bicycles on its path"
    if tr.sc.two_way:
        assert passes_near(tr, flow_rows(tr), tr.sc.conflict_point, 40.0) >= 1


def ego_stopped_near_blocker(world, sc) -> bool:
    """Stop condition: the ego stands within 13 m of the blocker."""
    t, row = world.table, sc.hazard_rows[0]
    return bool(np.linalg.norm(t.pos[0] - t.pos[row]) < 13.0 and t.speed[0] < 0.05)


def check_blocked(tr: Trace) -> None:
    """A car stands on the route right after the junction until the ego stopped close behind it."""
    row = tr.sc.hazard_rows[0]
    _, _, lo, hi = box_in_route(tr, row, 0)
    assert lo < 0.5 and hi > -0.5
    near = np.flatnonzero(np.linalg.norm(tr.pos[:, 0] - tr.pos[:, row], axis=1) < 13.0)
    assert len(near), "the ego never reached the blocker"
    k = int(near[0])
    assert np.all(tr.speed[:, row] == 0.0) and tr.speed[k:, 0].min() < 0.1


def check_hard_brake(tr: Trace) -> None:
    """The lead car, in the ego lane just ahead, brakes at 6-8 m/s^2 for >= 0.4 s to a stop."""
    row = tr.sc.hazard_rows[0]
    acc = np.diff(tr.speed[:, row]) / 0.1
    run = np.convolve((acc < -6.0) & (acc > -7.9), np.ones(4), "valid") == 4  # IDM clips at -8
    run &= tr.triggered[1 : len(run) + 1]
    assert run.any(), "no sustained hard braking"
    k = int(np.flatnonzero(run)[0])
    assert tr.speed[k + 4 :, row].min() < 0.05
    s, lat = route_frame(tr.world.route, tr.pos[k, row])
    assert abs(lat[0]) < 0.5 and 5.0 < s[0] - tr.ego_s[k] < 30.0


def check_parking_exit(tr: Trace) -> None:
    """The ego starts in the parking lane between two parked cars; traffic passes its slot."""
    sc, town, t = tr.sc, tr.world.town, tr.world.table
    lane = sc.site.lanes[sc.site.key]
    _, s_ego, d = town.index.project(tr.pos[0, 0][None], np.array([lane]))
    assert d[0] > 2.5
    parked = np.flatnonzero((t.scenario == 0) & (t.behaviour == PARKED))
    _, s_p, d_p = town.index.project(tr.pos[0, parked], np.array([lane]))
    assert np.all(np.abs(d_p - d[0]) < 0.3) and (s_p > s_ego[0]).any() and (s_p < s_ego[0]).any()
    assert np.all(np.abs(s_p - s_ego[0]) < 15.0)
    _, _, d_ego = town.index.project(tr.pos[:, 0], np.array([lane]))
    out = d_ego > 1.0  # the ego is still (mostly) in the parking lane
    threat = passing = 0
    for r in sc.hazard_rows:
        _, s_r, d_r = town.index.project(tr.pos[:, r], np.array([lane]))
        on = (d_r < 0.5) & tr.active[:, r]
        threat += int(
            np.any(out & on & (s_r < s_ego[0]) & (s_r > s_ego[0] - 40.0) & (tr.speed[:, r] > 3.0))
        )
        passing += int(np.any(on[1:] & on[:-1] & (s_r[:-1] < s_ego[0]) & (s_r[1:] >= s_ego[0])))
    assert threat >= 1, "no traffic approaching in the target lane while the ego leaves its slot"
    assert passing >= 2, "traffic does not flow past the slot"


#: name -> (check, trace keyword arguments, (seed, town) used by the fast test)
CASES = {
    "Accident": (check_multi_lane, {"ticks": 260, "until": stopped_after_trigger}, (3, "Town12")),
    "ConstructionObstacle": (
        check_multi_lane,
        {"ticks": 260, "until": stopped_after_trigger},
        (3, "Town12"),
    ),
    "ParkedObstacle": (
        check_multi_lane,
        {"ticks": 260, "until": stopped_after_trigger},
        (1, "Town12"),
    ),
    "AccidentTwoWays": (
        check_two_way,
        {"ticks": 260, "until": stopped_after_trigger},
        (3, "Town06"),
    ),
    "ConstructionObstacleTwoWays": (
        check_two_way,
        {"ticks": 260, "until": stopped_after_trigger},
        (3, "Town06"),
    ),
    "ParkedObstacleTwoWays": (
        check_two_way,
        {"ticks": 260, "until": stopped_after_trigger},
        (2, "Town06"),
    ),
    "VehicleOpensDoorTwoWays": (check_door, {"ticks": 260, "until": "door"}, (0, "Town06")),
    "ControlLoss": (check_control_loss, {"ticks": 400}, (4, "Town02")),
    "HazardAtSideLane": (check_bicycles, {"ticks": 230}, (3, "Town12")),
    "HazardAtSideLaneTwoWays": (check_bicycles, {"ticks": 230}, (3, "Town06")),
    "BlockedIntersection": (
        check_blocked,
        {"ticks": 320, "until": ego_stopped_near_blocker},
        (4, "Town01"),
    ),
    "HardBreakRoute": (check_hard_brake, {"ticks": 320}, (3, "Town12")),
    "ParkingCutIn": (check_cut_in, {"ticks": 300, "until": "moving"}, (2, "Town12")),
    "StaticCutIn": (check_cut_in, {"ticks": 300, "until": "moving"}, (2, "Town03")),
    "ParkingExit": (check_parking_exit, {"ticks": 200, "until_passed": False}, (0, "Town03")),
}


def run_case(name: str, seed: int, town: str | None = None, ticks_scale: float = 1.0) -> Trace:
    """Trace scenario ``name`` with its case's settings and apply its check (raises on failure)."""
    check, kw, _ = CASES[name]
    kw = dict(kw)
    if kw.get("until") == "door":
        kw["until"] = door_open_for(2.0)
    elif kw.get("until") == "moving":
        kw["until"] = hazard_moving_for(5.0)
    kw["ticks"] = int(kw["ticks"] * ticks_scale)
    tr = trace(name, seed, town, **kw)
    check(tr)
    return tr


@pytest.mark.parametrize("name", list(CASES))
def test_scenario_hazard_happens(name):
    seed, town = CASES[name][2]
    run_case(name, seed, town)


def test_all_own_scenarios_fit_the_test_town():
    from v2xbench.envs.v2x_intersection.scenarios.placement import pick_site

    for name in CASES:
        cls = get_scenario(name)
        assert cls.family and not cls.v2x and cls.towns
        pick_site(cls, get_town("Town12"), np.random.default_rng(0))  # raises if it does not fit
        pick_site(cls, get_town(cls.towns[0]), np.random.default_rng(0))


def test_scenario_ending_at_the_route_end_is_passed_when_the_route_completes():
    """A route that ends right after its AccidentTwoWays (test50's instance, its route cut after
    the key lane and the accident moved 4 m before that lane's end): the scenario counts as
    passed on the tick the route is completed (its end used to lie beyond the completing
    progress, and the world updates progress after the scenarios' tick)."""
    import json

    from v2xbench.envs.v2x_intersection.suites.route_files import SUITE_DIR, parse_route

    raw = json.loads((SUITE_DIR / "test50.json").read_text())
    d, inst = next((r, s) for r in raw["routes"] for s in r["scenarios"]
                   if s["type"] == "AccidentTwoWays")
    town = get_town(d["town"])
    key = inst["site"]["lanes"][inst["site"]["key"]]
    lanes = d["lanes"][: d["lanes"].index(key) + 1]
    inst = {**inst, "site": {**inst["site"], "s_on_key": float(town.index.length[key]) - 4.0}}
    inst.pop("trigger", None), inst.pop("conflict", None)
    ends = [town.lanes[ln].points[i].tolist() for ln in (lanes[0], lanes[-1]) for i in (0, -1)]
    spec = parse_route({**d, "lanes": lanes, "scenarios": [inst], "waypoints": ends})
    world = World(
        make_config(town=spec.town, num_vehicles=0, num_parked=0, num_pedestrians=0, num_bicycles=0)
    )
    world.reset(seed=0, spec=spec)
    sc = next(s for s in world.scenarios if s.name == "AccidentTwoWays")
    r, t = world.route, world.table
    assert sc.end_s == pytest.approx(r.s[-3])  # its end is where the route counts as complete
    for k in range(0, len(r.points), 3):  # the ego is carried along the route
        t.pos[0], t.yaw[0], t.speed[0] = r.points[k], r.headings[k], 0.0
        world.step(np.array([0.0, 0.0, 1.0]))
        if world.is_route_complete():
            break
    assert world.is_route_complete() and sc.triggered and sc.passed and not sc.timed_out


def test_lane_flow_ego_distance_test_matches_numpy_norm_at_and_away_from_the_radius():
    """``obstacles._ego_within`` (a lane flow's re-entry test, in Python floats) answers as
    ``np.linalg.norm(t.pos[0] - p) < radius`` does, also within the last bits of the radius."""
    from types import SimpleNamespace

    from v2xbench.envs.v2x_intersection.scenarios.obstacles import _ego_within

    rng = np.random.default_rng(3)
    p = np.array([12.5, -40.25])
    for k in range(4000):
        ang = rng.uniform(0, 2 * np.pi)
        r = 90.0 + (rng.integers(-4, 5) * np.spacing(90.0) if k % 2 else rng.uniform(-30.0, 30.0))
        t = SimpleNamespace(pos=np.array([[p[0] + r * np.cos(ang), p[1] + r * np.sin(ang)]]))
        assert _ego_within(t, p, 90.0) == bool(np.linalg.norm(t.pos[0] - p) < 90.0)


def test_parking_exit_route_rewrite_is_remembered_and_the_same_as_a_fresh_one():
    """``parking._exit_route`` (remembered per town): a second episode of a route file gets the
    same rewritten route as the first, read-only, and a fresh cache computes the same arrays; a
    rewritten route is left as it is."""
    from v2xbench.envs.v2x_intersection.scenarios.parking import _exit_route
    from v2xbench.envs.v2x_intersection.suites.route_files import (
        build_episode_from_spec,
        load_suite_cached,
    )

    spec = next(r for r in load_suite_cached("test50") if r.scenarios[0].type == "ParkingExit")
    (r1, sc1), (r2, _) = build_episode_from_spec(spec), build_episode_from_spec(spec)
    town = get_town(spec.town)
    fields = ("points", "headings", "lane_ids", "commands", "s")
    for f in fields:
        a, b = getattr(r1, f), getattr(r2, f)
        assert a is b and not a.flags.writeable
    assert r1.lanes == r2.lanes
    town.cache("parking_exit_routes").clear()
    (r3, sc3) = build_episode_from_spec(spec)
    for f in fields:
        np.testing.assert_array_equal(getattr(r1, f), getattr(r3, f))
        assert getattr(r1, f).dtype == getattr(r3, f).dtype
    assert sc1[0].conflict_s == sc3[0].conflict_s
    lane, s_p = sc1[0].site.lanes[sc1[0].site.key], sc1[0].site.s_on_key
    n, again = _exit_route(town, r1, lane, s_p, float(sc1[0].params["exit_length"]))
    assert again is None and r1.s[n] == sc1[0].conflict_s
