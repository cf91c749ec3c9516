"""What a ray sees where it stops: colour, semantic id, instance id and LiDAR intensity.

All functions take hits from the ray caster (:mod:`..raycast`): the box index (or ``GROUND`` /
``NO_HIT``) and the hit point. Nothing here casts rays. Arithmetic is float32.

Box surfaces (:func:`surface`): the face a point lies on is found from the hit point in the box's
local frame (``u = x / half_length``, ``v = y / half_width``, ``w = (z - z0) / height``; the face
is the coordinate nearest its bound): front (+x), back, left (+y), right, top, bottom. The face
selects the texel of the style's texture (:mod:`.textures`), lit by a fixed sun
(``scene.SUN``, Lambert ``AMBIENT + DIFFUSE * max(0, n . sun)`` per face) with a contact shadow
in the lowest 0.35 m; emissive texels (a lit signal lamp) are not lit. The ground takes the
textured colour of its material (:mod:`.ground`). Everything blends into the haze with distance,
``f = 1 - exp(-d / FOG_DIST)``; rays that hit nothing show a sky gradient by elevation (or the
haze below the horizon).

LiDAR intensity (:func:`lidar_returns`): ``reflectivity * |cos(incidence)|`` in ``[0, 1]``, with
the reflectivity of the ground material (:data:`.semantics.MATERIAL_REFLECTIVITY`: paint
0.7-0.8, asphalt 0.18, grass 0.22) or of the object class (:data:`.semantics.CLASS_REFLECTIVITY`:
signs and cones 0.85-0.9, vehicles 0.5-0.55, pedestrians 0.3) and the angle between the ray and
the surface normal.
"""

from __future__ import annotations

import numpy as np

from ..core.jit import HAVE_JIT
from ..core.raycast import GROUND, NO_HIT
from .ground import GroundRaster
from .kernels import lidar_returns_kernel, shade_kernel
from .scene import Scene
from .semantics import (
    CLASS_REFLECTIVITY,
    INSTANCE_NONE,
    M_TERRAIN,
    MATERIAL_REFLECTIVITY,
    MATERIAL_RGB,
    MATERIAL_SEMANTIC,
    SKY,
    TERRAIN,
)
from .textures import ATLAS_MODE, ATLAS_RGB, EMISSIVE, FIXED, REPEAT, STOREY, T

FOG_DIST = 260.0  # m
SKY_HORIZON = np.array([208.0, 221.0, 234.0], np.float32)
SKY_ZENITH = np.array([88.0, 138.0, 210.0], np.float32)
HAZE = SKY_HORIZON
F_TOP, F_BOTTOM = 4, 5
_F32 = np.float32


def surface(scene: Scene, j: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, ...]:
    """Face and texture coordinates of points ``p (M, 3)`` on boxes ``j (M,)``.

    Returns:
        ``(face, ta, tb, z)``: face (M,) int64 (0 front, 1 back, 2 left, 3 right, 4 top,
        5 bottom), texture coordinates across (``ta``) and down (``tb``) the face in ``[0, 1)``
        (per storey for repeating styles), and the height ``z`` (m), all float32.
    """
    g = scene.geo[j]  # (M, 8)
    c, s = g[:, 0], g[:, 1]
    dx, dy = p[:, 0] - g[:, 2], p[:, 1] - g[:, 3]
    u = (c * dx + s * dy) * g[:, 4]
    v = (c * dy - s * dx) * g[:, 5]
    w = (p[:, 2] - g[:, 6]) * g[:, 7]
    au, av, aw = np.abs(u), np.abs(v), np.abs(2 * w - 1)
    xf = (au >= av) & (au >= aw)
    yf = ~xf & (av >= aw)
    face = np.where(xf, (u < 0).astype(np.int64), np.where(yf, 2 + (v < 0), 4 + (w < 0.5)))
    ta = np.where(xf, v, u) * _F32(0.5) + _F32(0.5)
    tb = np.where(xf | yf, 1 - w, v * _F32(0.5) + _F32(0.5))
    rep = REPEAT[scene.style[j]] & (face < F_TOP)
    if rep.any():  # storey tiles: metres along the face and up
        along = np.where(xf, v / g[:, 5], u / g[:, 4])
        ta = np.where(rep, (along / STOREY[0]) % 1.0, ta)
        tb = np.where(rep, 1 - (p[:, 2] / STOREY[1]) % 1.0, tb)
    return face, ta, tb, p[:, 2]


_ATLAS_RGB = ATLAS_RGB.reshape(-1, 3)
_ATLAS_MODE = ATLAS_MODE.ravel()


def box_colors(scene: Scene, j: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Lit RGB ``(M, 3)`` float32 (0-255) of hit points ``p (M, 3)`` on boxes ``j (M,)``."""
    face, ta, tb, z = surface(scene, j, p)
    col = np.clip((ta * T).astype(np.int64), 0, T - 1)
    row = np.clip((tb * T).astype(np.int64), 0, T - 1)
    texel = ((scene.style[j] * 6 + face) * T + row) * T + col
    mode = _ATLAS_MODE[texel]
    tex = _ATLAS_RGB[texel]
    base = scene.colors.reshape(-1, 3)[j * 3 + np.minimum(mode, 2)]
    rgb = np.where((mode >= FIXED)[:, None], tex, base * (tex * _F32(1 / 255)))
    light = scene.light.ravel()[j * 6 + face]
    light[(face < F_TOP) & (z < 0.35)] *= _F32(0.82)
    light[mode == EMISSIVE] = 1.0
    return rgb * light[:, None]


def sky_colors(dz: np.ndarray) -> np.ndarray:
    """Sky gradient RGB ``(M, 3)`` float32 for the z component of unit ray directions."""
    t = np.clip(dz / _F32(0.6), 0.0, 1.0) ** _F32(0.7)
    return SKY_HORIZON + (SKY_ZENITH - SKY_HORIZON) * t[:, None]


def shade(
    scene: Scene,
    ground: GroundRaster,
    p: np.ndarray,
    dz: np.ndarray,
    dist: np.ndarray,
    idx: np.ndarray,
    sky: np.ndarray | None = None,
    rgb: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Colour, semantic and instance ids of camera rays.

    Args:
        scene: the render scene the rays were cast into.
        ground: the town's ground raster.
        p: ``(M, 3)`` float32 hit points (m, world; anything for misses).
        dz: ``(M,)`` z component of the unit ray directions.
        dist: ``(M,)`` distance from the camera to the hit (m; anything for misses).
        idx: ``(M,)`` box index, ``raycast.GROUND`` or ``raycast.NO_HIT``.
        sky: ``(M, 3)`` precomputed :func:`sky_colors` of the rays (computed when ``None``).
        rgb: compute the colours (``False``: only the ids, for cameras asked for no ``rgb``; the
            colours come back ``(0, 3)``).

    Returns:
        ``rgb (M, 3)`` uint8, ``semantic (M,)`` uint8, ``instance (M,)`` int32.
    """
    m = len(idx)
    if not rgb and not HAVE_JIT:
        return _ids(ground, p, dz, idx, scene)
    if HAVE_JIT:
        keep = np.exp(dist * _F32(-1.0 / FOG_DIST)) if rgb else dist
        if not rgb:
            sky = np.zeros((0, 3), np.float32)
        elif sky is None:
            sky = np.zeros((m, 3), np.float32)
            miss = np.flatnonzero(idx == NO_HIT)
            sky[miss] = sky_colors(dz[miss])
        return shade_kernel(
            p, dz, keep, np.ascontiguousarray(idx, np.int64), sky, scene.geo, scene.style,
            scene.colors.reshape(-1, 3), scene.light.ravel(), scene.sem, scene.inst, REPEAT, _F32(STOREY[0]),
            _F32(STOREY[1]), T, FIXED, EMISSIVE, _ATLAS_RGB, _ATLAS_MODE, ground.code, ground.rgb.reshape(-1, 3),
            _F32(ground.xmin), _F32(ground.ymin), _F32(1.0 / ground.mpp), M_TERRAIN,
            MATERIAL_RGB[M_TERRAIN].astype(np.uint8), MATERIAL_SEMANTIC, HAZE, SKY, TERRAIN, GROUND,
            INSTANCE_NONE, rgb)
    rgb = np.empty((m, 3), np.float32)
    sem = np.empty(m, np.uint8)
    inst = np.full(m, INSTANCE_NONE, np.int32)
    box = np.flatnonzero(idx >= 0)
    gnd = np.flatnonzero(idx == GROUND)
    miss = np.flatnonzero(idx == NO_HIT)
    if len(box):
        j = idx[box]
        rgb[box] = box_colors(scene, j, p[box])
        sem[box] = scene.sem[j]
        inst[box] = scene.inst[j]
    if len(gnd):
        code, col = ground.sample(p[gnd, 0], p[gnd, 1])
        rgb[gnd] = col  # the sun lights flat ground at AMBIENT + DIFFUSE * sun_z = 1.0
        sem[gnd] = MATERIAL_SEMANTIC[code]
    keep = np.exp(dist * _F32(-1.0 / FOG_DIST))  # 1 - fog
    if len(miss):
        up = dz[miss] >= 0
        rgb[miss] = sky_colors(dz[miss]) if sky is None else sky[miss]
        sem[miss] = np.where(up, SKY, TERRAIN)
        keep[miss] = up  # the sky keeps its gradient; below it, haze
    rgb *= keep[:, None]
    rgb += HAZE * (1.0 - keep)[:, None]
    np.minimum(rgb, 255.0, out=rgb)
    return rgb.astype(np.uint8), sem, inst


def _ids(ground: GroundRaster, p: np.ndarray, dz: np.ndarray, idx: np.ndarray, scene: Scene
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`shade` without colours (NumPy path): ``((0, 3) uint8, semantic, instance)``."""
    sem = np.where(dz >= 0, SKY, TERRAIN).astype(np.uint8)
    inst = np.full(len(idx), INSTANCE_NONE, np.int32)
    box, gnd = np.flatnonzero(idx >= 0), np.flatnonzero(idx == GROUND)
    sem[box] = scene.sem[idx[box]]
    inst[box] = scene.inst[idx[box]]
    if len(gnd):
        sem[gnd] = MATERIAL_SEMANTIC[ground.lookup(p[gnd, 0], p[gnd, 1])]
    return np.zeros((0, 3), np.uint8), sem, inst


def lidar_returns(
    scene: Scene, ground: GroundRaster, p: np.ndarray, d: np.ndarray, idx: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intensity, semantic and instance ids of LiDAR returns.

    Args:
        scene, ground: as :func:`shade`.
        p: ``(M, 3)`` float32 hit points (m, world). d: ``(M, 3)`` unit ray directions.
        idx: ``(M,)`` box index or ``raycast.GROUND`` (every ray here hit something).

    Returns:
        ``intensity (M,)`` float32 in ``[0, 1]``, ``semantic (M,)`` uint8, ``instance (M,)`` int32.
    """
    m = len(idx)
    if HAVE_JIT:
        return lidar_returns_kernel(
            p, d, np.ascontiguousarray(idx, np.int64), scene.geo, scene.normals, scene.sem, scene.inst,
            CLASS_REFLECTIVITY, ground.code, _F32(ground.xmin), _F32(ground.ymin), _F32(1.0 / ground.mpp),
            M_TERRAIN, MATERIAL_SEMANTIC, MATERIAL_REFLECTIVITY)
    inten = np.empty(m, np.float32)
    sem = np.empty(m, np.uint8)
    inst = np.zeros(m, np.int32)
    box = np.flatnonzero(idx >= 0)
    if len(box):
        j = idx[box]
        face = surface(scene, j, p[box])[0]
        n = scene.normals[j, face]
        cos = np.abs((n * d[box]).sum(1))
        sem[box] = scene.sem[j]
        inst[box] = scene.inst[j]
        inten[box] = CLASS_REFLECTIVITY[scene.sem[j]] * cos
    g = np.flatnonzero(idx < 0)
    if len(g):
        code = ground.lookup(p[g, 0], p[g, 1])
        sem[g] = MATERIAL_SEMANTIC[code]
        inten[g] = MATERIAL_REFLECTIVITY[code] * np.abs(d[g, 2])
    return np.clip(inten, 0.0, 1.0), sem, inst


__all__ = ["FOG_DIST", "box_colors", "lidar_returns", "shade", "sky_colors", "surface"]
