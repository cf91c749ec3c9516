"""Populating a world at reset: NPC vehicles, parked cars, pedestrians and bicycles.

:func:`populate` fills the actor table's rows after the ego, kind by kind, from the world's one
generator. The NumPy loops here are the reference and the fallback without numba; with numba,
drivers, riders and pedestrians are placed by :mod:`.jit_spawn`'s kernels, which draw the same
numbers and place the same actors
(``tests/core/test_jit.py``, ``test_world_reset_kernels_match_numpy``).
"""

from __future__ import annotations

import numpy as np

from ..core.actors import DRIVER, RIDER, SIZE_BOUNDS, WALKER, draw_size, pedestrian_size
from ..core.classes import BICYCLE, CAR, LARGE_VEHICLE, PEDESTRIAN
from ..core.draws import signs
from ..core.jit import HAVE_JIT
from ..core.jit_rng import state_views
from .jit_spawn import spawn_followers_kernel, spawn_walkers_kernel
from .vehicles import SPOT_TRIES, free_lane_spot, place_on_lane, spawn_parked

#: NPCs placed at reset keep this far from the ego (m), and this far from every other actor (m)
SPAWN_AWAY_M = 25.0
SPAWN_CLEARANCE_M = {DRIVER: 12.0, RIDER: 10.0}
#: desired speed draws: cars and large vehicles as a fraction of the speed limit, bicycles in m/s
V0_RANGES = {CAR: (0.75, 1.05), LARGE_VEHICLE: (0.65, 0.9), BICYCLE: (3.5, 5.5)}
#: speed at reset: vehicles at this fraction of desired speed x speed limit, bicycles of desired speed
START_SPEED_FRACTION = {DRIVER: 0.5, RIDER: 0.8}
WALKER_LAT_RANGE = (-0.8, 0.8)  # m, pedestrians' lateral offset on their sidewalk
WALKER_SPEED_RANGE = (1.0, 1.6)  # m/s

_FOLLOWER_KINDS = np.array([CAR, LARGE_VEHICLE, BICYCLE], np.int64)
#: ``(low (3, 3), high (3, 3))`` size bounds of the follower kinds, in ``_FOLLOWER_KINDS`` order
_FOLLOWER_SIZES = tuple(np.stack([SIZE_BOUNDS[k][j] for k in _FOLLOWER_KINDS]) for j in (0, 1))
#: ``(low (3,), high (3,))`` of :data:`V0_RANGES`, in ``_FOLLOWER_KINDS`` order
_FOLLOWER_V0 = tuple(np.array([V0_RANGES[k][j] for k in _FOLLOWER_KINDS]) for j in (0, 1))


def _followers_jit(world, row: int, count: int, riders: bool) -> int:
    """:func:`_drivers` / :func:`_riders` in one kernel (same draws, same actors)."""
    t, ix = world.table, world.town.index
    words, buf = state_views(world.rng)
    behaviour = RIDER if riders else DRIVER
    return spawn_followers_kernel(
        words, buf, row, count, riders, world._drive_lanes, SPAWN_AWAY_M, SPAWN_CLEARANCE_M[behaviour], SPOT_TRIES,
        float(world.config.large_vehicle_fraction), _FOLLOWER_KINDS, behaviour, *_FOLLOWER_SIZES, *_FOLLOWER_V0,
        START_SPEED_FRACTION[behaviour], t.kind, t.behaviour, t.active, t.length, t.width, t.height, t.v0,
        t.speed, t.lane, t.s, t.lat, t.pos, t.yaw, t.stopped_at_sign, t.wait, ix.speed_limit, ix.points,
        ix.heading, ix.offset, ix.n_points, ix.gs, ix.base, ix.length)

def _drivers(world, row: int, count: int) -> int:
    if HAVE_JIT and len(world._drive_lanes):
        return _followers_jit(world, row, count, False)
    t, rng = world.table, world.rng
    for _ in range(count):
        spot = free_lane_spot(t, world.town, world._drive_lanes, rng, t.pos[0], SPAWN_AWAY_M,
                              clearance=SPAWN_CLEARANCE_M[DRIVER])
        if spot is None:
            break
        kind = LARGE_VEHICLE if rng.random() < world.config.large_vehicle_fraction else CAR
        t.kind[row], t.behaviour[row], t.active[row] = kind, DRIVER, True
        t.length[row], t.width[row], t.height[row] = draw_size(kind, rng)
        t.v0[row] = rng.uniform(*V0_RANGES[kind])
        place_on_lane(t, world.town, row, *spot)
        t.speed[row] = START_SPEED_FRACTION[DRIVER] * t.v0[row] * world.town.index.speed_limit[spot[0]]
        row += 1
    return row

def _parked(world, row: int, count: int) -> int:
    return spawn_parked(world.table, world.town, world.rng, row, count, world.config.large_vehicle_fraction)

def _walkers(world, row: int, count: int) -> int:
    t, rng, net = world.table, world.rng, world.sidewalks
    if net.index is None:
        return row
    if HAVE_JIT:
        ix = net.index
        words, buf = state_views(rng)
        end = spawn_walkers_kernel(words, buf, row, count, PEDESTRIAN, WALKER, *SIZE_BOUNDS[PEDESTRIAN],
                                   *WALKER_LAT_RANGE, *WALKER_SPEED_RANGE, t.kind, t.behaviour, t.active,
                                   t.length, t.width, t.height, t.path, t.path_s, t.path_dir, t.lat, t.speed,
                                   t.pos, t.yaw, ix.points, ix.heading, ix.offset, ix.n_points, ix.gs, ix.base,
                                   ix.length)
        k = slice(row, end)  # some of them are children (as draw_size makes them)
        t.length[k], t.width[k], t.height[k] = pedestrian_size(t.length[k], t.width[k], t.height[k])
        return end
    for _ in range(count):
        sw = int(rng.integers(len(net.index.length)))
        t.kind[row], t.behaviour[row], t.active[row] = PEDESTRIAN, WALKER, True
        t.length[row], t.width[row], t.height[row] = draw_size(PEDESTRIAN, rng)
        t.path[row], t.path_s[row] = sw, rng.uniform(0.0, net.index.length[sw])
        t.path_dir[row] = signs(rng)
        t.lat[row] = rng.uniform(*WALKER_LAT_RANGE)
        t.speed[row] = rng.uniform(*WALKER_SPEED_RANGE)
        p, h = net.index.pose_at(np.array([sw]), np.array([t.path_s[row]]))
        t.pos[row] = p[0] + t.lat[row] * np.array([-np.sin(h[0]), np.cos(h[0])])
        t.yaw[row] = h[0] if t.path_dir[row] > 0 else h[0] + np.pi
        row += 1
    return row

def _riders(world, row: int, count: int) -> int:
    if HAVE_JIT and len(world._drive_lanes):
        return _followers_jit(world, row, count, True)
    t, rng = world.table, world.rng
    for _ in range(count):
        spot = free_lane_spot(t, world.town, world._drive_lanes, rng, t.pos[0], SPAWN_AWAY_M,
                              clearance=SPAWN_CLEARANCE_M[RIDER])
        if spot is None:
            break
        t.kind[row], t.behaviour[row], t.active[row] = BICYCLE, RIDER, True
        t.length[row], t.width[row], t.height[row] = draw_size(BICYCLE, rng)
        t.v0[row] = rng.uniform(*V0_RANGES[BICYCLE])
        place_on_lane(t, world.town, row, *spot)
        t.speed[row] = t.v0[row] * START_SPEED_FRACTION[RIDER]
        row += 1
    return row


def populate(world, asked: dict[str, int]) -> list[int]:
    """Spawn ``asked`` NPCs into ``world.table`` from row 1 on, in the order ``num_vehicles``,
    ``num_parked``, ``num_pedestrians``, ``num_bicycles`` (the order of ``asked``'s values);
    returns the row after each kind, ``[1, end_vehicles, end_parked, ...]`` (a town may fit fewer
    than asked)."""
    ends = [1]
    for spawn, count in zip((_drivers, _parked, _walkers, _riders), asked.values()):
        ends.append(spawn(world, ends[-1], count))
    return ends
