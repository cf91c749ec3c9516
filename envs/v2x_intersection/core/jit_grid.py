"""A uniform grid over polyline vertices, for exact nearest-vertex queries in O(1) cells.

``PolylineIndex.project`` finds the nearest vertex among a set of candidate vertex ids by scanning
all of them (``jit.project_kernel``), which is 6,000 to 12,000 points per query for a town's
driving lanes. :func:`point_grid` buckets the candidates into square cells; :func:`nearest_in_grid`
searches rings of cells around the query until no unsearched cell can hold a nearer point, and
breaks ties by the position in the candidate list, as the scan does. So
:func:`project_grid_kernel` returns exactly what ``project_kernel`` returns (``tests/core/test_jit.py``).
"""

from __future__ import annotations

import numpy as np

from .jit import _njit, project_refine

GRID_CELL_M = 10.0  # m, side of a grid cell


def point_grid(points: np.ndarray, pid: np.ndarray, cell: float = GRID_CELL_M) -> tuple:
    """Grid over ``points[pid]``: ``(x0, y0, cell, nx, ny, cell_start (nx*ny + 1,), order)`` where
    the candidate positions (indices into ``pid``) in cell ``k = iy * nx + ix`` are
    ``order[cell_start[k]:cell_start[k + 1]]``, ascending."""
    xy = points[pid]
    x0, y0 = float(xy[:, 0].min()), float(xy[:, 1].min())
    nx = int((xy[:, 0].max() - x0) // cell) + 1
    ny = int((xy[:, 1].max() - y0) // cell) + 1
    ix = np.minimum(((xy[:, 0] - x0) // cell).astype(np.int64), nx - 1)
    iy = np.minimum(((xy[:, 1] - y0) // cell).astype(np.int64), ny - 1)
    key = iy * nx + ix
    order = np.argsort(key, kind="stable").astype(np.int64)
    cell_start = np.searchsorted(key[order], np.arange(nx * ny + 1)).astype(np.int64)
    return x0, y0, float(cell), nx, ny, cell_start, order


@_njit
def _scan_cell(k, x, y, points, pid, cell_start, order, best_d2, best_pos):  # pragma: no cover
    for q in range(cell_start[k], cell_start[k + 1]):
        pos = order[q]
        p = pid[pos]
        dx = x - points[p, 0]
        dy = y - points[p, 1]
        d2 = dx * dx + dy * dy
        if d2 < best_d2 or (d2 == best_d2 and pos < best_pos):
            best_d2, best_pos = d2, pos
    return best_d2, best_pos


@_njit
def nearest_in_grid(x, y, points, pid, x0, y0, cell, nx, ny, cell_start, order):  # pragma: no cover
    """Position in ``pid`` of the vertex nearest ``(x, y)`` (the first such position on ties; 0,
    as the scan gives, when no distance compares, e.g. for a NaN query)."""
    if not (x == x and y == y):
        return 0
    cx = min(max(np.int64((x - x0) // cell), 0), nx - 1)
    cy = min(max(np.int64((y - y0) // cell), 0), ny - 1)
    best_d2, best_pos = np.inf, pid.shape[0]
    r = 0
    while True:
        for j in range(max(cy - r, 0), min(cy + r, ny - 1) + 1):  # the cells of ring r, row by row
            edge_row = j == cy - r or j == cy + r
            for i in range(max(cx - r, 0), min(cx + r, nx - 1) + 1):
                if edge_row or i == cx - r or i == cx + r:
                    best_d2, best_pos = _scan_cell(j * nx + i, x, y, points, pid, cell_start, order, best_d2,
                                                   best_pos)
        # the searched cells form the rectangle [cx - r, cx + r] x [cy - r, cy + r]; a point outside
        # it is at least as far as the nearest of its sides that is not the grid's border
        bound = np.inf
        if cx - r > 0:
            bound = min(bound, x - (x0 + (cx - r) * cell))
        if cx + r < nx - 1:
            bound = min(bound, (x0 + (cx + r + 1) * cell) - x)
        if cy - r > 0:
            bound = min(bound, y - (y0 + (cy - r) * cell))
        if cy + r < ny - 1:
            bound = min(bound, (y0 + (cy + r + 1) * cell) - y)
        if bound == np.inf or (best_pos < pid.shape[0] and best_d2 < bound * bound):
            return best_pos
        r += 1


@_njit
def project_grid_kernel(x, y, points, pid, owner, offset, n_points, gs, base, x0, y0, cell, nx, ny, cell_start,
                        order):  # pragma: no cover
    """``jit.project_kernel`` for one query ``(x, y)``, its nearest vertex found on the grid.

    Returns:
        ``(polyline, s, dist)``.
    """
    j = pid[nearest_in_grid(x, y, points, pid, x0, y0, cell, nx, ny, cell_start, order)]
    return project_refine(x, y, j, points, owner, offset, n_points, gs, base)
