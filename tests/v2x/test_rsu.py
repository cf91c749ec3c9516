"""Tests of route-adaptive RSU deployment and active-unit selection."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.geometry import (
    transform_points,
    world_to_local_2d,
    wrap_angle,
)
from v2xbench.envs.v2x_intersection.perception.jit_perception import SELECT_M_PER_RAD
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.routes import random_route
from v2xbench.envs.v2x_intersection.v2x import rsu as rsu_module
from v2xbench.envs.v2x_intersection.v2x.rsu import (
    KIND_JUNCTION,
    KIND_STRAIGHT,
    MIN_SPACING,
    RSU_HEIGHT,
    RSU_PITCH,
    SIDE_OFFSET,
    STRAIGHT_SPACING,
    RSUSet,
    deploy,
    select_active,
)

CASES = [("Town01", 0), ("Town01", 3), ("Town12", 3), ("Town03", 2), ("Town02", 4)]
AHEAD = 30.0  # m: a straight unit stands this far along the route from the point it serves
SNAP = getattr(rsu_module, "SNAP_M", 0.0)  # m: poles may move this far, onto the nearest sidewalk


@pytest.fixture(scope="module")
def deployments():
    out = {}
    for name, seed in CASES:
        town = get_town(name)
        route = random_route(town, np.random.default_rng(seed), 500.0)
        out[(name, seed)] = (town, route, deploy(town, route))
    return out


def _test50_route(route_id: str):
    """``(town, route)`` of a test50 route, by id."""
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached
    from v2xbench.envs.v2x_intersection.town.routes import route_from_lanes

    spec = next(s for s in load_suite_cached("test50") if s.id == route_id)
    town = get_town(spec.town)
    return town, route_from_lanes(town, list(spec.lanes))


def _entry_headings(town, route, jid: int) -> list[float]:
    """Heading of the route just before each of its entries into junction ``jid``."""
    inside = town.index.junction[route.lane_ids] == jid
    starts = np.flatnonzero(inside & ~np.concatenate([[False], inside[:-1]]))
    return [float(route.headings[max(e - 1, 0)]) for e in starts]


@pytest.mark.parametrize("case", CASES, ids=[f"{n}-{s}" for n, s in CASES])
def test_unit_at_every_junction_the_route_crosses(deployments, case):
    town, route, rsus = deployments[case]
    jl = town.index.junction[route.lane_ids]
    crossed = np.unique(jl[jl >= 0])
    assert len(crossed) >= 1
    units = np.flatnonzero(rsus.kind == KIND_JUNCTION)
    # one unit per pass through a junction, two where the route turns left there (see
    # test_left_turn_unit...); passes of one junction from one approach share theirs
    n_pass = len(rsu_module.junction_passes(town, route))
    assert len(crossed) <= len(units) <= 2 * n_pass
    for jid in crossed:
        j = town.junctions[jid]
        d = np.linalg.norm(rsus.pose[units, :2] - j.center, axis=1)
        u = units[np.argmin(d)]
        # on a corner just outside the conflict area (or on the sidewalk next to it) ...
        assert j.radius < d.min() <= j.radius + 3.0 + SNAP + 1e-6
        # ... looking over the junction
        to_centre = np.arctan2(*(j.center - rsus.pose[u, :2])[::-1])
        assert abs(float(wrap_angle(rsus.pose[u, 3] - to_centre))) < np.deg2rad(45.0)


@pytest.mark.parametrize("case", CASES, ids=[f"{n}-{s}" for n, s in CASES])
def test_junction_unit_on_the_far_right_corner(deployments, case):
    town, route, rsus = deployments[case]
    jl = town.index.junction[route.lane_ids]
    units = np.flatnonzero(rsus.kind == KIND_JUNCTION)
    for jid in np.unique(jl[jl >= 0]):
        j = town.junctions[jid]
        d = np.linalg.norm(rsus.pose[units, :2] - j.center, axis=1)
        mine = units[d <= j.radius + 3.0 + SNAP + 1e-6]
        # far-right corner as seen when arriving (on one of the route's visits of the junction)
        corners = [
            world_to_local_2d(rsus.pose[u, :2], j.center, h)
            for u in mine for h in _entry_headings(town, route, jid)
        ]
        assert any(x > 0.0 and y < 0.0 for x, y in corners), f"junction {jid}: unit at {corners}"


@pytest.mark.parametrize("case", CASES, ids=[f"{n}-{s}" for n, s in CASES])
def test_units_cover_the_straights(deployments, case):
    town, route, rsus = deployments[case]
    assert np.any(rsus.kind == KIND_STRAIGHT)
    # every candidate spot (every STRAIGHT_SPACING m) has a unit nearby: its own (AHEAD m further,
    # SIDE_OFFSET to the side), the junction it lies in, or the unit that pruned it
    reach = AHEAD + SIDE_OFFSET + MIN_SPACING
    for sk in np.arange(STRAIGHT_SPACING / 2, route.length, STRAIGHT_SPACING):
        k = min(int(np.searchsorted(route.s, sk)), len(route.s) - 1)
        d = np.linalg.norm(rsus.pose[:, :2] - route.points[k], axis=1).min()
        assert d <= reach + 1.0, f"no unit within {reach} m of route s={sk}"
    # and whatever the ego's position, the next unit is never much more than one spacing away
    d_all = np.linalg.norm(route.points[:, None] - rsus.pose[None, :, :2], axis=2).min(1)
    assert d_all.max() < STRAIGHT_SPACING + 2 * SIDE_OFFSET + 2.0


@pytest.mark.parametrize("case", CASES, ids=[f"{n}-{s}" for n, s in CASES])
def test_straight_units_stand_beside_the_route_looking_back(deployments, case):
    town, route, rsus = deployments[case]
    for u in np.flatnonzero(rsus.kind == KIND_STRAIGHT):
        # route_s is the route point at (just after) a candidate spot STRAIGHT_SPACING / 2 + k * spacing
        sk = STRAIGHT_SPACING / 2 + STRAIGHT_SPACING * np.floor(
            (rsus.route_s[u] - STRAIGHT_SPACING / 2) / STRAIGHT_SPACING
        )
        assert 0.0 <= rsus.route_s[u] - sk < 1.5
        k0 = min(int(np.searchsorted(route.s, sk)), len(route.s) - 1)
        k = min(int(np.searchsorted(route.s, sk + AHEAD)), len(route.s) - 1)
        setback = rsu_module.JUNCTION_SETBACK_M
        reach = min(int(np.searchsorted(route.s, sk + AHEAD + setback)), len(route.s) - 1)
        entry = np.flatnonzero(town.index.junction[route.lane_ids[k0 : reach + 1]] >= 0)
        if len(entry):  # a junction first: the unit stands just before it, on the same road
            k = max(int(np.searchsorted(route.s, route.s[k0 + entry[0]] - setback)), k0)
        h = route.headings[k]
        spot = route.points[k] + SIDE_OFFSET * np.array([np.sin(h), -np.cos(h)])  # to the right
        assert np.linalg.norm(rsus.pose[u, :2] - spot) <= SNAP + 1e-6
        x, y = world_to_local_2d(rsus.pose[u, :2], route.points[k], h)
        assert y < -2.0  # on the right-hand side of the route
        # looking back along the road (toward the approaching ego), slightly across it
        assert abs(float(wrap_angle(rsus.pose[u, 3] - (h + np.pi)))) < np.deg2rad(45.0)


@pytest.mark.parametrize("case", CASES, ids=[f"{n}-{s}" for n, s in CASES])
def test_min_spacing_height_and_order(deployments, case):
    town, route, rsus = deployments[case]
    assert len(rsus) >= 3
    d = np.linalg.norm(rsus.pose[:, None, :2] - rsus.pose[None, :, :2], axis=2)
    d[np.diag_indices(len(rsus))] = np.inf
    same_kind = rsus.kind[:, None] == rsus.kind[None, :]
    # street and junction units may stand closer, and so may a junction's two units of a left turn
    # (placed for the same route station, 1 mm apart)
    same_junction = np.abs(rsus.route_s[:, None] - rsus.route_s[None, :]) < 0.01
    # (the random routes here cross each junction once: see test_every_pass_... for two passes)
    assert d[same_kind & ~same_junction].min() >= MIN_SPACING
    np.testing.assert_array_equal(rsus.pose[:, 2], RSU_HEIGHT)
    assert np.all(np.diff(rsus.route_s) >= 0.0)
    assert rsus.pose.shape == (len(rsus), 4) and rsus.kind.shape == rsus.route_s.shape == (
        len(rsus),
    )


def test_every_pass_through_a_junction_gets_its_far_right_unit():
    """A route that comes back to a junction from another approach gets the far-right unit of
    that approach too (test50_038 crosses junction 6 twice; placing units per junction id mixed
    the first pass's entry with the second pass's exit and left the second approach unwatched)."""
    town, route = _test50_route("test50_038")
    rsus = deploy(town, route)
    passes = rsu_module.junction_passes(town, route)
    jids = [jid for jid, _ in passes]
    twice = [j for j in set(jids) if jids.count(j) > 1]
    assert twice, "test50_038 should cross a junction twice"
    units = np.flatnonzero(rsus.kind == KIND_JUNCTION)
    for jid, p in passes:
        j = town.junctions[jid]
        h_in = float(route.headings[max(int(p[0]) - 1, 0)])
        corners = [world_to_local_2d(rsus.pose[u, :2], j.center, h_in) for u in units
                   if np.linalg.norm(rsus.pose[u, :2] - j.center) <= j.radius + 3.0 + SNAP + 1e-6]
        # a unit on the far-right corner of this pass's approach, looking back at it
        far_right = [(x, y) for x, y in corners if x > 0.0 and y < 0.0]
        assert far_right, f"junction {jid}, pass at s={route.s[p[0]]:.0f}: units at {corners}"
    # and the passes are unbroken runs inside one junction, in route order
    jl = town.index.junction[route.lane_ids]
    assert sum(len(p) for _, p in passes) == int(np.sum(jl >= 0))
    for jid, p in passes:
        assert np.all(np.diff(p) == 1) and set(jl[p]) == {jid}


@pytest.mark.parametrize("route_id", ["test50_006", "test50_038"])
def test_a_route_back_along_a_street_keeps_units_looking_both_ways(route_id):
    """Where a route comes back along a street it drove (test50_006, test50_038), every street
    spot has a street unit near it looking back at the ego as it drives there, not only the unit
    of the first pass, which looks the other way."""
    town, route = _test50_route(route_id)
    rsus = deploy(town, route)
    in_junction = town.index.junction[route.lane_ids] >= 0
    street = np.flatnonzero(rsus.kind == KIND_STRAIGHT)
    reach = AHEAD + SIDE_OFFSET + MIN_SPACING
    for sk in np.arange(STRAIGHT_SPACING / 2, route.length, STRAIGHT_SPACING):
        k = min(int(np.searchsorted(route.s, sk)), len(route.s) - 1)
        if in_junction[k]:
            continue
        d = np.linalg.norm(rsus.pose[street, :2] - route.points[k], axis=1)
        back = np.abs(wrap_angle(rsus.pose[street, 3] - (route.headings[k] + np.pi)))
        assert np.any((d <= reach + 1.0) & (back < np.deg2rad(60.0))), (
            f"{route_id}: no street unit looking back at s={sk:.0f} m")


def test_rsu_matrix_is_pitched_down():
    rsus = RSUSet(
        np.array([[10.0, 20.0, RSU_HEIGHT, 0.5]]), np.array([KIND_STRAIGHT]), np.array([0.0])
    )
    t = rsus.matrix(0)
    np.testing.assert_allclose(t[:3, 3], [10.0, 20.0, RSU_HEIGHT])
    axis = transform_points(t, np.array([1.0, 0.0, 0.0])) - t[:3, 3]
    assert axis[2] == pytest.approx(-np.sin(RSU_PITCH), abs=1e-9)
    assert np.arctan2(axis[1], axis[0]) == pytest.approx(0.5, abs=0.02)


def test_poses_do_not_depend_on_the_scenarios():
    """Roadside units are infrastructure: a world with the route's scenarios deploys exactly the
    units of the same route without them, on test50 routes with V2X-type scenarios."""
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.suites.route_files import (
        build_episode_from_spec,
        load_suite,
    )

    episodes = [build_episode_from_spec(spec) + (spec,) for spec in load_suite("test50")[1]]
    v2x = [e for e in episodes if any(sc.v2x for sc in e[1])][:3]
    assert v2x, "test50 has V2X-type routes"
    for route, scenarios, spec in v2x:
        town = get_town(spec.town)
        world = World(make_config(town=spec.town, num_vehicles=4, num_pedestrians=2))
        world.reset(seed=0, route=route, scenarios=scenarios)
        with_sc = world.rsus.pose.copy()
        world.reset(seed=0, route=route, scenarios=[])
        assert np.array_equal(with_sc, world.rsus.pose)
        assert np.array_equal(with_sc, rsu_module._deploy(town, route).pose)


# ------------------------------------------------------------------------------ select_active


def _units(rows) -> RSUSet:
    pose = np.array([[x, y, RSU_HEIGHT, yaw] for x, y, yaw in rows], float)
    return RSUSet(pose, np.zeros(len(rows), np.int64), np.zeros(len(rows)))


def test_select_active_hand_cases():
    rsus = _units(
        [
            (50.0, -9.0, np.pi),  # 0: ahead, facing the ego
            (30.0, -9.0, 0.0),  # 1: ahead and closer, but looking away
            (-40.0, -9.0, 0.0),  # 2: behind, looking at the ego
            (120.0, -9.0, np.pi),  # 3: ahead, facing, further away
            (20.0, 9.0, -2.5),  # 4: ahead on the left, facing the ego diagonally
        ]
    )
    ego, yaw = np.zeros(2), 0.0
    assert select_active(rsus, ego, yaw, 75.0).tolist() == [4]
    np.testing.assert_array_equal(select_active(rsus, ego, yaw, 75.0, slots=3), [4, 0, -1])
    # unit 3 looks most directly at the road 12 m ahead of the ego (4.8 deg off its axis, unit 4:
    # 11.6 deg, unit 0: 13.3 deg) but stands 108 m from it (unit 4: 12 m, unit 0: 39 m)
    np.testing.assert_array_equal(select_active(rsus, ego, yaw, 200.0, slots=3), [4, 0, 3])
    # ego driving the other way: only unit 2 (now ahead, looking +x at the ego) qualifies
    np.testing.assert_array_equal(select_active(rsus, ego, np.pi, 200.0, slots=2), [2, -1])
    # a unit up to 10 m behind still counts
    near_behind = _units([(-8.0, -9.0, np.pi / 2)])
    assert select_active(near_behind, ego, yaw, 75.0).tolist() == [0]


def test_select_active_falls_back_to_the_nearest():
    rsus = _units([(30.0, 0.0, 0.0), (-60.0, 0.0, 0.0)])  # neither faces the ego
    np.testing.assert_array_equal(select_active(rsus, np.zeros(2), 0.0, 75.0, slots=2), [0, -1])
    empty = RSUSet(np.zeros((0, 4)), np.zeros(0, np.int64), np.zeros(0))
    np.testing.assert_array_equal(select_active(empty, np.zeros(2), 0.0, 75.0, slots=2), [-1, -1])


@pytest.mark.parametrize("case", CASES, ids=[f"{n}-{s}" for n, s in CASES])
def test_select_active_along_a_route(deployments, case):
    town, route, rsus = deployments[case]
    n_ok = 0
    steps = range(0, len(route.points), 25)
    for k in steps:
        ego, yaw = route.points[k], route.headings[k]
        u = int(select_active(rsus, ego, yaw, 75.0)[0])
        d = rsus.pose[:, :2] - ego
        dist = np.linalg.norm(d, axis=1)
        ahead = d @ np.array([np.cos(yaw), np.sin(yaw)]) > -10.0
        facing = np.abs(wrap_angle(np.arctan2(-d[:, 1], -d[:, 0]) - rsus.pose[:, 3])) < np.deg2rad(
            100.0
        )
        ok = ahead & facing & (dist < 75.0)
        look = ego + rsu_module.LOOKAHEAD_M * np.array([np.cos(yaw), np.sin(yaw)]) - rsus.pose[:, :2]
        d_look = np.linalg.norm(look, axis=1)
        off = np.abs(wrap_angle(np.arctan2(look[:, 1], look[:, 0]) - rsus.pose[:, 3]))
        sees = ok & (d_look < 75.0) & (off < rsu_module.VIEW_HALF_ANGLE)
        if ok.any():
            n_ok += 1
            assert ok[u], "the active unit must be ahead of the ego and facing it"
            if sees.any():  # a unit watching the road ahead: the one looking most directly at it
                key = off + d_look / SELECT_M_PER_RAD  # (unless it stands much farther away)
                assert sees[u] and key[u] == pytest.approx(key[sees].min())
            else:
                assert dist[u] == dist[ok].min()  # else the nearest forward-facing unit
        else:
            assert u == int(np.argmin(dist))  # fallback: the nearest unit
    # route-adaptive deployment: most of the time a forward-facing unit is in range
    assert n_ok >= 0.7 * len(steps)


def test_left_turn_gets_a_unit_watching_the_oncoming_approach():
    """Where the route turns left through a junction, a second unit stands on the near-right
    corner looking across the centre; it holds the oncoming lanes 20-40 m out in its view and is
    the active unit while the ego waits at the stop line (the far-right unit has them behind)."""
    from v2xbench.envs.v2x_intersection.town.model import LEFT
    from v2xbench.envs.v2x_intersection.town.routes import route_from_lanes

    town = get_town("Town01")
    ix = town.index
    lefts = [lane for lane in range(len(town.lanes))
             if town.lanes[lane].turn == LEFT and town.lanes[lane].predecessors]
    assert lefts
    conn = lefts[0]
    before = town.lanes[conn].predecessors[0]
    after = town.lanes[conn].successors[0]
    route = route_from_lanes(town, [before, conn, after])
    rsus = deploy(town, route)
    j = town.junctions[ix.junction[conn]]
    units = np.flatnonzero((rsus.kind == KIND_JUNCTION)
                           & (np.linalg.norm(rsus.pose[:, :2] - j.center, axis=1) < j.radius + 12))
    assert len(units) == 2
    h_in = float(route.headings[int(np.flatnonzero(ix.junction[route.lane_ids] >= 0)[0]) - 1])
    local = np.array([world_to_local_2d(rsus.pose[u, :2], j.center, h_in) for u in units])
    near = units[int(np.argmin(local[:, 0]))]
    assert local.min(0)[0] < 0.0 and np.all(local[:, 1] < 0.0)  # near-right and far-right
    # the oncoming lanes (ahead of the centre, left of the ego's axis) are in its view
    fwd, left = np.array([np.cos(h_in), np.sin(h_in)]), np.array([-np.sin(h_in), np.cos(h_in)])
    for d in (20.0, 30.0, 40.0):
        p = j.center + d * fwd + 2.0 * left - rsus.pose[near, :2]
        off = wrap_angle(np.arctan2(p[1], p[0]) - rsus.pose[near, 3])
        assert abs(float(off)) < rsu_module.VIEW_HALF_ANGLE, d
    # at the stop line the active unit is that one
    k = int(np.flatnonzero(ix.junction[route.lane_ids] >= 0)[0]) - 3
    assert int(select_active(rsus, route.points[k], float(route.headings[k]), 75.0)[0]) == near


def test_deployment_is_remembered_per_route_and_read_only():
    town = get_town("Town02")
    route = random_route(town, np.random.default_rng(7), 400.0)
    first = deploy(town, route)
    assert deploy(town, route) is first  # a replayed route reuses the placement
    fresh = rsu_module._deploy(town, route)
    for name in ("pose", "kind", "route_s"):
        assert np.array_equal(getattr(first, name), getattr(fresh, name))
        with pytest.raises(ValueError):
            getattr(first, name)[0] = 0
    other = random_route(town, np.random.default_rng(8), 400.0)
    assert deploy(town, other) is not first  # another route, another placement


@pytest.mark.parametrize("town_name", ["Town01", "Town03", "Town12"])
def test_sidewalk_snap_same_on_both_paths(monkeypatch, town_name):
    """A pole's snap onto the sidewalk (``rsu._on_sidewalk``): the one-pass kernel gives the NumPy
    path's pose, for candidates near sidewalks and beyond the snap distance."""
    rsu = rsu_module
    town = get_town(town_name)
    pts = rsu._sidewalk_index(town).points
    rng = np.random.default_rng(0)
    moved = 0
    for _ in range(300):
        x, y = pts[rng.integers(len(pts))] + rng.uniform(-12, 12, 2)
        cand = (float(x), float(y), float(rng.uniform(-np.pi, np.pi)), 1, 10.0)
        got = rsu._on_sidewalk(town, cand)
        with monkeypatch.context() as m:
            m.setattr(rsu, "HAVE_JIT", False)
            assert rsu._on_sidewalk(town, cand) == got
        moved += got != cand
    assert 0 < moved < 300
