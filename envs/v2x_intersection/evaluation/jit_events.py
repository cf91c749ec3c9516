"""numba kernel for step 6 of a tick (``World.check_events``): the ego's contacts, its route
progress and the lane-relative events of ``infractions.EventMonitor``, in one call.

:func:`monitor_kernel` repeats ``EventMonitor.update``'s Python lane tests in the same order with
the same float operations, so both paths emit the same events with the same values and leave
the monitor in the same state (``tests/evaluation/test_physics_infractions.py`` runs the monitor's tests on
both paths; ``tests/core/test_jit.py`` compares whole worlds). One call replaces two kernels
(``physics.ego_contacts_kernel``, ``jit_perception.route_monitor_kernel``) and the Python
between them; the episode's arguments come in a typed list of one tuple
(:class:`~.jit_args.PackedArgs`).

The monitor's running state lives in one float64 array (``STATE_*`` slots, defined here and
used by both paths); the collision filter stays in Python (contacts are rare).
"""

from __future__ import annotations

import numpy as np

from ..core.jit import _njit, _njit_inline
from ..perception.jit_perception import route_monitor_kernel
from .physics import ego_contacts_kernel

#: slots of ``EventMonitor``'s state array
(STATE_OUTSIDE_M, STATE_DRIVEN_M, STATE_STILL_S, STATE_HELD_BY_RED, STATE_LANE, STATE_S_ON_LANE,
 STATE_MIN_SPEED_NEAR_LINE, STATE_WRONG_WAY, STATE_OUTSIDE, STATE_OFF_ROAD, STATE_ROUTE_LANES_TEST) = range(11)
STATE_SIZE = 11
#: most lane events one tick can emit (deviation, outside, off road, wrong way, a stop line, blocked)
MAX_LANE_EVENTS = 6

# event codes, limits and lane kinds (infractions.py imports this module, so they are repeated
# here; tests/evaluation/test_physics_infractions.py compares them)
_RED_LIGHT, _STOP_SIGN, _OUTSIDE_LANES, _OFF_ROAD, _WRONG_WAY, _ROUTE_DEVIATION, _BLOCKED = 3, 4, 5, 6, 7, 8, 9
_ROUTE_DEVIATION_M = 30.0
_BLOCKED_S = 180.0
_STOP_SPEED = 0.5
_STOP_CHECK_M = 6.0
_HELD_SPEED = 1.0
_HELD_BY_RED_M = 15.0
_RED = 2
_CONNECTOR = 1


@_njit_inline
def _emit(codes, values, ne, code, value):  # pragma: no cover
    codes[ne] = code
    values[ne] = value
    return ne + 1


@_njit_inline
def lane_events_kernel(lane, s, dist, heading, dev, v, yaw, ego_length, moved, dt, lane_signal, lane_width,
                       lane_kind, lane_length, stop_at_end, stop_lane, on_route, setback, counts, state, codes,
                       values):  # pragma: no cover
    """``EventMonitor.update`` after the contacts and the route progress: the route deviation,
    the route's lanes left (``on_route``: per lane, whether the route takes it) and roads left,
    wrong way, red lights and stop signs at the stop line, held by a red light, blocked.
    Updates ``state`` in place; writes the events' codes and values into ``codes`` / ``values``
    and returns how many."""
    ne = 0
    state[STATE_DRIVEN_M] += moved
    if dev > _ROUTE_DEVIATION_M and counts[_ROUTE_DEVIATION] == 0:
        ne = _emit(codes, values, ne, _ROUTE_DEVIATION, dev)
    half = lane_width[lane] / 2.0
    off_lanes = dist > half + 0.3
    other_lane = state[STATE_ROUTE_LANES_TEST] != 0.0 and lane_kind[lane] != _CONNECTOR and not on_route[lane]
    outside = off_lanes or other_lane
    if outside:
        state[STATE_OUTSIDE_M] += moved
    if outside and state[STATE_OUTSIDE] == 0.0:
        ne = _emit(codes, values, ne, _OUTSIDE_LANES, dist)
    off_road = dist > half + 2.0
    if off_road and state[STATE_OFF_ROAD] == 0.0:
        ne = _emit(codes, values, ne, _OFF_ROAD, dist)
    state[STATE_OUTSIDE] = 1.0 if outside else 0.0
    state[STATE_OFF_ROAD] = 1.0 if off_road else 0.0
    wrong = v > 1.0 and not off_lanes and abs(((yaw - heading + np.pi) % (2 * np.pi)) - np.pi) > 2.1
    wrong = wrong and lane_kind[lane] != _CONNECTOR
    if wrong and state[STATE_WRONG_WAY] == 0.0:
        ne = _emit(codes, values, ne, _WRONG_WAY, float(lane))
    state[STATE_WRONG_WAY] = 1.0 if wrong else 0.0
    at_end = stop_at_end[lane]
    line = lane_length[lane] - setback
    if lane == np.int64(state[STATE_LANE]):
        if at_end and line - _STOP_CHECK_M < s and v < state[STATE_MIN_SPEED_NEAR_LINE]:
            state[STATE_MIN_SPEED_NEAR_LINE] = v  # Python's min(): the first unless the second is less
        if at_end and state[STATE_S_ON_LANE] < line and line <= s:
            if lane_signal[lane] == _RED:
                ne = _emit(codes, values, ne, _RED_LIGHT, float(lane))
            elif lane_signal[lane] == -1 and stop_lane[lane] and state[STATE_MIN_SPEED_NEAR_LINE] > _STOP_SPEED:
                ne = _emit(codes, values, ne, _STOP_SIGN, float(lane))
    else:
        state[STATE_MIN_SPEED_NEAR_LINE] = np.inf
    state[STATE_LANE] = lane
    state[STATE_S_ON_LANE] = s
    gap = line - s - 0.5 * ego_length  # the ego's front to the stop line
    held = at_end and lane_signal[lane] == _RED and v < _HELD_SPEED and gap <= _HELD_BY_RED_M
    state[STATE_HELD_BY_RED] = 1.0 if held else 0.0
    if v >= 0.1:
        state[STATE_STILL_S] = 0.0
    elif not held:
        state[STATE_STILL_S] = state[STATE_STILL_S] + dt
    if state[STATE_STILL_S] >= _BLOCKED_S:
        ne = _emit(codes, values, ne, _BLOCKED, state[STATE_STILL_S])
        state[STATE_STILL_S] = 0.0
    return ne


@_njit
def monitor_kernel(consts, lane_signal, progress, moved, ox, oy, with_contacts):  # pragma: no cover
    """One tick of ``EventMonitor``: with ``with_contacts`` the ego's contacts (into the contact
    buffer) and the distance it moved from ``(ox, oy)``, else ``moved`` as given; then the route
    progress (``route_monitor_kernel``) and :func:`lane_events_kernel`.

    ``consts[0]`` (``EventMonitor._kernel_args``): ``(pos, yaw, length, width, active, speed, statics,
    static_cos, static_sin, static_radius, route_points, points, pid, owner, offset, n_points, gs,
    base, heading, lane_length, x0, y0, cell, nx, ny, cell_start, order, lane_width, lane_kind,
    stop_at_end, stop_lane, setback, dt, counts, state, contacts, codes, values, on_route)``.

    Returns:
        ``(contacts, progress, events)``: how many contacts and lane events were written, and
        the new route progress.
    """
    c = consts[0]
    pos, yaw = c[0], c[1]
    nc = 0
    ex, ey = pos[0, 0], pos[0, 1]
    if with_contacts:
        found = ego_contacts_kernel(pos, yaw, c[2], c[3], c[4], c[6], c[7], c[8], c[9])
        buf = c[35]
        nc = found.shape[0]
        for k in range(nc):
            buf[k] = found[k]
        dx, dy = ex - ox, ey - oy
        moved = np.sqrt(dx * dx + dy * dy)
    progress, dev, lane, s, dist, heading = route_monitor_kernel(
        c[10], progress, ex, ey, c[11], c[12], c[13], c[14], c[15], c[16], c[17], c[18], c[19], c[20], c[21],
        c[22], c[23], c[24], c[25], c[26])
    ne = lane_events_kernel(lane, s, dist, heading, dev, c[5][0], yaw[0], c[2][0], moved, c[32], lane_signal, c[27],
                            c[28], c[19], c[29], c[30], c[38], c[31], c[33], c[34], c[36], c[37])
    return nc, progress, ne
