"""The privileged expert and its oracles: route completion without infractions, red lights,
crossing pedestrians, waypoint consistency, object-list restrictions and planning speed."""

from __future__ import annotations

import time

import numpy as np
import pytest
from v2xbench.agents.expert import EgoOnlyOracle, Expert, Objects, Planner, V2XOracle
from v2xbench.agents.expert.lanes import lane_map
from v2xbench.agents.expert.objects import ObjectMemory, from_observation_rows
from v2xbench.agents.expert.route_track import RouteTrack
from v2xbench.agents.interface import AGENTS
from v2xbench.envs.v2x_intersection.api.observations import ego_observation
from v2xbench.envs.v2x_intersection.core.geometry import world_to_local_2d
from v2xbench.envs.v2x_intersection.evaluation import infractions as inf
from v2xbench.envs.v2x_intersection.evaluation.episode import time_budget_steps
from v2xbench.envs.v2x_intersection.scenarios import build_episode
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.model import CONNECTOR, SIGNAL, STRAIGHT
from v2xbench.envs.v2x_intersection.town.routes import route_from_lanes
from v2xbench.envs.v2x_intersection.traffic.signals import GREEN, RED

EMPTY = dict(num_vehicles=0, num_parked=0, num_pedestrians=0, num_bicycles=0)
BAD = (inf.COLLISION_PEDESTRIAN, inf.COLLISION_VEHICLE, inf.COLLISION_STATIC, inf.RED_LIGHT, inf.STOP_SIGN)


def drive(world: World, agent, max_ticks: int, until=None) -> None:
    """Step ``world`` with ``agent`` until the route is complete, ``until(world)`` or the cap."""
    for _ in range(max_ticks):
        obs = ego_observation(world) if isinstance(agent, V2XOracle) else None
        world.step(agent.act(obs), world.default_rsu_message())
        if world.is_route_complete() or (until is not None and until(world)):
            return


def start(world: World, agent, **reset):
    world.reset(**reset)
    agent.reset({})
    agent.bind(world)
    return agent


def test_registered():
    import v2xbench.agents.expert  # noqa: F401

    for name in ("expert", "oracle_ego", "oracle_v2x"):
        agent = AGENTS[name]()
        assert agent.privileged and agent.obs_mode == "objects" and agent.rsu_policy == "share_objects"


@pytest.mark.parametrize("town,seed", [("Town01", 0), ("Town03", 1), ("Town05", 2)])
def test_expert_completes_random_routes(town, seed):
    world = World(make_config(town=town, route_length=180.0))
    expert = start(world, Expert(), seed=seed)
    drive(world, expert, time_budget_steps(world))
    assert world.monitor.route_completion >= 95.0
    counts = world.monitor.counts
    assert not any(counts[c] for c in BAD), {inf.EVENT_NAMES[i]: int(n) for i, n in enumerate(counts) if n}


class _ForcedSignal:
    """A signal plan whose state on one lane is set by the test."""

    def __init__(self, plan, lane: int, state: int) -> None:
        self.plan, self.lane, self.state = plan, lane, state

    def lane_states(self, t: float) -> np.ndarray:
        s = self.plan.lane_states(t)
        s[self.lane] = self.state
        return s


def _signal_route(town):
    ix = town.index
    for j in town.junctions:
        if j.control != SIGNAL:
            continue
        for c in j.connectors:
            ln = town.lanes[c]
            if ln.kind == CONNECTOR and ln.turn == STRAIGHT and ix.length[ln.predecessors[0]] > 70:
                return [ln.predecessors[0], c, ln.successors[0]]
    raise AssertionError("no signalized approach")


def test_expert_stops_at_red_then_goes_on_green():
    town = get_town("Town01")
    lanes = _signal_route(town)
    world = World(make_config(town="Town01", **EMPTY))
    world.reset(seed=0, route=route_from_lanes(town, lanes))
    forced = _ForcedSignal(world.signals, lanes[0], RED)
    world.signals = forced
    world.lane_signal = forced.lane_states(0.0)
    expert = Expert()
    expert.bind(world)
    entry = RouteTrack(town, world.route).entries[0]
    drive(world, expert, 300)
    lane, s_on_lane, _ = town.index.project(world.table.pos[:1])
    assert int(lane[0]) == lanes[0] and world.table.speed[0] < 0.1
    d_line = town.index.length[lanes[0]] - (entry.s_enter - entry.s_line) - float(s_on_lane[0])
    assert 0.0 < d_line < 8.0  # the ego centre waits before the stop line
    assert world.monitor.counts[inf.RED_LIGHT] == 0
    forced.state = GREEN
    drive(world, expert, 200, until=lambda w: w.route.s[w.monitor.progress] > entry.s_exit)
    assert world.route.s[world.monitor.progress] > entry.s_exit
    assert world.monitor.counts[inf.RED_LIGHT] == 0


def _crossing(agent_cls, seed: int) -> tuple[bool, int]:
    """Run DynamicObjectCrossing; returns (collided with the pedestrian, first braking tick after
    the pedestrian was released)."""
    town = get_town("Town01")
    world = World(make_config(town="Town01"))
    route, scenarios = build_episode("DynamicObjectCrossing", town, np.random.default_rng(seed))
    agent = start(world, agent_cls(), seed=seed, route=route, scenarios=scenarios)
    sc = scenarios[0]
    ped = sc.hazard_rows[0]
    released, brake_tick = None, None
    for _ in range(500):
        control = agent.act(None)
        if released is not None and brake_tick is None and control[2] > 0.2:
            brake_tick = world.tick - released
        world.step(control, world.default_rsu_message())
        if released is None and not world.table.hold[ped]:
            released = world.tick
        if sc.passed:
            break
    hit = any(e[0] == inf.COLLISION_PEDESTRIAN for e in world.monitor.events)
    return hit, 10**6 if brake_tick is None else brake_tick


@pytest.mark.parametrize("seed", [0, 1])
def test_expert_brakes_for_crossing_pedestrian_earlier_than_ego_only(seed):
    hit_expert, brake_expert = _crossing(Expert, seed)
    hit_ego, brake_ego = _crossing(EgoOnlyOracle, seed)
    assert not hit_expert
    assert brake_expert <= brake_ego


def _hazard_run(agent_cls, name: str, seed: int, town: str = "Town12") -> dict:
    """Run V2X scenario ``name`` with an agent; returns the event counts by name."""
    world = World(make_config(town=town))
    route, scenarios = build_episode(name, get_town(town), np.random.default_rng(seed))
    agent = start(world, agent_cls(), seed=seed, route=route, scenarios=scenarios)
    sc = scenarios[0]
    drive(world, agent, 600, until=lambda w: sc.passed)
    return {inf.EVENT_NAMES[i]: int(n) for i, n in enumerate(world.monitor.counts) if n}


@pytest.mark.parametrize("name,n_seeds", [("DynamicObjectCrossing", 4),
                                           ("ParkingCrossingPedestrian", 6)])
def test_v2x_matters_for_a_pedestrian_hidden_by_parked_vehicles(name, n_seeds):
    """The benchmark's premise: over a few instances, the same planner hits the hidden pedestrian
    more often with the ego's own view than with the RSU's objects (whose route-only units do
    not cover every instance), and the privileged expert never does. (ParkingCrossingPedestrian's
    child is sometimes seen in time between the cars: about half of its test50 instances, so six
    instances.)"""
    seeds = range(n_seeds)  # instances on Town12 (its sites, so some are easy for the ego alone)
    hits = {cls: sum(_hazard_run(cls, name, seed).get("collision_pedestrian", 0) for seed in seeds)
            for cls in (EgoOnlyOracle, V2XOracle, Expert)}
    assert hits[EgoOnlyOracle] >= 2, hits
    assert hits[V2XOracle] < hits[EgoOnlyOracle], hits
    assert hits[Expert] == 0, hits


def test_v2x_track_takes_precedence_over_remembered_object():
    """A remembered (unseen) object moves at its last velocity; a fresh RSU track of the same
    object replaces it in the V2X oracle's list."""
    world = World(make_config(town="Town01"))
    oracle = start(world, V2XOracle(), seed=0)
    t = world.table
    row = int(np.flatnonzero(t.active)[1])
    world.ego_vis[:] = 0.0
    world.ego_vis[row] = 1.0
    oracle.seen()  # the ego sees it: remembered from now on
    world.ego_vis[row] = 0.0
    obs = ego_observation(world)
    x, y = world_to_local_2d(t.pos[row], t.pos[0], float(t.yaw[0]))
    rows = np.zeros_like(obs["v2x_objects"])
    rows[0, :7] = [1, 0, x, y, 0.0, 4.5, 1.9]
    rows[0, 8] = float(t.speed[row]) + 6.0  # the RSU's track is faster than the remembered one
    objs = oracle.objects({**obs, "v2x_objects": rows})
    near = np.linalg.norm(objs.pos - t.pos[row], axis=1) < 1.0
    assert near.sum() == 1 and abs(objs.speed[near][0] - rows[0, 8]) < 1e-3
    remembered = oracle.objects(None)  # without the RSU: the remembered object
    k = np.linalg.norm(remembered.pos - t.pos[row], axis=1) < 1.0
    assert k.sum() == 1 and abs(remembered.speed[k][0] - t.speed[row]) < 1e-3


def test_waypoints_match_driven_trajectory_on_free_road():
    world = World(make_config(town="Town01", route_length=220.0, **EMPTY))
    expert = start(world, Expert(), seed=3)
    pending: list[tuple[int, np.ndarray]] = []
    errors = []
    for _ in range(260):
        control = expert.act(None)
        t = world.table
        pos, yaw = t.pos[0].copy(), float(t.yaw[0])
        c, s = np.cos(yaw), np.sin(yaw)
        wp = expert.last_waypoints[1]  # 1.0 s ahead, ego frame
        pending.append((world.tick + 10, pos + np.array([c * wp[0] - s * wp[1], s * wp[0] + c * wp[1]])))
        world.step(control, None)
        while pending and pending[0][0] == world.tick:
            errors.append(float(np.linalg.norm(pending.pop(0)[1] - world.table.pos[0])))
        if world.is_route_complete():
            break
    assert len(errors) > 100
    assert np.median(errors) < 0.3 and np.percentile(errors, 95) < 1.0


def test_oracles_see_less_than_expert():
    world = World(make_config(town="Town03"))
    world.reset(seed=4)
    for _ in range(5):
        world.step(np.array([0.0, 0.0, 1.0]), world.default_rsu_message())
    expert, ego, v2x = Expert(), EgoOnlyOracle(), V2XOracle()
    for a in (expert, ego, v2x):
        a.reset({})
        a.bind(world)
    all_ids = set(expert.objects(None).ids.tolist())
    seen = ego.objects(None)
    assert set(seen.ids.tolist()) <= all_ids and len(seen) < len(all_ids)
    obs = ego_observation(world)
    with_v2x = v2x.objects(obs)
    assert len(with_v2x) >= len(seen)


def test_object_memory_and_observation_rows():
    mem = ObjectMemory(2.0)
    one = Objects.empty()
    car = Objects(np.array([0]), np.array([[10.0, 0.0]]), np.zeros(1), np.array([[5.0, 0.0]]), np.zeros(1),
                  np.array([4.5]), np.array([1.9]), np.zeros(1, bool), np.zeros(1, bool), np.array([7]))
    assert len(mem.update(car, 0.0)) == 1
    out = mem.update(one, 1.0)
    assert len(out) == 1 and np.allclose(out.pos[0], [15.0, 0.0])
    assert len(mem.update(one, 3.5)) == 0
    rows = np.zeros((3, 11), np.float32)
    rows[0] = [1, 0, 10.0, 0.0, 0.0, 4.5, 1.9, 1.5, 2.0, 0.0, 1.0]
    objs = from_observation_rows(rows, np.array([100.0, 50.0]), np.pi / 2)
    assert len(objs) == 1 and np.allclose(objs.pos[0], [100.0, 60.0]) and np.allclose(objs.vel[0], [0.0, 2.0])


def test_planner_speed_with_many_objects():
    world = World(make_config(town="Town05", num_vehicles=40, num_pedestrians=20))
    world.reset(seed=5)
    planner = Planner()
    planner.reset(world.town, world.route)
    lane_map(world.town)
    expert = Expert()
    expert.bind(world)
    objs = expert.objects(None)
    t = world.table
    planner.step(t.pos[0], float(t.yaw[0]), float(t.speed[0]), objs, world.lane_signal)
    t0 = time.perf_counter()
    for _ in range(20):
        planner.step(t.pos[0], float(t.yaw[0]), 8.0, objs, world.lane_signal)
    per_call = (time.perf_counter() - t0) / 20
    assert len(objs) >= 40
    assert per_call < 0.05  # generous: ~1-5 ms on a laptop, CI machines vary


@pytest.mark.parametrize(
    "scenario,town,seed",
    [
        ("InvadingTurn", "Town01", 0),  # moves right, inside its lane, for invading oncoming cars
        ("ParkingExit", "Town03", 0),  # waits for a gap in the flow before leaving the slot
        ("VehicleOpensDoorTwoWays", "Town01", 1),  # replans when the door opens, then overtakes
        ("InterurbanActorFlow", "Town01", 0),  # finds a gap in the oncoming flow to turn left
    ],
)
def test_expert_passes_scenario_without_collision(scenario, town, seed):
    t = get_town(town)
    world = World(make_config(town=town))
    route, scenarios = build_episode(scenario, t, np.random.default_rng(seed))
    expert = start(world, Expert(), seed=seed, route=route, scenarios=scenarios)
    sc = scenarios[0]
    for _ in range(time_budget_steps(world)):
        world.step(expert.act(None), world.default_rsu_message())
        if sc.passed or world.is_route_complete():
            break
    counts = world.monitor.counts
    assert sc.passed, {inf.EVENT_NAMES[i]: int(n) for i, n in enumerate(counts) if n}
    assert not any(counts[c] for c in BAD), {inf.EVENT_NAMES[i]: int(n) for i, n in enumerate(counts) if n}


def test_held_manoeuvre_offsets_are_finite():
    from v2xbench.agents.expert.lateral import Manoeuvre

    man = Manoeuvre(-2.9, 10.0, 20.0, np.inf, np.inf, "emergency", False)
    off = man.value(np.array([0.0, 15.0, 30.0, 1e6]))
    assert np.all(np.isfinite(off)) and off[0] == 0.0 and np.isclose(off[2], -2.9)


def test_route_track_lane_change_segments():
    town = get_town("Town03")
    route, _ = build_episode("ParkingExit", town, np.random.default_rng(0))
    track = RouteTrack(town, route)
    assert track.merges and track.merges[0][0] == 0.0
    a, b = track.merges[0]
    assert track.merging(a) == 0.0 and track.merging(b - 0.1) is None


def test_scalar_clip_matches_numpy():
    """``scalar.clip`` gives ``np.clip``'s value for one number: signed zeros at a bound kept,
    NaN passed through, bounds crossed from either side, no upper bound, NumPy scalars."""
    from v2xbench.agents.expert.scalar import clip

    nan = float("nan")
    cases = [(-0.0, 0.0, 1.0), (0.0, -0.0, 1.0), (-0.0, -1.0, 0.0), (0.0, -1.0, -0.0), (nan, 0.0, 1.0),
             (2.0, 0.0, 1.0), (-2.0, -1.0, 1.0), (0.5, 0.0, 1.0), (-7.0, -5.0, None), (3.0, -5.0, None),
             (np.float64(1.5), 0.0, 1.0), (np.int64(9), 0, 4), (np.int64(-1), 0, 4), (1.0, 1.0, 1.0)]
    for x, lo, hi in cases:
        want = np.clip(x, lo, hi)
        got = clip(x, lo, hi)
        assert np.asarray(got, float).tobytes() == np.asarray(want, float).tobytes(), (x, lo, hi)


def test_v2x_memory_keeps_an_object_the_rsu_stops_reporting():
    """An object received over V2X and then no longer reported is remembered for the memory's
    horizon, moved along its velocity; a fresh report nearby replaces it."""
    from v2xbench.agents.expert.objects import AnonymousMemory, Objects

    def one(x: float, vx: float) -> Objects:
        z = np.zeros(1)
        return Objects(kind=np.array([2]), pos=np.array([[x, 0.0]]), yaw=z, vel=np.array([[vx, 0.0]]),
                       accel=z, length=z + 0.5, width=z + 0.5, static=np.zeros(1, bool),
                       emergency=np.zeros(1, bool), ids=np.full(1, -1))

    mem = AnonymousMemory(horizon_s=2.0)
    assert len(mem.update(one(0.0, 1.0), 0.0)) == 1
    kept = mem.update(Objects.empty(), 1.0)
    assert len(kept) == 1 and kept.pos[0, 0] == pytest.approx(1.0)  # moved at its velocity
    both = mem.update(one(1.2, 1.0), 1.2)  # a fresh report within 2 m: the same object
    assert len(both) == 1 and both.pos[0, 0] == pytest.approx(1.2)
    assert len(mem.update(Objects.empty(), 3.0)) == 1  # 1.8 s since the last report
    assert len(mem.update(Objects.empty(), 3.3)) == 0  # forgotten after 2 s


def _suite_world(route_id_pred, seed_index: int = 0):
    """The first test50 route for which ``route_id_pred(spec, town)`` holds, reset as the
    evaluation harness resets it (job seed of ``seed_index``), with a bound expert."""
    from v2xbench.collectors import jobs as J
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite

    spec = next(r for r in load_suite("test50")[1] if route_id_pred(r, get_town(r.town)))
    world = World(make_config(town=spec.town))
    world.reset(seed=J.job_seed(spec.seed, seed_index), spec=spec)
    agent = Expert()
    agent.reset({})
    agent.bind(world)
    return world, agent


def test_expert_changes_lane_around_construction_on_a_wide_lane():
    """Town12's lanes reach 4 m: road works closing such a lane up to its edge leave no corridor
    within the in-lane offset cap, so the expert moves to the neighbour lane's centre."""
    def pred(r, town):
        return any(sc.type == "ConstructionObstacle"
                   and town.index.width[sc.site_lanes[sc.key]] > 3.6 for sc in r.scenarios)

    world, agent = _suite_world(pred)
    drive(world, agent, time_budget_steps(world))
    assert world.is_route_complete() and all(sc.passed for sc in world.scenarios)
    assert not any(e[0] in BAD for e in world.monitor.events)


def test_released_blocker_turns_into_background_traffic():
    """BlockedIntersection's car, once released, follows background rules (no scenario id, no
    fixed plan), so it cannot queue for good behind a later scenario's obstacle on the route."""
    world = World(make_config(town="Town01"))
    route, scs = build_episode("BlockedIntersection", get_town("Town01"),
                               np.random.default_rng(3))
    world.reset(seed=3, route=route, scenarios=scs)
    sc, t = world.scenarios[0], world.table
    row = sc.hazard_rows[0]
    assert t.hold[row] and t.scenario[row] >= 0 and t.plan[row] >= 0
    sc._near_s = float(sc.params["wait_s"])
    sc.update(world)
    assert not t.hold[row] and t.scenario[row] == -1 and t.plan[row] == -1


def test_expert_passes_parked_obstacle_after_an_invader_shift():
    """An invader shift still ramping out when the ego stops behind a parked obstacle gives way to
    the pass around it (found on a test50 BlockedIntersection + ParkedObstacleTwoWays route, seed
    2, that stood there until the scenario timed out; the suite has since been rebuilt, so this
    drives test50's ParkedObstacleTwoWays route, oncoming traffic included)."""
    def pred(r, town):
        return "ParkedObstacleTwoWays" in {sc.type for sc in r.scenarios}

    world, agent = _suite_world(pred, seed_index=2)
    drive(world, agent, time_budget_steps(world))
    assert world.is_route_complete()
    assert not any(sc.timed_out for sc in world.scenarios)
