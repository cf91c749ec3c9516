"""numba plumbing (:func:`_njit`, :data:`HAVE_JIT`) and the lane-polyline kernels (projection, pose).

The ray-casting kernels live in :mod:`.jit_raycast`, IDM in :mod:`.dynamics`, the NPC
car-following kernels in ``traffic/jit_vehicles.py``. Kernels are optional (pure NumPy fallbacks exist for each).

numba is installed with the package but optional at run time: when it is missing, or
``V2XBENCH_NO_JIT=1`` is set, :data:`HAVE_JIT` is ``False`` and callers take their
NumPy path. Every kernel repeats the NumPy path's float operations in the same order and dtype
(no fastmath, no fused multiply-add), so both paths give bit-identical results; the tests check
that on random scenes. Where a kernel calls ``arctan2``, ``power``, ``tan``, ``hypot`` or
``arcsin``, its NumPy path takes them from :mod:`.libm` (the C library, as numba does), since
NumPy's own ufuncs differ from it by an ulp on CPUs with AVX-512.

Kernels are cached on disk (``cache=True``) in the user cache folder, keyed by the content of all
of the package's kernel sources (:mod:`.jit_cache`): every clone and process with the same
sources shares one compiled copy, and editing any kernel recompiles all of them.
``v2xbench warmup`` compiles ahead of time.
"""

from __future__ import annotations

import os

import numpy as np

try:  # pragma: no cover - depends on the environment
    if os.environ.get("V2XBENCH_NO_JIT", "") not in ("", "0"):
        raise ImportError("disabled by V2XBENCH_NO_JIT")
    import numba

    HAVE_JIT = True
    from .jit_cache import install as _install_cache

    KERNEL_CACHE_DIR = _install_cache(numba)
except ImportError:  # pragma: no cover
    numba = None
    HAVE_JIT = False
    KERNEL_CACHE_DIR = None


def _njit(fn):
    """``numba.njit(cache=True)`` when numba is available, else the plain Python function."""
    if not HAVE_JIT:
        return fn
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


def _njit_inline(fn):
    """:func:`_njit` with ``inline="always"`` (numba inlines the helper into its callers at the IR
    level), for small helpers called once per element. Give such helpers scalars, or a whole table
    and an index, not array views: with views a call cost ~35 ns (``docs/performance.md``)."""
    if not HAVE_JIT:
        return fn
    return numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(fn)



@_njit
def _fmin(a, b):
    """``np.fmin`` for scalars: the non-NaN operand when one is NaN."""
    if a != a:
        return b
    if b != b:
        return a
    return a if a < b else b


@_njit
def _fmax(a, b):
    """``np.fmax`` for scalars."""
    if a != a:
        return b
    if b != b:
        return a
    return a if a > b else b


@_njit
def project_kernel(xy, points, pid, owner, offset, n_points, gs, base):  # pragma: no cover
    """``town.model.PolylineIndex.project`` (nearest vertex, then the two segments beside it).

    Args:
        xy: ``(Q, 2)`` float64 queries. points: ``(P, 2)`` polyline vertices. pid: ``(C,)``
            candidate vertex ids. owner, offset, n_points, gs, base: the index's arrays.

    Returns:
        ``(polyline (Q,), s (Q,), dist (Q,))``.
    """
    nq = xy.shape[0]
    out_o = np.empty(nq, np.int64)
    out_s = np.empty(nq, np.float64)
    out_d = np.empty(nq, np.float64)
    for qi in range(nq):
        x, y = xy[qi, 0], xy[qi, 1]
        best = np.inf
        j = pid[0]
        for c in range(pid.shape[0]):
            p = pid[c]
            dx = x - points[p, 0]
            dy = y - points[p, 1]
            d2 = dx * dx + dy * dy
            if d2 < best:
                best = d2
                j = p
        out_o[qi], out_s[qi], out_d[qi] = project_refine(x, y, j, points, owner, offset, n_points, gs, base)
    return out_o, out_s, out_d


@_njit_inline
def project_refine(x, y, j, points, owner, offset, n_points, gs, base):  # pragma: no cover
    """The end of :func:`project_kernel` for one query ``(x, y)`` whose nearest vertex is ``j``:
    the nearer of the two segments beside it (within its polyline), as ``(polyline, s, dist)``."""
    npts = points.shape[0]
    o = owner[j]
    first = offset[o]
    last = first + n_points[o] - 1
    best_s = gs[j] - base[o]
    dx = x - points[j, 0]
    dy = y - points[j, 1]
    best_d = np.sqrt(dx * dx + dy * dy)
    for a, b in ((j, j + 1), (j - 1, j)):
        ok = (a >= first) and (b <= last)
        a = min(max(a, 0), npts - 1)
        b = min(max(b, 0), npts - 1)
        sx = points[b, 0] - points[a, 0]
        sy = points[b, 1] - points[a, 1]
        seg_len2 = max(sx * sx + sy * sy, 1e-12)
        t = ((x - points[a, 0]) * sx + (y - points[a, 1]) * sy) / seg_len2
        t = min(max(t, 0.0), 1.0)
        qx = points[a, 0] + t * sx
        qy = points[a, 1] + t * sy
        ex, ey = x - qx, y - qy
        d = np.sqrt(ex * ex + ey * ey)
        s = gs[a] - base[o] + t * np.sqrt(seg_len2)
        if ok and d < best_d:
            best_d = d
            best_s = s
    return o, best_s, best_d


@_njit
def _np_max(a, b):
    """``np.maximum`` for scalars (NaN and signed-zero semantics included)."""
    return a if (a >= b or a != a) else b


@_njit
def _np_min(a, b):
    """``np.minimum`` for scalars."""
    return a if (a <= b or a != a) else b


#: most steps :func:`vertex_at_or_below` walks from its estimate before it searches by bisection
VERTEX_WALK_STEPS = 4


@_njit_inline
def vertex_at_or_below(gs, first, last, g):  # pragma: no cover
    """``first + np.searchsorted(gs[first:last + 1], g, side="right") - 1``: the last vertex of
    the polyline ``first..last`` whose arc length ``gs`` (non-decreasing) is ``<= g``, ``first - 1``
    when none is (``last`` for a NaN ``g``, which NumPy sorts last).

    The towns' polylines are resampled at near-even spacing, so the vertex that an even spacing
    puts ``g`` at is at most one off: a short walk from it (checked by the same comparisons as a
    search) replaces the bisection's ~6 unpredictable branches. Should the walk not get there in
    :data:`VERTEX_WALK_STEPS` steps (an unevenly sampled polyline), the bisection answers."""
    if g != g:
        return last
    e = first
    span = gs[last] - gs[first]
    if span > 0.0:
        f = (g - gs[first]) / span * (last - first)
        if f >= last - first:
            e = last
        elif f > 0.0:
            e = first + np.int64(f)
    for _ in range(VERTEX_WALK_STEPS):
        if gs[e] <= g:
            if e == last or gs[e + 1] > g:
                return e
            e += 1
        else:
            if e == first:
                return first - 1
            e -= 1
            if gs[e] <= g:
                return e
    return first + np.searchsorted(gs[first:last + 1], g, side="right") - 1


@_njit
def pose_at_kernel(idx, s, points, heading, offset, n_points, gs, base, length):  # pragma: no cover
    """``town.model.PolylineIndex.pose_at``: positions ``(N, 2)`` and headings ``(N,)``."""
    m = idx.shape[0]
    p = np.empty((m, 2))
    h = np.empty(m)
    for k in range(m):
        ln = idx[k]
        sk = s[k] if (s[k] > 0.0 or s[k] != s[k]) else 0.0  # np.clip, NaN kept
        sk = sk if (sk < length[ln] or sk != sk) else length[ln]
        g = base[ln] + sk
        first = offset[ln]
        last = first + n_points[ln] - 1
        # the search over the polyline's own points gives what one over all of ``gs`` gives
        # after the clamp below (``gs`` ascends, and polylines are 1 km apart): fewer steps
        i = _np_min(_np_max(vertex_at_or_below(gs, first, last, g), first), last - 1)
        s0, s1 = gs[i], gs[i + 1]
        t = (g - s0) / _np_max(s1 - s0, 1e-9) if s1 > s0 else 0.0
        p[k, 0] = points[i, 0] * (1.0 - t) + points[i + 1, 0] * t
        p[k, 1] = points[i, 1] * (1.0 - t) + points[i + 1, 1] * t
        h[k] = heading[i]
    return p, h
