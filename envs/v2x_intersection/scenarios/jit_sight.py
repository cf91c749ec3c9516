"""numba kernel for the V2X scenarios' sight-line test (``scenarios.v2x.sight_blocked``).

Scenarios that hide a hazard search for a spot at reset, testing the sight lines from a few eye
points to a few points on a candidate box, against the town's buildings and poles within 90 m and
a vehicle just placed. The NumPy path builds a ``raycast.Boxes``, prepares it relative to the first
eye (``raycast._setup`` / ``_Prepared``) and calls ``segments_blocked``: ~150-300 us of array
set-up per test. :func:`sight_fraction_kernel` does the same steps in one call, with the same float
operations in the same order and dtype (the boxes' yaw cosines and sines come from NumPy), and
ends in the same ``jit.segments_blocked_kernel``; ``tests/core/test_jit.py`` compares both paths.
"""

from __future__ import annotations

import numpy as np

from ..core.jit import _njit
from ..core.jit_raycast import segments_blocked_kernel

KEEP_RADIUS_M = 90.0  # m, statics farther than this from the targets' mean are not tested


@_njit
def sight_fraction_kernel(eyes, targets, statics, heights, static_cos, static_sin, extra, extra_cos, extra_sin,
                          keep_radius, lo, hi):  # pragma: no cover
    """Fraction of the sight lines from each of ``eyes (E, 3)`` to each of ``targets (T, 3)``
    (eye-major, as ``np.repeat`` / ``np.tile`` order them) that a box blocks: the ``statics (S, 5)``
    ``(x, y, length, width, yaw)`` of height ``heights`` within ``keep_radius`` of the targets'
    mean, then the ``extra (X, 6)`` boxes ``(x, y, length, width, yaw, height)``; ``*_cos`` /
    ``*_sin``: their yaw's cosine and sine (from NumPy). ``lo``, ``hi``: float32 end tolerances."""
    ne, nt = eyes.shape[0], targets.shape[0]
    r = ne * nt
    if r == 0:
        return np.nan  # the mean of no sight lines, as NumPy's
    mx, my = targets[0, 0], targets[0, 1]  # NumPy's mean over axis 0: rows added in order, / T
    for k in range(1, nt):
        mx += targets[k, 0]
        my += targets[k, 1]
    mx, my = mx / nt, my / nt
    ns, nx = statics.shape[0], extra.shape[0]
    rows = np.empty(ns + nx, np.int64)  # kept statics (ascending), then the extras (as -1 - k)
    n = 0
    for k in range(ns):
        dx, dy = statics[k, 0] - mx, statics[k, 1] - my
        if np.sqrt(dx * dx + dy * dy) < keep_radius:
            rows[n] = k
            n += 1
    for k in range(nx):
        rows[n] = -1 - k
        n += 1
    # raycast._setup: origins relative to the first one (float32), one row when all are equal
    ref0, ref1 = eyes[0, 0], eyes[0, 1]
    same = True
    for e in range(ne):
        for a in range(3):
            if not eyes[e, a] == eyes[0, a]:
                same = False
    o = np.empty((1 if same else r, 3), np.float32)
    d = np.empty((r, 3), np.float32)
    for e in range(ne):
        for t in range(nt):
            i = e * nt + t
            if not same or i == 0:
                o[i, 0], o[i, 1], o[i, 2] = eyes[e, 0] - ref0, eyes[e, 1] - ref1, eyes[e, 2]
            for a in range(3):
                d[i, a] = targets[t, a] - eyes[e, a]
    # raycast._Prepared of the kept boxes
    c32, s32 = np.empty(n, np.float32), np.empty(n, np.float32)
    bx, by = np.empty(n, np.float32), np.empty(n, np.float32)
    hl, hw = np.empty(n, np.float32), np.empty(n, np.float32)
    z0, z1 = np.zeros(n, np.float32), np.empty(n, np.float32)
    for q in range(n):
        k = rows[q]
        if k >= 0:
            x, y, ln, wd, c, s, h = (statics[k, 0], statics[k, 1], statics[k, 2], statics[k, 3], static_cos[k],
                                     static_sin[k], heights[k])
        else:
            k = -1 - k
            x, y, ln, wd, c, s, h = (extra[k, 0], extra[k, 1], extra[k, 2], extra[k, 3], extra_cos[k], extra_sin[k],
                                     extra[k, 5])
        rel0, rel1 = x - ref0, y - ref1
        c32[q], s32[q] = np.float32(c), np.float32(s)
        bx[q] = np.float32(c * rel0 + s * rel1)
        by[q] = np.float32(-s * rel0 + c * rel1)
        hl[q], hw[q] = np.float32(0.5 * ln), np.float32(0.5 * wd)
        z1[q] = np.float32(0.0 + h)
    blocked = segments_blocked_kernel(o, d, c32, s32, bx, by, hl, hw, z0, z1, np.zeros((r, 0), np.int64), lo, hi)
    cnt = 0
    for i in range(r):
        if blocked[i]:
            cnt += 1
    return np.float64(cnt) / r
