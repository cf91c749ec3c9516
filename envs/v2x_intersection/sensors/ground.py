"""Per-town ground raster: what the ground looks like and is, at every point of the town.

The ground (``z = 0``) is drawn once per town into a material raster (uint8 codes of
:mod:`.semantics`, default :data:`GROUND_MPP` = 0.25 m per pixel) with the same layers, order and
geometry as the top-down renderer's static map (:func:`..render.static_map`): grass, sidewalks
(with curbs and paved junction corners), parking lanes, lanes and junction areas, parking-slot
lines, lane boundary markings (dashed between same-direction lanes, yellow between directions,
solid at the road edge), stop lines and zebra crossings. Lane centre lines are flagged in bit 7
(:data:`.semantics.CENTRE_BIT`) for the BEV. Cameras and LiDARs look up their ground hits here
(nearest pixel); the BEV samples it. Points outside the raster are terrain.

Colours (precomputed per pixel, ``rgb``): ``MATERIAL_RGB`` times a tiled, deterministic texture
noise (fine grain plus coarse patches) whose amplitude depends on the material, so asphalt, grass
and paint read differently. Memory: 4 bytes per pixel (about 12 MB for Town01, 20 MB for Town12).
"""

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
        rgb: ``(H, W, 3)`` uint8 textured colour of every pixel.
    """

    code: np.ndarray
    xmin: float
    ymin: float
    mpp: float
    rgb: np.ndarray

    def flat_index(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat raster index (clipped) of world points and whether each lies inside."""
        h, w = self.code.shape
        inv = 1.0 / self.mpp
        col = np.floor((np.asarray(x) - self.xmin) * inv).astype(np.int64)
        row = np.floor((np.asarray(y) - self.ymin) * inv).astype(np.int64)
        inside = (col.astype(np.uint64) < w) & (row.astype(np.uint64) < h)
        flat = row * w + col
        if not inside.all():
            flat = np.where(inside, flat, 0)
        return flat, inside

    def pixel(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raster indices of world points: ``(row, col, inside)``, rows/cols clipped."""
        flat, inside = self.flat_index(x, y)
        return flat // self.code.shape[1], flat % self.code.shape[1], inside

    def lookup(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Material codes (uint8, nearest pixel) at world points ``x, y`` (m); terrain outside."""
        flat, inside = self.flat_index(x, y)
        code = self.code.ravel()[flat]
        return code if inside.all() else np.where(inside, code, np.uint8(M_TERRAIN))

    def sample(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Material codes ``(M,)`` uint8 and colours ``(M, 3)`` uint8 at world points; terrain
        (its plain colour) outside the raster."""
        flat, inside = self.flat_index(x, y)
        code = self.code.ravel()[flat]
        rgb = self.rgb.reshape(-1, 3)[flat]
        if not inside.all():
            code = np.where(inside, code, np.uint8(M_TERRAIN))
            rgb[~inside] = MATERIAL_RGB[M_TERRAIN].astype(np.uint8)
        return code, rgb


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


def _zebra(code: np.ndarray, c: np.ndarray, xmin: float, ymin: float, mpp: float) -> None:
    """Paint a zebra crossing (corners ``c (4, 2)``) into ``code`` by pixel centres: the area
    is crossing asphalt, with 0.55 m bars every 1 m across the road, running along it."""
    v0, v2 = c[0] - c[1], c[2] - c[1]  # the two edges at corner 1, into the crossing
    along, across = (v0, v2) if np.linalg.norm(v0) < np.linalg.norm(v2) else (v2, v0)
    la, lc = float(np.linalg.norm(along)), float(np.linalg.norm(across))
    ua, uc = along / max(la, 1e-9), across / max(lc, 1e-9)
    h, w = code.shape
    lo = np.floor((c.min(0) - (xmin, ymin)) / mpp).astype(int)
    hi = np.ceil((c.max(0) - (xmin, ymin)) / mpp).astype(int) + 1
    c0, r0 = np.clip(lo, 0, (w, h))
    c1, r1 = np.clip(hi, 0, (w, h))
    if c1 <= c0 or r1 <= r0:
        return
    x = xmin + (np.arange(c0, c1) + 0.5) * mpp - c[1, 0]
    y = ymin + (np.arange(r0, r1) + 0.5) * mpp - c[1, 1]
    sa = x[None, :] * ua[0] + y[:, None] * ua[1]
    sc = x[None, :] * uc[0] + y[:, None] * uc[1]
    inside = (sa >= 0) & (sa <= la) & (sc >= 0) & (sc <= lc)
    bar = inside & (sc >= 0.3) & (sc <= lc - 0.3) & ((sc - 0.3) % 1.0 < 0.55)
    block = code[r0:r1, c0:c1]
    block[inside] = M_CROSS_GAP
    block[bar] = M_CROSS_STRIPE


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
        poly = px(np.concatenate([offset_polyline(points, width / 2), offset_polyline(points, -width / 2)[::-1]]))
        d.polygon(poly, fill=fill)
        if outline is not None:
            d.line(poly + poly[:1], fill=outline, width=max(1, int(round(0.25 * k))))

    def line(points: np.ndarray, fill: int, width_m: float, draw=d) -> None:
        if len(points) >= 2:
            draw.line(px(points), fill=fill, width=max(1, int(round(width_m * k))), joint="curve")

    lanes = town.lanes
    for sw in town.sidewalks:  # sidewalks with a curb outline, paved junction corners
        band(sw.points, sw.width, M_SIDEWALK, M_CURB)
    for hull in junction_corners(town):
        d.polygon(px(hull), fill=M_SIDEWALK)
    for ln in lanes:
        if ln.kind == PARKING:
            band(ln.points, ln.width, M_PARKING)
    for ln in lanes:
        if ln.kind != PARKING:
            band(ln.points, ln.width, M_ROAD)
    for hull in junction_roads(town):
        d.polygon(px(hull), fill=M_ROAD)
    for seg in parking_separators(town):
        line(seg, M_PARK_LINE, 0.15)
    for ln in lanes:  # centre lines (BEV only)
        if ln.kind in (DRIVING, RAMP, CONNECTOR):
            line(ln.points, 1, 0.5, dc)
    for pts, colour, width in lane_markings(town):  # lane boundary markings
        line(pts, M_MARK_WHITE if colour == "white" else M_MARK_YELLOW, width)
    for bar in stop_bars(town)[0]:  # stop lines
        line(bar, M_STOP_LINE, 0.4)
    code = np.array(img, dtype=np.uint8)
    for cw in town.crosswalks:
        _zebra(code, cw.corners, xmin, ymin, mpp)
    code |= np.asarray(centre, dtype=np.uint8) * CENTRE_BIT
    noise = _texture()
    rows, cols = np.arange(h) & (_TILE - 1), np.arange(w) & (_TILE - 1)
    rgb = np.empty((h, w, 3), np.uint8)
    for r0 in range(0, h, 256):  # in bands: bounded temporaries
        c = code[r0 : r0 + 256]
        n = noise[rows[r0 : r0 + 256, None], cols[None, :]]
        band_rgb = MATERIAL_RGB[c] * (1.0 + MATERIAL_NOISE[c] * n)[..., None]
        rgb[r0 : r0 + 256] = np.clip(band_rgb, 0, 255).astype(np.uint8)
    return GroundRaster(code=code, xmin=xmin, ymin=ymin, mpp=mpp, rgb=rgb)


__all__ = ["GROUND_MPP", "GroundRaster", "ground_raster"]
