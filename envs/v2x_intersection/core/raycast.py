"""Vectorized 2.5D ray casting: the one core that occlusion, cameras and LiDAR reuse.

The world is a set of oriented boxes standing on the ground plane (:class:`Boxes`: centre, length,
width, yaw, base height ``z0`` and height), plus the ground plane ``z = 0``. Each box is a vertical
prism ``{|x_l| <= length/2, |y_l| <= width/2, z0 <= z <= z0 + height}`` in its local frame (x
forward, y left, yaw counter-clockwise from world +x; see :mod:`geometry`).

Rays are ``p(t) = origin + t * dir`` with ``t >= 0``; ``dir`` need not be unit length and every
``t`` is in units of ``dir`` (unit dirs give metres; ``dir = end - start`` gives segment fractions).
A zero direction vector is not a ray; results for it are unspecified.

Numerics and speed:

- Computation runs in :data:`DTYPE` (float32): it halves memory traffic, which is what bounds these
  element-wise kernels, and float32 resolves ~10 um at the 100 m scale of a scene. Coordinates are
  shifted to a per-call reference point (the first ray origin) in float64 before the cast, so
  precision does not degrade far from the world origin. Returned ``t`` arrays are float32.
- Work is split over chunks of rays so that the ``(rays, boxes)`` temporaries hold at most
  ``chunk_elems`` elements (default :data:`CHUNK_ELEMS`, capped at :data:`MAX_CHUNK_ELEMS` = 4M);
  small chunks stay in cache and are faster. Results do not depend on the chunk size (every
  element is computed by the same element-wise operations).
- When all ray origins are equal (one sensor), the origin-dependent terms are computed once per
  box instead of once per ray and box.
- Rays parallel to a slab use IEEE infinities (``1/0``) with NaN-ignoring ``fmin``/``fmax``; a ray
  running exactly along a face (grazing) counts as a miss in that case. A ray that only touches a
  box (``t_in == t_out``, e.g. through an edge) is a hit for :func:`ray_box_intervals` and
  :func:`first_hit` but does not block in :func:`segments_blocked` (it needs a positive length
  inside the box).
- For a fan of rays from one origin (LiDAR azimuth x elevation, an unpitched camera's columns x
  rows) use :func:`first_hit_fan`: same answers as :func:`first_hit`, several times faster.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .jit import HAVE_JIT
from .jit_raycast import first_hit_fan_kernel, ray_box_intervals_kernel, segments_blocked_kernel

#: Floating dtype of the ray-casting computation and of the returned ``t`` arrays.
DTYPE = np.float32
#: Default end-point tolerance of :func:`segments_blocked` (fraction of the segment length).
END_EPS = 1e-5


def end_tolerances(eps: float) -> tuple:
    """``(lo, hi)`` in :data:`DTYPE`: the part ``(eps, 1 - eps)`` of a segment that
    :func:`segments_blocked` tests (what the kernels take as ``lo``, ``hi``)."""
    return DTYPE(eps), DTYPE(1.0 - eps)


#: :func:`end_tolerances` of :data:`END_EPS`
END_TOLERANCES = end_tolerances(END_EPS)
#: Default bound on the elements of one ``(rays, boxes)`` temporary array (cache-friendly).
CHUNK_ELEMS = 1 << 15
#: Hard upper bound on ``chunk_elems``.
MAX_CHUNK_ELEMS = 4_000_000
#: ``first_hit`` index for rays that hit nothing (or nothing within ``max_t``).
NO_HIT = -1
#: ``first_hit`` index for rays whose first hit is the ground plane ``z = 0``.
GROUND = -2
_FIELDS = ("center", "length", "width", "yaw", "z0", "height")


@dataclass(frozen=True, eq=False)
class Boxes:
    """Oriented 2.5D boxes (struct of read-only float64 arrays); ``len(boxes)`` is ``N``.

    Attributes:
        center: ``(N, 2)`` box centres on the ground plane (m, world frame).
        length: ``(N,)`` full extent along the box's local x (m).
        width: ``(N,)`` full extent along the box's local y (m).
        yaw: ``(N,)`` heading (rad, counter-clockwise from world +x).
        z0: ``(N,)`` base height (m; 0 for objects standing on the ground).
        height: ``(N,)`` vertical extent above ``z0`` (m).
    """

    center: np.ndarray
    length: np.ndarray
    width: np.ndarray
    yaw: np.ndarray
    z0: np.ndarray
    height: np.ndarray

    def __post_init__(self) -> None:
        center = np.array(self.center, dtype=np.float64).reshape(-1, 2)
        n = center.shape[0]
        center.setflags(write=False)
        object.__setattr__(self, "center", center)
        for name in _FIELDS[1:]:
            a = np.array(getattr(self, name), dtype=np.float64).reshape(-1)
            if a.shape != (n,):
                raise ValueError(f"Boxes.{name} has shape {a.shape}, expected ({n},)")
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @classmethod
    def from_arrays(
        cls,
        center: np.ndarray,
        length: np.ndarray | float,
        width: np.ndarray | float,
        yaw: np.ndarray | float = 0.0,
        height: np.ndarray | float = 1.5,
        z0: np.ndarray | float = 0.0,
    ) -> Boxes:
        """Build boxes from array-likes, broadcasting scalars to ``N = len(center)``.

        Args:
            center: ``(N, 2)``, or ``(2,)`` for one box (m).
            length, width, yaw, height, z0: ``(N,)`` or scalars (m; yaw in rad).
        """
        center = np.asarray(center, dtype=np.float64).reshape(-1, 2)
        n = center.shape[0]

        def b(x: np.ndarray | float) -> np.ndarray:
            return np.broadcast_to(np.asarray(x, dtype=np.float64).reshape(-1), (n,))

        return cls(center, b(length), b(width), b(yaw), b(z0), b(height))

    @classmethod
    def trusted(
        cls,
        center: np.ndarray,
        length: np.ndarray,
        width: np.ndarray,
        yaw: np.ndarray,
        z0: np.ndarray,
        height: np.ndarray,
    ) -> Boxes:
        """Wrap fresh float64 arrays (``(N, 2)`` and ``(N,)``, owned by the caller and not written
        afterwards) without the copies and checks of the constructor (a hot path of every tick)."""
        self = object.__new__(cls)
        for name, a in zip(_FIELDS, (center, length, width, yaw, z0, height)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        return self

    @classmethod
    def empty(cls) -> Boxes:
        """A set of zero boxes."""
        return cls.from_arrays(np.zeros((0, 2)), 0.0, 0.0)

    @staticmethod
    def concat(a: Boxes, b: Boxes) -> Boxes:
        """Boxes of ``a`` followed by those of ``b`` (indices of ``b`` shift by ``len(a)``)."""
        return Boxes(*(np.concatenate([getattr(a, f), getattr(b, f)]) for f in _FIELDS))

    def subset(self, idx: np.ndarray) -> Boxes:
        """Boxes selected by an index array or boolean mask ``(N,)``."""
        idx = np.asarray(idx)
        if idx.ndim != 1 or (idx.dtype != bool and idx.dtype.kind not in "iu"):
            return Boxes(*(getattr(self, f)[idx] for f in _FIELDS))
        return Boxes.trusted(*(getattr(self, f)[idx] for f in _FIELDS))  # fancy indexing copies

    def __len__(self) -> int:
        return self.center.shape[0]

    def trig(self) -> tuple[np.ndarray, np.ndarray]:
        """``(cos(yaw), sin(yaw))``, each ``(N,)`` float64 (computed once per instance)."""
        cs = self.__dict__.get("_trig")
        if cs is None:
            cs = (np.cos(self.yaw), np.sin(self.yaw))
            object.__setattr__(self, "_trig", cs)
        return cs


class _Prepared:
    """Per-call box terms in :data:`DTYPE`, relative to the reference point ``ref (2,)``."""

    def __init__(self, boxes: Boxes, ref: np.ndarray):
        c, s = np.cos(boxes.yaw), np.sin(boxes.yaw)
        rel = boxes.center - ref
        self._c64, self._s64 = c, s
        self.c, self.s = c.astype(DTYPE), s.astype(DTYPE)
        self.bx = (c * rel[:, 0] + s * rel[:, 1]).astype(DTYPE)  # centre in the rotated axes
        self.by = (-s * rel[:, 0] + c * rel[:, 1]).astype(DTYPE)
        self.hl = (0.5 * boxes.length).astype(DTYPE)
        self.hw = (0.5 * boxes.width).astype(DTYPE)
        self.z0 = boxes.z0.astype(DTYPE)
        self.z1 = (boxes.z0 + boxes.height).astype(DTYPE)

    @functools.cached_property
    def rot_x(self) -> np.ndarray:
        """``(2, N)``: world vector -> local x (the NumPy path's einsum operand)."""
        return np.stack([self._c64, self._s64]).astype(DTYPE)

    @functools.cached_property
    def rot_y(self) -> np.ndarray:
        """``(2, N)``: world vector -> local y."""
        return np.stack([-self._s64, self._c64]).astype(DTYPE)


def _slabs_xy(o: np.ndarray, d: np.ndarray, p: _Prepared) -> tuple[np.ndarray, np.ndarray]:
    """Footprint (local x and y slab) intervals ``(r, N)`` for ``o (r_o, >=2)``, ``d (r, >=2)``."""
    ox, oy = o[:, 0:1], o[:, 1:2]
    lx = ox * p.c + oy * p.s - p.bx  # (r_o, N) origin in the box frame
    # einsum, not matmul: BLAS takes another path for a 1-row chunk (last-bit differences)
    inv = np.divide(1.0, np.einsum("rk,kn->rn", d[:, :2], p.rot_x))  # (r, N) 1 / local dir x
    t1 = np.multiply(-p.hl - lx, inv)
    t2 = np.multiply(p.hl - lx, inv, out=inv)
    t_in = np.fmin(t1, t2)
    t_out = np.fmax(t1, t2, out=t1)
    ly = oy * p.c - ox * p.s - p.by
    inv = np.divide(1.0, np.einsum("rk,kn->rn", d[:, :2], p.rot_y))
    np.multiply(-p.hw - ly, inv, out=t2)
    t3 = np.multiply(p.hw - ly, inv, out=inv)
    np.fmax(t_in, np.fmin(t2, t3), out=t_in)
    np.fmin(t_out, np.fmax(t2, t3, out=t2), out=t_out)
    return t_in, t_out


def _slab_z(t_in, t_out, oz, invz, z0, z1) -> tuple[np.ndarray, np.ndarray]:
    """Intersect intervals in place with the z slab ``[z0, z1]`` and with ``t >= 0``."""
    t2 = np.multiply(z0 - oz, invz)
    t3 = np.multiply(z1 - oz, invz)
    np.fmax(t_in, np.fmin(t2, t3), out=t_in)
    np.fmin(t_out, np.fmax(t2, t3, out=t2), out=t_out)
    np.fmax(t_in, 0.0, out=t_in)
    return t_in, t_out


def _kernel(o: np.ndarray, d: np.ndarray, p: _Prepared) -> tuple[np.ndarray, np.ndarray]:
    """Raw prism intervals: ``o (r_o, 3)`` with ``r_o`` in ``{1, r}``, ``d (r, 3)``, both DTYPE.

    Returns ``(t_in, t_out)`` of shape ``(r, N)``; a hit is ``t_in <= t_out`` (``t_in >= 0``).
    Misses are left as they fall (``t_in > t_out``); callers turn them into what they need.
    """
    t_in, t_out = _slabs_xy(o, d, p)
    return _slab_z(t_in, t_out, o[:, 2:3], 1.0 / d[:, 2:3], p.z0, p.z1)


def _miss_to_inf(t_in: np.ndarray, t_out: np.ndarray) -> np.ndarray:
    """``where(t_in <= t_out, t_in, inf)`` in place in ``t_in`` (``t_out`` is clobbered).

    Branch-free: ``(t_in - t_out) * inf`` is ``+inf`` for a miss, ``-inf`` for a hit and NaN
    for a touch (ignored by ``fmax``); masked assignment is several times slower.
    """
    np.subtract(t_in, t_out, out=t_out)
    np.multiply(t_out, DTYPE(np.inf), out=t_out)
    return np.fmax(t_in, t_out, out=t_in)


def ray_box_setup(origins: np.ndarray, dirs: np.ndarray, boxes: Boxes) -> tuple:
    """:func:`ray_box_intervals`' inputs as its kernels take them (for callers that evaluate
    only some ray-box pairs with ``jit.ray_box_interval``): ``(o (1 or R, 3), d (R, 3)`` float32
    relative to the first origin, the prepared boxes, whether all rays share one origin)."""
    return _setup(origins, dirs, boxes)


def _setup(origins: np.ndarray, dirs: np.ndarray, boxes: Boxes):
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    if origins.shape[0] == 1 and dirs.shape[0] != 1:
        same = True
    else:
        if origins.shape != dirs.shape:
            raise ValueError(f"origins {origins.shape} and dirs {dirs.shape} do not match")
        same = bool(np.all(origins == origins[:1])) if len(origins) else True
    ref = origins[0, :2].copy() if len(origins) else np.zeros(2)
    o = origins.copy()
    o[:, :2] -= ref
    o = o[:1] if same else o
    return o.astype(DTYPE), dirs.astype(DTYPE), _Prepared(boxes, ref), same


def _chunks(r: int, n: int, chunk_elems: int | None):
    elems = min(chunk_elems or CHUNK_ELEMS, MAX_CHUNK_ELEMS)
    step = max(1, elems // max(n, 1))
    for a in range(0, r, step):
        yield slice(a, min(a + step, r))


def _ignore_spec(ignore, r: int, n: int):
    """Normalize ``ignore`` into ``(global_keep (N,) bool | None, per_row)``.

    ``per_row`` is ``None``, an ``(r, K)`` int array (negative entries = none) or an ``(r, N)``
    bool mask.
    """
    if ignore is None:
        return None, None
    ig = np.asarray(ignore)
    if ig.dtype == bool:
        if ig.shape == (n,):
            return ~ig, None
        if ig.shape == (r, n):
            return None, ig
        raise ValueError(f"bool ignore mask must be ({n},) or ({r}, {n}), got {ig.shape}")
    ig = ig.astype(np.intp)
    if ig.ndim == 0:
        keep = np.ones(n, dtype=bool)
        if ig >= 0:
            keep[ig] = False
        return keep, None
    if ig.shape[0] != r or ig.ndim > 2:
        raise ValueError(f"int ignore must be scalar, ({r},) or ({r}, K), got {ig.shape}")
    return None, ig.reshape(r, -1)


def _solid(keep: np.ndarray | None, boxes: Boxes) -> np.ndarray | None:
    """``keep`` restricted to boxes with a positive height (``None`` = keep all).

    A flat box on the ground would otherwise catch every ray that reaches the ground over it.
    """
    solid = boxes.height > 0
    if solid.all():
        return keep
    return solid if keep is None else keep & solid


def _apply_row_ignore(arr: np.ndarray, per_row, sl: slice, value) -> None:
    """Set ``arr[i, j] = value`` for the ignored boxes ``j`` of each row ``i`` of chunk ``sl``."""
    if per_row is None:
        return
    rows = per_row[sl]
    if rows.dtype == bool:
        np.putmask(arr, rows, value)
        return
    valid = rows >= 0
    ri = np.broadcast_to(np.arange(rows.shape[0])[:, None], rows.shape)
    arr[ri[valid], rows[valid]] = value


def _finish(t: np.ndarray, idx: np.ndarray, tg: np.ndarray | None, max_t) -> tuple:
    """Apply the ground hits ``tg`` (``inf`` = none; a box wins a tie) and the ``max_t`` cut."""
    if tg is not None:
        g = tg < t
        t[g], idx[g] = tg[g], GROUND
    max_t = np.broadcast_to(np.asarray(max_t, dtype=DTYPE), t.shape)
    far = t > max_t
    t[far], idx[far] = max_t[far], NO_HIT
    return t, idx


def ray_box_intervals(
    origins: np.ndarray, dirs: np.ndarray, boxes: Boxes, chunk_elems: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit parameters of every ray against every box (as a 3D prism).

    Args:
        origins: ``(R, 3)`` ray origins (m), or ``(1, 3)``/``(3,)`` shared by all rays.
        dirs: ``(R, 3)`` ray directions (any non-zero length).
        boxes: ``N`` boxes.
        chunk_elems: bound on temporary size (elements); ``None`` = :data:`CHUNK_ELEMS`.

    Returns:
        ``(t_in, t_out)``, each ``(R, N)`` float32 in units of ``dirs``. For a hit,
        ``0 <= t_in <= t_out`` (``t_in = 0`` when the origin is inside the box). For a miss,
        including boxes entirely behind the origin, ``t_in = +inf`` and ``t_out = -inf``.
    """
    o, d, p, same = _setup(origins, dirs, boxes)
    r, n = d.shape[0], len(boxes)
    if HAVE_JIT:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return ray_box_intervals_kernel(o, d, p.c, p.s, p.bx, p.by, p.hl, p.hw, p.z0, p.z1)
    t_in = np.empty((r, n), DTYPE)
    t_out = np.empty((r, n), DTYPE)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for sl in _chunks(r, n, chunk_elems):
            a, b = _kernel(o if same else o[sl], d[sl], p)
            gap = np.multiply(a - b, DTYPE(np.inf))  # +inf: miss, -inf: hit, NaN: touch
            np.fmax(a, gap, out=t_in[sl])
            np.fmin(b, np.negative(gap, out=gap), out=t_out[sl])
    return t_in, t_out


def first_hit(
    origins: np.ndarray,
    dirs: np.ndarray,
    boxes: Boxes,
    max_t: float | np.ndarray = np.inf,
    ground: bool = True,
    ignore=None,
    chunk_elems: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of each ray among the boxes and (optionally) the ground plane ``z = 0``.

    Args:
        origins: ``(R, 3)`` ray origins (m), or ``(1, 3)``/``(3,)`` shared by all rays.
        dirs: ``(R, 3)`` ray directions (any non-zero length; ``t`` is in units of ``dirs``).
        boxes: ``N`` boxes.
        max_t: scalar or ``(R,)`` farthest ``t`` that counts (e.g. sensor range for unit dirs).
        ground: whether rays pointing down (``dir_z < 0``) from ``z >= 0`` hit ``z = 0``.
            Boxes with ``height <= 0`` (e.g. inactive actors) are never hit.
        ignore: boxes that rays pass through: ``None``; a box index (int) or ``(N,)`` bool mask
            for all rays (e.g. the sensor's own vehicle); ``(R,)`` or ``(R, K)`` int per-ray
            indices (negative = none); or an ``(R, N)`` bool mask.
        chunk_elems: bound on temporary size (elements); ``None`` = :data:`CHUNK_ELEMS`.

    Returns:
        ``(t, index)``: ``t (R,)`` float32 is the entry parameter of the first surface hit with
        ``t <= max_t`` (0 when the origin is inside a box), or ``max_t`` when nothing is hit within
        ``max_t`` (``inf`` for the default). ``index (R,)`` int64 is the box index, :data:`GROUND`
        (-2) for the ground plane, or :data:`NO_HIT` (-1) for nothing. A box wins a tie with the
        ground.
    """
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    r, n = dirs.shape[0], len(boxes)
    keep, per_row = _ignore_spec(ignore, r, n)  # at most one of the two is set
    keep = _solid(keep, boxes)
    box_ids = np.arange(n)
    if keep is not None:  # ignored for all rays, or flat: drop them from the scene
        boxes, box_ids = boxes.subset(keep), box_ids[keep]
        n = len(boxes)
    t = np.full(r, np.inf, DTYPE)
    idx = np.full(r, NO_HIT, np.intp)
    if n and r:
        o, d, p, same = _setup(origins, dirs, boxes)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for sl in _chunks(r, n, chunk_elems):
                a = _miss_to_inf(*_kernel(o if same else o[sl], d[sl], p))
                _apply_row_ignore(a, per_row, sl, np.inf)
                j = np.argmin(a, axis=1)
                t[sl] = a[np.arange(a.shape[0]), j]
                idx[sl] = box_ids[j]
        idx[np.isinf(t)] = NO_HIT
    tg = None
    if ground:
        oz, dz = origins[:, 2], dirs[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = np.where((dz < 0) & (oz >= 0), oz / -dz, np.inf).astype(DTYPE)
    return _finish(t, idx, tg, max_t)


def segments_blocked(
    starts: np.ndarray,
    ends: np.ndarray,
    boxes: Boxes,
    ignore=None,
    eps: float = END_EPS,
    chunk_elems: int | None = None,
) -> np.ndarray:
    """Whether any (non-ignored) box intersects the open segment between ``start`` and ``end``.

    The ground plane is not considered: a segment between two points with ``z >= 0`` never goes
    below it. A box blocks when the segment crosses its interior for a positive length; the end
    points themselves are excluded with a relative tolerance ``eps`` (fraction of the segment).

    Args:
        starts: ``(S, 3)`` segment starts (m), or ``(3,)`` shared by all segments (one sensor).
        ends: ``(S, 3)`` segment ends (m).
        boxes: ``N`` boxes.
        ignore: boxes that never block: ``None``; an int or ``(N,)`` bool mask for all segments;
            ``(S,)`` or ``(S, K)`` int per-segment indices (negative = none), e.g. each segment's
            target box and the sensor's own vehicle; or an ``(S, N)`` bool mask.
        eps: end-point tolerance as a fraction of the segment length.
        chunk_elems: bound on temporary size (elements); ``None`` = :data:`CHUNK_ELEMS`.

    Returns:
        ``(S,)`` bool, True where the line of sight is blocked.
    """
    ends = np.asarray(ends, dtype=np.float64).reshape(-1, 3)
    starts = np.asarray(starts, dtype=np.float64).reshape(-1, 3)
    dirs = ends - starts
    s, n = dirs.shape[0], len(boxes)
    keep, per_row = _ignore_spec(ignore, s, n)
    if keep is not None:  # ignored for all segments: drop them from the scene
        boxes = boxes.subset(keep)
        n = len(boxes)
    out = np.zeros(s, dtype=bool)
    if n == 0 or s == 0:
        return out
    o, d, p, same = _setup(starts, dirs, boxes)
    lo, hi = end_tolerances(eps)
    if HAVE_JIT and (per_row is None or per_row.dtype != bool):
        ig = np.zeros((s, 0), np.intp) if per_row is None else np.ascontiguousarray(per_row, np.intp)
        return segments_blocked_kernel(o, d, p.c, p.s, p.bx, p.by, p.hl, p.hw, p.z0, p.z1, ig, lo, hi)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for sl in _chunks(s, n, chunk_elems):
            a, b = _kernel(o if same else o[sl], d[sl], p)
            np.fmax(a, lo, out=a)
            np.fmin(b, hi, out=b)
            blk = a < b
            _apply_row_ignore(blk, per_row, sl, False)
            out[sl] = blk.any(axis=1)
    return out


def _fan_setup(origin, dirs_h, slopes, boxes: Boxes, ignore) -> tuple:
    """:func:`first_hit_fan`'s inputs as its kernels take them: ``(origin (3,) float64, u (A, 2)
    unit float64, k (E, A) DTYPE, the solid boxes, their indices in ``boxes``)``."""
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    u = np.asarray(dirs_h, dtype=np.float64).reshape(-1, 2)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    k = np.asarray(slopes, dtype=np.float64)
    k = k.reshape(-1, 1) if k.ndim == 1 else k
    e, a, n = k.shape[0], u.shape[0], len(boxes)
    k = np.broadcast_to(k, (e, a)).astype(DTYPE)
    keep, per_row = _ignore_spec(ignore, a, n)
    if per_row is not None:
        raise ValueError("first_hit_fan takes only a global ignore (int or (N,) bool mask)")
    keep = _solid(keep, boxes)
    box_ids = np.arange(n)
    if keep is not None:
        boxes, box_ids = boxes.subset(keep), box_ids[keep]
    return origin, u, k, boxes, box_ids


def _fan_kernel(origin: np.ndarray, u: np.ndarray, k: np.ndarray, boxes: Boxes) -> tuple[np.ndarray, np.ndarray]:
    """``first_hit_fan_kernel`` on :func:`_fan_setup`'s outputs (at least one box and ray)."""
    p = _Prepared(boxes, origin[:2])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return first_hit_fan_kernel(u.astype(DTYPE), np.ascontiguousarray(k), p.c, p.s, p.bx, p.by, p.hl, p.hw,
                                    p.z0, p.z1, DTYPE(origin[2]), False, np.broadcast_to(DTYPE(np.inf), k.shape))


def first_hit_fan(
    origin: np.ndarray,
    dirs_h: np.ndarray,
    slopes: np.ndarray,
    boxes: Boxes,
    max_t: float | np.ndarray = np.inf,
    ground: bool = True,
    ignore=None,
    chunk_elems: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`first_hit` for a fan of rays from one origin: ``A`` azimuths x ``E`` slopes.

    The structure of a spinning LiDAR or an unpitched camera (one vertical plane per column):
    the footprint test runs once per azimuth, only the boxes a column's plane meets (at most
    ``K``, usually a handful) go on to the per-ray height test, so the cost is about
    ``A*N + E*A*K`` instead of ``E*A*N``.

    Args:
        origin: ``(3,)`` common ray origin (m).
        dirs_h: ``(A, 2)`` horizontal directions (any non-zero length; normalized here).
        slopes: ``(E, A)``, ``(E, 1)`` or ``(E,)`` rise per metre of horizontal travel
            (``tan(elevation)``); ray ``(e, a)`` is ``origin + t * (u_a, slopes[e, a])`` with
            ``u_a`` the unit ``dirs_h[a]``.
        boxes: ``N`` boxes.
        max_t: scalar or broadcastable to ``(E, A)``: farthest horizontal distance that counts (m).
        ground: whether descending rays from ``z >= 0`` hit ``z = 0``.
        ignore: a box index (int) or ``(N,)`` bool mask of boxes to ignore (e.g. own vehicle).
        chunk_elems: bound on temporary size (elements); ``None`` = :data:`CHUNK_ELEMS`.

    Returns:
        ``(t, index)``, each ``(E, A)``: ``t`` float32 is the horizontal distance to the hit (m;
        3D range is ``t * sqrt(1 + slope**2)``), ``max_t`` where nothing is hit; ``index`` as in
        :func:`first_hit` (box index, :data:`GROUND` = -2, :data:`NO_HIT` = -1).
    """
    origin, u, k, boxes, box_ids = _fan_setup(origin, dirs_h, slopes, boxes, ignore)
    e, a, n = k.shape[0], u.shape[0], len(boxes)
    t = np.full((e, a), np.inf, DTYPE)
    idx = np.full((e, a), NO_HIT, np.intp)
    if n and a and e and HAVE_JIT:
        t, j = _fan_kernel(origin, u, k, boxes)
        idx = np.where(j >= 0, box_ids[np.maximum(j, 0)], NO_HIT)
        idx[np.isinf(t)] = NO_HIT
    elif n and a and e:
        p = _Prepared(boxes, origin[:2])
        o = np.array([[0.0, 0.0, origin[2]]], DTYPE)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            a_in, a_out = _slabs_xy(o, u.astype(DTYPE), p)  # (A, N) horizontal metres
            np.fmax(a_in, 0.0, out=a_in)
            key = _miss_to_inf(a_in.copy(), a_out.copy())
            kmax = int(np.isfinite(key).sum(axis=1).max())
            if kmax:  # gather the (at most kmax) boxes each column meets, as (K, A) arrays
                order = np.ascontiguousarray(np.argsort(key, axis=1, kind="stable")[:, :kmax].T)
                cols = np.arange(a)
                g_in, g_out = a_in[cols, order], a_out[cols, order]
                g_in[~np.isfinite(key[cols, order])] = np.inf  # padding entries never hit
                z0, z1 = p.z0[order] - DTYPE(origin[2]), p.z1[order] - DTYPE(origin[2])
                rows = max(1, min(chunk_elems or CHUNK_ELEMS, MAX_CHUNK_ELEMS) // (a * kmax))
                for r0 in range(0, e, rows):
                    invk = 1.0 / k[r0 : r0 + rows, None, :]  # (e_c, 1, A)
                    za, zb = z0 * invk, z1 * invk  # (e_c, K, A): t at the box's base / top
                    b_in = np.fmax(g_in, np.fmin(za, zb))
                    b_out = np.fmin(g_out, np.fmax(za, zb, out=za), out=zb)
                    b_in = _miss_to_inf(b_in, b_out)
                    j = np.argmin(b_in, axis=1)  # (e_c, A)
                    t[r0 : r0 + rows] = np.take_along_axis(b_in, j[:, None], 1)[:, 0]
                    idx[r0 : r0 + rows] = box_ids[order[j, cols]]
        idx[np.isinf(t)] = NO_HIT
    tg = None
    if ground and origin[2] >= 0:
        with np.errstate(divide="ignore"):
            tg = np.where(k < 0, DTYPE(origin[2]) / -k, DTYPE(np.inf))
    return _finish(t, idx, tg, max_t)
