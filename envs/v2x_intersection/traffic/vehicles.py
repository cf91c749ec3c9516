"""NPC vehicles and bicycles: IDM along lane paths with signals, stop signs, junction yielding
and lane changes. One vectorized update per tick over all lane followers.
"""

from __future__ import annotations

import numpy as np

from ..core import libm
from ..core.actors import DRIVER, EGO, PARKED, RIDER, STATIC, ActorTable, draw_size
from ..core.classes import CAR, LARGE_VEHICLE
from ..core.draws import pick
from ..core.dynamics import IDMParams, idm_accel
from ..core.geometry import row_norms
from ..core.jit import HAVE_JIT
from ..core.jit_rng import state_views
from ..core.validation import ShortfallWarning, warn_once
from ..town.model import PRIORITY, STOP, STOP_LINE_SETBACK, Town
from .jit_vehicles import (
    CORRIDOR_MARGIN_M,
    CROSSING_SIN,
    followers_tick_kernel,
    free_lane_spot_kernel,
    leaders_kernel,
    occupied_kernel,
    respawn_kernel,
)
from .signals import RED, YELLOW

LOOKAHEAD = 50.0  # m, leader search distance
LANE_CHANGE_RATE = 1.2  # m/s lateral speed during a lane change
STUCK_RESPAWN_S = 40.0  # s stopped (not at a red light) before an NPC is respawned elsewhere
#: s an NPC waits behind a parked or static actor before it is respawned elsewhere: NPCs do not
#: drive around obstacles, and one queued at a scenario's obstacle would block the ego behind it
#: (CARLA's background activity likewise clears the lanes of an active scenario)
BLOCKED_RESPAWN_S = 5.0
#: :func:`free_lane_spot`'s defaults: distance to every active actor (m) and draws before giving up
SPOT_CLEARANCE_M, SPOT_TRIES = 10.0, 50
IDM = IDMParams()
IDM_BIKE = IDMParams(accel=1.0, decel=2.0, time_headway=1.0, min_gap=1.5)


def _idm_tuple(p: IDMParams) -> tuple[float, ...]:
    return (p.min_gap, p.time_headway, float(np.sqrt(p.accel * p.decel)), p.accel, p.delta, p.max_brake, p.decel)


_IDM_TUPLE, _IDM_BIKE_TUPLE = _idm_tuple(IDM), _idm_tuple(IDM_BIKE)


def leaders(t: ActorTable, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gap (m), approach rate (m/s) and row of the nearest actor in each follower's driving corridor.

    The corridor is the strip ahead of the follower along its heading, as wide as both actors
    (+0.4 m); an actor crossing it (more than 30 deg off its axis, e.g. a car standing or turning
    across the follower's path in a junction) counts with its oriented box's extent across the
    corridor, as CARLA's agents test bounding boxes against their path. Head-on actors moving
    faster than 1 m/s and not crossing are ignored (they are in another lane).

    Returns:
        ``(gap (M,), dv (M,), leader (M,))`` for followers ``idx``; ``inf`` gap and leader ``-1``
        where the corridor is free.
    """
    others = np.flatnonzero(t.active)
    if HAVE_JIT:
        return leaders_kernel(np.asarray(idx, np.int64), others, t.pos, t.yaw, t.length, t.width, t.speed,
                              LOOKAHEAD)
    d = t.pos[others][None, :, :] - t.pos[idx][:, None, :]
    c, s = np.cos(t.yaw[idx])[:, None], np.sin(t.yaw[idx])[:, None]
    dx = c * d[..., 0] + s * d[..., 1]
    dy = -s * d[..., 0] + c * d[..., 1]
    cos_rel = np.cos(t.yaw[others][None, :] - t.yaw[idx][:, None])
    # a crossing actor (more than 30 deg off the follower's axis) is measured across the corridor
    # by its oriented box, and never taken for oncoming traffic in another lane
    oc, osn = np.cos(t.yaw[others])[None, :], np.sin(t.yaw[others])[None, :]
    sr = np.abs(c * osn - s * oc)
    across = sr * t.length[others][None, :] + np.abs(c * oc + s * osn) * t.width[others][None, :]
    crossing = sr > CROSSING_SIN
    w_other = np.where(crossing, across, t.width[others][None, :])
    half = 0.5 * (t.width[idx][:, None] + w_other) + CORRIDOR_MARGIN_M
    reach = 0.5 * (t.length[idx][:, None] + t.length[others][None, :])
    ok = (dx > 0.0) & (dx < LOOKAHEAD + reach) & (np.abs(dy) < half)
    ok &= ~((cos_rel < -0.5) & (t.speed[others][None, :] > 1.0) & ~crossing)
    ok &= others[None, :] != idx[:, None]
    gap = np.where(ok, dx - reach, np.inf)
    j = np.argmin(gap, axis=1)
    g = gap[np.arange(len(idx)), j]
    dv = t.speed[idx] - t.speed[others[j]] * np.maximum(cos_rel[np.arange(len(idx)), j], 0.0)
    found = np.isfinite(g)
    return np.maximum(g, 0.0), np.where(found, dv, 0.0), np.where(found, others[j], -1)


def junction_clear(t: ActorTable, town: Town, jid: int, me: int) -> bool:
    """No other vehicle inside junction ``jid`` (and, for a minor-road vehicle at a priority
    junction, none arriving on a major approach within 30 m)."""
    j = town.junctions[jid]
    b = t.behaviour
    veh = t.active & ~t.hold & ((b == EGO) | (b == DRIVER) | (b == RIDER))  # held: scenario props
    veh[me] = False
    inside = row_norms(t.pos - j.center) < j.radius + 1.0
    if np.any(veh & inside):
        return False
    if j.control == PRIORITY and t.lane[me] in j.stop_lanes:  # minor road: wait for major traffic
        on_major = veh & _major_mask(town, jid)[t.lane] & (t.speed > 0.5)
        remaining = town.index.length[np.clip(t.lane, 0, None)] - t.s
        if np.any(on_major & (remaining < 30.0)):
            return False
    return True


def _major_mask(town: Town, jid: int) -> np.ndarray:
    """``(L + 1,)`` bool: lane is a major (no stop sign) approach of junction ``jid``; the extra
    last entry (lane -1) is False. Cached on the town."""
    cache = town.cache("major_masks")
    mask = cache.get(jid)
    if mask is None:
        j = town.junctions[jid]
        mask = np.zeros(len(town.lanes) + 1, bool)
        mask[np.setdiff1d(j.incoming, j.stop_lanes).astype(np.int64)] = True
        cache[jid] = mask
    return mask


def step_followers(t: ActorTable, town: Town, lane_signal: np.ndarray, rng: np.random.Generator,
                   dt: float, ego_pos: np.ndarray, plans: list[list[int]] | None = None) -> np.ndarray:
    """Advance all lane followers (``DRIVER`` and ``RIDER``) by one tick, in place.

    Args:
        t: actor table (modified).
        town: the road network.
        lane_signal: ``(num_lanes,)`` signal state per lane (``signals.SignalPlan.lane_states``).
        rng: the world's generator.
        dt: tick (s).
        ego_pos: ``(2,)`` ego position, to respawn out of its way.
        plans: fixed lane sequences referenced by ``t.plan`` (scenario actors).

    Returns:
        indices of followers that must be respawned (dead end or stuck).
    """
    ix = town.index
    if HAVE_JIT:
        return followers_tick_kernel(lane_signal, *flat_plans(plans), *followers_args(t, town, rng, dt))
    idx = np.flatnonzero(t.active & ~t.hold & ((t.behaviour == DRIVER) | (t.behaviour == RIDER)))
    if len(idx) == 0:
        return idx
    lane = t.lane[idx]
    bike = t.behaviour[idx] == RIDER
    gap, dv, s, v_new, stuck = _follow(t, town, lane_signal, dt, idx, lane, bike)
    respawn = _lane_transitions(t, town, idx, lane, s, rng, plans, np.flatnonzero(s > ix.length[lane]))
    respawn.extend(idx[stuck].tolist())

    _lane_changes(t, town, idx, lane, s, gap, dv, bike, rng, dt)
    t.lane[idx] = lane
    t.s[idx] = s
    # lateral offset: riders keep to the right edge; lane changes decay to the centre
    lat = t.lat[idx]
    edge = -(ix.width[lane] / 2.0 - 0.6)
    lat = np.where(bike, edge, np.sign(lat) * np.maximum(np.abs(lat) - LANE_CHANGE_RATE * dt, 0.0))
    dlat = lat - t.lat[idx]
    t.lat[idx] = lat
    p, h = ix.pose_at(lane, s)
    normal = np.stack([-np.sin(h), np.cos(h)], -1)
    t.pos[idx] = p + lat[:, None] * normal
    t.yaw[idx] = h + np.where(bike, 0.0, libm.arctan2(dlat / dt, np.maximum(v_new, 1.0)))
    return np.unique(np.array(respawn, np.int64))


def followers_args(t: ActorTable, town: Town, rng: np.random.Generator, dt: float) -> tuple:
    """The arguments of ``jit_traffic.followers_tick_kernel`` after the per-tick ones (the signal
    states and the plans): the same for a whole episode (``World`` keeps them from its first tick)."""
    ix = town.index
    a = _town_arrays(town)
    words, buf = state_views(rng)
    return (words, buf, a["succ"], a["succ_start"], a["n_succ"], t.active, t.hold, t.behaviour, t.pos, t.yaw,
            t.length, t.width, t.speed, t.lane, t.s, t.v0, t.stopped_at_sign, t.ignore_rules, t.wait, t.accel,
            t.scenario, t.plan, t.plan_pos, t.lat, ix.speed_limit, ix.length, ix.stop_at_end, ix.junction_ahead,
            a["stop_lane"], a["major"], a["center"], a["radius"], a["control"], _IDM_TUPLE, _IDM_BIKE_TUPLE,
            LOOKAHEAD, STOP_LINE_SETBACK, dt, BLOCKED_RESPAWN_S, STUCK_RESPAWN_S, ix.left, ix.right, ix.kind,
            ix.width, LANE_CHANGE_RATE, ix.points, ix.heading, ix.offset, ix.n_points, ix.gs, ix.base)


def _follow(t: ActorTable, town: Town, lane_signal: np.ndarray, dt: float, idx: np.ndarray, lane: np.ndarray,
            bike: np.ndarray) -> tuple[np.ndarray, ...]:
    """IDM behind the corridor leader and before stop lines (NumPy path of ``followers_kernel``):
    sets speed, accel, wait and stop-sign arrivals; returns ``(gap, dv, s_new, v_new, stuck)``."""
    ix = town.index
    limit = ix.speed_limit[lane]
    v0 = np.where(bike, np.minimum(t.v0[idx], limit), t.v0[idx] * limit)
    gap, dv, ahead = leaders(t, idx)
    v = t.speed[idx]
    acc = np.where(bike, idm_accel(v, v0, gap, dv, IDM_BIKE), idm_accel(v, v0, gap, dv, IDM))

    # stop lines: red / yellow lights, stop signs, junction not clear
    to_line = ix.length[lane] - t.s[idx] - STOP_LINE_SETBACK - 0.5 * t.length[idx]
    sig = lane_signal[lane]
    near = ix.stop_at_end[lane] & (to_line > -1.0) & (to_line < LOOKAHEAD)
    must_stop = near & ((sig == RED) | ((sig == YELLOW) & (to_line > v * v / (2 * IDM.decel))))
    jahead = ix.junction_ahead[lane]
    sign_lane = near & (sig == -1)
    arrived = sign_lane & (to_line < IDM.min_gap + 1.0) & (v < 0.3)  # IDM halts min_gap short
    t.stopped_at_sign[idx[arrived]] = True
    for k in np.flatnonzero(sign_lane):
        i = idx[k]
        control = town.junctions[jahead[k]].control
        needs_stop = control == STOP or lane[k] in town.junctions[jahead[k]].stop_lanes
        if needs_stop and not t.stopped_at_sign[i]:
            must_stop[k] = True
        elif (needs_stop or control == PRIORITY) and to_line[k] < 8.0 and not junction_clear(t, town, jahead[k], i):
            must_stop[k] = True
    must_stop &= ~t.ignore_rules[idx]
    acc_line = idm_accel(v, v0, np.maximum(to_line, 0.0), v, IDM)
    acc = np.where(must_stop, np.minimum(acc, acc_line), acc)

    v_new = np.maximum(v + acc * dt, 0.0)
    t.accel[idx] = (v_new - v) / dt
    t.speed[idx] = v_new
    s = t.s[idx] + v_new * dt
    waiting = (v_new < 0.1) & ~must_stop | (v_new < 0.1) & (sig == -1)
    t.wait[idx] = np.where(v_new < 0.1, t.wait[idx] + dt, 0.0)
    behind_obstacle = (ahead >= 0) & np.isin(t.behaviour[np.maximum(ahead, 0)], (PARKED, STATIC))
    limit_s = np.where(behind_obstacle, BLOCKED_RESPAWN_S, STUCK_RESPAWN_S)
    stuck = (t.wait[idx] > limit_s) & waiting & (sig != RED) & (t.scenario[idx] < 0)
    return gap, dv, s, v_new, stuck


def _lane_transitions(t: ActorTable, town: Town, idx: np.ndarray, lane: np.ndarray, s: np.ndarray,
                      rng: np.random.Generator, plans: list[list[int]] | None, over: np.ndarray) -> list[int]:
    """Move followers ``over`` (positions in ``idx``) past their lane's end onto a successor (their
    plan's next lane, else a random one), in place on ``lane``/``s``; returns the rows at a dead
    end (to respawn)."""
    ix = town.index
    respawn = []
    for k in over:
        i = idx[k]
        while s[k] > ix.length[lane[k]]:
            succ = town.lanes[lane[k]].successors
            planned = plans[t.plan[i]] if (plans is not None and t.plan[i] >= 0) else None
            if planned is not None and t.plan_pos[i] + 1 < len(planned):
                t.plan_pos[i] += 1
                nxt = planned[t.plan_pos[i]]
            elif succ and planned is None:
                nxt = succ[int(rng.integers(len(succ)))]
            else:
                respawn.append(i)
                break
            s[k] -= ix.length[lane[k]]
            lane[k] = nxt
            t.stopped_at_sign[i] = False
    return respawn


def stop_sign_lanes(town: Town) -> np.ndarray:
    """``(L,)`` bool: the lane ends at a stop sign of its junction (cached on the town)."""
    return _town_arrays(town)["stop_lane"]


def _town_arrays(town: Town) -> dict[str, np.ndarray]:
    """Junction tables for the kernels, cached on the town: ``stop_lane (L,)`` (the lane has a stop
    sign at its junction ahead), ``major (J, L + 1)`` (``_major_mask`` rows), the junctions'
    ``center``, ``radius``, ``control``, and the lane graph's successors as ``succ`` /
    ``succ_start`` / ``n_succ`` (lane ``l``'s: ``succ[succ_start[l]:succ_start[l] + n_succ[l]]``)."""
    a = town.cache("traffic_arrays")
    if not a:
        ix = town.index
        stop_lane = np.array([j >= 0 and k in town.junctions[j].stop_lanes
                              for k, j in enumerate(ix.junction_ahead)], bool)
        nj = len(town.junctions)
        major = (np.stack([_major_mask(town, j) for j in range(nj)]) if nj
                 else np.zeros((1, len(town.lanes) + 1), bool))
        n_succ = np.array([len(ln.successors) for ln in town.lanes], np.int64)
        succ = np.array([k for ln in town.lanes for k in ln.successors], np.int64)
        a.update(stop_lane=stop_lane, major=major, succ=succ, n_succ=n_succ,
                 succ_start=np.concatenate([[0], np.cumsum(n_succ)[:-1]]).astype(np.int64),
                 center=np.array([j.center for j in town.junctions], np.float64).reshape(-1, 2),
                 radius=np.array([j.radius for j in town.junctions], np.float64),
                 control=np.array([j.control for j in town.junctions], np.int64))
    return a


_NO_PLANS = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))


_PLANS: dict[int, tuple] = {}  # id(plans) -> (plans, len(plans), flat arrays); holding plans keeps its id


def flat_plans(plans: list[list[int]] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``World.plans`` for the kernel: ``(lanes, start, length)`` with plan ``p`` =
    ``lanes[start[p]:start[p] + length[p]]``. Scenarios only append plans (copies of their lane
    lists), so the arrays are rebuilt only when the list grew (cached for the last few lists)."""
    if not plans:
        return _NO_PLANS
    hit = _PLANS.get(id(plans))
    if hit is not None and hit[0] is plans and hit[1] == len(plans):
        return hit[2]
    n = np.array([len(p) for p in plans], np.int64)
    lanes = np.array([k for p in plans for k in p], np.int64)
    flat = (lanes, np.concatenate([[0], np.cumsum(n)[:-1]]).astype(np.int64), n)
    if len(_PLANS) >= 256 and id(plans) not in _PLANS:
        del _PLANS[next(iter(_PLANS))]
    _PLANS[id(plans)] = (plans, len(plans), flat)
    return flat


def _lane_changes(t, town, idx, lane, s, gap, dv, bike, rng, dt) -> None:
    """Overtake a slow leader: move to a neighbour lane whose nearby stretch is free (MOBIL-lite)."""
    ix = town.index
    want = (~bike) & (gap < 25.0) & (dv > 1.0) & (np.abs(t.lat[idx]) < 0.1) & (rng.random(len(idx)) < 0.05)
    for k in np.flatnonzero(want):
        cur = lane[k]
        for nb, side in ((ix.left[cur], 1.0), (ix.right[cur], -1.0)):
            if nb < 0 or ix.kind[nb] != ix.kind[cur]:
                continue
            s_nb = s[k] * ix.length[nb] / max(ix.length[cur], 1e-6)
            others = t.active & (t.lane == nb)
            if np.any(others & (t.s > s_nb - 15.0) & (t.s < s_nb + 25.0)):
                continue
            if ix.length[nb] - s_nb < 30.0:
                continue
            lane[k], s[k] = nb, s_nb
            t.lat[idx[k]] = -side * ix.width[cur]  # old position, seen from the new lane
            break


def occupied(t: ActorTable, xy: np.ndarray, radius: float) -> bool:
    """Whether any active actor is within ``radius`` m of ``xy``."""
    if HAVE_JIT:
        return occupied_kernel(t.active, t.pos, float(xy[0]), float(xy[1]), float(radius))
    return bool((t.active & (row_norms(t.pos - xy) < radius)).any())


def place_on_lane(t: ActorTable, town: Town, i: int, lane: int, s: float) -> None:
    """Put follower ``i`` on ``lane`` at arc length ``s``."""
    p, h = town.index.pose_at(np.array([lane]), np.array([s]))
    t.lane[i], t.s[i], t.lat[i] = lane, s, 0.0
    t.pos[i], t.yaw[i] = p[0], h[0]
    t.stopped_at_sign[i] = False
    t.wait[i] = 0.0


def respawn_followers(t: ActorTable, town: Town, lanes: np.ndarray, rng: np.random.Generator, rows: np.ndarray,
                      min_avoid: float = 60.0) -> None:
    """Rows ``rows`` (in order) leave the world, or come back at rest on a free spot of ``lanes``
    at least ``min_avoid`` m from the ego: scenario actors leave, background NPCs are placed with
    :func:`free_lane_spot` (and leave when it finds none)."""
    if HAVE_JIT and len(lanes):
        ix = town.index
        words, buf = state_views(rng)
        respawn_kernel(words, buf, np.asarray(rows, np.int64), np.asarray(lanes, np.int64), t.active, t.pos, t.yaw,
                       t.speed, t.lane, t.s, t.lat, t.stopped_at_sign, t.wait, t.scenario, float(min_avoid), SPOT_CLEARANCE_M,
                       SPOT_TRIES,
                       ix.points, ix.heading, ix.offset, ix.n_points, ix.gs, ix.base, ix.length)
        return
    for i in rows:
        if t.scenario[i] >= 0:
            t.active[i] = False
            continue
        spot = free_lane_spot(t, town, lanes, rng, t.pos[0], min_avoid)
        if spot is None:
            t.active[i] = False
        else:
            place_on_lane(t, town, int(i), *spot)
            t.speed[i] = 0.0


def free_lane_spot(t: ActorTable, town: Town, lanes: np.ndarray, rng: np.random.Generator,
                   avoid: np.ndarray, min_avoid: float, clearance: float = SPOT_CLEARANCE_M,
                   tries: int = SPOT_TRIES) -> tuple[int, float] | None:
    """A random ``(lane, s)`` on ``lanes`` at least ``clearance`` m from actors and ``min_avoid`` m
    from ``avoid (2,)``; ``None`` if none found in ``tries`` draws."""
    ix = town.index
    if HAVE_JIT:
        if len(lanes) == 0:
            raise ValueError("cannot pick from an empty sequence")
        words, buf = state_views(rng)
        lane, s = free_lane_spot_kernel(words, buf, np.asarray(lanes, np.int64), t.active, t.pos, float(avoid[0]),
                                        float(avoid[1]), float(min_avoid), float(clearance), int(tries), ix.points,
                                        ix.heading, ix.offset, ix.n_points, ix.gs, ix.base, ix.length)
        return None if lane < 0 else (int(lane), float(s))
    for _ in range(tries):
        lane = int(pick(rng, lanes))
        s = float(rng.uniform(2.0, max(ix.length[lane] - 2.0, 2.5)))
        p, _ = ix.pose_at(np.array([lane]), np.array([s]))
        if np.linalg.norm(p[0] - avoid) < min_avoid or occupied(t, p[0], clearance):
            continue
        return lane, s
    return None


# ---------------------------------------------------------------------------- parked vehicles
#: parking slots lie this far apart along their parking lane (``town.builder``)
PARKING_SLOT_PITCH_M = 6.5
#: the longest vehicle one slot holds (m); a longer one takes two neighbouring slots
ONE_SLOT_MAX_LENGTH_M = 6.2


def parking_neighbours(town: Town) -> np.ndarray:
    """``(K, 2)``: per parking slot of ``town.parking`` the next and the previous slot of the same
    parking lane (one pitch away, the same heading), -1 where there is none (lane end, a gap
    left for a crosswalk). Cached on the town."""
    store = town.cache("parking")
    hit = store.get("neighbours")
    if hit is None:
        p = np.asarray(town.parking, float).reshape(-1, 3)
        hit = np.full((len(p), 2), -1, np.int64)
        if len(p) > 1:
            gap = np.hypot(p[1:, 0] - p[:-1, 0], p[1:, 1] - p[:-1, 1])
            turn = np.abs((p[1:, 2] - p[:-1, 2] + np.pi) % (2 * np.pi) - np.pi)
            i = np.flatnonzero((np.abs(gap - PARKING_SLOT_PITCH_M) < 0.3) & (turn < 0.2))
            hit[i, 0], hit[i + 1, 1] = i + 1, i
        store["neighbours"] = hit
    return hit


def spawn_parked(t: ActorTable, town: Town, rng: np.random.Generator, row: int, count: int,
                 large_fraction: float) -> int:
    """Up to ``count`` parked vehicles from row ``row`` on random parking slots (a permutation of
    the slots, then per vehicle its class - large with probability ``large_fraction`` - and
    :func:`~.actors.draw_size`).

    Large vehicles keep the full ``actors.SIZES`` range (6-11 m, as the scenarios' trucks): one
    longer than :data:`ONE_SLOT_MAX_LENGTH_M` takes its slot and a free neighbouring one (the
    next, else the previous) and stands centred between the two; only where both neighbours are
    taken is it cut to one slot's length.

    Returns:
        the next free row.
    """
    slots = np.asarray(town.parking, float).reshape(-1, 3)
    if len(slots) == 0 or count <= 0:
        return row
    nb = parking_neighbours(town)
    taken = np.zeros(len(slots), bool)
    placed = 0
    for k in rng.permutation(len(slots)).tolist():
        if placed >= count:
            break
        if taken[k]:
            continue
        kind = LARGE_VEHICLE if rng.random() < large_fraction else CAR
        t.kind[row], t.behaviour[row], t.active[row] = kind, PARKED, True
        t.length[row], t.width[row], t.height[row] = draw_size(kind, rng)
        taken[k] = True
        t.pos[row], t.yaw[row] = slots[k, :2], slots[k, 2]
        if t.length[row] > ONE_SLOT_MAX_LENGTH_M:
            j = next((int(j) for j in nb[k] if j >= 0 and not taken[j]), -1)
            if j < 0:
                t.length[row] = ONE_SLOT_MAX_LENGTH_M
            else:
                taken[j] = True
                t.pos[row] = 0.5 * (slots[k, :2] + slots[j, :2])
        row += 1
        placed += 1
    return row


# ---------------------------------------------------------------------------- spawn shortfall
#: why fewer actors than asked can be placed, per config field
SHORTFALL_REASONS = {
    "num_vehicles": "no free lane spot is left clear of other actors and away from the ego",
    "num_parked": "every parking slot is taken",
    "num_pedestrians": "the town has no sidewalks",
    "num_bicycles": "no free lane spot is left clear of other actors and away from the ego",
}


def warn_spawn_shortfall(town: Town, asked: dict[str, int], placed: dict[str, int]) -> None:
    """Warn, once per process for each town, field and asked count, where ``placed[field]`` (the
    actors the reset placed) is below ``asked[field]`` (the config's ``num_*``)."""
    for field, n in asked.items():
        got = int(placed[field])
        if got >= n:
            continue
        why = SHORTFALL_REASONS[field]
        if field == "num_parked" and len(town.parking) == 0:
            why = "the town has no parking slots"
        warn_once(("spawn", town.name, field, int(n)),
                  f"config: {field}={n} but only {got} fit in {town.name} ({why}); this episode "
                  f"runs with {got} (warned once per town and value)",
                  ShortfallWarning, stacklevel=4)
