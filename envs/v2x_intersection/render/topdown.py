"""Top-down (bird's-eye) rendering of a :class:`~.world.World` and GIF/MP4 video writing.

The picture is north-up: world +x points right, world +y points up, and the view is centred on
the ego (or the active RSU, the whole map, or a given point). Everything static (ground, sidewalks,
lanes, markings, crosswalks, parking, buildings, stop signs) is drawn once per town and scale
into a big cached image; a frame crops that image and draws only what moves on top (signal
states, the route, RSUs and the active unit's field of view, actors, visibility outlines and a
text overlay), so a 512 x 512 frame costs a few milliseconds. The static layer lives in
:mod:`.render_map`, the colours in :mod:`.render_palette`, video writing in :mod:`.video`.

Colour key (see :func:`render_legend`): ego orange; cars blue; large vehicles purple; pedestrians
pink; bicycles teal (parked vehicles are shown faded); a cyan outline marks an actor the ego sees,
a magenta outline one the active RSU sees (both outlines: seen by both); the active RSU is a
magenta square with a translucent 120 deg wedge of its sensing range, other deployed units are
white squares; traffic-light poles and the stop bars of their lanes take the signal colour; the
ego's remaining route is a blue line.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..core.actors import PARKED, ActorTable
from ..core.classes import BICYCLE, CAR, LARGE_VEHICLE, PEDESTRIAN
from ..traffic.signals import GREEN, NO_SIGNAL, RED, YELLOW
from .map_layer import StaticMap, static_map
from .palette import (
    ACTOR_EDGE,
    BACKGROUND,
    CLASS_COLORS,
    EGO_COLOR,
    EGO_SEEN_COLOR,
    LIGHT_COLORS,
    LIGHT_HOUSING,
    OTHER_COLOR,
    PARKED_TINT,
    ROUTE_COLOR,
    RSU_ACTIVE_COLOR,
    RSU_COLOR,
    RSU_FOV_ALPHA,
    RSU_FOV_EDGE,
    RSU_FOV_RGB,
    RSU_SEEN_COLOR,
    STOP_SIGN,
    box_quads,
    mix_rgb,
)
from .video import save_video

if TYPE_CHECKING:
    from ..sim.world import World



# ----------------------------------------------------------------------------- the view
@dataclass(frozen=True)
class TopDownView:
    """Where a frame looks: world ``(x0, y1)`` at the centre of the top-left pixel, ``mpp``
    metres per pixel, ``size`` pixels square, north-up (x right, y up)."""

    x0: float
    y1: float
    mpp: float
    size: int

    def to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """World points ``(..., 2)`` (m) to pixel coordinates ``(..., 2)`` ``(column, row)``."""
        xy = np.asarray(xy, dtype=np.float64)
        return np.stack([(xy[..., 0] - self.x0) / self.mpp, (self.y1 - xy[..., 1]) / self.mpp], -1)


def _center_point(world: World, center: str | Sequence[float]) -> np.ndarray:
    if not isinstance(center, str):
        return np.asarray(center, dtype=np.float64).reshape(2)
    if center == "ego":
        return world.table.pos[0].astype(np.float64)
    if center == "rsu":
        u = int(world.active_rsu[0]) if len(world.rsus) else -1
        return world.rsus.pose[u, :2].astype(np.float64) if u >= 0 else world.table.pos[0]
    if center == "map":
        b = world.town.bounds
        return np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2], np.float64)
    raise ValueError(f"render: center={center!r}; use 'ego', 'rsu', 'map' or an (x, y) pair")


def make_view(
    world: World, size: int = 512, view_m: float = 120.0, center: str | Sequence[float] = "ego"
) -> tuple[TopDownView, StaticMap]:
    """The view of a frame and the static map it is cut from.

    Args:
        world, size, view_m, center: as :func:`render_topdown`.

    Returns:
        ``(view, static_map)``; ``view.to_pixel(xy)`` maps world points to the frame's pixels.

    Raises:
        ValueError: bad ``size``, ``view_m`` or ``center``.
    """
    if not isinstance(size, (int, np.integer)) or size < 16:
        raise ValueError(f"render: size={size!r} must be an int >= 16")
    if isinstance(center, str) and center == "map":
        b = world.town.bounds
        view_m = float(max(b[2] - b[0], b[3] - b[1])) + 2 * 10.0
    if not view_m > 0:
        raise ValueError(f"render: view_m={view_m!r} must be positive")
    mpp = float(view_m) / size
    sm = static_map(world.town, mpp)
    c = _center_point(world, center)
    x0, y1 = c[0] - (size - 1) / 2 * mpp, c[1] + (size - 1) / 2 * mpp
    if abs(sm.mpp - mpp) < 1e-12:  # snap to the static map's pixel grid: a crop, no resampling
        x0 = sm.x0 + round((x0 - sm.x0) / mpp) * mpp
        y1 = sm.y1 - round((sm.y1 - y1) / mpp) * mpp
    return TopDownView(float(x0), float(y1), mpp, int(size)), sm


_BG = np.array(BACKGROUND, np.uint8)


def _crop(sm: StaticMap, view: TopDownView) -> np.ndarray:
    """The static layer under ``view`` as a writable ``(size, size, 3)`` array."""
    n = view.size
    H, W = sm.image.shape[:2]
    if abs(sm.mpp - view.mpp) < 1e-12:
        c0 = int(round((view.x0 - sm.x0) / sm.mpp))
        r0 = int(round((sm.y1 - view.y1) / sm.mpp))
        out = np.empty((n, n, 3), np.uint8)
        a0, a1 = max(c0, 0), min(c0 + n, W)
        b0, b1 = max(r0, 0), min(r0 + n, H)
        if not (a0 == c0 and b0 == r0 and a1 == c0 + n and b1 == r0 + n):
            out[:] = _BG  # part of the view lies outside the map
        if a1 > a0 and b1 > b0:
            out[b0 - r0 : b1 - r0, a0 - c0 : a1 - c0] = sm.image[b0:b1, a0:a1]
        return out
    # coarser static map: resample the covered box (with a background border for out-of-map)
    f = view.mpp / sm.mpp
    bx0 = (view.x0 - sm.x0) / sm.mpp - 0.5 * f + 0.5
    by0 = (sm.y1 - view.y1) / sm.mpp - 0.5 * f + 0.5
    bx1, by1 = bx0 + n * f, by0 + n * f
    c0, r0 = int(np.floor(bx0)) - 1, int(np.floor(by0)) - 1
    c1, r1 = int(np.ceil(bx1)) + 1, int(np.ceil(by1)) + 1
    patch = np.empty((r1 - r0, c1 - c0, 3), np.uint8)
    patch[:] = _BG
    a0, a1, b0, b1 = max(c0, 0), min(c1, W), max(r0, 0), min(r1, H)
    if a1 > a0 and b1 > b0:
        patch[b0 - r0 : b1 - r0, a0 - c0 : a1 - c0] = sm.image[b0:b1, a0:a1]
    im = Image.fromarray(patch).resize(
        (n, n), Image.Resampling.BILINEAR, box=(bx0 - c0, by0 - r0, bx1 - c0, by1 - r0)
    )
    return np.array(im, dtype=np.uint8)


@functools.lru_cache(maxsize=8)
def font(px: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # Pillow < 10.1 has no scalable default font
        return ImageFont.load_default()


class _Glyphs:
    """Text as alpha masks composed from per-character bitmaps rendered once (fast per frame)."""

    def __init__(self, px: int) -> None:
        self.font = font(px)
        asc, desc = self.font.getmetrics() if hasattr(self.font, "getmetrics") else (px, 2)
        self.height = int(asc + desc)
        self._cache: dict[str, tuple[np.ndarray, float]] = {}
        self._lines: dict[str, np.ndarray] = {}

    def _glyph(self, ch: str) -> tuple[np.ndarray, float]:
        g = self._cache.get(ch)
        if g is None:
            adv = float(self.font.getlength(ch))
            im = Image.new("L", (int(np.ceil(adv)) + 2, self.height), 0)
            ImageDraw.Draw(im).text((0, 0), ch, fill=255, font=self.font)
            g = self._cache[ch] = (np.asarray(im, dtype=np.uint8), adv)
        return g

    def mask(self, s: str) -> np.ndarray:
        """``(height, width)`` uint8 alpha mask of one line of text."""
        out = self._lines.get(s)
        if out is not None:
            return out
        glyphs = [self._glyph(ch) for ch in s] or [self._glyph(" ")]
        xs = np.round(np.cumsum([0.0] + [a for _, a in glyphs])).astype(np.int64)
        out = np.concatenate([g[:, :w] for (g, _), w in zip(glyphs, np.diff(xs))], 1)
        if len(self._lines) > 512:
            self._lines.clear()
        self._lines[s] = out
        return out


@functools.lru_cache(maxsize=8)
def _glyphs(px: int) -> _Glyphs:
    return _Glyphs(px)


def _tint(
    im: Image.Image,
    color: tuple,
    alpha: float,
    box: tuple[float, float, float, float],
    polygon: list[tuple[float, float]] | None = None,
) -> None:
    """Blend the pixels of ``box`` (inside ``polygon`` if given) ``alpha`` of the way toward
    ``color``, in place (a translucent fill without Pillow's full-image RGBA path)."""
    x0, y0 = max(int(box[0]), 0), max(int(box[1]), 0)
    x1, y1 = min(int(np.ceil(box[2])), im.width), min(int(np.ceil(box[3])), im.height)
    if x1 <= x0 or y1 <= y0:
        return
    region = im.crop((x0, y0, x1, y1))
    tinted = Image.blend(region, Image.new("RGB", region.size, color), alpha)
    if polygon is None:
        im.paste(tinted, (x0, y0))
        return
    mask = Image.new("1", region.size, 0)
    ImageDraw.Draw(mask).polygon([(x - x0, y - y0) for x, y in polygon], fill=1)
    im.paste(tinted, (x0, y0), mask)


# ----------------------------------------------------------------------------- render a frame
def render_topdown(
    world: World,
    size: int = 512,
    view_m: float = 120.0,
    center: str | Sequence[float] = "ego",
    legend: bool = False,
    text: bool = True,
) -> np.ndarray:
    """Draw the world from above, north-up (world x to the right, y up).

    Static layers come from a per-town cache (:func:`static_map`); this call crops it and draws
    the signal states (stop bars and light poles), the ego's route ahead, the RSUs (the active
    one highlighted, with its field of view: ``world.RSU_HFOV`` wide, ``config.rsu_range``
    deep), the actors as oriented boxes coloured by class, visibility outlines (cyan: the ego
    sees the actor; magenta: the active RSU sees it; both: both rings) and a text overlay
    (tick, speed, route completion, V2X bytes/s from the channel, visible counts) with a scale
    bar. A 512 px frame costs about 5 ms once the town's static map is cached.

    Args:
        world: a world after ``reset``.
        size: picture side in pixels.
        view_m: side of the viewed square in metres (ignored for ``center="map"``).
        center: ``"ego"``, ``"rsu"`` (the active unit), ``"map"`` (the whole town) or an
            ``(x, y)`` world point.
        legend: append the colour key (:func:`render_legend`) below the picture; the result is
            then taller than ``size``.
        text: draw the text overlay and the scale bar.

    Returns:
        ``(size, size, 3)`` uint8 RGB image (``(size + legend height, size, 3)`` with ``legend``).
    """
    from ..sim.world import RSU_HFOV, VISIBLE_THRESHOLD  # local: the world may import this module

    if getattr(world, "table", None) is None:
        raise RuntimeError("render: the world has not been reset; call world.reset(seed) first")
    view, sm = make_view(world, size, view_m, center)
    frame = Image.fromarray(_crop(sm, view))
    d = ImageDraw.Draw(frame)
    mpp, n = view.mpp, view.size
    P = view.to_pixel
    half_span = 0.5 * n * mpp * np.sqrt(2.0)
    mid = np.array([view.x0 + (n - 1) / 2 * mpp, view.y1 - (n - 1) / 2 * mpp])
    t = world.table

    # the active RSU's field of view, under everything that moves
    rsus = world.rsus
    active = int(world.active_rsu[0]) if len(rsus) else -1
    if active >= 0:
        rx, ry, _, ryaw = rsus.pose[active]
        ((cx, cy),) = P(np.array([[rx, ry]]))
        r = world.config.rsu_range / mpp
        ang = -ryaw + np.linspace(-RSU_HFOV / 2, RSU_HFOV / 2, 49)
        arc = list(zip(cx + r * np.cos(ang), cy + r * np.sin(ang)))  # image y points down
        wedge = [(cx, cy), *arc]
        xs, ys = [p[0] for p in wedge], [p[1] for p in wedge]
        _tint(
            frame,
            RSU_FOV_RGB,
            RSU_FOV_ALPHA,
            (min(xs) - 1, min(ys) - 1, max(xs) + 2, max(ys) + 2),
            wedge,
        )
        d.line(wedge + [(cx, cy)], fill=RSU_FOV_EDGE, width=1)

    # signal states on the stop lines of the controlled lanes
    states = world.lane_signal
    if len(sm.stop_lanes):
        st = states[sm.stop_lanes]
        near = np.linalg.norm(sm.stop_bars[:, 0] - mid, axis=1) < half_span + 5.0
        keep = (st != NO_SIGNAL) & near
        bw = max(2, int(round(0.6 / mpp)))
        for bar, s in zip(P(sm.stop_bars[keep]), st[keep]):
            d.line([tuple(bar[0]), tuple(bar[1])], fill=LIGHT_COLORS[int(s)], width=bw)

    # the route ahead, from the ego to the goal
    route = world.route
    k0 = int(getattr(world.monitor, "progress", 0))
    ahead = np.concatenate([t.pos[:1], route.points[k0 + 1 :]], 0)
    inside = np.flatnonzero(np.linalg.norm(ahead - mid, axis=1) < half_span + 10.0)
    rw = max(2, int(round(0.5 / mpp)))
    if len(inside) > 1:  # draw each run of points inside the view as its own polyline
        cuts = np.flatnonzero(np.diff(inside) > 1) + 1
        for run in np.split(inside, cuts):
            if len(run) > 1:
                d.line(P(ahead[run]).ravel().tolist(), fill=ROUTE_COLOR, width=rw, joint="curve")
    ((gx, gy),) = P(route.points[-1:])
    gr = max(3.0, 0.9 / mpp)
    d.ellipse(
        (gx - gr, gy - gr, gx + gr, gy + gr),
        fill=ROUTE_COLOR,
        outline=(255, 255, 255),
        width=max(1, int(gr / 3)),
    )

    # RSU poles: every deployed unit a small square, the active one larger and magenta
    if len(rsus):
        q = max(2.5, 0.7 / mpp)
        for u, (x, y) in enumerate(P(rsus.pose[:, :2])):
            if u != active:
                d.rectangle((x - q, y - q, x + q, y + q), fill=RSU_COLOR, outline=ACTOR_EDGE)
        if active >= 0:
            qa = q * 1.6
            d.rectangle((cx - qa, cy - qa, cx + qa, cy + qa), fill=ACTOR_EDGE)
            d.rectangle((cx - qa + 1, cy - qa + 1, cx + qa - 1, cy + qa - 1), fill=(255, 255, 255))
            d.rectangle((cx - qa + 3, cy - qa + 3, cx + qa - 3, cy + qa - 3), fill=RSU_ACTIVE_COLOR)

    # traffic-light poles: a dark signal head lit in the state of the lane it controls
    lights = world.town.lights
    if len(lights):
        near = np.linalg.norm(lights[:, :2] - mid, axis=1) < half_span + 2.0
        lr = max(3.0, 0.7 / mpp)
        for (x, y), lid in zip(P(lights[near, :2]), lights[near, 3].astype(np.int64)):
            col = LIGHT_COLORS[int(states[lid])]
            h = lr + max(1.5, 0.25 / mpp)
            d.rounded_rectangle((x - h, y - h, x + h, y + h), radius=h / 2, fill=LIGHT_HOUSING)
            d.ellipse((x - lr, y - lr, x + lr, y + lr), fill=col)

    # actors, then the ego on top
    idx = np.flatnonzero(t.active)
    idx = idx[(idx > 0) & (np.linalg.norm(t.pos[idx] - mid, axis=1) < half_span + 12.0)]
    ego_seen = world.ego_vis[idx] >= VISIBLE_THRESHOLD
    if len(world.rsu_vis):
        rsu_seen = world.rsu_vis[0][idx] >= VISIBLE_THRESHOLD
    else:
        rsu_seen = np.zeros(len(idx), bool)
    _draw_actors(d, t, idx, ego_seen, rsu_seen, view)
    _draw_actors(d, t, np.array([0]), np.zeros(1, bool), np.zeros(1, bool), view, ego=True)

    if text:
        _draw_overlay(frame, d, world, view, ego_seen, rsu_seen, active)
    out = np.array(frame, dtype=np.uint8)
    if legend:
        out = np.concatenate([out, render_legend(n)], 0)
    return out


def _draw_actors(
    d: ImageDraw.ImageDraw,
    t: ActorTable,
    idx: np.ndarray,
    ego_seen: np.ndarray,
    rsu_seen: np.ndarray,
    view: TopDownView,
    ego: bool = False,
) -> None:
    """Oriented boxes (pedestrians: discs) with a windshield mark and visibility outlines."""
    if len(idx) == 0:
        return
    mpp = view.mpp
    kind = t.kind[idx]
    pos, yaw = t.pos[idx], t.yaw[idx]
    L = np.maximum(t.length[idx], 4.0 * mpp)
    W = np.maximum(t.width[idx], 3.0 * mpp)
    both = ego_seen & rsu_seen
    # outline rings just outside the box: cyan (ego) inside, magenta (RSU) outside when both
    r_ego = np.full(len(idx), 2.0 * mpp)
    r_rsu = np.where(both, 4.0 * mpp, 2.0 * mpp)
    quads = np.concatenate(
        [
            box_quads(pos, yaw, -L / 2, L / 2, -W / 2, W / 2),
            box_quads(pos, yaw, 0.1 * L, 0.3 * L, -0.36 * W, 0.36 * W),
            box_quads(pos, yaw, -L / 2 - r_ego, L / 2 + r_ego, -W / 2 - r_ego, W / 2 + r_ego),
            box_quads(pos, yaw, -L / 2 - r_rsu, L / 2 + r_rsu, -W / 2 - r_rsu, W / 2 + r_rsu),
        ],
        1,
    )
    px = view.to_pixel(quads).tolist()
    center = view.to_pixel(pos).tolist()
    parked = (t.behaviour[idx] == PARKED).tolist()
    pr = max(2.5, 0.35 / mpp)
    for i, k in enumerate(kind.tolist()):
        col = EGO_COLOR if ego else CLASS_COLORS.get(k, OTHER_COLOR)
        if parked[i]:
            col = mix_rgb(col, PARKED_TINT, 0.45)
        q = px[i]
        if k == PEDESTRIAN:
            cx, cy = center[i]
            if rsu_seen[i]:
                rr = pr + (5.0 if both[i] else 2.5)
                d.ellipse((cx - rr, cy - rr, cx + rr, cy + rr), outline=RSU_SEEN_COLOR, width=2)
            if ego_seen[i]:
                rr = pr + 2.5
                d.ellipse((cx - rr, cy - rr, cx + rr, cy + rr), outline=EGO_SEEN_COLOR, width=2)
            d.ellipse((cx - pr, cy - pr, cx + pr, cy + pr), fill=col, outline=ACTOR_EDGE)
            continue
        if rsu_seen[i]:  # closed wide lines: Pillow's wide polygon outlines cost a full mask
            d.line([tuple(p) for p in q[12:16] + q[12:13]], fill=RSU_SEEN_COLOR, width=2)
        if ego_seen[i]:
            d.line([tuple(p) for p in q[8:12] + q[8:9]], fill=EGO_SEEN_COLOR, width=2)
        d.polygon([tuple(p) for p in q[0:4]], fill=col, outline=ACTOR_EDGE)
        if k != BICYCLE:
            d.polygon([tuple(p) for p in q[4:8]], fill=mix_rgb(col, (255, 255, 255), 0.6))


def _nice_length(target: float) -> float:
    """A round scale-bar length (m) close to ``target``."""
    steps = np.array([1, 2, 5, 10, 20, 25, 50, 100, 200, 250, 500, 1000, 2000], float)
    return float(steps[np.argmin(np.abs(np.log(steps / max(target, 1e-3))))])


def _draw_overlay(
    frame: Image.Image,
    d: ImageDraw.ImageDraw,
    world: World,
    view: TopDownView,
    ego_seen: np.ndarray,
    rsu_seen: np.ndarray,
    active: int,
) -> None:
    """Text panel (top left) and scale bar (bottom right)."""
    n = view.size
    fs = max(9, int(round(n * 0.025)))
    glyphs = _glyphs(fs)
    t = world.table
    bps = float(world.channel.stats()["bps"])
    v = float(t.speed[0])
    lines = [
        f"tick {world.tick}   t = {world.tick * world.config.dt:.1f} s",
        f"speed {v:.1f} m/s  ({v * 3.6:.0f} km/h)",
        f"route {float(world.monitor.route_completion):.1f} %",
        f"V2X {bps / 1000:.2f} kB/s" if bps >= 1000 else f"V2X {bps:.0f} B/s",
        f"seen: ego {int(ego_seen.sum())}  RSU {int(rsu_seen.sum())}"
        + (f" (unit {active})" if active >= 0 else ""),
    ]
    masks = [glyphs.mask(s) for s in lines]
    pad, lh = max(3, fs // 3), glyphs.height + max(0, fs // 8)
    w = max(m.shape[1] for m in masks) + 2 * pad
    h = lh * len(masks) + 2 * pad
    _tint(frame, (14, 16, 22), 0.68, (4, 4, 4 + w, 4 + h))
    for i, m in enumerate(masks):
        frame.paste((255, 255, 255), (4 + pad, 4 + pad + i * lh), Image.fromarray(m))
    # scale bar
    metres = _nice_length(n * view.mpp / 5.0)
    length = metres / view.mpp
    label = glyphs.mask(f"{metres:g} m")
    x1, yb = n - 10, n - 9
    x0 = x1 - length
    _tint(frame, (255, 255, 255), 0.7, (x0 - 6, yb - label.shape[0] - 8, x1 + 7, yb + 6))
    d.line([(x0, yb), (x1, yb)], fill=(20, 20, 20), width=3)
    for x in (x0, x1):
        d.line([(x, yb - 5), (x, yb + 1)], fill=(20, 20, 20), width=2)
    lx = int(round((x0 + x1 - label.shape[1]) / 2))
    frame.paste((20, 20, 20), (lx, yb - label.shape[0] - 5), Image.fromarray(label))


# ----------------------------------------------------------------------------- legend
def render_legend(width: int = 512) -> np.ndarray:
    """A colour key strip ``(H, width, 3)`` uint8 matching :func:`render_topdown`."""
    fs = max(9, int(round(width * 0.022)))
    fnt = font(fs)
    items: list[tuple[str, str, tuple]] = [
        ("box", "ego", EGO_COLOR),
        ("box", "car", CLASS_COLORS[CAR]),
        ("box", "large vehicle", CLASS_COLORS[LARGE_VEHICLE]),
        ("disc", "pedestrian", CLASS_COLORS[PEDESTRIAN]),
        ("box", "bicycle", CLASS_COLORS[BICYCLE]),
        ("ring", "ego sees", EGO_SEEN_COLOR),
        ("ring", "RSU sees", RSU_SEEN_COLOR),
        ("square", "active RSU + FOV", RSU_ACTIVE_COLOR),
        ("square", "RSU", RSU_COLOR),
        ("disc", "green", LIGHT_COLORS[GREEN]),
        ("disc", "yellow", LIGHT_COLORS[YELLOW]),
        ("disc", "red", LIGHT_COLORS[RED]),
        ("oct", "stop sign", STOP_SIGN),
        ("line", "route", ROUTE_COLOR),
    ]
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    sw, gap, pad = fs, max(4, fs // 2), 6
    cells = [sw + 4 + probe.textlength(label, font=fnt) for _, label, _ in items]
    rows: list[list[int]] = [[]]
    x = pad
    for i, w in enumerate(cells):
        if rows[-1] and x + w > width - pad:
            rows.append([])
            x = pad
        rows[-1].append(i)
        x += w + 2 * gap
    row_h = fs + 8
    img = Image.new("RGB", (width, len(rows) * row_h + 2 * pad - 8 + 4), (246, 246, 244))
    d = ImageDraw.Draw(img)
    y = pad
    for row in rows:
        x = pad
        for i in row:
            shape, label, col = items[i]
            box = (x, y + 1, x + sw - 2, y + sw - 1)
            if shape == "box":
                d.rectangle(box, fill=col, outline=ACTOR_EDGE)
            elif shape == "disc":
                d.ellipse(box, fill=col, outline=ACTOR_EDGE)
            elif shape == "ring":
                d.rectangle(box, outline=col, width=2)
            elif shape == "square":
                d.rectangle(box, fill=col, outline=ACTOR_EDGE)
            elif shape == "oct":
                c = ((box[0] + box[2]) / 2, (box[1] + box[3]) / 2, (sw - 2) / 2)
                d.regular_polygon(c, 8, rotation=22.5, fill=col)
            else:
                d.line(
                    [(box[0], (box[1] + box[3]) / 2), (box[2], (box[1] + box[3]) / 2)],
                    fill=col,
                    width=3,
                )
            d.text((x + sw + 2, y), label, fill=(30, 30, 30), font=fnt)
            x += cells[i] + 2 * gap
        y += row_h
    return np.asarray(img, dtype=np.uint8)


__all__ = [
    "CLASS_COLORS",
    "EGO_COLOR",
    "EGO_SEEN_COLOR",
    "LIGHT_COLORS",
    "RSU_SEEN_COLOR",
    "StaticMap",
    "TopDownView",
    "make_view",
    "render_legend",
    "render_topdown",
    "save_video",
    "static_map",
]

