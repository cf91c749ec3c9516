"""numba kernels for populating a world at reset (``world.World._spawn_*``): NPC vehicles and
bicycles on free lane spots, pedestrians on sidewalks. Every draw comes from the world's generator
(:mod:`.jit_rng`) in the NumPy path's order, so a reset gives the same actors and leaves the
generator in the same state with or without numba (``tests/core/test_jit.py``).
"""

from __future__ import annotations

import numpy as np

from ..core.jit import _njit, pose_at_kernel
from ..core.jit_rng import integers, next_double, uniform
from .jit_vehicles import free_lane_spot_kernel, place_kernel

_SIGNS = (-1.0, 1.0)


@_njit
def spawn_followers_kernel(words, buf, row, count, riders, lanes, min_avoid, clearance, tries, large_fraction, kinds,
                           behaviour_code, size_lo, size_hi, v0_lo, v0_hi, start_fraction, kind, behaviour, active,
                           box_l, box_w, box_h, v0, speed, lane_arr, s_arr, lat, pos, yaw, stopped_at_sign, wait,
                           speed_limit, points, heading, offset, n_points, gs, base, length):  # pragma: no cover
    """``World._spawn_drivers`` (``riders`` false) or ``World._spawn_riders``: up to ``count``
    followers from row ``row`` on free spots of ``lanes`` (``free_lane_spot_kernel`` with
    ``min_avoid`` from the ego in row 0, ``clearance`` and ``tries``; stopping at the first spot not
    found), starting at ``start_fraction`` of their desired speed (times the speed limit for
    vehicles).

    ``kinds``: ``(car, large vehicle, bicycle)`` class ids; ``size_lo``/``size_hi``: ``(3, 3)``
    ``actors.SIZES`` bounds (length, width, height) and ``v0_lo``/``v0_hi``: ``(3,)`` desired
    speed ranges, in that order; ``box_l``, ``box_w``, ``box_h``: the table's size columns.

    Returns:
        the next free row.
    """
    ax, ay = pos[0, 0], pos[0, 1]
    for _ in range(count):
        lane, s = free_lane_spot_kernel(words, buf, lanes, active, pos, ax, ay, min_avoid, clearance, tries, points,
                                        heading, offset, n_points, gs, base, length)
        if lane < 0:
            break
        if riders:
            c = 2
        else:
            c = 1 if next_double(words) < large_fraction else 0
        kind[row], behaviour[row], active[row] = kinds[c], behaviour_code, True
        box_l[row] = uniform(words, size_lo[c, 0], size_hi[c, 0])  # actors.draw_size
        box_w[row] = uniform(words, size_lo[c, 1], size_hi[c, 1])
        box_h[row] = uniform(words, size_lo[c, 2], size_hi[c, 2])
        v0[row] = uniform(words, v0_lo[c], v0_hi[c])
        place_kernel(row, lane, s, lane_arr, s_arr, lat, pos, yaw, stopped_at_sign, wait, points, heading, offset,
                     n_points, gs, base, length)
        speed[row] = v0[row] * start_fraction if riders else start_fraction * v0[row] * speed_limit[lane]
        row += 1
    return row


@_njit
def spawn_walkers_kernel(words, buf, row, count, kind_code, behaviour_code, size_lo, size_hi, lat_lo, lat_hi,
                         speed_lo, speed_hi, kind, behaviour, active, box_l, box_w, box_h, path, path_s, path_dir, lat,
                         speed, pos, yaw, points, heading, offset, n_points, gs, base, length):  # pragma: no cover
    """``World._spawn_walkers``: ``count`` pedestrians from row ``row`` at random places of random
    sidewalks (the sidewalk index's arrays), with a random direction, a lateral offset drawn in
    ``[lat_lo, lat_hi)`` and a speed in ``[speed_lo, speed_hi)``.

    Returns:
        the next free row.
    """
    one = np.empty(1, np.int64)
    at = np.empty(1)
    for _ in range(count):
        sw = integers(words, buf, length.shape[0])
        kind[row], behaviour[row], active[row] = kind_code, behaviour_code, True
        box_l[row] = uniform(words, size_lo[0], size_hi[0])
        box_w[row] = uniform(words, size_lo[1], size_hi[1])
        box_h[row] = uniform(words, size_lo[2], size_hi[2])
        path[row], path_s[row] = sw, uniform(words, 0.0, length[sw])
        path_dir[row] = _SIGNS[integers(words, buf, 2)]
        lat[row] = uniform(words, lat_lo, lat_hi)
        speed[row] = uniform(words, speed_lo, speed_hi)
        one[0], at[0] = sw, path_s[row]
        p, h = pose_at_kernel(one, at, points, heading, offset, n_points, gs, base, length)
        pos[row, 0] = p[0, 0] + lat[row] * -np.sin(h[0])
        pos[row, 1] = p[0, 1] + lat[row] * np.cos(h[0])
        yaw[row] = h[0] if path_dir[row] > 0 else h[0] + np.pi
        row += 1
    return row
