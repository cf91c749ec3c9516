"""Traffic-flow, junction and highway scenarios (``scenarios/flows.py``, ``junctions.py``,
``highway.py``).

Each test drives one scenario with the observation-only route follower (``probe``) and watches
the world after every tick until the hazard is seen to happen geometrically or kinematically
(flow vehicles through the conflict area as the ego arrives, a red-light runner entering on red,
a cut-in ending ahead of the ego in its lane, ...); the run stops there to keep the file fast.
The ``check_*`` functions are also used by ``robustness()`` to sweep seeds and towns.
"""

from __future__ import annotations

import numpy as np
import pytest
import v2xbench.agents.route_follower as route_follower
from v2xbench.envs.v2x_intersection.core.classes import TRAFFIC_CONE
from v2xbench.envs.v2x_intersection.core.geometry import world_to_local_2d
from v2xbench.envs.v2x_intersection.evaluation.infractions import YIELD_EMERGENCY
from v2xbench.envs.v2x_intersection.scenarios import (  # noqa: F401  (importing registers them)
    flows,
    get_scenario,
    highway,
    junctions,
)
from v2xbench.envs.v2x_intersection.scenarios.probe import probe
from v2xbench.envs.v2x_intersection.town.model import RAMP, SIGNAL
from v2xbench.envs.v2x_intersection.traffic.signals import GREEN, RED, YELLOW
from v2xbench.envs.v2x_intersection.traffic.vehicles import STOP_LINE_SETBACK

SMALL = dict(num_vehicles=6, num_parked=4, num_pedestrians=4, num_bicycles=1)


class _Seen(Exception):
    """Raised from the per-tick hook once the hazard has been observed."""


def watch(name: str, seed: int, town: str | None, check, max_ticks: int = 600, **kw):
    """Run ``probe(name, seed, town)`` calling ``check(world, memo)`` after every tick; returns
    ``(world, memo)`` as soon as ``check`` returns True, ``(None, memo)`` if it never does."""
    memo: dict = {}
    seen: dict = {}

    def hook(world) -> None:
        if check(world, memo):
            seen["world"] = world
            raise _Seen

    try:
        probe(name, seed=seed, town=town, max_ticks=max_ticks, on_tick=hook, **SMALL, **kw)
    except _Seen:
        return seen["world"], memo
    return None, memo


def _active(world, rows) -> np.ndarray:
    rows = np.asarray(rows, np.int64)
    return rows[world.table.active[rows]]


# ----------------------------------------------------------------------------- checks
def check_flow(
    world, memo, entry_m: float = 10.0, radius: float = 2.5, window_s: float = 8.0
) -> bool:
    """Every flow sends a vehicle through its conflict point within ``window_s`` (or the time its
    largest spacing takes, if longer: parallel-lane flows share one carriageway's spacing) of the
    ego arriving ``entry_m`` before the lane where the conflict is (the junction, merge or lane
    change it must negotiate)."""
    sc = world.scenarios[0]
    t = world.table
    if "flows_ok" not in memo:  # geometry: each flow's conflict point lies on the ego's route
        memo["flows_ok"] = all(
            np.min(np.linalg.norm(sc.route.points - f.conflict_xy, axis=1)) < 2.5 for f in sc.flows
        )
        memo["passed"] = set()
        key = np.flatnonzero(sc.route.lane_ids == sc.site.lanes[sc.site.key])[0]
        memo["entry_s"] = float(sc.route.s[key]) - entry_m
    if sc.ego_s(world) < memo["entry_s"]:
        return False
    memo.setdefault("arrival", world.tick)
    window_s = max([window_s] + [f.spacing[1] / f.speed for f in sc.flows])
    if world.tick - memo["arrival"] > window_s / world.config.dt:
        return False
    for k, f in enumerate(sc.flows):
        rows = _active(world, f.rows)
        if len(rows) and np.min(np.linalg.norm(t.pos[rows] - f.conflict_xy, axis=1)) < radius:
            memo["passed"].add(k)
    return memo["flows_ok"] and len(memo["passed"]) == len(sc.flows)


def check_cut_in(world, memo) -> bool:
    """The vehicle came up the on-ramp and ends up in the ego's lane, less than 30 m ahead."""
    sc, t = world.scenarios[0], world.table
    r = sc.hazard_rows[0]
    if not t.active[r]:
        return False
    if world.town.index.kind[t.lane[r]] == RAMP:
        memo["on_ramp"] = True
    rel = world_to_local_2d(t.pos[r], t.pos[0], float(t.yaw[0]))
    ego_lane_ok = np.min(np.linalg.norm(sc.route.points - t.pos[r], axis=1)) < 0.8
    return memo.get("on_ramp", False) and 0.0 < rel[0] < 30.0 and abs(rel[1]) < 1.0 and ego_lane_ok


def _runner_state(world, memo):
    sc, t = world.scenarios[0], world.table
    r = sc.hazard_rows[0]
    if "lane_in" not in memo:
        memo["lane_in"] = int(t.lane[r])
    lane_in = memo["lane_in"]
    line = world.town.index.length[lane_in] - STOP_LINE_SETBACK
    crossed = t.lane[r] != lane_in or t.s[r] + 0.5 * t.length[r] >= line
    return sc, t, r, lane_in, crossed


def _crosses_ego_path(world, memo, r: int, radius: float = 1.5, ego_within: float = 20.0) -> bool:
    """Actor ``r`` is on the ego's route (within ``radius`` m of a route point near the conflict)
    while the ego is within ``ego_within`` m of that point."""
    sc, t = world.scenarios[0], world.table
    if "near_pts" not in memo:
        near = np.abs(sc.route.s - sc.conflict_s) < 25.0
        memo["near_pts"] = sc.route.points[near]
    d = np.linalg.norm(memo["near_pts"] - t.pos[r], axis=1)
    k = int(np.argmin(d))
    return d[k] < radius and np.linalg.norm(t.pos[0] - memo["near_pts"][k]) < ego_within


def check_red_light_runner(world, memo) -> bool:
    """When the runner's front crosses its stop line its light is red and the ego's is green;
    then it drives through the ego's path while the ego is close."""
    sc, t, r, lane_in, crossed = _runner_state(world, memo)
    if crossed and "entry" not in memo:
        memo["entry"] = (int(world.lane_signal[lane_in]), int(world.lane_signal[sc.site.lanes[0]]))
    return "entry" in memo and _crosses_ego_path(world, memo, r)


def check_taking_priority(world, memo) -> bool:
    """A vehicle from a lane that must give way passes its stop line without stopping and drives
    through the ego's path while the ego is close."""
    sc, t, r, lane_in, crossed = _runner_state(world, memo)
    j = world.town.junctions[world.town.index.junction_ahead[lane_in]]
    memo["must_yield"] = lane_in in j.stop_lanes
    if not crossed:
        to_line = world.town.index.length[lane_in] - STOP_LINE_SETBACK - t.s[r] - 0.5 * t.length[r]
        if to_line < 10.0 and not t.hold[r]:
            memo["min_v"] = min(memo.get("min_v", np.inf), float(t.speed[r]))
    return crossed and _crosses_ego_path(world, memo, r)


def check_priority(world, memo) -> bool:
    """Crossing vehicles reach their (forced red) stop line as the ego (forced green) passes the
    conflict point, and none crosses its line before the ego has passed."""
    sc, t = world.scenarios[0], world.table
    ix = world.town.index
    if "lanes" not in memo:
        memo["lanes"] = {r: int(t.lane[r]) for r in sc.hazard_rows}
        memo["violations"] = 0
        memo["ego_light"] = set()
    to_line = {}
    for r, lane in memo["lanes"].items():
        if t.lane[r] != lane:
            to_line[r] = -1.0
        else:
            to_line[r] = float(ix.length[lane] - STOP_LINE_SETBACK - t.s[r] - 0.5 * t.length[r])
    if sc.triggered and world.tick > sc.trigger_tick + 1 and sc.ego_s(world) < sc.conflict_s:
        memo["ego_light"].add(int(world.lane_signal[sc.site.lanes[0]]))
    if sc.ego_s(world) < sc.conflict_s:
        memo["violations"] += sum(d < 0.0 for d in to_line.values())
        return False
    memo["at_pass"] = to_line
    memo["cross_light"] = {r: int(world.lane_signal[lane]) for r, lane in memo["lanes"].items()}
    return True


def check_invading(world, memo) -> bool:
    """An oncoming vehicle alongside the ego intrudes into the ego's lane by ``invasion`` m."""
    sc, t = world.scenarios[0], world.table
    ix = world.town.index
    e = sc.site.lanes[0]
    for r in _active(world, sc.hazard_rows):
        rel = world_to_local_2d(t.pos[r], t.pos[0], float(t.yaw[0]))
        if abs(rel[0]) > 0.5 * (t.length[r] + t.length[0]) or rel[1] < 0.0:
            continue
        _, s, _ = ix.project(t.pos[r][None], np.array([e]))
        p, h = ix.pose_at(np.array([e]), s)
        lat = float(world_to_local_2d(t.pos[r], p[0], h[0])[1])  # left of the ego lane centre
        memo["intrusion"] = float(ix.width[e] / 2 - (lat - t.width[r] / 2))
        return True
    return False


def check_emergency(world, memo) -> bool:
    """The emergency vehicle catches up and sits right behind the ego in its lane; the failure is
    reported (once) when the ego does not yield."""
    sc, t = world.scenarios[0], world.table
    r = sc.emergency_rows[0]
    if t.active[r]:
        rel = world_to_local_2d(t.pos[0], t.pos[r], float(t.yaw[r]))
        gap = rel[0] - 0.5 * (t.length[0] + t.length[r])
        if 0.0 < gap < 15.0 and abs(rel[1]) < 1.0:
            memo["close_behind"] = memo.get("close_behind", 0) + 1
    n = int(world.monitor.counts[YIELD_EMERGENCY])
    if n and "first" not in memo:
        memo["first"] = world.tick
    return n > 0 and world.tick - memo["first"] >= 30


# ----------------------------------------------------------------------------- tests
FLOW_CASES = [  # (scenario, town, seed, max_ticks): quick seeds; see robustness() for sweeps
    ("EnterActorFlow", "Town06", 1, 320),
    (
        "EnterActorFlowV2",
        "Town06",
        0,
        250,
    ),  # junction variant (the ramp one: MergerIntoSlowTraffic)
    ("MergerIntoSlowTraffic", "Town04", 0, 350),  # on-ramp variant
    ("MergerIntoSlowTrafficV2", "Town06", 0, 300),
    ("InterurbanActorFlow", "Town05", 4, 250),
    ("InterurbanAdvancedActorFlow", "Town06", 0, 300),
    ("SignalizedJunctionLeftTurn", "Town05", 2, 250),
    ("SignalizedJunctionRightTurn", "Town05", 2, 250),
    ("HighwayExit", "Town04", 0, 250),
]


@pytest.mark.parametrize("name,town,seed,max_ticks", FLOW_CASES)
def test_flow_passes_conflict_as_ego_arrives(name, town, seed, max_ticks):
    world, memo = watch(name, seed, town, check_flow, max_ticks)
    assert memo.get("flows_ok"), "a flow's conflict point is not on the ego's route"
    assert world is not None, (
        f"{name}: flows passed {memo.get('passed')} of the conflict points near arrival"
    )
    sc = world.scenarios[0]
    assert sc.triggered and get_scenario(name).family in ("flow", "junction", "highway")
    assert len(sc.hazard_rows) == len(set(sc.hazard_rows)) >= len(sc.flows)


def test_highway_cut_in_ends_ahead_in_ego_lane(monkeypatch):
    monkeypatch.setattr(
        route_follower, "CRUISE_SPEED", 20.0
    )  # highway speed for the route follower
    world, memo = watch("HighwayCutIn", 0, "Town04", check_cut_in, 420)
    assert world is not None, f"no cut-in seen: {memo}"


def test_red_light_runner_enters_on_red_while_ego_green():
    world, memo = watch("OppositeVehicleRunningRedLight", 3, "Town03", check_red_light_runner, 350)
    assert world is not None, f"runner never crossed the ego's path near the ego: {memo}"
    assert memo["entry"] == (RED, GREEN)
    assert world.table.ignore_rules[world.scenarios[0].hazard_rows[0]]


def test_opposite_vehicle_takes_priority_without_stopping():
    world, memo = watch("OppositeVehicleTakingPriority", 0, "Town01", check_taking_priority, 250)
    assert world is not None, f"adversary never crossed the ego's path near the ego: {memo}"
    assert memo["must_yield"]  # it came from a stop / minor lane
    assert memo.get("min_v", np.inf) > 3.0  # ... and did not stop there


def test_priority_at_junction_forces_the_ego_green_and_crossers_stop_at_red():
    """CARLA's PriorityAtJunction: from the trigger on the ego's light is green at a signalized
    junction, the crossing vehicles arrive as the ego does and stop at their red line; the
    override ends once the ego has passed."""
    world, memo = watch("PriorityAtJunction", 0, "Town01", check_priority, 600)
    assert world is not None
    sc = world.scenarios[0]
    j = world.town.junctions[world.town.index.junction_ahead[sc.site.lanes[0]]]
    assert j.control == SIGNAL
    assert memo["ego_light"] == {GREEN}  # green all the way from the trigger to the junction
    assert len(memo["lanes"]) >= 1 and set(memo["cross_light"].values()) <= {RED, YELLOW}
    assert memo["violations"] == 0  # none crossed its line before the ego passed
    assert all(0.0 <= d < 10.0 for d in memo["at_pass"].values()), memo["at_pass"]
    for _ in range(80):  # the plan runs on once the ego is through
        world.step(np.zeros(3))
        if not sc.forced:
            break
    assert not sc.forced and world.signals._forced is None


def test_invading_turn_intrudes_into_ego_lane():
    world, memo = watch("InvadingTurn", 0, "Town06", check_invading, 200)
    assert world is not None
    sc = world.scenarios[0]
    assert memo["intrusion"] >= float(sc.params["invasion"]) - 0.15
    cones = sc.rows[3:]  # they narrow the oncoming lane, on its far side from the ego
    assert len(cones) >= 3 and np.all(world.table.kind[cones] == TRAFFIC_CONE)
    d_cones = np.linalg.norm(world.table.pos[cones] - world.table.pos[0], axis=1)
    assert d_cones.min() < 30.0


def test_emergency_vehicle_stuck_behind_reports_once():
    world, memo = watch(
        "YieldToEmergencyVehicle", 0, "Town12", check_emergency, 340, stop_after_pass=8.0
    )
    assert world is not None, f"no YIELD_EMERGENCY: {memo}"
    sc = world.scenarios[0]
    assert sc.emergency_rows == sc.hazard_rows and len(sc.emergency_rows) == 1
    assert memo["close_behind"] * world.config.dt >= float(sc.params["stuck_time"])
    assert int(world.monitor.counts[YIELD_EMERGENCY]) == 1


class _LaneShiftDriver(route_follower.RouteFollower):
    """The route follower, driving ``shift`` m to the left of its route once told to (yields)."""

    shift = 0.0

    def act(self, obs: dict) -> np.ndarray:
        if self.shift:
            route = obs["route"].copy()
            route[:, 1] += self.shift
            obs = {**obs, "route": route}
        return super().act(obs)


def test_emergency_vehicle_passes_an_ego_that_yields():
    driver = _LaneShiftDriver()

    def passed(world, memo) -> bool:
        sc, t = world.scenarios[0], world.table
        if sc.triggered and not driver.shift:
            ln = world.town.lanes[sc.site.lanes[0]]
            driver.shift = ln.width if ln.left >= 0 else -ln.width  # move to the neighbour lane
        r = sc.emergency_rows[0]
        ahead = world_to_local_2d(t.pos[r], t.pos[0], float(t.yaw[0]))[0]
        return bool(t.active[r]) and ahead > 0.5 * (t.length[0] + t.length[r]) + 2.0

    world, _ = watch("YieldToEmergencyVehicle", 0, "Town12", passed, 300, driver=driver)
    assert world is not None, "the emergency vehicle never got past the ego"
    assert int(world.monitor.counts[YIELD_EMERGENCY]) == 0


def test_sites_rebuild_from_route_file_fields():
    """Route files keep only lanes, key and s_on_key: the scenarios find their flows again."""
    from v2xbench.envs.v2x_intersection.scenarios.base import Site
    from v2xbench.envs.v2x_intersection.town import get_town

    town = get_town("Town12")
    for name in ("InterurbanAdvancedActorFlow", "OppositeVehicleTakingPriority", "HighwayCutIn"):
        cls = get_scenario(name)
        site = cls.find_sites(town)[0]
        bare = Site(site.lanes, site.key, site.s_on_key)
        sc = cls.__new__(cls)
        sc.site = bare
        assert flows.resolve_extra(sc, town) == site.extra


# ----------------------------------------------------------------------------- seed sweep
CHECKS = {
    **{c[0]: check_flow for c in FLOW_CASES},
    "HighwayCutIn": check_cut_in,
    "OppositeVehicleRunningRedLight": check_red_light_runner,
    "OppositeVehicleTakingPriority": check_taking_priority,
    "PriorityAtJunction": check_priority,
    "InvadingTurn": check_invading,
    "YieldToEmergencyVehicle": check_emergency,
}


def robustness(names=None, seeds=range(5), towns=(None, "Town12"), max_ticks: int = 1500) -> dict:
    """Pass rate of each scenario's check over ``seeds`` in its preferred town and Town12 (not a
    test: ``python -c "from tests.scenarios.test_scenarios_flows import robustness; print(robustness())"``)."""
    out = {}
    default = route_follower.CRUISE_SPEED
    for name in names or CHECKS:
        route_follower.CRUISE_SPEED = 20.0 if name == "HighwayCutIn" else default
        for town in towns:
            ok = 0
            for seed in seeds:
                world, memo = watch(name, seed, town, CHECKS[name], max_ticks, stop_after_pass=8.0)
                ok += world is not None and _extra_ok(name, world, memo)
            out[(name, town or get_scenario(name).towns[0])] = ok / len(seeds)
    route_follower.CRUISE_SPEED = default
    return out


def _extra_ok(name: str, world, memo) -> bool:
    if name == "OppositeVehicleRunningRedLight":
        return memo.get("entry") == (RED, GREEN)
    if name == "OppositeVehicleTakingPriority":
        return memo.get("must_yield", False) and memo.get("min_v", np.inf) > 3.0
    if name == "PriorityAtJunction":
        return memo["violations"] == 0 and all(0.0 <= d < 10.0 for d in memo["at_pass"].values())
    if name == "InvadingTurn":
        return memo["intrusion"] >= float(world.scenarios[0].params["invasion"]) - 0.15
    return True


def test_flow_vehicle_steers_around_an_ego_standing_in_its_lane():
    """A flow vehicle held up by the ego for longer than ``DODGE_AFTER_S`` eases sideways around
    it (``Flow._dodge``), passes, and forgets the dodge once the ego is behind it."""
    from v2xbench.envs.v2x_intersection.scenarios import build_episode
    from v2xbench.envs.v2x_intersection.scenarios.flows import DODGE_AFTER_S
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.town import get_town

    world = World(make_config(town="Town05", num_vehicles=0, num_parked=0, num_pedestrians=0, num_bicycles=0))
    route, scenarios = build_episode("InterurbanActorFlow", get_town("Town05"), np.random.default_rng(4))
    world.reset(seed=4, route=route, scenarios=scenarios)
    flow = scenarios[0].flows[0]
    t = world.table
    path_s = flow.path_s(t)
    k = int(np.nanargmin(path_s))  # the vehicle nearest the source: the most path ahead of it
    r = int(flow.rows[k])
    assert path_s[k] + 15.0 < flow.end_s - 10.0, "no room ahead of a flow vehicle on its path"
    p, h = flow.point(world.town, float(path_s[k]) + 15.0)  # the ego stands 15 m ahead of it
    brake = np.array([0.0, 0.0, 1.0])
    dodged, max_lat = None, 0.0
    for tick in range(300):
        t.pos[0], t.yaw[0], t.speed[0] = p, h, 0.0  # the ego stands in the lane
        world.step(brake)
        if r in flow.dodge and dodged is None:
            dodged = tick
        max_lat = max(max_lat, abs(float(t.lat[r])))
        if dodged is not None and r not in flow.dodge:
            break
    assert dodged is not None, "the held-up vehicle never started to steer around the ego"
    assert dodged * world.config.dt >= DODGE_AFTER_S  # it waited first
    assert max_lat > 1.0  # it moved sideways
    rel = world_to_local_2d(t.pos[0], t.pos[r], float(t.yaw[r]))
    assert r not in flow.dodge and rel[0] < 0.0, "it did not get past the ego"
