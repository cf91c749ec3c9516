"""A uniform grid over a town's static boxes, so that a sight test visits the boxes near its
sensor instead of all of them.

``jit.points_blocked_kernel`` keeps every box whose bounding circle comes within ``reach`` of the
sensor (``jit.keeps_box``), scanning all boxes: ~375 static boxes per sensor in a town, of which
a few dozen are near. :func:`box_grid` puts each static box in every cell that its bounding square
(slightly enlarged) overlaps; :func:`boxes_near` returns the boxes of the cells that a square of
half-side ``reach`` (slightly enlarged) around the sensor overlaps, ascending and without repeats.
A box that ``keeps_box`` keeps has a point within ``reach`` of the sensor and within its circle,
which lies in both squares, so in a cell of both: the grid misses none, and the caller applies
``keeps_box`` to the candidates in ascending order, so it keeps the same boxes in the same order
as the scan (``tests/test_jit.py``).
"""

from __future__ import annotations

import numpy as np

from .jit import _njit

BOX_GRID_CELL_M = 20.0  # m, side of a cell
_PAD = 1.001  # relative enlargement of both squares (far above float64 rounding)
_PAD_M = 0.01  # m, absolute enlargement of the query square


def box_grid(center: np.ndarray, length: np.ndarray, width: np.ndarray, cell: float = BOX_GRID_CELL_M) -> tuple:
    """Grid over boxes ``(S,)``: ``(x0, y0, cell, nx, ny, cell_start (nx*ny + 1,), ids)``; the
    boxes in cell ``k = iy * nx + ix`` are ``ids[cell_start[k]:cell_start[k + 1]]``, ascending.
    No boxes: a 1 x 1 grid with no ids."""
    if len(center) == 0:
        return 0.0, 0.0, float(cell), 1, 1, np.zeros(2, np.int64), np.zeros(0, np.int64)
    rad = (0.5 * np.sqrt(length * length + width * width) + 1e-3) * _PAD
    lo, hi = center - rad[:, None], center + rad[:, None]
    x0, y0 = float(lo[:, 0].min()), float(lo[:, 1].min())
    nx = int((hi[:, 0].max() - x0) // cell) + 1
    ny = int((hi[:, 1].max() - y0) // cell) + 1
    keys, ids = [], []
    for j in range(len(center)):
        ix0, ix1 = int((lo[j, 0] - x0) // cell), min(int((hi[j, 0] - x0) // cell), nx - 1)
        iy0, iy1 = int((lo[j, 1] - y0) // cell), min(int((hi[j, 1] - y0) // cell), ny - 1)
        for iy in range(iy0, iy1 + 1):
            for ix in range(ix0, ix1 + 1):
                keys.append(iy * nx + ix)
                ids.append(j)
    keys_a, ids_a = np.array(keys, np.int64), np.array(ids, np.int64)
    order = np.lexsort((ids_a, keys_a))
    cell_start = np.searchsorted(keys_a[order], np.arange(nx * ny + 1)).astype(np.int64)
    return x0, y0, float(cell), nx, ny, cell_start, ids_a[order]


@_njit
def boxes_near(sx, sy, reach, x0, y0, cell, nx, ny, cell_start, ids):  # pragma: no cover
    """Ascending ids, without repeats, of the boxes in the cells that the square of half-side
    ``reach * 1.001 + 0.01`` around ``(sx, sy)`` overlaps (finite arguments only)."""
    half = reach * _PAD + _PAD_M
    ix0 = max(np.int64(np.floor((sx - half - x0) / cell)), 0)
    ix1 = min(np.int64(np.floor((sx + half - x0) / cell)), nx - 1)
    iy0 = max(np.int64(np.floor((sy - half - y0) / cell)), 0)
    iy1 = min(np.int64(np.floor((sy + half - y0) / cell)), ny - 1)
    total = 0
    for iy in range(iy0, iy1 + 1):
        for ix in range(ix0, ix1 + 1):
            k = iy * nx + ix
            total += cell_start[k + 1] - cell_start[k]
    found = np.empty(total, np.int64)
    m = 0
    for iy in range(iy0, iy1 + 1):
        for ix in range(ix0, ix1 + 1):
            k = iy * nx + ix
            for q in range(cell_start[k], cell_start[k + 1]):
                found[m] = ids[q]
                m += 1
    found.sort()
    out = np.empty(m, np.int64)
    u = 0
    for q in range(m):
        if u == 0 or found[q] != out[u - 1]:
            out[u] = found[q]
            u += 1
    return out[:u]
