"""Vectorized map ground truth: on the town's lanes, road edges and crosswalks, in the ego frame
and in a roadside unit's pitched and rolled frame, cut to the range, resampled."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from v2xbench.envs.v2x_intersection.core.geometry import (
    invert_transform,
    offset_polyline,
    polyline_lengths,
    pose_matrix,
    transform_points,
)
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.areas import junction_roads, lane_markings
from v2xbench.envs.v2x_intersection.town.map_vectors import (
    BOUNDARY,
    CROSSWALK,
    DIVIDER,
    frame_to_ground,
    map_vectors,
    town_vectors,
)
from v2xbench.envs.v2x_intersection.town.model import CONNECTOR, DRIVING, RAMP
from v2xbench.envs.v2x_intersection.v2x.rsu import RSU_HEIGHT, RSU_PITCH, RSU_ROLL

TOWN = "Town01"
EGO_RANGE = (-30.0, -15.0, -5.0, 30.0, 15.0, 3.0)
RSU_RANGE = (0.0, -25.0, -20.0, 50.0, 25.0, 2.0)


def _dense(poly: np.ndarray, closed: bool = False, step: float = 0.05) -> np.ndarray:
    """Points every ``step`` m along a polyline (or a ring)."""
    p = np.concatenate([poly, poly[:1]]) if closed else poly
    s = polyline_lengths(p)
    t = np.linspace(0.0, s[-1], max(2, int(s[-1] / step) + 1))
    return np.stack([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])], -1)


def _dist(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Distance of each query point to the nearest reference point."""
    return cKDTree(ref).query(np.asarray(q, np.float64).reshape(-1, 2))[0]


def _class_points(tv, k: int, step: float = 0.05) -> np.ndarray:
    """The town's elements of class ``k`` sampled every ``step`` m."""
    return np.concatenate([_dense(tv.points[tv.start[e]:tv.start[e] + tv.count[e]],
                                  bool(tv.closed[e]), step) for e in np.flatnonzero(tv.label == k)])


@pytest.fixture(scope="module")
def town():
    return get_town(TOWN)


@pytest.fixture(scope="module")
def geometry(town):
    """The town's own geometry, densely sampled: lane edges (every lane, both sides), junction
    drivable-area outlines (``areas.junction_roads``) and crosswalk outlines."""
    edges = [_dense(offset_polyline(ln.points, s * ln.width / 2)) for ln in town.lanes
             if ln.kind in (DRIVING, RAMP, CONNECTOR) for s in (1.0, -1.0)]
    hulls = [_dense(h, closed=True) for h in junction_roads(town)]
    cross = [_dense(c.corners, closed=True) for c in town.crosswalks]
    return {"edges": np.concatenate(edges), "hulls": np.concatenate(hulls),
            "cross": np.concatenate(cross)}


def _check_on_town(world_pts: np.ndarray, labels: np.ndarray, geometry: dict,
                   cut: np.ndarray | None = None) -> None:
    """Points of each class lie on the town's geometry of that class; ``cut`` marks points on
    the range's edge (a crosswalk outline cut by the range is closed along it)."""
    cut = np.zeros(len(labels), bool) if cut is None else cut
    div, bnd = (world_pts[labels == k] for k in (DIVIDER, BOUNDARY))
    crs = world_pts[(labels == CROSSWALK) & ~cut]
    assert len(div) and len(bnd) and len(crs), "the view should hold all three classes"
    assert _dist(div, geometry["edges"]).max() < 0.03
    road_edge = np.minimum(_dist(bnd, geometry["edges"]), _dist(bnd, geometry["hulls"]))
    assert road_edge.max() < 0.25  # junction corners: the mouth hull, within cm of junction_roads
    assert _dist(crs, geometry["cross"]).max() < 0.03


def test_town_elements_are_the_painted_lines_and_road_edges(town, geometry):
    tv = town_vectors(town)
    assert town_vectors(town) is tv  # cached on the town
    assert set(np.unique(tv.label)) == {DIVIDER, BOUNDARY, CROSSWALK}
    assert tv.closed[tv.label == CROSSWALK].all() and not tv.closed[tv.label == DIVIDER].any()
    assert np.diff(tv.points, axis=0)[np.diff(tv.element) == 0].max() <= 1.0 + 1e-9
    _check_on_town(tv.points, tv.label[tv.element], geometry)
    # every painted marking of the renderer lies on a divider (dashed white, yellow) or on a
    # road boundary (solid white road edge)
    div, bnd = _class_points(tv, DIVIDER), _class_points(tv, BOUNDARY)
    for pts, colour, _ in lane_markings(town):
        q = _dense(pts, step=0.5)
        dashed_or_yellow = colour == "yellow" or polyline_lengths(pts)[-1] < 3.5
        target = div if dashed_or_yellow else bnd
        assert _dist(q, target).max() < 0.05, (colour, pts[0])
    # junction corners join lane edges into kerbs around the blocks (Town01: 4 inner blocks)
    assert tv.closed[tv.label == BOUNDARY].sum() == 4


def _ego_pose(town) -> np.ndarray:
    """On an incoming lane, 15 m before its junction."""
    ln = next(ln for ln in town.lanes if ln.kind == DRIVING and ln.junction_ahead >= 0
              and ln.length > 40 and ln.opposite >= 0)
    p, h = town.index.pose_at(np.array([ln.id]), np.array([ln.length - 15.0]))
    return pose_matrix(p[0, 0], p[0, 1], 0.0, float(h[0]))


def _rsu_pose(town) -> np.ndarray:
    """A roadside unit at a junction corner, 5 m up, pitched and rolled, looking at it."""
    j = town.junctions[0]
    pos = j.center + np.array([-j.radius - 6.0, -j.radius - 6.0])
    yaw = float(np.arctan2(*(j.center - pos)[::-1]))
    return pose_matrix(pos[0], pos[1], RSU_HEIGHT, yaw, RSU_PITCH, RSU_ROLL)


@pytest.mark.parametrize("frame", ["ego", "rsu"])
def test_frame_elements_lie_on_the_town_and_in_range(town, geometry, frame):
    t_wf = _ego_pose(town) if frame == "ego" else _rsu_pose(town)
    rng = EGO_RANGE if frame == "ego" else RSU_RANGE
    mv = map_vectors(town, t_wf, rng, num_points=20)
    assert mv.points.shape == (len(mv), 20, 2) and mv.points.dtype == np.float32
    assert mv.labels.dtype == np.int64 and mv.closed.dtype == bool
    x, y = mv.points[..., 0], mv.points[..., 1]
    eps = 1e-4
    assert (x >= rng[0] - eps).all() and (x <= rng[3] + eps).all()
    assert (y >= rng[1] - eps).all() and (y <= rng[4] + eps).all()
    # back to the world: a ground point whose frame x, y are the element's
    world = frame_to_ground(t_wf, mv.points.astype(np.float64))
    back = transform_points(invert_transform(t_wf), np.c_[world.reshape(-1, 2),
                                                          np.zeros(world.size // 2)])
    assert np.abs(back[:, :2] - mv.points.reshape(-1, 2)).max() < 1e-3
    if frame == "rsu":  # the pitched frame: the ground is not its x-y plane
        assert np.ptp(back[:, 2]) > 3.0
    flat = mv.points.reshape(-1, 2)
    on_edge = np.minimum.reduce([np.abs(flat[:, 0] - rng[0]), np.abs(flat[:, 0] - rng[3]),
                                 np.abs(flat[:, 1] - rng[1]), np.abs(flat[:, 1] - rng[4])]) < 1e-3
    _check_on_town(world.reshape(-1, 2), np.repeat(mv.labels, 20), geometry, on_edge)
    # resampled evenly: equal spacing along each element
    d = np.linalg.norm(np.diff(mv.points.astype(np.float64), axis=1), axis=2)
    opened = ~mv.closed
    assert (d[opened].max(1) <= d[opened].mean(1) * 1.01 + 1e-3).all()


def test_clipping_keeps_exactly_the_part_in_range(town):
    """The lengths of the cut elements equal the lengths of the town's elements inside the
    range (measured by dense sampling), per class; crosswalk outlines stay closed polygons."""
    t_wf, rng = _ego_pose(town), EGO_RANGE
    mv = map_vectors(town, t_wf, rng, num_points=400)
    tv = town_vectors(town)
    t_fw = invert_transform(t_wf)
    for k in (DIVIDER, BOUNDARY):
        inside = 0.0
        for e in np.flatnonzero(tv.label == k):  # kerb loops around blocks included
            q = _dense(tv.points[tv.start[e]:tv.start[e] + tv.count[e]], tv.closed[e], 0.02)
            f = transform_points(t_fw, np.c_[q, np.zeros(len(q))])
            inside += 0.02 * np.sum((f[:, 0] >= rng[0]) & (f[:, 0] <= rng[3])
                                    & (f[:, 1] >= rng[1]) & (f[:, 1] <= rng[4]))
        got = sum(polyline_lengths(np.concatenate([p, p[:1]]) if c else p)[-1] for p, c in
                  zip(mv.points[mv.labels == k].astype(np.float64), mv.closed[mv.labels == k]))
        assert inside > 20.0
        assert abs(got - inside) < 0.02 * inside + 1.0, (k, got, inside)
    cw = mv.points[mv.labels == CROSSWALK].astype(np.float64)
    assert len(cw) and mv.closed[mv.labels == CROSSWALK].all()
    assert (np.linalg.norm(cw[:, 0] - cw[:, -1], axis=1) > 1e-3).all()  # first not repeated
    # an element that leaves the range ends on the range's edge
    ends = mv.points[~mv.closed][:, [0, -1]].reshape(-1, 2)
    on_edge = np.minimum.reduce([np.abs(ends[:, 0] - rng[0]), np.abs(ends[:, 0] - rng[3]),
                                 np.abs(ends[:, 1] - rng[1]), np.abs(ends[:, 1] - rng[4])])
    assert (on_edge < 1e-3).any()


def test_max_elements_keeps_the_nearest_and_bad_input_is_named(town):
    t_wf = _ego_pose(town)
    full = map_vectors(town, t_wf, EGO_RANGE, num_points=10)
    few = map_vectors(town, t_wf, EGO_RANGE, num_points=10, max_elements=3)
    assert len(full) > 3 and len(few) == 3
    dmin = np.sort(np.linalg.norm(full.points, axis=2).min(1))[:3]
    np.testing.assert_allclose(np.sort(np.linalg.norm(few.points, axis=2).min(1)), dmin)
    far = map_vectors(town, pose_matrix(5000.0, 5000.0, 0.0, 0.0), EGO_RANGE, num_points=10)
    assert len(far) == 0 and far.points.shape == (0, 10, 2)
    with pytest.raises(ValueError, match="pc_range"):
        map_vectors(town, t_wf, (10.0, 0.0, -10.0, 5.0), num_points=10)
    with pytest.raises(ValueError, match="num_points"):
        map_vectors(town, t_wf, EGO_RANGE, num_points=1)
    with pytest.raises(ValueError, match="t_world_frame"):
        map_vectors(town, np.eye(3), EGO_RANGE, num_points=10)
