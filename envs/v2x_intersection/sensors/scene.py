"""The render scene: every box a sensor can hit, with what it is and how it looks.

A :class:`Scene` is built from a :class:`~..world.World` once per capture (:func:`build_scene`).
Its boxes (a :class:`..raycast.Boxes`) are, in order:

1. every actor row of ``world.table`` (row ``r`` is box ``r``; inactive rows have height 0 and
   are never hit, the ray caster drops flat boxes),
2. every static box of ``world.static_boxes`` (buildings, traffic-light poles, stop-sign poles),
3. decorations that give a thin pole a readable top: a traffic-light head (0.6 x 0.7 x 1.5 m,
   3.3-4.8 m above the ground, on the pole's side facing the traffic it controls) and a stop-sign
   plate (0.12 x 0.8 x 0.8 m at 1.5-2.3 m). A decoration carries the instance id, class and
   semantic id of its pole, so images and point clouds see one object. Decorations are not in
   ``world.occluders()`` (world visibility ignores them); they stick out of their pole by at most
   0.25 m.

Per box the scene holds its instance id (:mod:`.semantics` encoding), semantic (class) id, a
style code (how :mod:`.shading` paints it), a base colour (per-instance: ``world.table.color`` for
actors, a hash of the index for buildings) and an ``aux`` integer (a light head's signal state).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from ..classes import STATIC_OBSTACLE, TRAFFIC_CONE, TRAFFIC_LIGHT, TRAFFIC_SIGN
from ..raycast import Boxes
from .semantics import actor_instance, static_instance

# style codes
S_CAR, S_TRUCK, S_PED, S_BIKE, S_POLE, S_HEAD, S_SIGN_POLE, S_PLATE = 0, 1, 2, 3, 4, 5, 6, 7
S_CONE, S_OBSTACLE, S_BUILDING, S_SIGN = 8, 9, 10, 11
_KIND_STYLE = np.array([S_CAR, S_TRUCK, S_PED, S_BIKE, S_POLE, S_SIGN, S_CONE, S_OBSTACLE])

#: Instance colour palettes (RGB 0-255), indexed by ``world.table.color % 8``.
CAR_COLORS = np.array(
    [(225, 225, 222), (168, 172, 178), (40, 40, 46), (176, 32, 30), (38, 76, 168), (36, 92, 62),
     (214, 170, 36), (120, 66, 40)], np.float32)  # fmt: skip
TRUCK_COLORS = np.array(
    [(226, 226, 220), (226, 178, 30), (164, 40, 36), (52, 90, 158), (58, 118, 72), (120, 120, 126),
     (214, 116, 30), (214, 204, 176)], np.float32)  # fmt: skip
SHIRT_COLORS = np.array(
    [(200, 40, 44), (40, 90, 190), (40, 150, 70), (230, 190, 40), (120, 50, 150), (230, 110, 30),
     (235, 235, 235), (30, 30, 34)], np.float32)  # fmt: skip
BUILDING_COLORS = np.array(
    [(150, 84, 64), (204, 190, 160), (160, 160, 156), (218, 212, 200), (104, 104, 112),
     (190, 160, 120), (122, 136, 150), (176, 112, 82)], np.float32)  # fmt: skip
_STATIC_RGB = {
    S_POLE: (72, 74, 78),
    S_HEAD: (28, 28, 30),
    S_SIGN_POLE: (150, 150, 156),
    S_PLATE: (200, 24, 32),
    S_CONE: (255, 110, 0),
    S_OBSTACLE: (230, 170, 20),
    S_SIGN: (30, 80, 180),
}

HEAD_SIZE = (0.6, 0.7, 3.3, 1.5)  # length (along the facing), width, base z, height (m)
HEAD_OFFSET = 0.25  # m, head centre in front of the pole centre
PLATE_SIZE = (0.12, 0.8, 1.5, 0.8)
PLATE_OFFSET = 0.26


@dataclass(frozen=True)
class _StaticPart:
    """The per-town, per-world constant part of the scene (statics and decorations)."""

    source: np.ndarray  # the world.static_boxes array this part was built from
    center: np.ndarray
    length: np.ndarray
    width: np.ndarray
    yaw: np.ndarray
    z0: np.ndarray
    height: np.ndarray
    inst: np.ndarray
    sem: np.ndarray
    style: np.ndarray
    color: np.ndarray
    head_lanes: np.ndarray  # (num light heads,) lane id each head shows
    head_slice: slice  # positions of the light heads within this part


@dataclass(frozen=True)
class Scene:
    """Boxes plus per-box metadata (all arrays ``(N,)`` unless noted).

    Attributes:
        boxes: all ``N`` boxes (actors, statics, decorations; see module docstring).
        inst: int64 instance ids. sem: int64 semantic/class ids. style: int64 style codes.
        color: ``(N, 3)`` float32 base colour (0-255). aux: int64 (light heads: signal state,
            ``signals.GREEN/YELLOW/RED`` or -1; others: ``world.table.color`` or a hash).
        active: bool, the box can be hit (positive height).
        radius: float64 half diagonal of the footprint (m), for culling.
        n_actors: rows of ``world.table`` (boxes ``[0, n_actors)``).
    """

    boxes: Boxes
    inst: np.ndarray
    sem: np.ndarray
    style: np.ndarray
    color: np.ndarray
    aux: np.ndarray
    active: np.ndarray
    radius: np.ndarray
    n_actors: int

    def cull(
        self,
        origin: np.ndarray,
        yaw: float,
        half_fov: float,
        max_range: float,
        exclude: np.ndarray | None = None,
    ) -> np.ndarray:
        """Indices of the boxes that may be hit from ``origin`` within a horizontal wedge.

        Args:
            origin: ``(>=2,)`` sensor position (m, world frame; only x, y are used).
            yaw: wedge axis (rad, world frame).
            half_fov: half the wedge's opening (rad); ``>= pi`` keeps every direction.
            max_range: horizontal range (m).
            exclude: box indices never to keep (e.g. the ego's own box for ego sensors).

        Returns:
            ``(K,)`` int64 box indices (conservative: bounding circles against the wedge).
        """
        b = self.boxes
        rel = b.center - np.asarray(origin, dtype=np.float64)[:2]
        dist = np.hypot(rel[:, 0], rel[:, 1])
        r = self.radius
        keep = self.active & (dist - r < max_range)
        if half_fov < np.pi:
            ang = np.abs((np.arctan2(rel[:, 1], rel[:, 0]) - yaw + np.pi) % (2 * np.pi) - np.pi)
            slack = np.arcsin(np.clip(r / np.maximum(dist, 1e-9), 0.0, 1.0))
            keep &= (ang <= half_fov + slack) | (dist <= r)
        if exclude is not None:
            keep[np.asarray(exclude, dtype=np.int64)] = False
        return np.flatnonzero(keep)


_STATIC_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _static_part(world) -> _StaticPart:
    s, heights, kinds = world.static_boxes, world.static_heights, world.static_kinds
    hit = _STATIC_CACHE.get(world)
    if hit is not None and hit.source is s:
        return hit
    n_build = len(world.town.buildings)
    n = len(s)
    idx = np.arange(n)
    style = np.where(kinds == TRAFFIC_LIGHT, S_POLE, np.where(kinds == TRAFFIC_SIGN, S_SIGN_POLE, 0))
    style = np.where(kinds == STATIC_OBSTACLE, S_OBSTACLE, style)
    style = np.where(kinds == TRAFFIC_CONE, S_CONE, style)
    style[:n_build] = S_BUILDING
    color = np.zeros((n, 3), np.float32)
    for st, rgb in _STATIC_RGB.items():
        color[style == st] = rgb
    hashed = (idx * 2654435761) % 7919
    color[:n_build] = BUILDING_COLORS[hashed[:n_build] % len(BUILDING_COLORS)]
    # decorations on light poles and stop-sign poles
    lights = world.town.lights
    lights_at = np.flatnonzero(kinds == TRAFFIC_LIGHT)
    signs_at = np.flatnonzero(kinds == TRAFFIC_SIGN)
    deco = [(lights_at, HEAD_SIZE, HEAD_OFFSET, S_HEAD), (signs_at, PLATE_SIZE, PLATE_OFFSET, S_PLATE)]
    parts = {f: [] for f in ("center", "length", "width", "yaw", "z0", "height", "inst", "sem",
                             "style", "color")}  # fmt: skip
    for at, (ln, wd, z0, ht), off, st in deco:
        yaw = s[at, 4]
        fwd = np.stack([np.cos(yaw), np.sin(yaw)], -1)
        parts["center"].append(s[at, :2] + off * fwd)
        for f, v in (("length", ln), ("width", wd), ("z0", z0), ("height", ht)):
            parts[f].append(np.full(len(at), v))
        parts["yaw"].append(yaw)
        parts["inst"].append(static_instance(at))
        parts["sem"].append(kinds[at])
        parts["style"].append(np.full(len(at), st))
        parts["color"].append(np.tile(np.asarray(_STATIC_RGB[st], np.float32), (len(at), 1)))
    # which lane each light head shows: the town light row at the same position
    head_lanes = np.full(len(lights_at), -1, np.int64)
    if len(lights_at) and len(lights):
        d2 = ((s[lights_at, None, :2] - lights[None, :, :2]) ** 2).sum(-1)
        head_lanes = lights[np.argmin(d2, axis=1), 3].astype(np.int64)
    cat = {f: np.concatenate(v) for f, v in parts.items()}
    part = _StaticPart(
        source=s,
        center=np.concatenate([s[:, :2], cat["center"].reshape(-1, 2)]),
        length=np.concatenate([s[:, 2], cat["length"]]),
        width=np.concatenate([s[:, 3], cat["width"]]),
        yaw=np.concatenate([s[:, 4], cat["yaw"]]),
        z0=np.concatenate([np.zeros(n), cat["z0"]]),
        height=np.concatenate([heights, cat["height"]]),
        inst=np.concatenate([static_instance(idx), cat["inst"]]),
        sem=np.concatenate([kinds, cat["sem"]]).astype(np.int64),
        style=np.concatenate([style, cat["style"]]).astype(np.int64),
        color=np.concatenate([color, cat["color"].reshape(-1, 3)]).astype(np.float32),
        head_lanes=head_lanes,
        head_slice=slice(n, n + len(lights_at)),
    )
    _STATIC_CACHE[world] = part
    return part


def build_scene(world) -> Scene:
    """The :class:`Scene` of a world's current state (actors, statics, decorations, signals).

    Args:
        world: a :class:`~..world.World` after ``reset`` (or ``step``).
    """
    t = world.table
    sp = _static_part(world)
    na = len(t)
    kind = t.kind.astype(np.int64)
    style = _KIND_STYLE[kind]
    cidx = t.color.astype(np.int64) % 8
    color = np.zeros((na, 3), np.float32)
    for st, pal in ((S_CAR, CAR_COLORS), (S_TRUCK, TRUCK_COLORS), (S_PED, SHIRT_COLORS),
                    (S_BIKE, SHIRT_COLORS)):  # fmt: skip
        m = style == st
        color[m] = pal[cidx[m]]
    for st, rgb in _STATIC_RGB.items():
        color[style == st] = rgb
    height = np.where(t.active, t.height, 0.0)
    boxes = Boxes(
        np.concatenate([t.pos, sp.center]),
        np.concatenate([t.length, sp.length]),
        np.concatenate([t.width, sp.width]),
        np.concatenate([t.yaw, sp.yaw]),
        np.concatenate([np.zeros(na), sp.z0]),
        np.concatenate([height, sp.height]),
    )
    aux = np.concatenate([cidx, np.arange(len(sp.inst)) * 7 % 13])
    if len(sp.head_lanes):
        sig = np.asarray(world.lane_signal)
        lanes = sp.head_lanes
        aux[na + sp.head_slice.start : na + sp.head_slice.stop] = np.where(
            lanes >= 0, sig[np.clip(lanes, 0, len(sig) - 1)], -1
        )
    return Scene(
        boxes=boxes,
        inst=np.concatenate([actor_instance(np.arange(na)), sp.inst]),
        sem=np.concatenate([kind, sp.sem]),
        style=np.concatenate([style, sp.style]),
        color=np.concatenate([color, sp.color]),
        aux=aux,
        active=boxes.height > 0,
        radius=0.5 * np.hypot(boxes.length, boxes.width),
        n_actors=na,
    )


__all__ = ["Scene", "build_scene"]
