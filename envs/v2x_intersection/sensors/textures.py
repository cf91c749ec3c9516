"""Procedural texture atlas of the box styles: how every face of every kind of box is painted.

Painting a box hit is one lookup: ``ATLAS_RGB[style, face, row, col]`` and ``ATLAS_MODE[...]``
with ``T x T`` texels (:data:`T` = 16) per face. Texture coordinates (:func:`.shading.surface`):
front/back faces span the box's width (``v``) and height (``w``); the sides its length (``u``)
and height; top and bottom its length and width. Buildings repeat one storey tile every
:data:`STOREY` = (2.8 m along the face, 3.2 m up) instead.

A texel's mode says where its colour comes from: :data:`PRIMARY` / :data:`SECONDARY` /
:data:`TERTIARY` multiply one of the box's three instance colours (:mod:`.scene`: body or
shirt, trousers, skin) by the texel's grey level, :data:`FIXED` is the texel's own colour, lit
like any surface, :data:`EMISSIVE` its own colour unlit (a lit signal lamp).

The patterns (read the rules below): vehicles have windows, wheels, head and tail lights and a
grille; pedestrians and riders hair, skin, shirt and trousers; bicycles two dark wheels under a
frame; traffic-light heads a dark housing with three lamps (red, yellow, green top to bottom) on
the face toward traffic, one style per state with that lamp lit; stop-sign plates a red face with
a white rim; cones a white band; barriers stripes; buildings a window per storey tile and a flat
grey roof.
"""

from __future__ import annotations

import numpy as np

from .scene import (
    N_STYLES,
    S_BIKE,
    S_BUILDING,
    S_CAR,
    S_CONE,
    S_HEAD,
    S_OBSTACLE,
    S_PED,
    S_PLATE,
    S_RIDER,
    S_SIGN,
    S_TRUCK,
)

T = 16
PRIMARY, SECONDARY, TERTIARY, FIXED, EMISSIVE = 0, 1, 2, 3, 4
F_FRONT, F_BACK, F_LEFT, F_RIGHT, F_TOP, F_BOTTOM = range(6)
STOREY = (2.8, 3.2)  # m, building tile width and height
HEAD_STATES = 4  # head styles S_HEAD + k: k = 0 dark, 1 red, 2 yellow, 3 green lit

GLASS = (52, 66, 84)
TYRE = (26, 26, 28)
DARK = (44, 44, 48)
HEADLIGHT = (250, 244, 214)
TAILLIGHT = (196, 22, 24)
WHITE = (236, 236, 236)
HAIR = (48, 34, 26)
METAL = (150, 150, 156)
_LAMPS = ((255, 40, 30), (255, 200, 0), (40, 255, 110))  # red, yellow, green (lit)
_LAMPS_OFF = ((70, 20, 18), (70, 60, 14), (16, 60, 30))


def _grid(face: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normalized box coordinates ``(u, v, w)`` of the texel centres of one face, ``(T, T)``."""
    c = (np.arange(T) + 0.5) / T
    a = np.broadcast_to(2 * c[None, :] - 1, (T, T))  # across the face, columns
    b = np.broadcast_to(1 - c[:, None], (T, T))  # up the face (row 0 at the top)
    one = np.ones((T, T))
    if face in (F_FRONT, F_BACK):
        return (one if face == F_FRONT else -one), a, b
    if face in (F_LEFT, F_RIGHT):
        return a, (one if face == F_LEFT else -one), b
    return a, 2 * b - 1, (one if face == F_TOP else 0 * one)


def _paint(style: int, face: int, rgb: np.ndarray, mode: np.ndarray) -> None:
    """Fill one face of one style (in place): rules per style."""
    u, v, w = _grid(face)
    side = face in (F_LEFT, F_RIGHT)
    front, back, top = face == F_FRONT, face == F_BACK, face == F_TOP
    av = np.abs(v)

    def put(mask, col, m=FIXED):
        mask = np.broadcast_to(mask, (T, T))
        rgb[mask] = col
        mode[mask] = m

    if style == S_CAR:
        put(side & (w > 0.6) & (w < 0.93) & (u > -0.72) & (u < 0.42), GLASS)
        put((front or back) & (w > 0.62) & (w < 0.93) & (av < 0.86), GLASS)
        put(side & (w < 0.34) & (np.abs(np.abs(u) - 0.64) < 0.15), TYRE)
        put(front & (w > 0.36) & (w < 0.52) & (av > 0.55) & (av < 0.92), HEADLIGHT)
        put(front & (w > 0.18) & (w < 0.36) & (av < 0.45), DARK)
        put(back & (w > 0.4) & (w < 0.56) & (av > 0.55) & (av < 0.93), TAILLIGHT)
        put(back & (w > 0.24) & (w < 0.36) & (av < 0.22), WHITE)
        put((face < F_TOP) & (w < 0.1), DARK)
        if top:
            rgb[:] = 220
    elif style == S_TRUCK:
        put(front & (w > 0.5) & (w < 0.82) & (av < 0.88), GLASS)
        put(front & (w > 0.12) & (w < 0.4) & (av < 0.5), DARK)
        put(front & (w > 0.12) & (w < 0.22) & (av > 0.62) & (av < 0.92), HEADLIGHT)
        put(side & (u > 0.74) & (w > 0.5) & (w < 0.8), GLASS)
        put(side & (w > 0.23) & (w < 0.28), DARK)
        wheel = (np.abs(u - 0.7) < 0.085) | (np.abs(u + 0.58) < 0.085) | (np.abs(u + 0.76) < 0.085)
        put(side & (w < 0.23) & wheel, TYRE)
        put(back & (av < 0.07), DARK)
        put(back & (w > 0.1) & (w < 0.18) & (av > 0.7) & (av < 0.95), TAILLIGHT)
        put((face < F_TOP) & (w < 0.07), DARK)
        if top:
            rgb[:] = 200
    elif style in (S_PED, S_RIDER):
        leg, head = (0.5, 0.87) if style == S_PED else (0.3, 0.83)
        put(w <= leg, (255, 255, 255), SECONDARY)
        put(w > head, (255, 255, 255), TERTIARY)
        put((w > head + 0.08) | top, HAIR)
        put(w < 0.04, DARK)
    elif style == S_BIKE:
        put((w < 0.72) & (np.abs(np.abs(u) - 0.6) < 0.36), TYRE)
        put(side & (w > 0.4) & (w < 0.52), (255, 255, 255), PRIMARY)
        put(top, DARK)
    elif S_HEAD <= style < S_HEAD + HEAD_STATES:
        lit = style - S_HEAD - 1  # -1: dark, 0 red, 1 yellow, 2 green
        k = np.clip(((1.0 - w) * 3.0).astype(np.int64), 0, 2)  # 0 top (red) .. 2 bottom (green)
        cell = (1.0 - w) * 3.0 - k - 0.5
        lamp = front & (av < 0.86) & (np.abs(cell) < 0.42)
        for i in range(3):
            put(
                lamp & (k == i),
                _LAMPS[i] if i == lit else _LAMPS_OFF[i],
                EMISSIVE if i == lit else FIXED,
            )
    elif style == S_PLATE:
        rim = (np.maximum(av, np.abs(2 * w - 1)) > 0.78) | (av + np.abs(2 * w - 1) > 1.42)
        put(front & rim, WHITE)
        put(not front, METAL)
    elif style == S_SIGN:
        put(w < 0.6, METAL)
        put((w >= 0.6) & front & (np.maximum(av, np.abs(5 * w - 4)) > 0.8), WHITE)
    elif style == S_CONE:
        put((w > 0.45) & (w < 0.65), WHITE)
        put(w < 0.08, DARK)
    elif style == S_OBSTACLE:
        put((np.floor((u + 2 * w) * 2.5) % 2) == 0, WHITE)
    elif style == S_BUILDING:
        if face < F_TOP:  # one storey tile: a window in the middle, sill shadow below
            a, b = (u + 1) / 2 if side else (v + 1) / 2, w
            put((a > 0.2) & (a < 0.8) & (b > 0.3) & (b < 0.78), GLASS)
            put((a > 0.2) & (a < 0.8) & (b > 0.24) & (b <= 0.3), (255, 255, 255), SECONDARY)
        else:
            put(True, (116, 114, 112))


def _build() -> tuple[np.ndarray, np.ndarray]:
    rgb = np.full((N_STYLES, 6, T, T, 3), 255.0, np.float32)
    mode = np.zeros((N_STYLES, 6, T, T), np.int8)
    for st in range(N_STYLES):
        for f in range(6):
            _paint(st, f, rgb[st, f], mode[st, f])
    return rgb, mode


ATLAS_RGB, ATLAS_MODE = _build()
#: Per style: 1 when the texture repeats per storey (buildings), 0 when it spans the face.
REPEAT = np.zeros(N_STYLES, bool)
REPEAT[S_BUILDING] = True

__all__ = ["ATLAS_MODE", "ATLAS_RGB", "EMISSIVE", "FIXED", "REPEAT", "STOREY", "T"]
