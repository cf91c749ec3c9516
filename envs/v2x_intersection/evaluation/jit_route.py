"""The ego's continuous progress along its route (a numba kernel, plain Python without numba).

The route monitor (``infractions.EventMonitor``, ``jit_perception.route_monitor_kernel``) counts
progress as the furthest route *point* (1 m apart) within ``PROGRESS_RADIUS_M`` of the ego among
the next ``PROGRESS_WINDOW`` points. :func:`route_progress_kernel` is its continuous version: the
furthest *position on the route polyline* within that radius, so the progress reward
(``episode.route_progress``) moves with the ego, not in 1 m steps, and always lies between the
monitor's point and the next one (``floor`` of it is the monitor's index).
"""

from __future__ import annotations

import math

from ..core.jit import _njit

#: m, a route point (or polyline position) this close to the ego counts as reached
PROGRESS_RADIUS_M = 3.0
#: route points searched ahead of the monitor's progress index (as the monitor does)
PROGRESS_WINDOW = 40


@_njit
def route_progress_kernel(points, s, k0, x, y, radius, window):  # pragma: no cover
    """The furthest arc length (m) on the route polyline ``points (P, 2)`` (arc lengths ``s (P,)``,
    m) within ``radius`` (m) of ``(x, y)``, among points ``k0`` to ``k0 + window - 1``; ``s[k0]``
    when none of that stretch is within ``radius``."""
    n = points.shape[0]
    hi = min(k0 + window, n) - 1  # the last segment searched is (hi - 1, hi)
    r2 = radius * radius
    for k in range(hi - 1, k0 - 1, -1):  # from the far end: the first hit is the furthest
        ax, ay = points[k, 0] - x, points[k, 1] - y
        dx, dy = points[k + 1, 0] - points[k, 0], points[k + 1, 1] - points[k, 1]
        a = dx * dx + dy * dy
        if a <= 0.0:
            continue
        b = ax * dx + ay * dy
        disc = b * b - a * (ax * ax + ay * ay - r2)  # |A - P + t D|^2 <= r^2 for t in the roots
        if disc < 0.0:
            continue
        root = math.sqrt(disc)
        t_hi = (-b + root) / a
        t_lo = (-b - root) / a
        if t_hi < 0.0 or t_lo > 1.0:
            continue
        t = t_hi if t_hi < 1.0 else 1.0
        return s[k] + t * (s[k + 1] - s[k])
    return s[min(k0, n - 1)]
