"""Ego-centred bird's-eye-view semantic raster for map and object supervision.

The BEV is a ``(C, H, W)`` uint8 stack of 0/1 masks (multi-label: a crosswalk pixel is also
drivable), in the ego frame: the ego's centre is the image centre, row 0 is ahead (+x, forward
up), column 0 is to the left (+y). Pixel ``[r, c]`` covers the square centred at
``x = (H/2 - r - 0.5) * mpp``, ``y = (W/2 - c - 0.5) * mpp``. Default 128 x 128 at 0.5 m per pixel
(64 m x 64 m).

Channels (:data:`BEV_CHANNELS`): drivable area (lanes, junctions, markings and crosswalks on
them; not parking), lane centre lines (lanes, ramps and junction connectors), lane markings
(boundaries, stop lines), crosswalks, sidewalks (with curbs), parking lanes (with their slot
lines), vehicles (cars and large vehicles, the ego excluded), VRUs (pedestrians, bicycles), the
ego, static obstacles (buildings, poles, cones, barriers), and traffic control drawn on the stop
lines of the lanes it governs: light_green / light_yellow / light_red (signal-controlled lanes,
the current state of ``world.lane_signal``), stop_sign (stop-sign lanes), and emergency
(emergency vehicles with their siren on, :data:`~..classes.EMERGENCY_VEHICLE`; also in the
vehicle channel). Map channels are
sampled from the town's ground raster over ``s x s`` of its pixels per BEV pixel (``s = mpp /
0.25 m``, OR of
the samples, precomputed per town as a dilated channel-bit raster, so thin lines stay
connected); objects are filled by pixel centres (extents below a pixel widened to one pixel) and
stop lines drawn as 1 m wide lines.

Which actors are drawn: the ego's observation (``BevSpec.privileged = False``, the default) draws
only the actors the ego can see, by the same test as the ``objects`` observation (``world.ego_vis
>= visibility.VISIBLE_THRESHOLD``: occluded and out-of-range actors are left out), plus the ego.
``BevSpec(privileged=True)`` draws every active actor in reach: the ground-truth raster, for data
sets and privileged agents only, never an ego observation (:func:`bev_actor_rows`). Map
channels, signals and static boxes (buildings, poles) are drawn in both.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw

from ..core.classes import BICYCLE, CAR, EMERGENCY_VEHICLE, LARGE_VEHICLE, PEDESTRIAN
from ..core.jit import HAVE_JIT
from ..perception.visibility import VISIBLE_THRESHOLD
from ..town.areas import stop_bars
from ..traffic.signals import GREEN, NO_SIGNAL, RED, YELLOW
from .ground import GroundRaster
from .kernels import bev_ground_kernel, fill_boxes_kernel
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
)

BEV_CHANNELS = (
    "drivable",
    "lane_centerline",
    "lane_marking",
    "crosswalk",
    "sidewalk",
    "parking",
    "vehicle",
    "vru",
    "ego",
    "obstacle",
    "light_green",
    "light_yellow",
    "light_red",
    "stop_sign",
    "emergency",
)
(
    DRIVABLE,
    CENTRELINE,
    MARKING,
    CROSSWALK_CH,
    SIDEWALK_CH,
    PARKING_CH,
    VEHICLE,
    VRU,
    EGO_CH,
    OBSTACLE,
    LIGHT_GREEN,
    LIGHT_YELLOW,
    LIGHT_RED,
    STOP_SIGN_CH,
    EMERGENCY_CH,
) = range(len(BEV_CHANNELS))
_LIGHT_CH = {GREEN: LIGHT_GREEN, YELLOW: LIGHT_YELLOW, RED: LIGHT_RED}
_KIND_CHANNEL = np.full(256, OBSTACLE)  # object class -> BEV channel (everything else: obstacle)
_KIND_CHANNEL[[CAR, LARGE_VEHICLE, EMERGENCY_VEHICLE]] = VEHICLE
_KIND_CHANNEL[[PEDESTRIAN, BICYCLE]] = VRU


def _material_bits() -> np.ndarray:
    lut = np.zeros(256, np.uint16)
    rules = {
        DRIVABLE: (M_ROAD, M_MARK_WHITE, M_MARK_YELLOW, M_STOP_LINE, M_CROSS_STRIPE, M_CROSS_GAP),
        MARKING: (M_MARK_WHITE, M_MARK_YELLOW, M_STOP_LINE),
        CROSSWALK_CH: (M_CROSS_STRIPE, M_CROSS_GAP),
        SIDEWALK_CH: (M_SIDEWALK, M_CURB),
        PARKING_CH: (M_PARKING, M_PARK_LINE),
    }
    for ch, mats in rules.items():
        for m in mats:
            lut[m] |= 1 << ch
            lut[m | CENTRE_BIT] |= 1 << ch
    lut[CENTRE_BIT:] |= 1 << CENTRELINE
    return lut


_BITS = _material_bits()
_SHIFTS = np.arange(len(BEV_CHANNELS), dtype=np.uint16)[:, None, None]


@dataclass(frozen=True)
class BevSpec:
    """BEV raster size: ``size x size`` pixels at ``mpp`` metres per pixel.

    ``privileged``: draw every actor in reach, seen by the ego or not (ground truth for data sets
    and privileged agents); ``False`` (an ego observation): only the actors the ego sees.
    """

    size: int = 128
    mpp: float = 0.5
    privileged: bool = False


def bev_actor_rows(world, reach: float, privileged: bool = False) -> np.ndarray:
    """Actor-table rows a BEV draws: active actors within ``reach`` m of the ego (row 0, always
    drawn), and unless ``privileged`` only those the ego sees (``world.ego_vis >=
    VISIBLE_THRESHOLD``, the ``objects`` observation's test). Increasing row order."""
    t = world.table
    ex, ey = float(t.pos[0, 0]), float(t.pos[0, 1])
    keep = t.active & (np.hypot(t.pos[:, 0] - ex, t.pos[:, 1] - ey) < reach)
    if not privileged:
        keep &= np.asarray(world.ego_vis) >= VISIBLE_THRESHOLD
        keep[0] = bool(t.active[0])
    return np.flatnonzero(keep)


@functools.lru_cache(maxsize=8)
def _grid(size: int, mpp: float) -> tuple[np.ndarray, np.ndarray]:
    """Ego-frame x and y (m) of the BEV pixel centres, each ``(size, size)``."""
    off = (np.arange(size) + 0.5 - size / 2) * mpp
    return np.ascontiguousarray(np.broadcast_to(-off[:, None], (size, size))), np.ascontiguousarray(
        np.broadcast_to(-off[None, :], (size, size))
    )


_DILATED: dict[tuple[int, int], tuple[GroundRaster, np.ndarray]] = {}


def _dilated_bits(ground: GroundRaster, s: int) -> np.ndarray:
    """BEV channel bits of every ground pixel, OR-ed over the ``s x s`` block it starts."""
    key = (id(ground), s)
    hit = _DILATED.get(key)
    if hit is not None and hit[0] is ground:
        return hit[1]
    bits = _BITS[ground.code]
    out = bits.copy()
    for dr in range(s):
        for dc in range(s):
            if dr or dc:
                out[: out.shape[0] - dr, : out.shape[1] - dc] |= bits[dr:, dc:]
    if len(_DILATED) > 8:
        _DILATED.clear()
    _DILATED[key] = (ground, out)
    return out


def _fill_boxes(out, chans, boxes, ex, ey, yaw, mpp) -> None:
    """Set ``out[ch]`` where a BEV pixel centre lies in a box ``(x, y, length, width, yaw)``.

    Extents below one pixel are widened to one pixel, so that small VRUs never vanish.
    """
    n = out.shape[1]
    c, s = np.cos(yaw), np.sin(yaw)
    if HAVE_JIT:
        fill_boxes_kernel(out, np.asarray(chans, np.int64), boxes, float(ex), float(ey), float(c), float(s), float(yaw),
                          float(mpp))
        return
    d = boxes[:, :2] - (ex, ey)
    bx, by = c * d[:, 0] + s * d[:, 1], c * d[:, 1] - s * d[:, 0]  # ego frame
    rel = boxes[:, 4] - yaw
    hl, hw = np.maximum(boxes[:, 2], mpp) / 2, np.maximum(boxes[:, 3], mpp) / 2
    ext = (
        np.abs(np.cos(rel)) * hl + np.abs(np.sin(rel)) * hw,
        np.abs(np.sin(rel)) * hl + np.abs(np.cos(rel)) * hw,
    )
    # pixel (r, k) centre: x = (n/2 - r - 0.5) mpp, y = (n/2 - k - 0.5) mpp
    r0 = np.clip(np.floor(n / 2 - 0.5 - (bx + ext[0]) / mpp), 0, n).astype(int)
    r1 = np.clip(np.ceil(n / 2 - 0.5 - (bx - ext[0]) / mpp) + 1, 0, n).astype(int)
    k0 = np.clip(np.floor(n / 2 - 0.5 - (by + ext[1]) / mpp), 0, n).astype(int)
    k1 = np.clip(np.ceil(n / 2 - 0.5 - (by - ext[1]) / mpp) + 1, 0, n).astype(int)
    for i in np.flatnonzero((r1 > r0) & (k1 > k0)):
        x = (n / 2 - np.arange(r0[i], r1[i]) - 0.5)[:, None] * mpp - bx[i]
        y = (n / 2 - np.arange(k0[i], k1[i]) - 0.5)[None, :] * mpp - by[i]
        cr, sr = np.cos(rel[i]), np.sin(rel[i])
        inside = (np.abs(cr * x + sr * y) <= hl[i]) & (np.abs(cr * y - sr * x) <= hw[i])
        out[chans[i], r0[i] : r1[i], k0[i] : k1[i]] |= inside.astype(np.uint8)


def bev_reach(spec: BevSpec) -> float:
    """Distance (m) from the ego within which actors and stop lines are drawn."""
    return spec.size * float(spec.mpp) * 0.75 + 15.0


def capture_bev(world, ground: GroundRaster, spec: BevSpec = BevSpec()) -> np.ndarray:
    """The ego-centred BEV of ``world``.

    Args:
        world: a :class:`~..world.World` after ``reset`` (its ``ego_vis`` of this tick).
        ground: the town's ground raster (:func:`.ground.ground_raster`).
        spec: raster size and resolution, and whether it is the privileged raster (every actor)
            or the ego's (the actors it sees).

    Returns:
        ``(len(BEV_CHANNELS), size, size)`` uint8 in ``{0, 1}``.
    """
    n, mpp = spec.size, float(spec.mpp)
    s = min(max(round(mpp / ground.mpp), 1), 4)
    t = world.table
    ex, ey, yaw = float(t.pos[0, 0]), float(t.pos[0, 1]), float(t.yaw[0])
    c, si = np.cos(yaw), np.sin(yaw)
    lx, ly = _grid(n, mpp)
    # sample the block of s x s ground pixels under each BEV pixel (its lower-left corner)
    half = 0.5 * mpp - 0.5 * ground.mpp
    if HAVE_JIT:
        out = bev_ground_kernel(_dilated_bits(ground, s), lx, ly, ex, ey, float(c), float(si), half,
                                float(ground.xmin), float(ground.ymin), 1.0 / ground.mpp, len(BEV_CHANNELS))
    else:
        row, col, inside = ground.pixel(ex + c * lx - si * ly - half, ey + si * lx + c * ly - half)
        bits = np.where(inside, _dilated_bits(ground, s)[row, col], np.uint16(0))
        out = ((bits[None] >> _SHIFTS) & 1).astype(np.uint8)
    reach = bev_reach(spec)

    def to_px(pts: np.ndarray) -> np.ndarray:
        d = pts - (ex, ey)
        x, y = c * d[..., 0] + si * d[..., 1], c * d[..., 1] - si * d[..., 0]
        return np.stack([n / 2 - y / mpp - 0.5, n / 2 - x / mpp - 0.5], -1)

    # objects, filled by pixel centres (statics first, then actors)
    idx = bev_actor_rows(world, reach, spec.privileged)
    sb = world.static_boxes
    near = np.flatnonzero(
        np.hypot(sb[:, 0] - ex, sb[:, 1] - ey) < reach + 0.5 * np.hypot(sb[:, 2], sb[:, 3])
    )
    k = len(near)
    boxes = np.empty((k + len(idx), 5))
    boxes[:k] = sb[near]
    boxes[k:, :2], boxes[k:, 2], boxes[k:, 3], boxes[k:, 4] = t.pos[idx], t.length[idx], t.width[idx], t.yaw[idx]
    kinds = world.object_classes()[idx]
    chans = np.full(len(boxes), OBSTACLE)
    chans[k:] = _KIND_CHANNEL[kinds]
    chans[k:][idx == 0] = EGO_CH
    em = np.flatnonzero(kinds == EMERGENCY_VEHICLE)  # drawn twice: vehicle and emergency channels
    if len(em):
        boxes = np.concatenate([boxes, boxes[k + em]])
        chans = np.concatenate([chans, np.full(len(em), EMERGENCY_CH)])
    _fill_boxes(out, chans, boxes, ex, ey, yaw, mpp)
    # traffic control on the stop lines (green 1, yellow 2, red 3, stop sign 4)
    bars, lanes = stop_bars(world.town)
    if len(bars):
        state = np.asarray(world.lane_signal)[lanes]
        close = np.flatnonzero(np.hypot(bars[:, 0, 0] - ex, bars[:, 0, 1] - ey) < reach)
        if len(close):
            img = Image.new("L", (n, n), 0)
            d = ImageDraw.Draw(img)
            code = {GREEN: 1, YELLOW: 2, RED: 3, NO_SIGNAL: 4}
            width = max(1, int(round(1.0 / mpp)))
            for q, st in zip(to_px(bars[close]).tolist(), state[close].tolist()):
                d.line([tuple(p) for p in q], fill=code.get(int(st), 4), width=width)
            sig = np.asarray(img, np.uint8)
            for ch, v in ((LIGHT_GREEN, 1), (LIGHT_YELLOW, 2), (LIGHT_RED, 3), (STOP_SIGN_CH, 4)):
                out[ch] = sig == v
    return out


__all__ = ["BEV_CHANNELS", "BevSpec", "bev_actor_rows", "bev_reach", "capture_bev", "stop_bars"]
