"""The renderer's static layer: a town's ground, lanes, markings, crosswalks, parking, buildings
and stop signs rasterized once per town and scale (:func:`static_map`), cached; frames crop it
(:mod:`.render`)."""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw

from ..core.geometry import offset_polyline
from ..town.areas import (
    junction_corners,
    junction_roads,
    lane_markings,
    parking_separators,
    stop_bars,
)
from ..town.model import CONNECTOR, DRIVING, PARKING, RAMP, Town
from .palette import (
    BACKGROUND,
    BUILDING_EDGE,
    BUILDING_HIGH,
    BUILDING_LOW,
    CENTRE_LINE,
    CROSSWALK,
    MARK_WHITE,
    MARK_YELLOW,
    PARKING_FILL,
    ROAD,
    SIDEWALK,
    STOP_SIGN,
    box_quads,
    mix_rgb,
)

MAX_STATIC_PIXELS = 30_000_000  # cap on a cached static map (beyond it the map is coarser)
_SUPERSAMPLE_PIXELS = 10_000_000  # static maps up to this size are drawn at 2x and reduced
_MARGIN_M = 25.0  # m of ground around the town's bounds in the static map
_CACHE_SIZE = 6  # static maps kept (least recently used dropped first) ...
_CACHE_BYTES = 320 * 2**20  # ... and at most this many bytes of them



# ----------------------------------------------------------------------------- the static map
@dataclass
class StaticMap:
    """A town's static layer rasterized at a fixed scale.

    Attributes:
        image: ``(H, W, 3)`` uint8 picture of the whole town (plus a margin).
        x0: world x (m) of pixel column 0's centre. y1: world y (m) of pixel row 0's centre.
        mpp: metres per pixel.
        stop_bars: ``(K, 2, 2)`` world end points of the stop line of each signal-controlled
            incoming lane; ``stop_lanes (K,)`` are those lanes' ids.
    """

    image: np.ndarray
    x0: float
    y1: float
    mpp: float
    stop_bars: np.ndarray
    stop_lanes: np.ndarray


_STATIC_CACHE: OrderedDict[tuple, StaticMap] = OrderedDict()


def static_map(town: Town, mpp: float) -> StaticMap:
    """The cached static map of ``town`` at ``mpp`` metres per pixel (built on first use).

    Building takes 0.1 to 1.5 s per town and scale (drawn at 2x and reduced, for smooth
    edges); the last few maps are kept (least recently used dropped first).

    Args:
        town: the road network.
        mpp: metres per pixel; maps that would exceed :data:`MAX_STATIC_PIXELS` are built
            coarser (the returned ``mpp`` is then larger than asked and frames are resampled).

    Returns:
        The :class:`StaticMap`.
    """
    xmin, ymin, xmax, ymax = (float(v) for v in town.bounds)
    w_m, h_m = xmax - xmin + 2 * _MARGIN_M, ymax - ymin + 2 * _MARGIN_M
    mpp = max(float(mpp), float(np.sqrt(w_m * h_m / MAX_STATIC_PIXELS)))
    key = (town.name, town.template, town.seed, len(town.lanes), len(town.buildings), round(mpp, 9))
    hit = _STATIC_CACHE.get(key)
    if hit is not None:
        _STATIC_CACHE.move_to_end(key)
        return hit
    sm = _build_static(town, mpp)
    _STATIC_CACHE[key] = sm
    while len(_STATIC_CACHE) > 1 and (
        len(_STATIC_CACHE) > _CACHE_SIZE
        or sum(m.image.nbytes for m in _STATIC_CACHE.values()) > _CACHE_BYTES
    ):
        _STATIC_CACHE.popitem(last=False)
    return sm


def _build_static(town: Town, mpp: float) -> StaticMap:
    """Rasterize a town's static layers (back to front) at ``mpp`` metres per pixel."""
    xmin, ymin, xmax, ymax = (float(v) for v in town.bounds)
    x0, y1 = xmin - _MARGIN_M, ymax + _MARGIN_M
    W = int(np.ceil((xmax - xmin + 2 * _MARGIN_M) / mpp))
    H = int(np.ceil((ymax - ymin + 2 * _MARGIN_M) / mpp))
    ss = 2 if W * H <= _SUPERSAMPLE_PIXELS else 1
    img = Image.new("RGB", (W * ss, H * ss), BACKGROUND)
    d = ImageDraw.Draw(img)
    k = ss / mpp  # supersampled pixels per metre

    def px(p: np.ndarray) -> list[tuple[float, float]]:
        p = np.asarray(p, float).reshape(-1, 2)
        return list(
            zip(((p[:, 0] - x0) / mpp + 0.5) * ss - 0.5, ((y1 - p[:, 1]) / mpp + 0.5) * ss - 0.5)
        )

    def band(points: np.ndarray, width: float, fill: tuple) -> None:
        poly = np.concatenate([offset_polyline(points, width / 2), offset_polyline(points, -width / 2)[::-1]], 0)
        d.polygon(px(poly), fill=fill)

    def line(points: np.ndarray, fill: tuple, width_m: float, min_px: float = 1.0) -> None:
        if len(points) >= 2:
            d.line(
                px(points),
                fill=fill,
                width=max(int(round(width_m * k)), int(round(min_px * ss))),
                joint="curve",
            )

    lanes = town.lanes
    # sidewalks, with the corners of junctions paved
    for sw in town.sidewalks:
        band(sw.points, sw.width, SIDEWALK)
    for hull in junction_corners(town):
        d.polygon(px(hull), fill=SIDEWALK)
    # drivable area: parking lanes, lanes, junction areas
    for ln in lanes:
        if ln.kind == PARKING:
            band(ln.points, ln.width, PARKING_FILL)
    for ln in lanes:
        if ln.kind != PARKING:
            band(ln.points, ln.width, ROAD)
    for hull in junction_roads(town):
        d.polygon(px(hull), fill=ROAD)
    for seg in parking_separators(town):
        line(seg, MARK_WHITE, 0.12)
    # faint lane centre lines (connectors show the turning paths)
    for ln in lanes:
        if ln.kind in (DRIVING, RAMP, CONNECTOR):
            line(ln.points, CENTRE_LINE, 0.1)
    # lane boundary markings, stopped short of junction mouths
    for pts, colour, width in lane_markings(town):
        line(pts, MARK_WHITE if colour == "white" else MARK_YELLOW, width)
    # stop lines (signal lanes get a coloured bar on top at render time)
    bars, bar_lanes = stop_bars(town)
    for bar in bars:
        line(bar, MARK_WHITE, 0.4)
    # zebra crossings: bars along the road, repeated across it
    for cw in town.crosswalks:
        c = cw.corners
        e1, e2 = c[1] - c[0], c[2] - c[1]
        along, across = (e1, e2) if np.linalg.norm(e1) < np.linalg.norm(e2) else (e2, e1)
        origin = c[0]  # both edge choices start at corner 0 and stay inside the crossing
        L = float(np.linalg.norm(across))
        u = across / max(L, 1e-9)
        for a in np.arange(0.3, L - 0.3, 1.0):
            q0 = origin + u * a
            d.polygon(
                px(np.stack([q0, q0 + u * 0.55, q0 + u * 0.55 + along, q0 + along])), fill=CROSSWALK
            )
    # buildings: soft shadow, then the box shaded by height
    if len(town.buildings):
        b = town.buildings
        corners = box_quads(b[:, :2], b[:, 4], -b[:, 2] / 2, b[:, 2] / 2, -b[:, 3] / 2, b[:, 3] / 2)
        heights = town.building_heights
        for q, h in zip(corners, heights):  # translucent shadow, blended in its own box
            sq = np.array(px(q + np.array([0.12, -0.12]) * h))
            b0 = np.maximum(np.floor(sq.min(0)).astype(int) - 1, 0)
            b1 = np.minimum(np.ceil(sq.max(0)).astype(int) + 2, img.size)
            if np.all(b1 > b0):
                mask = Image.new("L", tuple(int(v) for v in b1 - b0), 0)
                ImageDraw.Draw(mask).polygon([tuple(p) for p in sq - b0], fill=40)
                img.paste((0, 0, 0), (int(b0[0]), int(b0[1])), mask)
        for q, h in zip(corners, heights):
            t = float(np.clip((h - 5.0) / 20.0, 0.0, 1.0))
            ring = px(q)
            d.polygon(ring, fill=mix_rgb(BUILDING_LOW, BUILDING_HIGH, t))
            d.line(ring + ring[:1], fill=BUILDING_EDGE, width=ss)
    # stop signs
    r = max(1.2 * k, 5.0 * ss)
    for x, y, *_ in town.stop_signs:
        ((cx, cy),) = px(np.array([x, y]))
        d.regular_polygon((cx, cy, r + 1.2 * ss), 8, rotation=22.5, fill=(255, 255, 255))
        d.regular_polygon((cx, cy, r), 8, rotation=22.5, fill=STOP_SIGN)
    if ss > 1:
        img = img.reduce(ss)
    return StaticMap(
        image=np.asarray(img, dtype=np.uint8).copy(),
        x0=x0,
        y1=y1,
        mpp=mpp,
        stop_bars=bars,
        stop_lanes=bar_lanes,
    )


