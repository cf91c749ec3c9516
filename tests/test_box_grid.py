"""The static-box grid of perception (``jit_box_grid``) keeps exactly the boxes the full scan keeps."""

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.config import make_config
from v2xbench.envs.v2x_intersection.jit import HAVE_JIT, keeps_box
from v2xbench.envs.v2x_intersection.jit_box_grid import box_grid
from v2xbench.envs.v2x_intersection.world import World

pytestmark = pytest.mark.skipif(not HAVE_JIT, reason="numba not installed")


def _scan(sx, sy, reach, center, length, width, extra):
    """The reference: ``points_blocked_kernel``'s scan, in plain Python."""
    keep = keeps_box.py_func
    return [j for j in range(len(center)) if keep(j, sx, sy, center, length, width, extra, reach)]


@pytest.mark.parametrize("town", ["Town01", "Town03", "Town12"])
def test_grid_keeps_what_the_scan_keeps(town):
    from v2xbench.envs.v2x_intersection.jit_perception import _occluders_near, occluder_arrays

    w = World(make_config(town=town, num_vehicles=10, num_pedestrians=4))
    w.reset(seed=1)
    n = len(w.table)
    xy, geo = occluder_arrays(n, w.static_boxes, w.static_heights, *w.static_trig)
    xy[:n] = w.table.pos
    geo[2, :n], geo[3, :n] = w.table.length, w.table.width
    grid = w.static_grid
    x0, y0, cell, nx, ny = grid[:5]
    rng = np.random.default_rng(0)
    sensors = [(rng.uniform(x0 - 150, x0 + nx * cell + 150), rng.uniform(y0 - 150, y0 + ny * cell + 150))
               for _ in range(150)]
    sensors += [(x0 + i * cell, y0 + j * cell) for i in (0, 1, nx // 2, nx) for j in (0, 1, ny // 2, ny)]
    sensors += [tuple(w.static_boxes[k, :2]) for k in range(0, len(w.static_boxes), 25)]
    sensors += [(np.nan, 0.0), (0.0, np.inf)]
    kept_statics = 0
    for i, (sx, sy) in enumerate(sensors):
        reach = float(rng.choice([1.0, 7.5, 30.0, 61.0, 76.0, 200.0, np.nextafter(20.0, 0.0)]))
        extra = np.array([0] if i % 2 else [], np.int64)
        got = _occluders_near(sx, sy, reach, n, xy, geo[2], geo[3], extra, *grid).tolist()
        want = _scan(sx, sy, reach, xy, geo[2], geo[3], extra)
        assert got == want, (sx, sy, reach)
        kept_statics += sum(j >= n for j in want)
    assert kept_statics > 100  # the sensors do see static boxes


def test_box_grid_lists_each_box_in_every_cell_it_overlaps():
    center = np.array([[0.0, 0.0], [45.0, 5.0], [100.0, 100.0]])
    length, width = np.array([30.0, 2.0, 1.0]), np.array([30.0, 2.0, 1.0])
    x0, y0, cell, nx, ny, start, ids = box_grid(center, length, width, cell=20.0)
    cells = {k: ids[start[k]:start[k + 1]].tolist() for k in range(nx * ny)}
    big = [k for k, v in cells.items() if 0 in v]
    assert len(big) == 9  # a 42 m bounding square over 20 m cells starting at its corner: 3 x 3 cells
    assert sum(1 in v for v in cells.values()) >= 1 and sum(2 in v for v in cells.values()) >= 1
    assert all(v == sorted(v) for v in cells.values())
    empty = box_grid(np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    assert empty[3:5] == (1, 1) and len(empty[6]) == 0
