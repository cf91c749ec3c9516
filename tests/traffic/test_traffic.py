"""Tests of NPC traffic and pedestrians, run inside small worlds (``world.World``)."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.actors import DRIVER, WALKER, ActorTable
from v2xbench.envs.v2x_intersection.core.geometry import box_corners_2d
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town.model import CONNECTOR, DRIVING, PARKING, SIGNAL, STOP
from v2xbench.envs.v2x_intersection.traffic.signals import GREEN, RED
from v2xbench.envs.v2x_intersection.traffic.vehicles import (
    BLOCKED_RESPAWN_S,
    STOP_LINE_SETBACK,
    STUCK_RESPAWN_S,
    leaders,
    place_on_lane,
)

BRAKE = np.array([0.0, 0.0, 1.0])  # the ego stands still at its route start


def overlap_depths(corners: np.ndarray) -> np.ndarray:
    """Separating-axis penetration depth (m) for every pair of boxes ``(N, 4, 2)``; <= 0: apart."""
    n = len(corners)
    edges = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 1]], 1)  # (N, 2, 2)
    axes = np.stack([-edges[..., 1], edges[..., 0]], -1)
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    depth = np.full((n, n), np.inf)
    for owner in range(2):  # axes of box a, then of box b
        ax = axes[:, None] if owner == 0 else axes[None, :]  # (N|1, N|1, 2, 2)
        ax = np.broadcast_to(ax, (n, n, 2, 2))
        pa = np.einsum("ikd,ijad->ijak", corners, ax)  # projections of box i on the axes
        pb = np.einsum("jkd,ijad->ijak", corners, ax)
        d = np.minimum(pa.max(-1), pb.max(-1)) - np.maximum(pa.min(-1), pb.min(-1))
        depth = np.minimum(depth, d.min(-1))
    return depth


def test_overlap_helper_hand_cases():
    c = box_corners_2d(
        np.array([[0.0, 0.0], [3.0, 0.0], [10.0, 0.0], [0.0, 2.5]]),
        np.full(4, 4.0),
        np.full(4, 2.0),
        np.array([0.0, 0.0, 0.3, np.pi / 2]),
    )
    d = overlap_depths(c)
    assert d[0, 1] == pytest.approx(1.0)  # 4 m boxes 3 m apart overlap by 1 m
    assert d[0, 2] < 0.0
    assert d[0, 3] == pytest.approx(0.5)  # crossed boxes: 1 m half width + 2 m half length - 2.5


# ------------------------------------------------------------------------------ NPC vehicles


@pytest.fixture(scope="module")
def npc_run():
    """Town01, 20 NPC vehicles, 300 ticks; per-tick measurements."""
    w = World(
        make_config(town="Town01", num_vehicles=20, num_parked=0, num_pedestrians=0, num_bicycles=0)
    )
    w.reset(seed=0)
    t, ix = w.table, w.town.index
    driving = np.array([ln.id for ln in w.town.lanes if ln.kind != PARKING])
    rec = {
        "overlaps": 0,
        "ego_overlaps": 0,
        "max_off_lane": 0.0,
        "max_off_centre": 0.0,
        "max_pose_err": 0.0,
        "lane_changes": 0,
        "moved": np.zeros(len(t)),
        "ticks": 0,
        "drivers": 0,
        "min_speed": np.inf,
    }
    start = t.pos.copy()
    for tick in range(300):
        w.step(BRAKE)
        idx = np.flatnonzero(t.active & (t.behaviour == DRIVER))
        rec["drivers"] = max(rec["drivers"], len(idx))
        rec["min_speed"] = min(rec["min_speed"], float(t.speed[idx].min()))
        rows = np.concatenate([[0], idx])
        c = box_corners_2d(t.pos[rows], t.length[rows], t.width[rows], t.yaw[rows])
        d = overlap_depths(c)
        iu = np.triu_indices(len(rows), 1)
        hit = d[iu] > 0.05
        rec["overlaps"] += int(np.sum(hit & (iu[0] > 0)))
        rec["ego_overlaps"] += int(np.sum(hit & (iu[0] == 0)))
        # position agrees with (lane, s, lat), and the car is on a lane of the road network
        p, h = ix.pose_at(t.lane[idx], t.s[idx])
        normal = np.stack([-np.sin(h), np.cos(h)], -1)
        err = np.linalg.norm(t.pos[idx] - (p + t.lat[idx, None] * normal), axis=1)
        rec["max_pose_err"] = max(rec["max_pose_err"], float(err.max()))
        centred = np.abs(t.lat[idx]) < 1e-9
        rec["lane_changes"] += int(np.sum(~centred))
        off = np.linalg.norm(t.pos[idx] - p, axis=1)
        if np.any(centred):
            rec["max_off_centre"] = max(rec["max_off_centre"], float(off[centred].max()))
        if tick % 10 == 0:  # an independent check on the road network (project is slow)
            _, _, dist = ix.project(t.pos[idx], driving)
            rec["max_off_lane"] = max(rec["max_off_lane"], float(dist.max()))
        rec["ticks"] += 1
    rec["moved"] = np.linalg.norm(t.pos - start, axis=1)
    rec["world"] = w
    return rec


def test_npcs_are_spawned_and_move(npc_run):
    assert npc_run["ticks"] == 300
    assert npc_run["drivers"] == 20
    w = npc_run["world"]
    moved = npc_run["moved"][1:][w.table.behaviour[1:] == DRIVER]
    assert np.sum(moved > 20.0) >= 15  # most of them drove somewhere in 30 s
    assert npc_run["min_speed"] >= 0.0  # never reverse


def test_npcs_stay_on_lanes(npc_run):
    assert npc_run["max_pose_err"] < 1e-6
    assert npc_run["max_off_centre"] < 1e-6  # exactly on the centre line outside lane changes
    assert npc_run["max_off_lane"] < 2.0  # also during lane changes (between two lanes)


def test_npcs_do_not_overlap(npc_run):
    # measured: no NPC-NPC overlap deeper than 5 cm in 300 ticks x 190 pairs
    assert npc_run["overlaps"] == 0
    assert npc_run["ego_overlaps"] == 0  # and none drives into the standing ego


def _single_npc_world(seed: int = 0) -> World:
    w = World(
        make_config(town="Town01", num_vehicles=1, num_parked=0, num_pedestrians=0, num_bicycles=0)
    )
    w.reset(seed=seed)
    return w


def _far_lane(w: World, control: int, min_len: float = 60.0) -> int:
    town, ego = w.town, w.table.pos[0]
    for ln in town.lanes:
        if (
            ln.kind == DRIVING
            and ln.stop_at_end
            and ln.length > min_len
            and town.junctions[ln.junction_ahead].control == control
            and np.linalg.norm(ln.points - ego, axis=1).min() > 60.0
        ):
            return ln.id
    raise AssertionError("no suitable lane")


def _force_signals(w: World, state: int) -> None:
    orig = w.signals.lane_states

    def forced(time_s: float) -> np.ndarray:
        out = orig(time_s)
        out[w.signals.lanes] = state
        return out

    w.signals.lane_states = forced


def test_npc_stops_before_the_stop_line_at_red():
    w = _single_npc_world()
    t, town = w.table, w.town
    lane = _far_lane(w, SIGNAL)
    _force_signals(w, RED)
    place_on_lane(t, town, 1, lane, 10.0)
    t.speed[1] = 10.0
    line = town.index.length[lane] - STOP_LINE_SETBACK
    front = []
    for _ in range(250):
        w.step(BRAKE)
        assert t.lane[1] == lane, "drove into the junction on red"
        front.append(t.s[1] + 0.5 * t.length[1])
    assert t.speed[1] < 0.05
    assert max(front) <= line  # the front bumper never passes the stop line
    assert line - front[-1] < 4.0  # and it stops close to it, not far back
    assert w.lane_signal[lane] == RED


def test_npc_drives_through_on_green():
    w = _single_npc_world()
    t, town = w.table, w.town
    lane = _far_lane(w, SIGNAL)
    _force_signals(w, GREEN)
    place_on_lane(t, town, 1, lane, 10.0)
    t.speed[1] = 10.0
    lanes = set()
    for _ in range(150):
        w.step(BRAKE)
        lanes.add(int(t.lane[1]))
    assert any(town.lanes[x].kind == CONNECTOR for x in lanes)


def test_npc_halts_at_a_stop_sign_then_goes():
    w = _single_npc_world(seed=1)
    t, town = w.table, w.town
    lane = _far_lane(w, STOP, min_len=40.0)
    place_on_lane(t, town, 1, lane, 5.0)
    t.speed[1] = 8.0
    line = town.index.length[lane] - STOP_LINE_SETBACK
    min_v_near_line = np.inf
    for _ in range(300):  # 30 s: less than traffic.STUCK_RESPAWN_S
        w.step(BRAKE)
        if t.lane[1] != lane:
            break
        if line - (t.s[1] + 0.5 * t.length[1]) < 6.0:
            min_v_near_line = min(min_v_near_line, float(t.speed[1]))
    assert min_v_near_line < 0.3  # full stop at the line
    # then it goes on, into one of the junction's connectors (not respawned elsewhere)
    assert int(t.lane[1]) in town.lanes[lane].successors


def test_npc_blocked_by_a_static_obstacle_is_respawned_soon():
    """NPCs do not drive around obstacles: one queued behind a standing box (a scenario's cone,
    debris, broken-down car) is respawned after BLOCKED_RESPAWN_S, not STUCK_RESPAWN_S."""
    from v2xbench.envs.v2x_intersection.core.classes import TRAFFIC_CONE
    from v2xbench.envs.v2x_intersection.scenarios.placement import spawn_static

    w = World(
        make_config(town="Town01", num_vehicles=2, num_parked=0, num_pedestrians=0, num_bicycles=0)
    )
    w.reset(seed=0)
    t, town = w.table, w.town
    lane = next(  # a single-lane carriageway: no neighbour lane to change into
        ln.id
        for ln in town.lanes
        if ln.kind == DRIVING
        and ln.length > 60.0
        and ln.left < 0
        and ln.right < 0
        and np.linalg.norm(ln.points - t.pos[0], axis=1).min() > 60.0
    )
    place_on_lane(t, town, 1, lane, 5.0)
    row = 2  # the second NPC becomes a cone in the first one's lane
    p, h = town.index.pose_at(np.array([lane]), np.array([40.0]))
    spawn_static(w, row, TRAFFIC_CONE, p[0], float(h[0]), (0.4, 0.4, 0.7))
    waited, jumped_at = 0.0, None
    for k in range(150):  # 15 s, well under STUCK_RESPAWN_S
        before = t.pos[1].copy()
        w.step(BRAKE)
        if np.linalg.norm(t.pos[1] - before) > 5.0:
            jumped_at = k
            break
        waited += w.config.dt * (t.speed[1] < 0.1)
    assert BLOCKED_RESPAWN_S < 15.0 < STUCK_RESPAWN_S
    assert jumped_at is not None, "the NPC stayed queued behind the cone"
    assert waited == pytest.approx(BLOCKED_RESPAWN_S, abs=0.3)  # it stopped first, then left


def test_leaders_hand_case():
    t = ActorTable.empty(4)
    t.active[:] = True
    t.length[:], t.width[:] = 4.0, 2.0
    t.pos[:] = [[0.0, 0.0], [20.0, 0.5], [10.0, 8.0], [-10.0, 0.0]]  # ahead, beside, behind
    t.speed[:] = [10.0, 4.0, 0.0, 0.0]
    gap, dv, who = leaders(t, np.array([0, 3]))
    assert who.tolist() == [1, 0]
    assert gap[0] == pytest.approx(16.0)  # 20 m centre distance - 4 m of half lengths
    assert dv[0] == pytest.approx(6.0)
    assert gap[1] == pytest.approx(6.0)  # actor 3 sees the ego 10 m ahead
    t.yaw[1] = np.pi  # head-on and moving: another lane, ignored
    gap, _, who = leaders(t, np.array([0]))
    assert np.isinf(gap[0]) and who[0] == -1


@pytest.mark.parametrize("jit", [True, False])
def test_leaders_see_an_actor_across_the_path_by_its_footprint(jit, monkeypatch):
    """A car standing or turning across a follower's path (a junction) is its leader when its box
    reaches into the corridor, though its centre is beside it; one moving 145 deg off the
    follower's heading (a left turn across it) is not taken for oncoming traffic."""
    from v2xbench.envs.v2x_intersection.traffic import vehicles as traffic

    monkeypatch.setattr(traffic, "HAVE_JIT", jit)
    t = ActorTable.empty(2)
    t.active[:] = True
    t.length[:], t.width[:] = 4.7, 1.9
    # the follower drives along +x at 10 m/s; the other stands 20 m ahead, 2.6 m to the side,
    # turned 138 deg: its centre is outside the 2.3 m half corridor, its nose is in it
    t.pos[:] = [[0.0, 0.0], [20.0, 2.6]]
    t.speed[:] = [10.0, 0.0]
    t.yaw[1] = np.deg2rad(-138.0)
    gap, _, who = traffic.leaders(t, np.array([0]))
    assert who[0] == 1 and gap[0] == pytest.approx(20.0 - 4.7)
    t.yaw[1] = 0.0  # the same place, parallel: beside the corridor, no leader
    assert traffic.leaders(t, np.array([0]))[2][0] == -1
    t.pos[1], t.yaw[1], t.speed[1] = [20.0, 1.0], np.deg2rad(145.0), 5.0  # turning across
    assert traffic.leaders(t, np.array([0]))[2][0] == 1
    t.yaw[1] = np.deg2rad(170.0)  # nearly head-on and moving: oncoming, ignored
    assert traffic.leaders(t, np.array([0]))[2][0] == -1


# ------------------------------------------------------------------------------ pedestrians


def _segment_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    u = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab**2).sum(-1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + u[:, None] * ab), axis=1)


def _walk(jaywalk_prob: float, ticks: int):
    w = World(
        make_config(
            town="Town03",
            num_vehicles=0,
            num_parked=0,
            num_pedestrians=30,
            num_bicycles=0,
            jaywalk_prob=jaywalk_prob,
        )
    )
    w.reset(seed=0)
    t, net = w.table, w.sidewalks
    driving = np.array([ln.id for ln in w.town.lanes if ln.kind != PARKING])
    out = {
        "max_sidewalk_dist": 0.0,
        "max_segment_dist": 0.0,
        "starts": [],
        "walking_ticks": 0,
        "max_step_ratio": 0.0,  # per-tick displacement / (speed * dt)
    }
    prev = t.path.copy()
    prev_pos = t.pos.copy()
    for _ in range(ticks):
        w.step(BRAKE)
        idx = np.flatnonzero(t.active & (t.behaviour == WALKER))
        step = np.linalg.norm(t.pos[idx] - prev_pos[idx], axis=1)
        ratio = step / np.maximum(t.speed[idx] * w.config.dt, 1e-3)
        out["max_step_ratio"] = max(out["max_step_ratio"], float(ratio.max(initial=0.0)))
        prev_pos = t.pos.copy()
        walk = idx[t.path[idx] >= 0]
        cross = idx[t.path[idx] < 0]
        out["walking_ticks"] += len(walk)
        if len(walk):  # distance to the nearest sidewalk, as a fraction of its half width
            sw, _, d = net.index.project(t.pos[walk])
            half = np.array([w.town.sidewalks[k].width / 2.0 for k in sw])
            out["max_sidewalk_dist"] = max(out["max_sidewalk_dist"], float((d / half).max()))
        if len(cross):
            d = _segment_dist(t.pos[cross], t.cross_from[cross], t.cross_to[cross])
            out["max_segment_dist"] = max(out["max_segment_dist"], float(d.max()))
        for i in idx[(t.path[idx] < 0) & (prev[idx] >= 0)]:
            a, b = t.cross_from[i].copy(), t.cross_to[i].copy()
            # a crossing starts where the walker stands (near one end of a crosswalk, no jump)
            # and heads for the crosswalk's other end
            on_crosswalk = any(
                (np.linalg.norm(a - c[0]) < 6.5 and np.allclose(b, c[1]))
                or (np.linalg.norm(a - c[1]) < 6.5 and np.allclose(b, c[0]))
                for c in net.crossings
            )
            mid = 0.5 * (a + b)
            _, _, d_lane = w.town.index.project(mid[None], driving)
            out["starts"].append((on_crosswalk, float(np.linalg.norm(b - a)), float(d_lane[0])))
        prev = t.path.copy()
    return out


@pytest.fixture(scope="module")
def walk_run():
    return _walk(jaywalk_prob=0.0, ticks=300)


def test_pedestrians_stay_on_sidewalks_and_crosswalks(walk_run):
    r = walk_run
    assert r["walking_ticks"] > 1000
    assert r["max_sidewalk_dist"] <= 1.0  # inside the sidewalk (fraction of its half width)
    assert r["max_segment_dist"] < 1e-6  # crossing pedestrians stay on their crossing line
    assert len(r["starts"]) >= 3  # some did cross within 30 s
    assert all(on for on, _, _ in r["starts"])  # ... and only at crosswalks


def test_jaywalking_happens_with_probability_one():
    r = _walk(jaywalk_prob=1.0, ticks=100)
    jay = [(length, d) for on, length, d in r["starts"] if not on]
    assert len(jay) >= 10
    for length, d_lane in jay:
        assert length > 6.0  # straight over the road to the opposite sidewalk
        assert d_lane < 4.0  # the middle of the crossing is on the carriageway
    assert r["max_segment_dist"] < 1e-6
    assert r["max_sidewalk_dist"] <= 1.0


def test_pedestrians_move_continuously(walk_run):
    # a walker covers speed * dt per tick; allow 50 % for the lateral blending of a turn
    assert walk_run["max_step_ratio"] < 1.5


def test_crossing_walker_waits_while_the_ego_stands_in_its_way():
    from v2xbench.envs.v2x_intersection.town import get_town
    from v2xbench.envs.v2x_intersection.traffic.pedestrians import SidewalkNetwork, step_walkers

    net = SidewalkNetwork(get_town("Town01"))  # only the crossing walker moves here

    t = ActorTable.empty(2)
    t.active[:] = True
    t.kind[:] = [0, 2]  # the ego (a car) and a pedestrian
    t.behaviour[1], t.scenario[:] = WALKER, -1
    t.length[:], t.width[:] = [4.6, 0.5], [1.9, 0.5]
    t.pos[:] = [[0.0, 0.0], [0.0, -2.0]]  # the walker 2 m to the ego's right, crossing to the left
    t.path[1], t.cross_from[1], t.cross_to[1], t.speed[1] = -1, [0.0, -2.0], [0.0, 8.0], 1.4
    rng = np.random.default_rng(0)
    step_walkers(t, net, rng, 0.1, 0.0)
    assert t.pos[1, 1] == pytest.approx(-2.0)  # 1 m ahead of it is inside the ego: it waits
    t.pos[0] = [10.0, 0.0]  # the ego moved on
    step_walkers(t, net, rng, 0.1, 0.0)
    assert t.pos[1, 1] == pytest.approx(-2.0 + 0.14)


def test_held_scenario_vehicles_do_not_block_junctions():
    from v2xbench.envs.v2x_intersection.town import get_town
    from v2xbench.envs.v2x_intersection.traffic.vehicles import junction_clear

    town = get_town("Town01")
    j = town.junctions[0]
    t = ActorTable.empty(2)
    t.active[:] = True
    t.behaviour[:] = DRIVER
    t.lane[:] = j.incoming[0]
    t.pos[1] = j.center  # a vehicle standing inside the junction
    assert not junction_clear(t, town, 0, 0)
    t.hold[1] = True  # a held scenario prop (e.g. BlockedIntersection's car) is an obstacle only
    assert junction_clear(t, town, 0, 0)
