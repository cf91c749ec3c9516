"""Per-town ground raster: what the ground looks like and is, at every point of the town.

The ground (``z = 0``) is drawn once per town into a material raster (uint8 codes of
:mod:`.semantics`, default :data:`GROUND_MPP` = 0.25 m per pixel) with the same layers, order and
geometry as the top-down renderer's static map (:func:`..render.static_map`): grass, sidewalks
(with curbs and paved junction corners), parking lanes, lanes and junction areas, parking-slot
lines, lane boundary markings (dashed between same-direction lanes, yellow between directions,
solid at the road edge), stop lines and zebra crossings. Lane centre lines are flagged in bit 7
(:data:`.semantics.CENTRE_BIT`) for the BEV. Cameras and LiDARs look up their ground hits here
(nearest pixel); the BEV samples it. Points outside the raster are terrain.

Colours: ``MATERIAL_RGB`` times a tiled, deterministic texture noise (fine grain plus coarse
patches) whose amplitude depends on the material, so asphalt, grass and paint read differently.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw

from ..render import _convex_hull, _cut, _dashes, _offset
from ..town.model import CONNECTOR, DRIVING, MERGE, PARKING, RAMP, Town
from ..traffic import STOP_LINE_SETBACK
from .semantics import (
    CENTRE_BIT,
    M_CROSS_GAP,
    M_CROSS_STRIPE,
    M_CURB,
    M_MARK_WHITE,
    M_MARK_YELLOW,
    M_PARK_LINE,
    M_PARKING,
    M_ROAD,
    M_SIDEWALK,
    M_STOP_LINE,
    M_TERRAIN,
    MATERIAL_NOISE,
    MATERIAL_RGB,
)

#: Default ground raster resolution (m per pixel).
GROUND_MPP = 0.25
_TILE = 64  # texture tile side (pixels)
_CACHE: OrderedDict[tuple, GroundRaster] = OrderedDict()
_CACHE_SIZE = 4


@dataclass(frozen=True)
class GroundRaster:
    """A town's ground materials.

    Attributes:
        code: ``(H, W)`` uint8 material codes; row ``i`` is world ``y = ymin + (i + 0.5) * mpp``,
            column ``j`` is ``x = xmin + (j + 0.5) * mpp``.
        xmin, ymin: world corner of the raster (m). mpp: metres per pixel.
        noise: ``(64, 64)`` float32 tiled texture in ``[-1, 1]`` (fine grain + coarse patches).
    """

    code: np.ndarray
    xmin: float
    ymin: float
    mpp: float
    noise: np.ndarray

    def pixel(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raster indices of world points: ``(row, col, inside)``, rows/cols clipped."""
        h, w = self.code.shape
        col = np.floor((np.asarray(x) - self.xmin) * (1.0 / self.mpp)).astype(np.int64)
        row = np.floor((np.asarray(y) - self.ymin) * (1.0 / self.mpp)).astype(np.int64)
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        return np.clip(row, 0, h - 1), np.clip(col, 0, w - 1), inside

    def lookup(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Material codes (uint8, nearest pixel) at world points ``x, y`` (m); terrain outside."""
        row, col, inside = self.pixel(x, y)
        return np.where(inside, self.code[row, col], np.uint8(M_TERRAIN)).astype(np.uint8)

    def colors(self, x: np.ndarray, y: np.ndarray, code: np.ndarray) -> np.ndarray:
        """Textured RGB ``(..., 3)`` float32 (0-255) of ground points with material ``code``."""
        ix = np.floor(np.asarray(x) * (1.0 / self.mpp)).astype(np.int64)
        iy = np.floor(np.asarray(y) * (1.0 / self.mpp)).astype(np.int64)
        n = self.noise[iy & (_TILE - 1), ix & (_TILE - 1)]
        return MATERIAL_RGB[code] * (1.0 + MATERIAL_NOISE[code] * n)[..., None]


def ground_raster(town: Town, mpp: float = GROUND_MPP) -> GroundRaster:
    """The cached :class:`GroundRaster` of ``town`` (built on first use, ~0.1-0.5 s)."""
    key = (town.name, town.template, town.seed, len(town.lanes), round(float(mpp), 9))
    hit = _CACHE.get(key)
    if hit is not None:
        _CACHE.move_to_end(key)
        return hit
    g = _build(town, float(mpp))
    _CACHE[key] = g
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return g


def _texture() -> np.ndarray:
    """Deterministic tileable noise: fine grain plus 8x coarser patches, in ``[-1, 1]``."""
    rng = np.random.default_rng(12345)
    fine = rng.uniform(-1.0, 1.0, (_TILE, _TILE))
    coarse = rng.uniform(-1.0, 1.0, (_TILE // 8, _TILE // 8))
    coarse = np.kron(coarse, np.ones((8, 8)))
    # soften the coarse patches with a small tileable box blur
    for ax in (0, 1):
        coarse = (np.roll(coarse, 2, ax) + np.roll(coarse, -2, ax) + 2 * coarse) / 4
    return np.clip(0.45 * fine + 0.75 * coarse, -1.0, 1.0).astype(np.float32)


def _build(town: Town, mpp: float) -> GroundRaster:
    xmin, ymin, xmax, ymax = (float(v) for v in town.bounds)
    w = int(np.ceil((xmax - xmin) / mpp))
    h = int(np.ceil((ymax - ymin) / mpp))
    img = Image.new("L", (w, h), M_TERRAIN)
    centre = Image.new("L", (w, h), 0)
    d, dc = ImageDraw.Draw(img), ImageDraw.Draw(centre)
    k = 1.0 / mpp

    def px(p: np.ndarray) -> list[tuple[float, float]]:
        p = np.asarray(p, float).reshape(-1, 2)
        return list(zip((p[:, 0] - xmin) * k - 0.5, (p[:, 1] - ymin) * k - 0.5))

    def band(points: np.ndarray, width: float, fill: int, outline: int | None = None) -> None:
        poly = px(np.concatenate([_offset(points, width / 2), _offset(points, -width / 2)[::-1]]))
        d.polygon(poly, fill=fill)
        if outline is not None:
            d.line(poly + poly[:1], fill=outline, width=max(1, int(round(0.25 * k))))

    def line(points: np.ndarray, fill: int, width_m: float, draw=d) -> None:
        if len(points) >= 2:
            draw.line(px(points), fill=fill, width=max(1, int(round(width_m * k))), joint="curve")

    lanes = town.lanes
    for sw in town.sidewalks:  # sidewalks with a curb outline, paved junction corners
        band(sw.points, sw.width, M_SIDEWALK, M_CURB)
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
            d.polygon(px(_convex_hull(np.array(ends))), fill=M_SIDEWALK)
    for ln in lanes:
        if ln.kind == PARKING:
            band(ln.points, ln.width, M_PARKING)
    for ln in lanes:
        if ln.kind != PARKING:
            band(ln.points, ln.width, M_ROAD)
    for j in town.junctions:
        if j.control == MERGE:
            continue
        edge = []
        for lid, ends in [(i, (-1,)) for i in j.incoming] + [(c, (0, -1)) for c in j.connectors]:
            ln = lanes[lid]
            for side in (0.5, -0.5):
                off = _offset(ln.points, side * ln.width)
                edge.extend(off[e] for e in ends)
        if len(edge) >= 3:
            d.polygon(px(_convex_hull(np.array(edge))), fill=M_ROAD)
    for x, y, yaw in town.parking:  # slot separators
        c, s = np.cos(yaw), np.sin(yaw)
        for e in (-3.25, 3.25):
            a = np.array([x + c * e - s * 1.25, y + s * e + c * 1.25])
            b = np.array([x + c * e + s * 1.25, y + s * e - c * 1.25])
            line(np.stack([a, b]), M_PARK_LINE, 0.15)
    for ln in lanes:  # centre lines (BEV only)
        if ln.kind in (DRIVING, RAMP, CONNECTOR):
            line(ln.points, 1, 0.5, dc)
    for ln in lanes:  # lane boundary markings, stopped short of junction mouths
        if ln.kind not in (DRIVING, RAMP):
            continue
        s0 = STOP_LINE_SETBACK if any(lanes[p].kind == CONNECTOR for p in ln.predecessors) else 0.0
        s1 = ln.length - (STOP_LINE_SETBACK if ln.junction_ahead >= 0 else 0.0)
        pts = _cut(ln.points, s0, s1)
        if len(pts) < 2:
            continue
        left, right = _offset(pts, ln.width / 2), _offset(pts, -ln.width / 2)
        if ln.left >= 0:
            for dash in _dashes(left, 3.0, 6.0):
                line(dash, M_MARK_WHITE, 0.15)
        elif ln.opposite >= 0:
            line(left, M_MARK_YELLOW, 0.2)
        else:
            line(left, M_MARK_WHITE, 0.15)
        if ln.right < 0:
            line(right, M_MARK_WHITE, 0.15)
    for ln in lanes:  # stop lines
        if ln.stop_at_end:
            p, hd = town.index.pose_at(np.array([ln.id]), np.array([ln.length - STOP_LINE_SETBACK]))
            n = np.array([-np.sin(hd[0]), np.cos(hd[0])]) * ln.width / 2
            line(np.stack([p[0] + n, p[0] - n]), M_STOP_LINE, 0.4)
    for cw in town.crosswalks:  # zebra crossings: area, then bars along the road
        c = cw.corners
        d.polygon(px(c), fill=M_CROSS_GAP)
        e1, e2 = c[1] - c[0], c[2] - c[1]
        short = np.linalg.norm(e1) < np.linalg.norm(e2)
        along, across = (e1, e2) if short else (e2, e1)
        origin = c[1] if short else c[0]
        span = float(np.linalg.norm(across))
        u = across / max(span, 1e-9)
        for a in np.arange(0.3, span - 0.3, 1.0):
            q0 = origin + u * a
            bar = np.stack([q0, q0 + u * 0.55, q0 + u * 0.55 + along, q0 + along])
            d.polygon(px(bar), fill=M_CROSS_STRIPE)
    code = np.asarray(img, dtype=np.uint8) | (np.asarray(centre, dtype=np.uint8) * CENTRE_BIT)
    return GroundRaster(code=code, xmin=xmin, ymin=ymin, mpp=mpp, noise=_texture())


__all__ = ["GROUND_MPP", "GroundRaster", "ground_raster"]
