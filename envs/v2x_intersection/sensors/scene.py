"""The render scene: every box a sensor can hit, with what it is and how it looks.

A :class:`Scene` is built from a :class:`~..world.World` once per capture (:func:`build_scene`).
Its boxes (a :class:`..raycast.Boxes`) are, in order:

1. every actor row of ``world.table`` (row ``r`` is box ``r``; inactive rows have height 0 and
   are never hit: the ray caster drops flat boxes);
2. every static box of ``world.static_boxes`` (buildings, traffic-light poles, stop-sign poles);
3. decorations that give a thin pole a readable top: a traffic-light head (0.6 x 0.7 x 1.4 m,
   2.5-3.9 m above the ground, on the pole's side facing the traffic it controls, low enough to
   stay in view of a car waiting at the stop line) and a stop-sign plate (0.12 x 0.8 x 0.8 m at
   1.5-2.3 m). They stick out of their pole by at most 0.25 m and are not in
   ``world.occluders()`` (world visibility ignores them);
4. one rider per active bicycle: the bicycle's own box is cut to :data:`BIKE_HEIGHT` (frame and
   wheels) and a rider box (0.6 x 0.5 m, from 0.5 m up to the actor's height) sits on it, so
   the space in front of and behind the rider is empty, as on a real bicycle.

A decoration or rider carries the instance id, class and semantic id of its owner, so images and
point clouds see one object. Per box the scene also holds a style (:mod:`.textures`), three
instance colours (:data:`CAR_COLORS` etc. by ``world.table.color``; buildings by a hash of their
index) and the float32 terms that shading needs (orientation, extents, face normals, sunlight).

Classes and semantic ids are the observed ones (``World.object_classes``): an emergency vehicle
with its siren on is :data:`~..classes.EMERGENCY_VEHICLE`, drawn as a truck in the livery
:data:`EMERGENCY_RGB` (a signal yellow-green no other vehicle has).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from ..core import libm
from ..core.classes import BICYCLE, EMERGENCY_VEHICLE, TRAFFIC_CONE, TRAFFIC_LIGHT, TRAFFIC_SIGN
from ..core.jit import HAVE_JIT
from ..core.raycast import Boxes
from ..traffic.signals import GREEN, RED, YELLOW
from .kernels import cast_fan_kernel, cull_kernel
from .semantics import actor_instance, static_instance

# style codes (texture atlas rows); S_HEAD + k: light head, k = 0 dark, 1 red, 2 yellow, 3 green
S_CAR, S_TRUCK, S_PED, S_BIKE, S_POLE, S_SIGN_POLE, S_PLATE, S_CONE = range(8)
S_OBSTACLE, S_BUILDING, S_SIGN, S_RIDER, S_HEAD = 8, 9, 10, 11, 12
N_STYLES = S_HEAD + 4
_NONE = np.zeros(0, np.int64)
_KIND_STYLE = np.array([S_CAR, S_TRUCK, S_PED, S_BIKE, S_POLE, S_SIGN, S_CONE, S_OBSTACLE, S_TRUCK])
#: Body colour of an emergency vehicle (RGB 0-255): not in any vehicle palette.
EMERGENCY_RGB = (206, 232, 30)
_HEAD_K = np.zeros(4, np.int64)  # signal state + 1 -> head style offset
_HEAD_K[[RED + 1, YELLOW + 1, GREEN + 1]] = (1, 2, 3)

SUN = np.array([-0.42, -0.30, 0.86]) / np.linalg.norm([-0.42, -0.30, 0.86])  # toward the sun
AMBIENT, DIFFUSE = 0.58, 0.5

#: Instance colour palettes (RGB 0-255), indexed by ``world.table.color % 8``.
CAR_COLORS = np.array(
    [
        (225, 225, 222),
        (168, 172, 178),
        (40, 40, 46),
        (176, 32, 30),
        (38, 76, 168),
        (36, 92, 62),
        (214, 170, 36),
        (120, 66, 40),
    ],
    np.float32,
)
TRUCK_COLORS = np.array(
    [
        (226, 226, 220),
        (226, 178, 30),
        (164, 40, 36),
        (52, 90, 158),
        (58, 118, 72),
        (120, 120, 126),
        (214, 116, 30),
        (214, 204, 176),
    ],
    np.float32,
)
SHIRT_COLORS = np.array(
    [
        (200, 40, 44),
        (40, 90, 190),
        (40, 150, 70),
        (230, 190, 40),
        (120, 50, 150),
        (230, 110, 30),
        (235, 235, 235),
        (30, 30, 34),
    ],
    np.float32,
)
TROUSER_COLORS = np.array(
    [
        (36, 44, 80),
        (30, 30, 32),
        (160, 140, 100),
        (100, 100, 104),
        (60, 84, 130),
        (96, 66, 44),
        (40, 70, 48),
        (64, 64, 68),
    ],
    np.float32,
)
SKIN_COLORS = np.array(
    [(232, 186, 150), (196, 136, 100), (140, 90, 60), (220, 170, 124)], np.float32
)
BUILDING_COLORS = np.array(
    [
        (150, 84, 64),
        (204, 190, 160),
        (160, 160, 156),
        (218, 212, 200),
        (104, 104, 112),
        (190, 160, 120),
        (122, 136, 150),
        (176, 112, 82),
    ],
    np.float32,
)
_STYLE_RGB = {
    S_POLE: (72, 74, 78),
    S_HEAD: (28, 28, 30),
    S_SIGN_POLE: (150, 150, 156),
    S_PLATE: (200, 24, 32),
    S_CONE: (255, 110, 0),
    S_OBSTACLE: (230, 170, 20),
    S_SIGN: (30, 80, 180),
}

HEAD_SIZE = (0.6, 0.7, 2.5, 1.4)  # length (along the facing), width, base z, height (m)
HEAD_OFFSET = 0.25  # m, head centre in front of the pole centre
PLATE_SIZE = (0.12, 0.8, 1.5, 0.8)
PLATE_OFFSET = 0.26
BIKE_HEIGHT = 1.05  # m, the bicycle part of a bicycle actor
RIDER_SIZE = (0.6, 0.5, 0.5)  # length, width, base z (m)
RIDER_OFFSET = -0.1  # rider centre behind the bicycle centre, fraction of the length


@dataclass(frozen=True)
class Scene:
    """Boxes plus per-box metadata (arrays ``(N,)`` unless noted).

    Attributes:
        boxes: all ``N`` boxes (module docstring).
        inst: int64 instance ids. sem: int64 semantic (class) ids. style: int64 style codes.
        colors: ``(N, 3, 3)`` float32 primary, secondary, tertiary colour (RGB 0-255).
        active: bool, the box can be hit (positive height).
        radius: float64 half diagonal of the footprint (m), for culling.
        geo: ``(N, 8)`` float32 shading terms: cos yaw, sin yaw, centre x, centre y,
            1 / half length, 1 / half width, base z, 1 / height.
        normals: ``(N, 6, 3)`` float32 world normals of the faces (front, back, left, right,
            top, bottom). light: ``(N, 6)`` float32 Lambert light of each face.
        n_actors: rows of ``world.table`` (boxes ``[0, n_actors)``).
    """

    boxes: Boxes
    inst: np.ndarray
    sem: np.ndarray
    style: np.ndarray
    colors: np.ndarray
    active: np.ndarray
    radius: np.ndarray
    geo: np.ndarray
    normals: np.ndarray
    light: np.ndarray
    n_actors: int

    def cull(
        self,
        origin: np.ndarray,
        yaw: float,
        half_fov: float,
        max_range: float,
        exclude: np.ndarray | None = None,
        max_depth: float | None = None,
    ) -> np.ndarray:
        """Indices of the boxes that may be hit from ``origin`` within a horizontal wedge.

        Conservative tests on each box's bounding circle: within ``max_range`` (horizontal
        distance), within the wedge ``|bearing - yaw| <= half_fov``, and (if given) nearer than
        ``max_depth`` along the wedge's axis.

        Args:
            origin: ``(>=2,)`` sensor position (m, world frame; x and y used).
            yaw: wedge axis (rad, world frame).
            half_fov: half the wedge's opening (rad); ``>= pi`` keeps every direction.
            max_range: horizontal range (m).
            exclude: box indices never to keep (e.g. the ego's own box for ego sensors).
            max_depth: farthest distance along the axis (m), e.g. a camera's far clip.

        Returns:
            ``(K,)`` int64 box indices.
        """
        b = self.boxes
        if HAVE_JIT:
            ex = _NONE if exclude is None else np.asarray(exclude, dtype=np.int64)
            depth = np.inf if max_depth is None else float(max_depth)
            return cull_kernel(b.center, self.radius, self.active, float(origin[0]), float(origin[1]),
                               float(yaw), float(half_fov), float(max_range), depth, ex)
        rel = b.center - np.asarray(origin, dtype=np.float64)[:2]
        dist = libm.hypot(rel[:, 0], rel[:, 1])
        r = self.radius
        keep = self.active & (dist - r < max_range)
        if max_depth is not None:
            keep &= rel @ np.array([np.cos(yaw), np.sin(yaw)]) - r < max_depth
        if half_fov < np.pi:
            ang = np.abs((libm.arctan2(rel[:, 1], rel[:, 0]) - yaw + np.pi) % (2 * np.pi) - np.pi)
            slack = libm.arcsin(np.clip(r / np.maximum(dist, 1e-9), 0.0, 1.0))
            keep &= (ang <= half_fov + slack) | (dist <= r)
        if exclude is not None:
            keep[np.asarray(exclude, dtype=np.int64)] = False
        return np.flatnonzero(keep)


    def cast_fan(
        self,
        origin: np.ndarray,
        yaw: float,
        half_fov: float,
        max_range: float,
        exclude: np.ndarray | None,
        max_depth: float | None,
        azimuths: np.ndarray,
        k: np.ndarray,
        max_t: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A sensor fan's box hits (numba path only): :meth:`cull`, then the box part of
        ``raycast.first_hit_fan`` on the kept boxes, in one kernel call.

        Args:
            origin, yaw, half_fov, max_range, exclude, max_depth: as :meth:`cull`.
            azimuths: ``(A,)`` world azimuths of the fan's columns (rad). k: ``(E, A)``
                contiguous float32 slopes. max_t: ``(E, A)`` float32 far cut of the finishing
                step (with the ground plane when ``origin[2] >= 0``); rays stop looking for
                boxes beyond it (the finished result is the same).

        Returns:
            ``(t (E, A), j (E, A), sel)``: horizontal distance to the first box (``inf``: none),
            its position in ``sel`` (-1: none), and the kept box indices.
        """
        b = self.boxes
        c, s = b.trig()
        ex = _NONE if exclude is None else np.asarray(exclude, dtype=np.int64)
        depth = np.inf if max_depth is None else float(max_depth)
        return cast_fan_kernel(b.center, b.length, b.width, b.z0, b.height, c, s, self.radius, self.active,
                               float(origin[0]), float(origin[1]), float(origin[2]), float(yaw), float(half_fov),
                               float(max_range), depth, ex, np.cos(azimuths), np.sin(azimuths), k, max_t)


@dataclass(frozen=True)
class _StaticPart:
    """The constant part of a world's scene (statics and decorations), cached per world."""

    source: np.ndarray  # the world.static_boxes array it was built from
    box: np.ndarray  # (S, 7) x, y, length, width, yaw, z0, height
    inst: np.ndarray
    sem: np.ndarray
    style: np.ndarray
    colors: np.ndarray
    head_at: np.ndarray  # positions of the light heads within this part
    head_lanes: np.ndarray  # the lane each head shows
    terms: tuple  # _box_terms(box): geo, normals, light, radius, active


_STATIC_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _static_part(world) -> _StaticPart:
    s, heights, kinds = world.static_boxes, world.static_heights, world.static_kinds
    hit = _STATIC_CACHE.get(world)
    if hit is not None and hit.source is s:
        return hit
    n_build, n = len(world.town.buildings), len(s)
    style = np.full(n, S_OBSTACLE)
    for kind, st in ((TRAFFIC_LIGHT, S_POLE), (TRAFFIC_SIGN, S_SIGN_POLE), (TRAFFIC_CONE, S_CONE)):
        style[kinds == kind] = st
    style[:n_build] = S_BUILDING
    rows = [np.c_[s, np.zeros(n), heights]]
    inst, sem, styles = [static_instance(np.arange(n))], [kinds], [style]
    lights_at = np.flatnonzero(kinds == TRAFFIC_LIGHT)
    signs_at = np.flatnonzero(kinds == TRAFFIC_SIGN)
    for at, (ln, wd, z0, ht), off, st in (
        (lights_at, HEAD_SIZE, HEAD_OFFSET, S_HEAD),
        (signs_at, PLATE_SIZE, PLATE_OFFSET, S_PLATE),
    ):
        yaw = s[at, 4]
        c = s[at, :2] + off * np.stack([np.cos(yaw), np.sin(yaw)], -1)
        k = len(at)
        rows.append(np.c_[c, np.full(k, ln), np.full(k, wd), yaw, np.full(k, z0), np.full(k, ht)])
        inst.append(static_instance(at))
        sem.append(kinds[at])
        styles.append(np.full(k, st))
    style = np.concatenate(styles)
    colors = np.zeros((len(style), 3, 3), np.float32)
    for st, rgb in _STYLE_RGB.items():
        colors[style == st] = rgb
    facade = BUILDING_COLORS[(np.arange(n_build) * 2654435761 % 7919) % len(BUILDING_COLORS)]
    colors[:n_build, 0] = facade
    colors[:n_build, 1] = facade * 0.7
    lights = world.town.lights
    head_lanes = np.full(len(lights_at), -1, np.int64)
    if len(lights_at) and len(lights):
        d2 = ((s[lights_at, None, :2] - lights[None, :, :2]) ** 2).sum(-1)
        head_lanes = lights[np.argmin(d2, axis=1), 3].astype(np.int64)
    box = np.concatenate(rows)
    part = _StaticPart(
        source=s,
        box=box,
        inst=np.concatenate(inst),
        sem=np.concatenate(sem).astype(np.int64),
        style=style.astype(np.int64),
        colors=colors,
        head_at=n + np.arange(len(lights_at)),
        head_lanes=head_lanes,
        terms=_box_terms(box),
    )
    _STATIC_CACHE[world] = part
    return part


def _box_terms(box: np.ndarray) -> tuple:
    """Per-box shading and culling terms of ``(N, 7)`` rows ``x, y, length, width, yaw, z0,
    height``: ``geo (N, 8)``, ``normals (N, 6, 3)``, ``light (N, 6)`` (float32), ``radius``,
    ``active`` (row-wise, so a scene's constant rows are computed once per world)."""
    n = len(box)
    c, s = np.cos(box[:, 4]), np.sin(box[:, 4])
    normals = np.zeros((n, 6, 3))
    normals[:, 0, 0], normals[:, 0, 1] = c, s  # front
    normals[:, 1, 0], normals[:, 1, 1] = -c, -s  # back
    normals[:, 2, 0], normals[:, 2, 1] = -s, c  # left
    normals[:, 3, 0], normals[:, 3, 1] = s, -c  # right
    normals[:, 4, 2], normals[:, 5, 2] = 1.0, -1.0  # top, bottom
    light = AMBIENT + DIFFUSE * np.maximum(normals @ SUN, 0.0)
    light[:, 5] = AMBIENT * 0.7
    geo = np.empty((n, 8))
    geo[:, 0], geo[:, 1], geo[:, 2], geo[:, 3] = c, s, box[:, 0], box[:, 1]
    geo[:, 4] = 2 / np.maximum(box[:, 2], 1e-6)
    geo[:, 5] = 2 / np.maximum(box[:, 3], 1e-6)
    geo[:, 6] = box[:, 5]
    geo[:, 7] = 1 / np.maximum(box[:, 6], 1e-6)
    return (
        geo.astype(np.float32),
        normals.astype(np.float32),
        light.astype(np.float32),
        0.5 * np.hypot(box[:, 2], box[:, 3]),
        box[:, 6] > 0,
    )


def build_scene(world) -> Scene:
    """The :class:`Scene` of a world's current state (actors, statics, decorations, signals).

    Args:
        world: a :class:`~..world.World` after ``reset`` (or ``step``).
    """
    t = world.table
    sp = _static_part(world)
    na = len(t)
    kind = world.object_classes().astype(np.int64)
    cidx = t.color.astype(np.int64) % 8
    style = _KIND_STYLE[kind]
    colors = np.zeros((na, 3, 3), np.float32)
    for st, pal in ((S_CAR, CAR_COLORS), (S_TRUCK, TRUCK_COLORS), (S_BIKE, TRUCK_COLORS)):
        m = style == st
        colors[m, 0] = pal[cidx[m]]
    m = style == S_PED
    colors[m, 0] = SHIRT_COLORS[cidx[m]]
    for st, rgb in _STYLE_RGB.items():
        colors[style == st, 0] = rgb
    colors[kind == EMERGENCY_VEHICLE, 0] = EMERGENCY_RGB
    height = np.where(t.active, t.height, 0.0)
    bikes = np.flatnonzero(t.active & (kind == BICYCLE))
    full = t.height[bikes]
    height[bikes] = np.minimum(full, BIKE_HEIGHT)
    rl, rw, rz = RIDER_SIZE
    nb = len(bikes)
    dyn = np.empty((na + nb, 7))  # rows x, y, length, width, yaw, z0, height: actors, riders
    dyn[:na, :2], dyn[:na, 2], dyn[:na, 3], dyn[:na, 4] = t.pos, t.length, t.width, t.yaw
    dyn[:na, 5], dyn[:na, 6] = 0.0, height
    by = t.yaw[bikes]
    back = RIDER_OFFSET * t.length[bikes]
    rider = dyn[na:]
    rider[:, 0] = t.pos[bikes, 0] + back * np.cos(by)
    rider[:, 1] = t.pos[bikes, 1] + back * np.sin(by)
    rider[:, 2], rider[:, 3], rider[:, 4], rider[:, 5] = rl, rw, by, rz
    rider[:, 6] = np.maximum(full - rz, 0.0)
    actors = dyn[:na]
    box = np.concatenate([actors, sp.box, rider])
    people = np.concatenate([np.flatnonzero(style == S_PED), bikes])  # shirt, trousers, skin
    rider_colors = np.zeros((nb, 3, 3), np.float32)
    rider_colors[:, 0] = SHIRT_COLORS[(cidx[bikes] + 5) % 8]
    colors[people, 1] = TROUSER_COLORS[(cidx[people] + 3) % 8]
    colors[people, 2] = SKIN_COLORS[cidx[people] % 4]
    rider_colors[:, 1:] = colors[bikes, 1:]
    styles = np.concatenate([style, sp.style, np.full(nb, S_RIDER)])
    if len(sp.head_at):
        sig = np.asarray(world.lane_signal)
        state = np.where(sp.head_lanes >= 0, sig[np.clip(sp.head_lanes, 0, len(sig) - 1)], -1)
        styles[na + sp.head_at] = S_HEAD + _HEAD_K[np.clip(state, -1, 2) + 1]
    geo, normals, light, radius, active = (
        np.concatenate([d[:na], st, d[na:]]) for d, st in zip(_box_terms(dyn), sp.terms)
    )
    return Scene(
        boxes=Boxes.trusted(*(np.ascontiguousarray(box[:, k]) for k in (slice(0, 2), 2, 3, 4, 5, 6))),
        inst=np.concatenate([actor_instance(np.arange(na)), sp.inst, actor_instance(bikes)]),
        sem=np.concatenate([kind, sp.sem, kind[bikes]]),
        style=styles,
        colors=np.concatenate([colors, sp.colors, rider_colors]),
        active=active,
        radius=radius,
        geo=geo,
        normals=normals,
        light=light,
        n_actors=na,
    )


__all__ = ["N_STYLES", "Scene", "build_scene"]
