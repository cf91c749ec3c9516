"""Painted and paved geometry of a town: junction areas, parking-slot separators, lane boundary
markings and stop lines, in world metres. The one home of this geometry for the renderer's static
map (:mod:`..render_map`), the sensors' ground raster (:mod:`..sensors.ground`) and the BEV
(:mod:`..sensors.bev`)."""

from __future__ import annotations

import numpy as np

from ..core.geometry import convex_hull, cut_polyline, dash_polyline, offset_polyline
from .model import CONNECTOR, DRIVING, MERGE, RAMP, STOP_LINE_SETBACK, Town


def junction_corners(town: Town) -> list[np.ndarray]:
    """Per non-merge junction, the convex hull ``(K, 2)`` (m) of the sidewalk ends within its
    radius + 8 m (the paved corners); junctions with fewer than 3 such ends are skipped."""
    out = []
    for j in town.junctions:
        if j.control == MERGE:
            continue
        ends = [
            p
            for sw in town.sidewalks
            for p in (sw.points[0], sw.points[-1])
            if np.linalg.norm(p - j.center) < j.radius + 8.0
        ]
        if len(ends) >= 3:
            out.append(convex_hull(np.array(ends)))
    return out


def parking_separators(town: Town) -> list[np.ndarray]:
    """The painted separators of the parking slots: per slot, its two short edges as ``(2, 2)``
    segments (m), rear then front (slots are 6.5 m x 2.5 m)."""
    out = []
    for x, y, yaw in town.parking:
        c, s = np.cos(yaw), np.sin(yaw)
        for e in (-3.25, 3.25):
            a = np.array([x + c * e - s * 1.25, y + s * e + c * 1.25])
            b = np.array([x + c * e + s * 1.25, y + s * e - c * 1.25])
            out.append(np.stack([a, b]))
    return out


def junction_roads(town: Town) -> list[np.ndarray]:
    """Per non-merge junction, the convex hull ``(K, 2)`` (m) of its incoming lanes' end edges and
    its connectors' end edges (the drivable junction area)."""
    lanes, out = town.lanes, []
    for j in town.junctions:
        if j.control == MERGE:
            continue
        edge = []
        for lid, ends in [(i, (-1,)) for i in j.incoming] + [(c, (0, -1)) for c in j.connectors]:
            ln = lanes[lid]
            for side in (0.5, -0.5):
                off = offset_polyline(ln.points, side * ln.width)
                edge.extend(off[e] for e in ends)
        if len(edge) >= 3:
            out.append(convex_hull(np.array(edge)))
    return out


def lane_markings(town: Town) -> list[tuple[np.ndarray, str, float]]:
    """Lane boundary markings, stopped short of junction mouths: ``(polyline (K, 2), colour
    "white" | "yellow", width m)`` in drawing order (dashed between same-direction lanes, yellow
    towards opposite traffic, solid white at the road edges)."""
    lanes, out = town.lanes, []
    for ln in lanes:
        if ln.kind not in (DRIVING, RAMP):
            continue
        s0 = STOP_LINE_SETBACK if any(lanes[p].kind == CONNECTOR for p in ln.predecessors) else 0.0
        s1 = ln.length - (STOP_LINE_SETBACK if ln.junction_ahead >= 0 else 0.0)
        pts = cut_polyline(ln.points, s0, s1)
        if len(pts) < 2:
            continue
        left, right = offset_polyline(pts, ln.width / 2), offset_polyline(pts, -ln.width / 2)
        if ln.left >= 0:
            out.extend((dash, "white", 0.15) for dash in dash_polyline(left, 3.0, 6.0))
        elif ln.opposite >= 0:
            out.append((left, "yellow", 0.2))
        else:
            out.append((left, "white", 0.15))
        if ln.right < 0:
            out.append((right, "white", 0.15))
    return out


_BARS: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


def stop_bars(town: Town) -> tuple[np.ndarray, np.ndarray]:
    """``(bars (K, 2, 2), lanes (K,))``: stop-line end points (m) of every lane with a stop line,
    ``STOP_LINE_SETBACK`` before its end (cached per town)."""
    key = (town.name, town.template, town.seed, len(town.lanes))
    if key not in _BARS:
        bars, lanes = [], []
        for ln in town.lanes:
            if ln.stop_at_end:
                p, h = town.index.pose_at(np.array([ln.id]), np.array([ln.length - STOP_LINE_SETBACK]))
                n = np.array([-np.sin(h[0]), np.cos(h[0])]) * ln.width / 2
                bars.append(np.stack([p[0] + n, p[0] - n]))
                lanes.append(ln.id)
        _BARS[key] = (np.array(bars, float).reshape(-1, 2, 2), np.array(lanes, np.int64))
    return _BARS[key]


__all__ = ["junction_corners", "junction_roads", "lane_markings", "stop_bars"]
