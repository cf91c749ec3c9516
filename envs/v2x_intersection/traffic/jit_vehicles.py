"""numba kernels for NPC vehicles and bicycles (``traffic.step_followers``): car-following, stop
lines, junction yielding, lane transitions and lane changes, the pose update; respawns and free
lane spots; and the traffic lights' states. The pedestrians' kernels are in :mod:`.jit_walkers`.

Like :mod:`.jit`, each kernel repeats the NumPy path's float operations in the same order and
dtype, so both paths give bit-identical results (``tests/core/test_jit.py``). What draws random
numbers (lane transitions at a lane's end, lane changes, a walker's choice at a sidewalk's end,
jaywalking) draws from the world's generator itself (:mod:`.jit_rng`), in the NumPy path's order,
so the generator is in the same state after a tick with or without numba.
"""

from __future__ import annotations

import numpy as np

from ..core.actors import DRIVER as _DRIVER
from ..core.actors import EGO as _EGO
from ..core.actors import PARKED as _PARKED
from ..core.actors import RIDER as _RIDER
from ..core.actors import STATIC as _STATIC
from ..core.dynamics import idm_one
from ..core.jit import _njit, _njit_inline, _np_max, _np_min, pose_at_kernel
from ..core.jit_rng import integers, next_double, uniform
from ..town.model import PRIORITY as _PRIORITY
from ..town.model import STOP as _STOP

#: m added to both actors' half widths in the car-following corridor (``leaders_kernel`` and
#: ``traffic.leaders``)
CORRIDOR_MARGIN_M = 0.4
#: |sine| of the heading difference above which an actor counts as crossing a follower's
#: corridor (more than 30 deg off its axis): its footprint across the corridor is measured from
#: its oriented box, and it is never taken for oncoming traffic in another lane
CROSSING_SIN = 0.5

# signal states (signals.py imports this module, so they are repeated here; a test compares them)
_GREEN, _RED, _YELLOW, _NO_SIGNAL = 0, 2, 1, -1


@_njit_inline
def junction_clear_kernel(active, hold, behaviour, pos, speed, lane, s, lane_length, jcenter, jradius, jcontrol,
                          stop_lane, major, jid, me):  # pragma: no cover
    """``traffic.junction_clear``: no vehicle inside junction ``jid`` (and none arriving on a
    major approach within 30 m when ``me`` waits on a minor road of a priority junction)."""
    n = active.shape[0]
    cx, cy = jcenter[jid, 0], jcenter[jid, 1]
    r = jradius[jid] + 1.0
    for i in range(n):
        b = behaviour[i]
        if i == me or not active[i] or hold[i] or not (b == _EGO or b == _DRIVER or b == _RIDER):
            continue
        dx = pos[i, 0] - cx
        dy = pos[i, 1] - cy
        if np.sqrt(dx * dx + dy * dy) < r:
            return False
    if jcontrol[jid] == _PRIORITY and stop_lane[lane[me]]:
        nl = lane_length.shape[0]
        for i in range(n):
            b = behaviour[i]
            if i == me or not active[i] or hold[i] or not (b == _EGO or b == _DRIVER or b == _RIDER):
                continue
            li = lane[i]
            if not major[jid, li if li >= 0 else nl] or not speed[i] > 0.5:
                continue
            if lane_length[li if li >= 0 else 0] - s[i] < 30.0:
                return False
    return True


@_njit
def followers_kernel(idx, active, hold, behaviour, pos, yaw, length, width, speed, lane_arr, s_arr, v0_arr,
                     stopped_at_sign, ignore_rules, wait, accel, scenario, lane_signal, speed_limit, lane_length,
                     stop_at_end, junction_ahead, stop_lane, major, jcenter, jradius, jcontrol, idm_car, idm_bike,
                     lookahead, setback, dt, blocked_s, stuck_s):  # pragma: no cover
    """The car-following part of ``traffic.step_followers`` for followers ``idx``, in place on
    ``stopped_at_sign``, ``wait``, ``accel`` and ``speed``.

    ``idm_car`` / ``idm_bike``: ``(min_gap, time_headway, sqrt(accel * decel), accel, delta,
    max_brake, decel)``.

    Returns:
        ``(gap, dv, s_new, v_new, stuck, over)``: per follower the leader gap and approach rate,
        the arc length after the move (before lane transitions) and the new speed; the rows that
        waited too long (to respawn); the followers (positions in ``idx``) past their lane's end.
    """
    m = idx.shape[0]
    others = np.flatnonzero(active)
    gap, dv, ahead = leaders_kernel(idx, others, pos, yaw, length, width, speed, lookahead)
    lane = np.empty(m, np.int64)
    bike = np.empty(m, np.bool_)
    v = np.empty(m)
    v0 = np.empty(m)
    for k in range(m):
        i = idx[k]
        lane[k] = lane_arr[i]
        bike[k] = behaviour[i] == _RIDER
        v[k] = speed[i]
        lim = speed_limit[lane[k]]
        v0[k] = _np_min(v0_arr[i], lim) if bike[k] else v0_arr[i] * lim
    c = idm_car
    to_line = np.empty(m)
    must_stop = np.zeros(m, np.bool_)
    sign_lane = np.zeros(m, np.bool_)
    sig = np.empty(m, np.int64)
    for k in range(m):
        i = idx[k]
        ln = lane[k]
        to_line[k] = lane_length[ln] - s_arr[i] - setback - 0.5 * length[i]
        sig[k] = lane_signal[ln]
        near = stop_at_end[ln] and to_line[k] > -1.0 and to_line[k] < lookahead
        must_stop[k] = near and (sig[k] == _RED or (sig[k] == _YELLOW and to_line[k] > v[k] * v[k] / (2 * c[6])))
        sign_lane[k] = near and sig[k] == _NO_SIGNAL
        if sign_lane[k] and to_line[k] < c[0] + 1.0 and v[k] < 0.3:  # arrived (IDM halts min_gap short)
            stopped_at_sign[i] = True
    for k in range(m):
        if not sign_lane[k]:
            continue
        i = idx[k]
        j = junction_ahead[lane[k]]
        control = jcontrol[j]
        needs_stop = control == _STOP or stop_lane[lane[k]]
        if needs_stop and not stopped_at_sign[i]:
            must_stop[k] = True
        elif (needs_stop or control == _PRIORITY) and to_line[k] < 8.0 and not junction_clear_kernel(
                active, hold, behaviour, pos, speed, lane_arr, s_arr, lane_length, jcenter, jradius, jcontrol,
                stop_lane, major, j, i):
            must_stop[k] = True
    for k in range(m):
        must_stop[k] = must_stop[k] and not ignore_rules[idx[k]]
    s_new = np.empty(m)
    v_new = np.empty(m)
    stuck = np.zeros(m, np.bool_)
    for k in range(m):
        i = idx[k]
        # IDM behind the leader with the follower's own parameters, and towards the stop line (car
        # parameters) only where it must stop: the values the NumPy path keeps of its full arrays
        p = idm_bike if bike[k] else idm_car
        acc = idm_one(v[k], v0[k], gap[k], dv[k], p[0], p[1], p[2], p[3], p[4], p[5])
        if must_stop[k]:
            acc = _np_min(acc, idm_one(v[k], v0[k], _np_max(to_line[k], 0.0), v[k], c[0], c[1], c[2], c[3], c[4],
                                       c[5]))
        vn = _np_max(v[k] + acc * dt, 0.0)
        v_new[k] = vn
        accel[i] = (vn - v[k]) / dt
        speed[i] = vn
        s_new[k] = s_arr[i] + vn * dt
        waiting = (vn < 0.1 and not must_stop[k]) or (vn < 0.1 and sig[k] == _NO_SIGNAL)
        wait[i] = wait[i] + dt if vn < 0.1 else 0.0
        behind_obstacle = ahead[k] >= 0 and (behaviour[ahead[k]] == _PARKED or behaviour[ahead[k]] == _STATIC)
        limit = blocked_s if behind_obstacle else stuck_s
        stuck[k] = wait[i] > limit and waiting and sig[k] != _RED and scenario[i] < 0
    over = np.flatnonzero(s_new > lane_length[lane])
    return gap, dv, s_new, v_new, idx[stuck], over


@_njit_inline
def lane_change_kernel(idx, lane, s, gap, dv, bike, draws, lat_arr, active, lane_arr, s_arr, left, right, kind,
                       lane_length, lane_width):  # pragma: no cover
    """``traffic._lane_changes``: a car behind a slower leader (and whose ``draws`` < 0.05) moves
    to a free neighbour lane, in place on ``lane``, ``s`` and ``lat_arr``."""
    for k in range(idx.shape[0]):
        if bike[k] or not gap[k] < 25.0 or not dv[k] > 1.0 or not abs(lat_arr[idx[k]]) < 0.1 or not draws[k] < 0.05:
            continue
        cur = lane[k]
        for side_k in range(2):
            nb = left[cur] if side_k == 0 else right[cur]
            side = 1.0 if side_k == 0 else -1.0
            if nb < 0 or kind[nb] != kind[cur]:
                continue
            s_nb = s[k] * lane_length[nb] / _np_max(lane_length[cur], 1e-6)
            busy = False
            for j in range(active.shape[0]):
                if active[j] and lane_arr[j] == nb and s_arr[j] > s_nb - 15.0 and s_arr[j] < s_nb + 25.0:
                    busy = True
                    break
            if busy or lane_length[nb] - s_nb < 30.0:
                continue
            lane[k], s[k] = nb, s_nb
            lat_arr[idx[k]] = -side * lane_width[cur]
            break


@_njit_inline
def pose_kernel(idx, lane, s, bike, v_new, lane_arr, s_arr, lat_arr, pos, yaw, lane_width, lane_change_rate, dt,
                points, heading, offset, n_points, gs, base, length):  # pragma: no cover
    """The end of ``traffic.step_followers``: new lane and arc length, lateral offset (riders
    keep right, lane changes decay to the centre), then position and heading on the lane, in
    place on ``lane_arr``, ``s_arr``, ``lat_arr``, ``pos``, ``yaw``."""
    m = idx.shape[0]
    p, h = pose_at_kernel(lane, s, points, heading, offset, n_points, gs, base, length)
    for k in range(m):
        i = idx[k]
        lane_arr[i], s_arr[i] = lane[k], s[k]
        old = lat_arr[i]
        if bike[k]:
            lat = -(lane_width[lane[k]] / 2.0 - 0.6)
        else:
            a = abs(old) - lane_change_rate * dt
            sign = 1.0 if old > 0.0 else (-1.0 if old < 0.0 else (0.0 if old == 0.0 else old))  # np.sign
            lat = sign * _np_max(a, 0.0)
        dlat = lat - old
        lat_arr[i] = lat
        # on the lane's centre line (most cars): ``p + 0 * n`` is ``p`` unless ``p`` is a zero
        if lat == 0.0 and p[k, 0] != 0.0 and p[k, 1] != 0.0:
            pos[i, 0] = p[k, 0]
            pos[i, 1] = p[k, 1]
        else:
            nx, ny = -np.sin(h[k]), np.cos(h[k])
            pos[i, 0] = p[k, 0] + lat * nx
            pos[i, 1] = p[k, 1] + lat * ny
        if bike[k]:
            yaw[i] = h[k] + 0.0
        else:
            q = dlat / dt
            w = _np_max(v_new[k], 1.0)
            # arctan2(+-0, w > 0) is that zero: no lateral move, no call
            yaw[i] = h[k] + (q if q == 0.0 and w > 0.0 else np.arctan2(q, w))


@_njit
def followers_tick_kernel(lane_signal, plan_lanes, plan_start, plan_len, words, buf, succ, succ_start, n_succ, active,
                          hold, behaviour, pos, yaw, length, width, speed, lane_arr, s_arr, v0_arr, stopped_at_sign,
                          ignore_rules, wait, accel, scenario, plan, plan_pos, lat_arr, speed_limit, lane_length,
                          stop_at_end, junction_ahead, stop_lane, major, jcenter, jradius, jcontrol, idm_car, idm_bike,
                          lookahead, setback, dt, blocked_s, stuck_s, left, right, kind, lane_width, change_rate,
                          points, heading, offset, n_points, gs, base):  # pragma: no cover
    """``traffic.step_followers`` in one call, in place on the table's columns: car-following
    (:func:`followers_kernel`), lane transitions at a lane's end (the plan's next lane, else a
    random successor drawn from ``words``/``buf``, :mod:`.jit_rng`), lane changes (one draw per
    follower) and the pose update (:func:`pose_kernel`).

    The arguments that change from tick to tick come first (``lane_signal``, the plans); the rest
    are ``traffic.followers_args``, the same for a whole episode.
    ``plan_lanes[plan_start[p]:plan_start[p] + plan_len[p]]`` is ``World.plans[p]``;
    ``succ[succ_start[l]:succ_start[l] + n_succ[l]]`` are lane ``l``'s successors.

    Returns:
        the rows to respawn (dead end or stuck), sorted and unique.
    """
    n = active.shape[0]
    idx = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        if active[i] and not hold[i] and (behaviour[i] == _DRIVER or behaviour[i] == _RIDER):
            idx[m] = i
            m += 1
    idx = idx[:m]
    if m == 0:
        return idx
    lane = np.empty(m, np.int64)
    bike = np.empty(m, np.bool_)
    for k in range(m):
        lane[k] = lane_arr[idx[k]]
        bike[k] = behaviour[idx[k]] == _RIDER
    gap, dv, s, v_new, stuck, over = followers_kernel(
        idx, active, hold, behaviour, pos, yaw, length, width, speed, lane_arr, s_arr, v0_arr, stopped_at_sign,
        ignore_rules, wait, accel, scenario, lane_signal, speed_limit, lane_length, stop_at_end, junction_ahead,
        stop_lane, major, jcenter, jradius, jcontrol, idm_car, idm_bike, lookahead, setback, dt, blocked_s, stuck_s)
    respawn = np.empty(over.shape[0] + stuck.shape[0], np.int64)
    nr = 0
    for k in over:  # traffic._lane_transitions
        i = idx[k]
        while s[k] > lane_length[lane[k]]:
            p = plan[i]
            if p >= 0 and plan_pos[i] + 1 < plan_len[p]:
                plan_pos[i] += 1
                nxt = plan_lanes[plan_start[p] + plan_pos[i]]
            elif n_succ[lane[k]] > 0 and p < 0:
                nxt = succ[succ_start[lane[k]] + integers(words, buf, n_succ[lane[k]])]
            else:
                respawn[nr] = i
                nr += 1
                break
            s[k] -= lane_length[lane[k]]
            lane[k] = nxt
            stopped_at_sign[i] = False
    for i in stuck:
        respawn[nr] = i
        nr += 1
    draws = np.empty(m)
    for k in range(m):
        draws[k] = next_double(words)
    lane_change_kernel(idx, lane, s, gap, dv, bike, draws, lat_arr, active, lane_arr, s_arr, left, right, kind,
                       lane_length, lane_width)
    pose_kernel(idx, lane, s, bike, v_new, lane_arr, s_arr, lat_arr, pos, yaw, lane_width, change_rate, dt, points,
                heading, offset, n_points, gs, base, lane_length)
    return np.unique(respawn[:nr])


@_njit
def free_lane_spot_kernel(words, buf, lanes, active, pos, ax, ay, min_avoid, clearance, tries, points, heading,
                          offset, n_points, gs, base, length):  # pragma: no cover
    """``traffic.free_lane_spot``: a random ``(lane, s)`` on ``lanes`` at least ``clearance`` m
    from active actors and ``min_avoid`` m from ``(ax, ay)``, drawn from ``words``/``buf``;
    ``(-1, 0.0)`` when ``tries`` draws found none."""
    one = np.empty(1, np.int64)
    at = np.empty(1)
    for _ in range(tries):
        lane = lanes[integers(words, buf, lanes.shape[0])]
        hi = length[lane] - 2.0
        s = uniform(words, 2.0, hi if not 2.5 > hi else 2.5)  # Python's max(length - 2, 2.5)
        one[0], at[0] = lane, s
        p, _ = pose_at_kernel(one, at, points, heading, offset, n_points, gs, base, length)
        dx, dy = p[0, 0] - ax, p[0, 1] - ay
        if np.sqrt(dx * dx + dy * dy) < min_avoid:
            continue
        busy = False
        for i in range(active.shape[0]):
            if active[i]:
                dx, dy = pos[i, 0] - p[0, 0], pos[i, 1] - p[0, 1]
                if np.sqrt(dx * dx + dy * dy) < clearance:
                    busy = True
                    break
        if not busy:
            return lane, s
    return -1, 0.0


@_njit
def respawn_kernel(words, buf, rows, lanes, active, pos, yaw, speed, lane_arr, s_arr, lat, stopped_at_sign, wait,
                   scenario, min_avoid, clearance, tries, points, heading, offset, n_points, gs, base,
                   length):  # pragma: no cover
    """Step 5 of ``World.step``: each of ``rows`` in order leaves the world (a scenario actor, or no
    free spot found) or is put back at rest on a free lane spot (:func:`free_lane_spot_kernel`
    away from the ego, ``traffic.place_on_lane``)."""
    for i in rows:
        if scenario[i] >= 0:
            active[i] = False
            continue
        lane, s = free_lane_spot_kernel(words, buf, lanes, active, pos, pos[0, 0], pos[0, 1], min_avoid, clearance,
                                        tries, points, heading, offset, n_points, gs, base, length)
        if lane < 0:
            active[i] = False
            continue
        place_kernel(i, lane, s, lane_arr, s_arr, lat, pos, yaw, stopped_at_sign, wait, points, heading, offset,
                     n_points, gs, base, length)
        speed[i] = 0.0


@_njit
def place_kernel(row, lane, s, lane_arr, s_arr, lat, pos, yaw, stopped_at_sign, wait, points, heading, offset,
                 n_points, gs, base, length):  # pragma: no cover
    """``traffic.place_on_lane`` for one row."""
    p, h = pose_at_kernel(np.full(1, lane, np.int64), np.full(1, s), points, heading, offset, n_points, gs, base,
                          length)
    lane_arr[row], s_arr[row], lat[row] = lane, s, 0.0
    pos[row, 0], pos[row, 1], yaw[row] = p[0, 0], p[0, 1], h[0]
    stopped_at_sign[row] = False
    wait[row] = 0.0


@_njit
def occupied_kernel(active, pos, x, y, radius):  # pragma: no cover
    """``traffic.occupied``: any active actor within ``radius`` m of ``(x, y)``."""
    for i in range(active.shape[0]):
        if active[i]:
            dx = pos[i, 0] - x
            dy = pos[i, 1] - y
            if np.sqrt(dx * dx + dy * dy) < radius:
                return True
    return False


@_njit
def lane_states_kernel(t, lanes, group, period, green, yellow, n_groups, offset, num_lanes):  # pragma: no cover
    """``signals.SignalPlan.lane_states``: ``(num_lanes,)`` signal state per lane at time ``t``."""
    out = np.full(num_lanes, _NO_SIGNAL, np.int64)
    for k in range(lanes.shape[0]):
        tm = (t + offset[k]) % _np_max(period[k] * n_groups[k], 1e-9)
        phase = np.int64(np.floor(tm / period[k]))
        within = tm - phase * period[k]
        state = _GREEN if within < green[k] else (_YELLOW if within < green[k] + yellow[k] else _RED)
        out[lanes[k]] = state if phase == group[k] else _RED
    return out


@_njit
def phase_valid_until_kernel(t, period, green, yellow, n_groups, offset, slack):  # pragma: no cover
    """``signals.SignalPlan._valid_until``: ``t`` plus the time to the nearest phase boundary
    (end of green, of yellow, of the phase) of any controlled lane, less ``slack``; ``t`` where a
    period is not positive, ``inf`` without lanes."""
    until = np.inf
    for k in range(period.shape[0]):
        if not period[k] > 0.0:
            return t
        tm = (t + offset[k]) % _np_max(period[k] * n_groups[k], 1e-9)
        within = tm - np.floor(tm / period[k]) * period[k]
        if within < green[k]:
            nxt = green[k]
        elif within < green[k] + yellow[k]:
            nxt = green[k] + yellow[k]
        else:
            nxt = period[k]
        until = min(until, t + (nxt - within) - slack)
    return until


@_njit
def leaders_kernel(idx, others, pos, yaw, length, width, speed, lookahead):  # pragma: no cover
    """``traffic.leaders``: gap (m) and approach rate (m/s) to each follower's corridor leader.

    Args:
        idx: ``(M,)`` follower rows. others: ``(O,)`` active rows. pos ... speed: the actor table's
            arrays. lookahead: search distance (m).

    Returns:
        ``(gap (M,), dv (M,), leader row (M,), -1 where none)``.
    """
    m = idx.shape[0]
    n = others.shape[0]
    gap_out = np.empty(m)
    dv_out = np.empty(m)
    who_out = np.full(m, -1, np.int64)
    # the others' columns gathered once, so that the corridor test below runs over contiguous
    # arrays without a branch (the CPU vectorizes it; the branchy test mispredicted about every
    # other pair); then only the few pairs in the corridor take the branchy part
    ox, oy, ow, ol = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    oc, osn = np.empty(n), np.empty(n)
    for q in range(n):
        o = others[q]
        ox[q], oy[q], ow[q], ol[q] = pos[o, 0], pos[o, 1], width[o], length[o]
        oc[q], osn[q] = np.cos(yaw[o]), np.sin(yaw[o])
    inside = np.empty(n, np.bool_)
    for a in range(m):
        i = idx[a]
        c, s = np.cos(yaw[i]), np.sin(yaw[i])
        px, py, wi, li = pos[i, 0], pos[i, 1], width[i], length[i]
        for q in range(n):
            d0 = ox[q] - px
            d1 = oy[q] - py
            dx = c * d0 + s * d1
            dy = -s * d0 + c * d1
            # a crossing actor's extent across the corridor is that of its oriented box
            sr = abs(c * osn[q] - s * oc[q])
            across = sr * ol[q] + abs(c * oc[q] + s * osn[q]) * ow[q]
            half = 0.5 * (wi + (across if sr > CROSSING_SIN else ow[q])) + CORRIDOR_MARGIN_M
            reach = 0.5 * (li + ol[q])
            inside[q] = (dx > 0.0) & (dx < lookahead + reach) & (abs(dy) < half)
        best = np.inf
        bj = -1
        bcos = 0.0
        for q in range(n):
            o = others[q]
            if not inside[q] or o == i:
                continue
            dx = c * (ox[q] - px) + s * (oy[q] - py)
            reach = 0.5 * (li + ol[q])
            cos_rel = np.cos(yaw[o] - yaw[i])
            crossing = abs(c * osn[q] - s * oc[q]) > CROSSING_SIN
            if not ((cos_rel < -0.5) and (speed[o] > 1.0) and not crossing) and dx - reach < best:
                best = dx - reach
                bj = o
                bcos = cos_rel
        gap_out[a] = max(best, 0.0)
        dv_out[a] = speed[i] - speed[bj] * max(bcos, 0.0) if best < np.inf else 0.0
        if best < np.inf:
            who_out[a] = bj
    return gap_out, dv_out, who_out
