"""Vectorized map ground truth (MapTR style) from the town model, in any frame.

Three element classes (:data:`MAP_CLASSES`):

- ``divider`` (0): the painted lane boundaries *inside* a road - between same-direction lanes
  (dashed white) and between the two directions (yellow centre line, once per lane pair) - as
  continuous lines, stopped short of junction mouths exactly as the paint
  (:func:`.areas.lane_markings`: the same lanes, offsets and cuts, undashed);
- ``boundary`` (1): the edges of the drivable carriageway - the outer edge of every outermost
  driving / ramp lane (the solid white road-edge line, over the lane's full length), the left
  edge of one-way carriageways, the corners of each junction's drivable area (edges of the
  convex hull of the lanes' ends at the junction that join two different roads; the edges
  across a road's mouth are not boundaries) and, in merge / diverge areas, the outer edges of the
  connectors between outermost lanes. Pieces that meet end to end are chained into one
  polyline (a kerb around a block is one element);
- ``crosswalk`` (2): zebra-crossing outlines, closed (counter-clockwise).

Per town the elements are built once in world metres and densified to at most
:data:`DENSIFY_STEP` between vertices (keeping every original vertex), then cached on the town
(``town.cache("map_vectors")``). Per frame (:func:`map_vectors`) the points go into the frame
(a 4x4 ``T_world_frame``: the ego pose, or a roadside unit's pitched and rolled pose; map points
lie on the ground, ``z = 0`` in the world), open polylines are clipped to the rectangular
perception range in the frame's ``x, y`` (Liang-Barsky per segment; a polyline that leaves and
re-enters the range becomes two elements), closed outlines are clipped as polygons
(Sutherland-Hodgman), and every element is resampled to ``P`` points evenly spaced in arc
length: open polylines from end to end in the town's direction, closed ones around the ring
(``P`` distinct points, the first not repeated). :func:`frame_to_ground` maps frame ``x, y``
back onto the ground (the inverse used by the tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.geometry import convex_hull, cut_polyline, invert_transform, offset_polyline
from .model import CONNECTOR, DRIVING, MERGE, RAMP, STOP_LINE_SETBACK, Town

MAP_CLASSES = ("divider", "boundary", "crosswalk")
DIVIDER, BOUNDARY, CROSSWALK = 0, 1, 2
DENSIFY_STEP = 1.0  # m, largest vertex spacing of the cached world polylines
MIN_LENGTH = 1.0  # m, clipped open pieces shorter than this are dropped
MIN_AREA = 1.0  # m^2, clipped crosswalk outlines smaller than this are dropped
_JOIN_TOL = 1e-3  # m, end points closer than this chain two boundary pieces


@dataclass(frozen=True)
class TownVectors:
    """A town's map elements in world metres, flattened (built once per town).

    Attributes:
        points: ``(N, 2)`` densified vertices of every element, concatenated.
        start, count: ``(E,)`` first index into ``points`` and number of vertices per element.
        label: ``(E,)`` class (:data:`MAP_CLASSES`). closed: ``(E,)`` closed outline (the first
            vertex is not repeated at the end).
        bbox: ``(E, 4)`` world ``xmin, ymin, xmax, ymax`` per element.
        element: ``(N,)`` element of each vertex.
    """

    points: np.ndarray
    start: np.ndarray
    count: np.ndarray
    label: np.ndarray
    closed: np.ndarray
    bbox: np.ndarray
    element: np.ndarray


@dataclass(frozen=True)
class MapVectors:
    """Map elements of one frame, cut to the range and resampled.

    Attributes:
        points: ``(K, P, 2)`` float32 ``x, y`` in the frame (m). labels: ``(K,)`` int64.
        closed: ``(K,)`` bool.
    """

    points: np.ndarray
    labels: np.ndarray
    closed: np.ndarray

    def __len__(self) -> int:
        return len(self.labels)


# ------------------------------------------------------------------------------- town elements
def _densify(points: np.ndarray, closed: bool, step: float = DENSIFY_STEP) -> np.ndarray:
    """Insert vertices so that no segment is longer than ``step`` (original vertices kept)."""
    p = np.asarray(points, np.float64)
    ring = np.concatenate([p, p[:1]]) if closed else p
    seg = np.diff(ring, axis=0)
    n = np.maximum(1, np.ceil(np.linalg.norm(seg, axis=1) / step).astype(np.int64))
    t = np.concatenate([np.arange(k) / k for k in n])
    base = np.repeat(np.arange(len(seg)), n)
    out = ring[base] + t[:, None] * seg[base]
    return out if closed else np.concatenate([out, ring[-1:]])


def _dividers(town: Town) -> list[np.ndarray]:
    """Lane boundaries inside roads (the cut and offsets of :func:`.areas.lane_markings`)."""
    lanes, out = town.lanes, []
    for ln in lanes:
        if ln.kind not in (DRIVING, RAMP):
            continue
        if ln.left < 0 and not (ln.opposite >= 0 and ln.id < ln.opposite):
            continue  # a road edge, or the centre line already taken from the opposite lane
        s0 = STOP_LINE_SETBACK if any(lanes[p].kind == CONNECTOR for p in ln.predecessors) else 0.0
        s1 = ln.length - (STOP_LINE_SETBACK if ln.junction_ahead >= 0 else 0.0)
        pts = cut_polyline(ln.points, s0, s1)
        if len(pts) >= 2:
            out.append(offset_polyline(pts, ln.width / 2))
    return out


def _lane_edge_pieces(town: Town) -> list[np.ndarray]:
    """Outer road edges along lanes and merge-area connectors (full length)."""
    lanes, out = town.lanes, []
    merge = {j.id for j in town.junctions if j.control == MERGE}
    one_way_left = [ln.left < 0 and ln.opposite < 0 for ln in lanes]
    for ln in lanes:
        if ln.kind in (DRIVING, RAMP):
            right_outer, left_outer = ln.right < 0, one_way_left[ln.id]
        elif ln.kind == CONNECTOR and ln.junction in merge and ln.predecessors and ln.successors:
            a, b = lanes[ln.predecessors[0]], lanes[ln.successors[0]]
            right_outer = a.right < 0 and b.right < 0
            left_outer = one_way_left[a.id] and one_way_left[b.id]
        else:
            continue
        if right_outer:
            out.append(offset_polyline(ln.points, -ln.width / 2))
        if left_outer:
            out.append(offset_polyline(ln.points, ln.width / 2))
    return out


def _junction_corner_pieces(town: Town) -> list[np.ndarray]:
    """Edges of each junction's mouth hull (the convex hull of its incoming lanes' end edges
    and outgoing lanes' start edges: :func:`.areas.junction_roads` without the connectors'
    ends, which lie within centimetres of those) that join two different roads."""
    lanes, out = town.lanes, []
    for j in town.junctions:
        if j.control == MERGE:
            continue
        outgoing = sorted({s for c in j.connectors for s in lanes[c].successors})
        pts, road = [], []
        for lid, end in [(i, -1) for i in j.incoming] + [(o, 0) for o in outgoing]:
            ln = lanes[lid]
            for side in (0.5, -0.5):
                pts.append(offset_polyline(ln.points, side * ln.width)[end])
                road.append(ln.road)
        if len(pts) < 3:
            continue
        hull = convex_hull(np.array(pts))
        d = np.linalg.norm(hull[:, None, :] - np.array(pts)[None], axis=2)
        near = np.argmin(d, axis=1)
        hull = np.array(pts)[near]  # the exact end points (convex_hull rounds to 1e-6 m)
        hull_road = np.array(road)[near]
        for i in range(len(hull)):
            k = (i + 1) % len(hull)
            if hull_road[i] != hull_road[k]:
                out.append(np.stack([hull[i], hull[k]]))
    return out


def _chain(pieces: list[np.ndarray], tol: float = _JOIN_TOL) -> list[tuple[np.ndarray, bool]]:
    """Join pieces whose end points meet (only where exactly two pieces meet); returns
    ``(polyline, closed)`` per chain."""
    def key(p: np.ndarray) -> tuple[int, int]:
        return (int(round(p[0] / tol)), int(round(p[1] / tol)))

    ends: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for i, p in enumerate(pieces):
        for side in (0, 1):
            ends.setdefault(key(p[-side]), []).append((i, side))
    used = np.zeros(len(pieces), bool)

    def partner(i: int, side: int) -> tuple[int, int] | None:
        at = ends[key(pieces[i][-side])]
        if len(at) != 2:
            return None
        j, s = at[0] if at[1] == (i, side) else at[1]
        return None if used[j] or j == i else (j, s)

    out = []
    for i in range(len(pieces)):
        if used[i]:
            continue
        used[i] = True
        line = [pieces[i]]
        for forward in (True, False):  # grow at the end, then at the start
            cur, side = i, 1 if forward else 0
            while (nb := partner(cur, side)) is not None:
                j, s = nb
                used[j] = True
                seg = pieces[j] if s == 0 else pieces[j][::-1]  # oriented away from the joint
                if forward:
                    line.append(seg[1:])
                else:
                    line.insert(0, seg[::-1][:-1])
                cur, side = j, 1 - s
        poly = np.concatenate(line)
        closed = len(poly) > 3 and np.linalg.norm(poly[0] - poly[-1]) < tol
        out.append((poly[:-1] if closed else poly, bool(closed)))
    return out


def _ccw(corners: np.ndarray) -> np.ndarray:
    x, y = corners[:, 0], corners[:, 1]
    area2 = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return corners if area2 >= 0 else corners[::-1].copy()


def town_vectors(town: Town) -> TownVectors:
    """The town's map elements in world metres (built once, cached on the town)."""
    cache = town.cache("map_vectors")
    if "town" in cache:
        return cache["town"]
    elems: list[tuple[np.ndarray, int, bool]] = [(p, DIVIDER, False) for p in _dividers(town)]
    pieces = _lane_edge_pieces(town) + _junction_corner_pieces(town)
    elems += [(p, BOUNDARY, c) for p, c in _chain(pieces)]
    elems += [(_ccw(np.asarray(c.corners, np.float64)), CROSSWALK, True) for c in town.crosswalks]
    dense = [_densify(p, c) for p, _, c in elems]
    count = np.array([len(d) for d in dense], np.int64)
    start = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
    points = np.concatenate(dense) if dense else np.zeros((0, 2))
    bbox = np.array([[*d.min(0), *d.max(0)] for d in dense]).reshape(-1, 4)
    tv = TownVectors(points, start, count, np.array([e[1] for e in elems], np.int64),
                     np.array([e[2] for e in elems], bool), bbox,
                     np.repeat(np.arange(len(dense)), count))
    for a in (tv.points, tv.start, tv.count, tv.label, tv.closed, tv.bbox, tv.element):
        a.setflags(write=False)
    cache["town"] = tv
    return tv


# ------------------------------------------------------------------------------- frame geometry
def ground_affine(t_world_frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A (2, 2), b (2,))`` with ``xy_frame = A @ xy_world + b`` for ground points (z = 0)."""
    t = invert_transform(np.asarray(t_world_frame, np.float64))
    return t[:2, :2], t[:2, 3]


def frame_to_ground(t_world_frame: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """World ground points ``(..., 2)`` whose frame ``x, y`` are ``xy (..., 2)``: the inverse
    of the frame's ground map (a frame whose z axis lies in the ground plane has none)."""
    a, b = ground_affine(t_world_frame)
    xy = np.asarray(xy, np.float64)
    return np.linalg.solve(a, (xy - b).reshape(-1, 2).T).T.reshape(xy.shape)


def _range_xy(pc_range) -> tuple[float, float, float, float]:
    r = [float(v) for v in pc_range]
    if len(r) == 6:
        r = [r[0], r[1], r[3], r[4]]
    if len(r) != 4 or not (r[0] < r[2] and r[1] < r[3]):
        raise ValueError(f"map_vectors: pc_range={tuple(pc_range)} must be (xmin, ymin, xmax, "
                         "ymax) or (xmin, ymin, zmin, xmax, ymax, zmax) with min < max")
    return r[0], r[1], r[2], r[3]


def _clip_segments(p0: np.ndarray, p1: np.ndarray, box) -> tuple[np.ndarray, np.ndarray]:
    """Liang-Barsky: entry and exit parameters ``t0, t1 (S,)`` of segments in a rectangle
    (``t0 >= t1``: the segment misses it)."""
    xmin, ymin, xmax, ymax = box
    d = p1 - p0
    t0, t1 = np.zeros(len(p0)), np.ones(len(p0))
    for p, q in ((-d[:, 0], p0[:, 0] - xmin), (d[:, 0], xmax - p0[:, 0]),
                 (-d[:, 1], p0[:, 1] - ymin), (d[:, 1], ymax - p0[:, 1])):
        with np.errstate(divide="ignore", invalid="ignore"):
            r = q / p
        t0 = np.where(p < 0, np.maximum(t0, r), t0)
        t1 = np.where(p > 0, np.minimum(t1, r), t1)
        t1 = np.where((p == 0) & (q < 0), -1.0, t1)  # parallel and outside
    return t0, t1


def _clip_lines(tv: TownVectors, elems: np.ndarray, a: np.ndarray, b: np.ndarray,
                box) -> list[tuple[np.ndarray, int, bool]]:
    """Polylines (closed ones as rings: a kerb loop) of ``elems`` in the frame, clipped to
    ``box``: ``(points (V, 2), element, closed)`` per piece in range. A ring wholly in range
    stays closed; a cut ring becomes open pieces (the piece across its first vertex joined)."""
    if not len(elems):
        return []
    idx = np.concatenate([np.r_[np.arange(tv.start[e], tv.start[e] + tv.count[e]),
                                [tv.start[e]] if tv.closed[e] else []].astype(np.int64)
                          for e in elems])
    pts = tv.points[idx] @ a.T + b
    elem = tv.element[idx]
    seg = np.flatnonzero(elem[:-1] == elem[1:])  # segment k joins pts[k] and pts[k + 1]
    first_seg = np.r_[True, elem[seg[1:]] != elem[seg[:-1]]]
    last_seg = np.r_[first_seg[1:], True]
    t0, t1 = _clip_segments(pts[seg], pts[seg + 1], box)
    keep = t1 - t0 > 1e-9
    seg, t0, t1 = seg[keep], t0[keep], t1[keep]
    first_seg, last_seg = first_seg[keep], last_seg[keep]
    if not len(seg):
        return []
    d = pts[seg + 1] - pts[seg]
    p_in, p_out = pts[seg] + t0[:, None] * d, pts[seg] + t1[:, None] * d
    cont = np.r_[False, (seg[1:] == seg[:-1] + 1) & (t1[:-1] >= 1.0) & (t0[1:] <= 0.0)]
    bounds = np.r_[np.flatnonzero(~cont), len(seg)]
    runs = []  # (line, element, starts at the ring's first vertex, ends at its last)
    for i, j in zip(bounds[:-1], bounds[1:]):
        at_start = bool(first_seg[i] and t0[i] <= 0.0)
        at_end = bool(last_seg[j - 1] and t1[j - 1] >= 1.0)
        runs.append((np.concatenate([p_in[i:i + 1], p_out[i:j]]), int(elem[seg[i]]), at_start,
                     at_end))
    out = []
    for line, e, at_start, at_end in runs:
        if tv.closed[e]:
            if at_start and at_end:  # the whole ring is in range
                out.append((line[:-1], e, True))
                continue
            if at_start and any(r[1] == e and r[3] for r in runs):
                continue  # joined to the run that ends at the ring's last vertex
            if at_end:
                nxt = next((r for r in runs if r[1] == e and r[2]), None)
                if nxt is not None:
                    line = np.concatenate([line, nxt[0][1:]])
        out.append((line, e, False))
    return [(ln, e, c) for ln, e, c in out
            if c or np.linalg.norm(np.diff(ln, axis=0), axis=1).sum() >= MIN_LENGTH]


def _resample(pieces: list[np.ndarray], closed: list[bool], n: int) -> np.ndarray:
    """``(len(pieces), n, 2)``: each piece at ``n`` points evenly spaced in arc length."""
    out = np.zeros((len(pieces), n, 2))
    for i, (p, c) in enumerate(zip(pieces, closed)):
        ring = np.concatenate([p, p[:1]]) if c else p
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ring, axis=0), axis=1))])
        t = np.arange(n) * s[-1] / n if c else np.linspace(0.0, s[-1], n)
        out[i] = np.stack([np.interp(t, s, ring[:, 0]), np.interp(t, s, ring[:, 1])], -1)
    return out


def _clip_polygon(poly: np.ndarray, box) -> np.ndarray:
    """Sutherland-Hodgman clip of a convex or simple polygon ``(V, 2)`` to a rectangle."""
    xmin, ymin, xmax, ymax = box
    for axis, bound, keep_below in ((0, xmin, False), (0, xmax, True), (1, ymin, False),
                                    (1, ymax, True)):
        if len(poly) == 0:
            break
        nxt = np.roll(poly, -1, axis=0)
        val, vnx = poly[:, axis] - bound, nxt[:, axis] - bound
        if keep_below:
            val, vnx = -val, -vnx
        out = []
        for a, b, va, vb in zip(poly, nxt, val, vnx):
            if va >= 0:
                out.append(a)
            if (va >= 0) != (vb >= 0):
                out.append(a + (b - a) * (va / (va - vb)))
        poly = np.array(out).reshape(-1, 2)
    return poly


def _area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))


def map_vectors(town: Town, t_world_frame: np.ndarray, pc_range, num_points: int,
                max_elements: int | None = None) -> MapVectors:
    """The town's map elements in a frame, cut to its perception range (module docstring).

    Args:
        town: the town of the frame.
        t_world_frame: ``(4, 4)`` frame -> world (``calib/T_world_ego`` or ``calib/T_world_rsu``).
        pc_range: ``(xmin, ymin, xmax, ymax)`` or ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in the
            frame (m); only ``x, y`` cut the map.
        num_points: ``P`` points per element (>= 2).
        max_elements: keep at most this many, nearest to the frame origin first (``None``: all).

    Returns:
        :class:`MapVectors`, ordered by class, then by the element's first point (``x``, ``y``).
    """
    if int(num_points) < 2:
        raise ValueError(f"map_vectors: num_points={num_points} must be >= 2")
    t_world_frame = np.asarray(t_world_frame, np.float64)
    if t_world_frame.shape != (4, 4):
        raise ValueError(f"map_vectors: t_world_frame has shape {t_world_frame.shape}, not (4, 4)")
    box = _range_xy(pc_range)
    tv = town_vectors(town)
    a, b = ground_affine(t_world_frame)
    # world bounding box of the range's ground footprint (a parallelogram) culls the elements
    corners = frame_to_ground(t_world_frame, np.array(
        [[box[0], box[1]], [box[2], box[1]], [box[2], box[3]], [box[0], box[3]]]))
    lo, hi = corners.min(0), corners.max(0)
    near = np.flatnonzero((tv.bbox[:, 0] <= hi[0]) & (tv.bbox[:, 2] >= lo[0])
                          & (tv.bbox[:, 1] <= hi[1]) & (tv.bbox[:, 3] >= lo[1]))
    pieces, labels, closed = [], [], []
    polygons = tv.closed[near] & (tv.label[near] == CROSSWALK)
    for line, e, is_closed in _clip_lines(tv, near[~polygons], a, b, box):
        pieces.append(line)
        labels.append(int(tv.label[e]))
        closed.append(is_closed)
    for e in near[polygons]:
        ring = tv.points[tv.start[e]:tv.start[e] + tv.count[e]] @ a.T + b
        inside = ((ring[:, 0] >= box[0]) & (ring[:, 0] <= box[2]) & (ring[:, 1] >= box[1])
                  & (ring[:, 1] <= box[3]))
        poly = ring if inside.all() else _clip_polygon(ring, box)
        if len(poly) >= 3 and _area(poly) >= MIN_AREA:
            pieces.append(poly)
            labels.append(int(tv.label[e]))
            closed.append(True)
    if not pieces:
        return MapVectors(np.zeros((0, num_points, 2), np.float32), np.zeros(0, np.int64),
                          np.zeros(0, bool))
    res = _resample(pieces, closed, int(num_points))
    lab, clo = np.array(labels, np.int64), np.array(closed, bool)
    if max_elements is not None and len(res) > max_elements:
        nearest = np.argsort(np.linalg.norm(res, axis=2).min(1), kind="stable")[:max_elements]
        res, lab, clo = res[nearest], lab[nearest], clo[nearest]
    order = np.lexsort((res[:, 0, 1], res[:, 0, 0], lab))
    return MapVectors(res[order].astype(np.float32), lab[order], clo[order])


__all__ = ["BOUNDARY", "CROSSWALK", "DENSIFY_STEP", "DIVIDER", "MAP_CLASSES", "MapVectors",
           "TownVectors", "frame_to_ground", "ground_affine", "map_vectors", "town_vectors"]
