"""No hidden information in the ego's observations (issue 29, item 3).

- the ``bev`` observation draws only the actors the ego sees (``world.ego_vis``, the object
  list's test), the privileged raster every actor: over a few hundred ticks of scenarios whose
  hazard starts hidden behind a truck, the ego's BEV equals the privileged raster of the world
  without its hidden actors, pixel for pixel, and the hidden hazard is in the privileged raster;
- background parked large vehicles come in the sizes of the scenarios' occluding trucks;
- the emergency vehicle is its own class in the object list, the RSU's message, the BEV and the
  camera semantics.
"""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.agents.expert.agents import Expert
from v2xbench.envs.v2x_intersection.core.actors import PARKED, SIZES
from v2xbench.envs.v2x_intersection.core.classes import EMERGENCY_VEHICLE, LARGE_VEHICLE
from v2xbench.envs.v2x_intersection.perception.visibility import VISIBLE_THRESHOLD
from v2xbench.envs.v2x_intersection.scenarios import build_episode
from v2xbench.envs.v2x_intersection.scenarios.placement import truck_size
from v2xbench.envs.v2x_intersection.sensors import bev
from v2xbench.envs.v2x_intersection.sensors.bev import BEV_CHANNELS, BevSpec, bev_reach, capture_bev
from v2xbench.envs.v2x_intersection.sensors.ground import ground_raster
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.traffic import vehicles as traffic

SMALL = dict(num_vehicles=6, num_parked=6, num_pedestrians=6, num_bicycles=2)
_ACTOR_CHANNELS = [BEV_CHANNELS.index(c) for c in ("vehicle", "vru", "ego", "obstacle", "emergency")]


def _footprint(world, row: int, spec: BevSpec) -> np.ndarray:
    """The BEV pixels of actor ``row`` drawn alone, ``(size, size)`` bool."""
    t = world.table
    out = np.zeros((1, spec.size, spec.size), np.uint8)
    box = np.array([[*t.pos[row], t.length[row], t.width[row], t.yaw[row]]])
    bev._fill_boxes(out, np.zeros(1, np.int64), box, float(t.pos[0, 0]), float(t.pos[0, 1]), float(t.yaw[0]),
                    float(spec.mpp))
    return out[0] > 0


@pytest.mark.parametrize("name", ["DynamicObjectCrossing", "ParkingCrossingPedestrian"])
def test_ego_bev_never_shows_an_actor_the_ego_cannot_see(name):
    town = get_town("Town12")
    world = World(make_config(town="Town12", **SMALL))
    route, scs = build_episode(name, town, np.random.default_rng(0))
    world.reset(seed=0, route=route, scenarios=scs)
    expert = Expert()
    expert.bind(world)
    ground, spec = ground_raster(town), BevSpec()
    full_spec = BevSpec(privileged=True)
    hazards = [int(r) for sc in world.scenarios for r in sc.hazard_rows]
    t = world.table
    hidden_hazard_ticks = differing_ticks = 0
    for _ in range(300):
        if world.ended:
            break
        world.step_builtin(expert.act())
        ego = capture_bev(world, ground, spec)
        full = capture_bev(world, ground, full_spec)
        # the ego's raster is the ground truth of the world without the actors it cannot see
        near = bev.bev_actor_rows(world, bev_reach(spec), privileged=True)
        hidden = near[(near > 0) & (world.ego_vis[near] < VISIBLE_THRESHOLD)]
        active = t.active.copy()
        t.active[hidden] = False
        try:
            seen_only = capture_bev(world, ground, full_spec)
        finally:
            t.active[:] = active
        np.testing.assert_array_equal(ego, seen_only)
        differing_ticks += bool((ego != full).any())
        # a hidden hazard: its pixels are in the privileged raster, and none of them in the ego's
        # actor channels but where a seen actor covers them
        for h in set(hidden.tolist()) & set(hazards):
            fp = _footprint(world, h, spec)
            drawn = ego[_ACTOR_CHANNELS].any(0)
            others = np.zeros_like(fp)
            for r in near[(near != h) & ~np.isin(near, hidden)]:
                others |= _footprint(world, int(r), spec)
            own = fp & ~others & ~ego[BEV_CHANNELS.index("obstacle")].astype(bool)
            if fp.any():
                assert full[BEV_CHANNELS.index("vru")][fp].all()
                assert not drawn[own].any()
                hidden_hazard_ticks += bool(own.any())
    assert hidden_hazard_ticks >= 5, hidden_hazard_ticks  # the test saw hidden hazards (it can fail)
    assert differing_ticks >= hidden_hazard_ticks


def test_background_parked_trucks_cover_the_scenario_truck_sizes():
    """Parked large vehicles keep the full large-vehicle range (two slots for a long one), so a
    standing truck's size does not tell a scenario occluder from background traffic."""
    lengths, heights = [], []
    for seed in range(12):
        world = World(make_config(town="Town03", num_vehicles=0, num_parked=40, num_pedestrians=0,
                                  num_bicycles=0, large_vehicle_fraction=0.5))
        world.reset(seed=seed)
        t = world.table
        big = np.flatnonzero(t.active & (t.behaviour == PARKED) & (t.kind == LARGE_VEHICLE))
        lengths += t.length[big].tolist()
        heights += t.height[big].tolist()
        # no two parked vehicles overlap (a long truck takes a free neighbouring slot)
        park = np.flatnonzero(t.active & (t.behaviour == PARKED))
        for a in park:
            d = t.pos[park] - t.pos[a]
            c, s = np.cos(t.yaw[a]), np.sin(t.yaw[a])
            along, across = c * d[:, 0] + s * d[:, 1], c * d[:, 1] - s * d[:, 0]
            same_lane = (np.abs(across) < 1.0) & (park != a)
            assert (np.abs(along) >= 0.5 * (t.length[a] + t.length[park]) - 1e-9)[same_lane].all()
    lengths, heights = np.array(lengths), np.array(heights)
    rng = np.random.default_rng(0)
    trucks = np.array([truck_size(rng) for _ in range(500)])
    (l_lo, l_hi), (w_lo, w_hi), (h_lo, h_hi) = SIZES[LARGE_VEHICLE]
    # every scenario truck lies inside the background's range
    assert (trucks[:, 0] >= l_lo).all() and (trucks[:, 0] <= l_hi).all()
    assert (trucks[:, 1] >= w_lo).all() and (trucks[:, 1] <= w_hi).all()
    assert (trucks[:, 2] >= h_lo).all() and (trucks[:, 2] <= h_hi).all()
    # and the background's parked trucks cover the scenario range, quarter by quarter
    assert lengths.max() > traffic.ONE_SLOT_MAX_LENGTH_M + 3.0
    edges = np.linspace(trucks[:, 0].min(), trucks[:, 0].max(), 5)
    counts = np.histogram(lengths, edges)[0]
    assert (counts >= 3).all(), counts
    assert ((heights >= trucks[:, 2].min()) & (lengths >= trucks[:, 0].min())).sum() >= 5


def test_parking_neighbours_are_one_pitch_apart():
    town = get_town("Town03")
    nb = traffic.parking_neighbours(town)
    p = town.parking
    assert len(p) and (nb[:, 0] >= 0).sum() > len(p) // 2
    i = np.flatnonzero(nb[:, 0] >= 0)
    gap = np.hypot(*(p[nb[i, 0], :2] - p[i, :2]).T)
    np.testing.assert_allclose(gap, traffic.PARKING_SLOT_PITCH_M, atol=0.3)
    np.testing.assert_array_equal(nb[nb[i, 0], 1], i)


def _cruise(world, speed: float) -> np.ndarray:
    """Straight ahead at about ``speed`` m/s (the emergency vehicle catches up from behind)."""
    return np.array([0.4, 0.0, 0.0]) if world.table.speed[0] < speed else np.array([0.0, 0.0, 0.3])


def test_emergency_vehicle_is_its_own_class_in_every_observation():
    from v2xbench.envs.v2x_intersection.api.observations import ego_observation, rsu_observation
    from v2xbench.envs.v2x_intersection.sensors import build_scene

    world = World(make_config(town="Town04", obs_mode="objects", **SMALL))
    route, scs = build_episode("YieldToEmergencyVehicle", get_town("Town04"), np.random.default_rng(0))
    world.reset(seed=0, route=route, scenarios=scs)
    ev = int(world.scenarios[0].emergency_rows[0])
    t = world.table
    seen = 0
    for _ in range(600):
        world.step_builtin(_cruise(world, 8.0))
        assert t.kind[ev] == LARGE_VEHICLE  # the simulation's class is unchanged
        classes = world.object_classes()
        assert classes[ev] == EMERGENCY_VEHICLE and (np.delete(classes, ev) == np.delete(t.kind, ev)).all()
        close = np.hypot(*(t.pos[ev] - t.pos[0])) < 25.0
        if t.active[ev] and close and world.ego_vis[ev] >= VISIBLE_THRESHOLD:
            seen += 1
            if seen == 3:
                break
    assert seen == 3, "the emergency vehicle never came into the ego's view"
    # the object list: one row of class 8 (and the RSU's list / message when a unit sees it)
    rows = ego_observation(world)["objects"]
    assert (rows[rows[:, 0] > 0, 1] == EMERGENCY_VEHICLE).sum() == 1
    if world.active_rsu[0] >= 0 and world.rsu_vis[0, ev] >= VISIBLE_THRESHOLD:
        assert (rsu_observation(world)["objects"][:, 1] == EMERGENCY_VEHICLE).sum() == 1
        assert (world.rsu_objects(0)[:, 0] == EMERGENCY_VEHICLE).sum() == 1
    # the BEV: in the vehicle channel and in its own channel, nothing else there
    b = dict(zip(BEV_CHANNELS, capture_bev(world, ground_raster(world.town), BevSpec())))
    fp = _footprint(world, ev, BevSpec())
    assert fp.any() and b["emergency"][fp].all() and b["vehicle"][fp].all()
    assert b["emergency"].sum() == fp.sum()
    # the camera / LiDAR semantics: class 8, a livery of its own
    scene = build_scene(world)
    assert scene.sem[ev] == EMERGENCY_VEHICLE
    assert (np.delete(scene.sem[: len(t)], ev) != EMERGENCY_VEHICLE).all()
    assert (scene.colors[ev, 0] != np.delete(scene.colors[: len(t), 0], ev, axis=0)).any(1).all()


def test_rsu_message_carries_the_emergency_class():
    """The built-in message (numba kernel or NumPy packing) carries class 8 for the emergency
    vehicle: the ego decodes it into its ``v2x_objects``."""
    from v2xbench.envs.v2x_intersection.api.observations import ego_observation

    world = World(make_config(town="Town04", obs_mode="objects", **SMALL))
    route, scs = build_episode("YieldToEmergencyVehicle", get_town("Town04"), np.random.default_rng(0))
    world.reset(seed=0, route=route, scenarios=scs)
    ev = int(world.scenarios[0].emergency_rows[0])
    sent = received = 0
    for _ in range(600):
        world.step_builtin(_cruise(world, 8.0))
        if world.active_rsu[0] >= 0 and world.rsu_vis[0, ev] >= VISIBLE_THRESHOLD:
            assert (world.rsu_objects(0)[:, 0] == EMERGENCY_VEHICLE).sum() == 1
            sent += 1
        v2x = ego_observation(world)["v2x_objects"]
        n = (v2x[v2x[:, 0] > 0, 1] == EMERGENCY_VEHICLE).sum()
        assert n <= 1
        received += int(n)
        if received >= 3:
            break
    assert sent >= 1 and received >= 3, (sent, received)


def test_agents_read_the_emergency_class_from_observation_rows():
    """An ego-only agent built on the expert's object model learns the emergency flag from the
    object list (class 8), as the privileged expert does from the scenario."""
    from v2xbench.agents.expert.objects import from_observation_rows

    rows = np.zeros((3, 11), np.float32)
    rows[:2, 0] = 1.0
    rows[:2, 1] = (EMERGENCY_VEHICLE, LARGE_VEHICLE)
    rows[:2, 2] = (-20.0, 10.0)
    objs = from_observation_rows(rows, np.zeros(2), 0.0)
    assert objs.emergency.tolist() == [True, False]
    assert objs.kind.tolist() == [LARGE_VEHICLE, LARGE_VEHICLE]
