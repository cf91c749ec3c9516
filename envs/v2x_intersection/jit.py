"""Optional numba kernels for the hottest per-tick loops (pure NumPy fallbacks exist for each).

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


#: m, slack of the conservative broad phases in front of exact float32 box tests
BROAD_PHASE_MARGIN = 0.05
#: m added to both actors' half widths in the car-following corridor (``leaders_kernel`` and
#: ``traffic.leaders``)
CORRIDOR_MARGIN_M = 0.4
#: |sine| of the heading difference above which an actor counts as crossing a follower's
#: corridor (more than 30 deg off its axis): its footprint across the corridor is measured from
#: its oriented box, and it is never taken for oncoming traffic in another lane
CROSSING_SIN = 0.5
#: rad: a field-of-view answer from the bearing's cosine is taken only this far from the edge
FOV_SURE_RAD = 1e-7


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


@_njit_inline
def _slabs_xy(ox, oy, d0, d1, c, s, bx, by, hl, hw):  # pragma: no cover
    """Footprint slab interval ``(t_in, t_out)`` of one ray ``o + t d`` (``o``, ``d`` horizontal
    parts, relative to the reference point) against one prepared box, in float32
    (``raycast._slabs_xy``'s operations, the dot products accumulated as ``np.einsum`` does)."""
    one = np.float32(1.0)
    zero = np.float32(0.0)
    lx = ox * c + oy * s - bx
    acc = zero
    acc += d0 * c
    acc += d1 * s
    inv = one / acc
    t1 = (-hl - lx) * inv
    t2 = (hl - lx) * inv
    t_in = _fmin(t1, t2)
    t_out = _fmax(t1, t2)
    ly = oy * c - ox * s - by
    acc = zero
    acc += d0 * (-s)
    acc += d1 * c
    inv = one / acc
    t2 = (-hw - ly) * inv
    t3 = (hw - ly) * inv
    return _fmax(t_in, _fmin(t2, t3)), _fmin(t_out, _fmax(t2, t3))


@_njit
def segments_blocked_kernel(o, d, c, s, bx, by, hl, hw, z0, z1, ig, lo, hi):  # pragma: no cover
    """Whether each segment ``o + t d``, ``t in (lo, hi)``, crosses a box (see ``raycast``).

    Args:
        o: ``(r_o, 3)`` float32 starts relative to the reference point, ``r_o in {1, r}``.
        d: ``(r, 3)`` float32 segment vectors.
        c, s, bx, by, hl, hw, z0, z1: ``(N,)`` float32 box terms (``raycast._Prepared``).
        ig: ``(r, K)`` int box indices ignored per segment (negative = none; ``K`` may be 0).
        lo, hi: float32 end-point tolerances.

    Returns:
        ``(r,)`` bool.
    """
    r = d.shape[0]
    n = c.shape[0]
    kk = ig.shape[1]
    one = np.float32(1.0)
    zero = np.float32(0.0)
    out = np.zeros(r, np.bool_)
    for i in range(r):
        io = i if o.shape[0] > 1 else 0
        ox, oy, oz = o[io, 0], o[io, 1], o[io, 2]
        d0, d1 = d[i, 0], d[i, 1]
        invz = one / d[i, 2]
        for j in range(n):
            skip = False
            for q in range(kk):
                if ig[i, q] == j:
                    skip = True
            if skip:
                continue
            t_in, t_out = _slabs_xy(ox, oy, d0, d1, c[j], s[j], bx[j], by[j], hl[j], hw[j])
            t2 = (z0[j] - oz) * invz
            t3 = (z1[j] - oz) * invz
            t_in = _fmax(t_in, _fmin(t2, t3))
            t_out = _fmin(t_out, _fmax(t2, t3))
            t_in = _fmax(t_in, zero)
            if _fmax(t_in, lo) < _fmin(t_out, hi):
                out[i] = True
                break
    return out


@_njit
def ray_box_intervals_kernel(o, d, c, s, bx, by, hl, hw, z0, z1):  # pragma: no cover
    """``raycast.ray_box_intervals`` after its set-up: per ray and box the float32 entry and exit
    (``+inf`` / ``-inf`` for a miss), the NumPy path's operations (``o`` ``(r_o, 3)``, ``r_o in
    {1, r}``, and ``d`` ``(r, 3)`` as ``segments_blocked_kernel``'s)."""
    r = d.shape[0]
    n = c.shape[0]
    t_in_out = np.empty((r, n), np.float32)
    t_out_out = np.empty((r, n), np.float32)
    for i in range(r):
        io = i if o.shape[0] > 1 else 0
        for j in range(n):
            t_in_out[i, j], t_out_out[i, j] = ray_box_interval(o, d, io, i, c[j], s[j], bx[j], by[j], hl[j], hw[j],
                                                               z0[j], z1[j])
    return t_in_out, t_out_out


@_njit_inline
def ray_box_interval(o, d, io, i, c, s, bx, by, hl, hw, z0, z1):  # pragma: no cover
    """One element of :func:`ray_box_intervals_kernel`: ray ``i`` (origin row ``io``) against one
    prepared box."""
    one, zero, inf = np.float32(1.0), np.float32(0.0), np.float32(np.inf)
    oz = o[io, 2]
    invz = one / d[i, 2]
    t_in, t_out = _slabs_xy(o[io, 0], o[io, 1], d[i, 0], d[i, 1], c, s, bx, by, hl, hw)
    t2 = (z0 - oz) * invz
    t3 = (z1 - oz) * invz
    t_in = _fmax(t_in, _fmin(t2, t3))
    t_out = _fmin(t_out, _fmax(t2, t3))
    t_in = _fmax(t_in, zero)
    gap = (t_in - t_out) * inf  # +inf: miss, -inf: hit, NaN: touch
    return _fmax(t_in, gap), _fmin(t_out, -gap)


@_njit_inline
def _box_blocks(ox, oy, oz, d0, d1, d2, c, s, bx, by, hl, hw, z0, z1, lo, hi):  # pragma: no cover
    """One segment against one prepared box, in float32 (``raycast.segments_blocked``'s steps)."""
    one = np.float32(1.0)
    zero = np.float32(0.0)
    invz = one / d2
    t_in, t_out = _slabs_xy(ox, oy, d0, d1, c, s, bx, by, hl, hw)
    t2 = (z0 - oz) * invz
    t3 = (z1 - oz) * invz
    t_in = _fmax(t_in, _fmin(t2, t3))
    t_out = _fmin(t_out, _fmax(t2, t3))
    t_in = _fmax(t_in, zero)
    return _fmax(t_in, lo) < _fmin(t_out, hi)


@_njit_inline
def half_diagonal(length, width):  # pragma: no cover
    """``0.5 * sqrt(length^2 + width^2)``: how far a box reaches from its centre (the sight
    test's culling)."""
    return 0.5 * np.sqrt(length * length + width * width)


@_njit
def half_diagonals_kernel(length, width):  # pragma: no cover
    """:func:`half_diagonal` per box."""
    out = np.empty(length.shape[0])
    for j in range(length.shape[0]):
        out[j] = half_diagonal(length[j], width[j])
    return out


@_njit
def points_blocked_kernel(sensor, pts, cand, own, extra, center, cos_yaw, sin_yaw, length, width, z0, height,
                          half_diag, reach, lo, hi):  # pragma: no cover
    """``visibility.visible_fraction``'s line-of-sight test from one sensor, all in one call.

    Args:
        sensor: ``(3,)`` float64 sensor position. pts: ``(P, 3)`` float64 sample points.
        cand: ``(C,)`` indices of the points to test. own: ``(C,)`` box index of each tested
            point's target (never blocks it). extra: ``(E,)`` boxes that never block (negative: none).
        center, cos_yaw, sin_yaw, length, width, z0, height: the ``N`` boxes (float64).
        half_diag: ``(N,)`` their half diagonals (:func:`half_diagonals_kernel`).
        reach: float64, farthest tested point distance + 1 m (boxes beyond cannot block).
        lo, hi: float32 end-point tolerances.

    Returns:
        ``(C,)`` bool, True where blocked.
    """
    n = center.shape[0]
    sx, sy = sensor[0], sensor[1]
    keep = np.empty(n, np.int64)
    k = 0
    for j in range(n):
        dx, dy = center[j, 0] - sx, center[j, 1] - sy
        rad = half_diag[j] + 1e-3
        if dx * dx + dy * dy < (reach + rad) * (reach + rad) * 1.000001:
            ig = False
            for q in range(extra.shape[0]):
                if extra[q] == j:
                    ig = True
            if not ig:
                keep[k] = j
                k += 1
    c32 = np.empty(k, np.float32)
    s32 = np.empty(k, np.float32)
    bx = np.empty(k, np.float32)
    by = np.empty(k, np.float32)
    hl = np.empty(k, np.float32)
    hw = np.empty(k, np.float32)
    za = np.empty(k, np.float32)
    zb = np.empty(k, np.float32)
    rx = np.empty(k)  # box centre relative to the sensor, and half diagonal (the broad phase's)
    ry = np.empty(k)
    kept_diag = np.empty(k)
    for q in range(k):
        j = keep[q]
        rx[q], ry[q] = center[j, 0] - sx, center[j, 1] - sy
        kept_diag[q] = half_diag[j]
        c, s = cos_yaw[j], sin_yaw[j]
        r0, r1 = rx[q], ry[q]
        c32[q], s32[q] = np.float32(c), np.float32(s)
        bx[q] = np.float32(c * r0 + s * r1)
        by[q] = np.float32(-s * r0 + c * r1)
        hl[q] = np.float32(0.5 * length[j])
        hw[q] = np.float32(0.5 * width[j])
        za[q] = np.float32(z0[j])
        zb[q] = np.float32(z0[j] + height[j])
    oz = np.float32(sensor[2])
    zero = np.float32(0.0)
    out = np.zeros(cand.shape[0], np.bool_)
    # Broad phase per target (consecutive points share one): a box can block a sight line to a
    # point inside the target's footprint only if it comes within both half diagonals (+ a margin
    # far above float32 rounding) of the segment from the sensor to the target's centre.
    near = np.empty(k, np.int64)
    k_near = 0
    target = -1
    for i in range(cand.shape[0]):
        if own[i] != target:
            target = own[i]
            tx, ty = center[target, 0] - sx, center[target, 1] - sy
            tt = tx * tx + ty * ty
            t_rad = half_diag[target]
            k_near = 0
            for q in range(k):
                r0, r1 = rx[q], ry[q]
                u = (r0 * tx + r1 * ty) / tt if tt > 0.0 else 0.0
                u = min(max(u, 0.0), 1.0)
                e0, e1 = r0 - u * tx, r1 - u * ty
                lim = kept_diag[q] + t_rad + BROAD_PHASE_MARGIN
                near[k_near] = q  # kept only when it passes (no branch)
                k_near += (e0 * e0 + e1 * e1 <= lim * lim) & (keep[q] != target)
        p = cand[i]
        d0 = np.float32(pts[p, 0] - sx)
        d1 = np.float32(pts[p, 1] - sy)
        d2 = np.float32(pts[p, 2] - sensor[2])
        for w in range(k_near):
            q = near[w]
            if _box_blocks(zero, zero, oz, d0, d1, d2, c32[q], s32[q], bx[q], by[q], hl[q], hw[q], za[q], zb[q],
                           lo, hi):
                out[i] = True
                break
    return out


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
def visible_fraction_kernel(sensor, center, cos_yaw, sin_yaw, length, width, z0, height, half_diag, targets,
                            extra, max_r2, use_fov, sensor_yaw, half_fov, levels, pattern, shrink,
                            lo, hi):  # pragma: no cover
    """``visibility.visible_fraction`` in one call (sample points, range, field of view, sight).

    Args:
        sensor: ``(3,)``. center ... height: the ``N`` boxes (float64; ``cos_yaw``/``sin_yaw`` from
            NumPy). half_diag: their half diagonals (:func:`half_diagonals_kernel`).
            targets: ``(M,)`` box indices. extra: ``(E,)`` boxes that never block.
        max_r2: squared range (m^2). use_fov, sensor_yaw, half_fov: horizontal field of view test.
        levels: ``(L,)`` height fractions. pattern: ``(5, 2)`` unit offsets. shrink: ``0.5 * XY_SHRINK``.
        lo, hi: float32 end-point tolerances.

    Returns:
        ``(M,)`` visible fraction.
    """
    m = targets.shape[0]
    nl, nxy = levels.shape[0], pattern.shape[0]
    kk = nl * nxy
    pts = np.empty((m * kk, 3))
    ok = np.zeros(m * kk, np.bool_)
    own = np.empty(m * kk, np.int64)
    sx, sy, sz = sensor[0], sensor[1], sensor[2]
    two_pi = 2.0 * np.pi
    reach2 = -1.0
    # The field-of-view test is |wrap(arctan2(r1, r0) - sensor_yaw)| <= half_fov. Its answer is
    # certain without the arctan2 where the bearing's cosine (a dot product) puts it more than
    # FOV_SURE_RAD inside or outside (the two ways of computing the angle differ by ~1e-15 rad);
    # the points in that band, and at the sensor, take the exact test.
    fc, fs = np.cos(sensor_yaw), np.sin(sensor_yaw)
    cos_in = np.cos(half_fov - FOV_SURE_RAD) if half_fov - FOV_SURE_RAD >= 0.0 else 2.0
    cos_out = np.cos(half_fov + FOV_SURE_RAD) if half_fov + FOV_SURE_RAD <= np.pi else -2.0
    for a in range(m):
        b = targets[a]
        h0 = shrink * length[b]
        h1 = shrink * width[b]
        c, s = cos_yaw[b], sin_yaw[b]
        for li in range(nl):
            z = z0[b] + levels[li] * height[b]
            for q in range(nxy):
                px = pattern[q, 0] * h0
                py = pattern[q, 1] * h1
                i = a * kk + li * nxy + q
                x = (c * px - s * py) + center[b, 0]
                y = (s * px + c * py) + center[b, 1]
                pts[i, 0], pts[i, 1], pts[i, 2] = x, y, z
                own[i] = b
                r0, r1, r2 = x - sx, y - sy, z - sz
                acc = 0.0
                acc += r0 * r0
                acc += r1 * r1
                acc += r2 * r2
                good = acc <= max_r2
                if good and use_fov:
                    hyp = np.sqrt(r0 * r0 + r1 * r1)
                    along = r0 * fc + r1 * fs
                    if hyp > 0.0 and along > cos_in * hyp:
                        good = True
                    elif hyp > 0.0 and along < cos_out * hyp:
                        good = False
                    else:
                        w = (np.arctan2(r1, r0) - sensor_yaw + np.pi) % two_pi - np.pi
                        good = abs(w) <= half_fov
                if good:
                    ok[i] = True
                    if acc > reach2:
                        reach2 = acc
    cand = np.flatnonzero(ok)
    if cand.shape[0]:
        blocked = points_blocked_kernel(sensor, pts, cand, own[cand], extra, center, cos_yaw, sin_yaw, length,
                                        width, z0, height, half_diag, np.sqrt(reach2) + 1.0, lo, hi)
        for q in range(cand.shape[0]):
            if blocked[q]:
                ok[cand[q]] = False
    out = np.empty(m)
    for a in range(m):
        cnt = 0
        for i in range(a * kk, (a + 1) * kk):
            if ok[i]:
                cnt += 1
        out[a] = np.float64(cnt) / kk
    return out


@_njit
def leaders_kernel(idx, others, pos, yaw, length, width, speed, lookahead):  # pragma: no cover
    """``traffic.leaders``: gap (m) and approach rate (m/s) to each follower's corridor leader.

    Args:
        idx: ``(M,)`` follower rows. others: ``(O,)`` active rows. pos ... speed: the actor table's
            arrays. lookahead: search distance (m).

    Returns:
        ``(gap (M,), dv (M,), leader row (M,), -1 where none)``.
    """
    m = idx.shape[0]
    n = others.shape[0]
    gap_out = np.empty(m)
    dv_out = np.empty(m)
    who_out = np.full(m, -1, np.int64)
    # the others' columns gathered once, so that the corridor test below runs over contiguous
    # arrays without a branch (the CPU vectorizes it; the branchy test mispredicted about every
    # other pair); then only the few pairs in the corridor take the branchy part
    ox, oy, ow, ol = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    oc, osn = np.empty(n), np.empty(n)
    for q in range(n):
        o = others[q]
        ox[q], oy[q], ow[q], ol[q] = pos[o, 0], pos[o, 1], width[o], length[o]
        oc[q], osn[q] = np.cos(yaw[o]), np.sin(yaw[o])
    inside = np.empty(n, np.bool_)
    for a in range(m):
        i = idx[a]
        c, s = np.cos(yaw[i]), np.sin(yaw[i])
        px, py, wi, li = pos[i, 0], pos[i, 1], width[i], length[i]
        for q in range(n):
            d0 = ox[q] - px
            d1 = oy[q] - py
            dx = c * d0 + s * d1
            dy = -s * d0 + c * d1
            # a crossing actor's extent across the corridor is that of its oriented box
            sr = abs(c * osn[q] - s * oc[q])
            across = sr * ol[q] + abs(c * oc[q] + s * osn[q]) * ow[q]
            half = 0.5 * (wi + (across if sr > CROSSING_SIN else ow[q])) + CORRIDOR_MARGIN_M
            reach = 0.5 * (li + ol[q])
            inside[q] = (dx > 0.0) & (dx < lookahead + reach) & (abs(dy) < half)
        best = np.inf
        bj = -1
        bcos = 0.0
        for q in range(n):
            o = others[q]
            if not inside[q] or o == i:
                continue
            dx = c * (ox[q] - px) + s * (oy[q] - py)
            reach = 0.5 * (li + ol[q])
            cos_rel = np.cos(yaw[o] - yaw[i])
            crossing = abs(c * osn[q] - s * oc[q]) > CROSSING_SIN
            if not ((cos_rel < -0.5) and (speed[o] > 1.0) and not crossing) and dx - reach < best:
                best = dx - reach
                bj = o
                bcos = cos_rel
        gap_out[a] = max(best, 0.0)
        dv_out[a] = speed[i] - speed[bj] * max(bcos, 0.0) if best < np.inf else 0.0
        if best < np.inf:
            who_out[a] = bj
    return gap_out, dv_out, who_out


@_njit_inline
def idm_one(v, v0, gap, dv, min_gap, headway, sqrt_ab, a_max, delta, max_brake):  # pragma: no cover
    """``dynamics.idm_accel`` for one follower (``sqrt_ab = np.sqrt(accel * decel)``)."""
    w0 = max(v0, 0.1)
    s_star = min_gap + max(0.0, v * headway + v * dv / (2.0 * sqrt_ab))
    free = 1.0 - np.power(v / w0, delta)
    if np.isfinite(gap):
        r = s_star / max(gap, 0.1)
        inter = r * r
    else:
        inter = 0.0
    return min(max(a_max * (free - inter), -max_brake), a_max)


@_njit
def idm_kernel(v, v0, gap, dv, min_gap, headway, sqrt_ab, a_max, delta, max_brake):  # pragma: no cover
    """``dynamics.idm_accel`` element by element (:func:`idm_one`)."""
    out = np.empty(v.shape[0])
    for i in range(v.shape[0]):
        out[i] = idm_one(v[i], v0[i], gap[i], dv[i], min_gap, headway, sqrt_ab, a_max, delta, max_brake)
    return out


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


@_njit
def first_hit_fan_kernel(u, k, c, s, bx, by, hl, hw, z0, z1, oz, ground, max_t):  # pragma: no cover
    """The box part of ``raycast.first_hit_fan`` in float32: per azimuth column the footprint
    slab test against every box (``_slabs_xy`` with the origin at 0), the boxes the column meets
    ordered by entry distance (stable), then per elevation row the nearest hit among them.

    Args:
        u: ``(A, 2)`` float32 unit horizontal directions. k: ``(E, A)`` float32 slopes.
        c, s, bx, by, hl, hw, z0, z1: ``(N,)`` float32 box terms (``raycast._Prepared``).
        oz: float32 origin height.
        ground, max_t: the caller's finishing step (``raycast._finish``, the sensors'
            ``_finish_ray``): with ``ground`` a descending ray hits ``z = 0`` at ``oz / -k``, and
            ``max_t (E, A)`` float32 cuts hits farther away (a box wins a tie). A row stops at the
            first box entered beyond both, which cannot change the finished result; the box part
            returned for such a ray may be ``inf`` where a farther box was hit.

    Returns:
        ``(t (E, A) float32, box (E, A) int64)``: horizontal distance to the first box hit
        (``inf``: none) and its index (-1: none).
    """
    a_n, n = u.shape[0], c.shape[0]
    e_n = k.shape[0]
    zero, one, inf = np.float32(0.0), np.float32(1.0), np.float32(np.inf)
    t_out_arr = np.full((e_n, a_n), inf, np.float32)
    idx_out = np.full((e_n, a_n), -1, np.int64)
    g_in = np.empty(n, np.float32)
    g_out = np.empty(n, np.float32)
    key = np.empty(n, np.float32)
    cand = np.empty(n, np.int64)
    smax = np.empty(n, np.float32)
    za0 = np.empty(n, np.float32)
    za1 = np.empty(n, np.float32)
    cx = np.empty(n)  # box centres relative to the origin, world axes, and bounding radii (broad phase)
    cy = np.empty(n)
    rad = np.empty(n)
    for j in range(n):
        za0[j] = z0[j] - oz
        za1[j] = z1[j] - oz
        cj, sj, pj, qj = np.float64(c[j]), np.float64(s[j]), np.float64(bx[j]), np.float64(by[j])
        cx[j] = cj * pj - sj * qj
        cy[j] = sj * pj + cj * qj
        rad[j] = np.sqrt(np.float64(hl[j]) ** 2 + np.float64(hw[j]) ** 2) + BROAD_PHASE_MARGIN
    for a in range(a_n):
        u0, u1 = u[a, 0], u[a, 1]
        w0, w1 = np.float64(u0), np.float64(u1)
        m = 0
        for j in range(n):
            # the column's ray misses a box whose bounding circle it passes by or lies behind
            perp = w0 * cy[j] - w1 * cx[j]
            if perp > rad[j] or perp < -rad[j] or w0 * cx[j] + w1 * cy[j] < -rad[j]:
                continue
            t_in, t_out = _slabs_xy(zero, zero, u0, u1, c[j], s[j], bx[j], by[j], hl[j], hw[j])
            t_in = _fmax(t_in, zero)
            kj = _fmax(t_in, (t_in - t_out) * inf)
            if np.isfinite(kj):  # insertion sort by key, stable (ties keep index order)
                q = m
                while q > 0 and key[cand[q - 1]] > kj:
                    cand[q] = cand[q - 1]
                    q -= 1
                cand[q] = j
                key[j], g_in[j], g_out[j] = kj, t_in, t_out
                m += 1
        if m == 0:
            continue
        top = -inf  # suffix maxima of the candidates' tops: a rising ray stops when none is reachable
        for q in range(m - 1, -1, -1):
            j = cand[q]
            if za1[j] > top:
                top = za1[j]
            smax[q] = top
        for e in range(e_n):
            ke = k[e, a]
            invk = one / ke
            cut = max_t[e, a]
            if ground and ke < zero:
                tg = oz / -ke
                if tg < cut:
                    cut = tg
            best, bj = inf, -1
            for q in range(m):
                j = cand[q]
                if bj >= 0 and key[j] >= best:  # sorted by entry: no later box can be nearer
                    break
                if key[j] > cut:  # entered beyond the ground / far cut: it loses to them (ties go to boxes)
                    break
                if ke > zero and key[j] > smax[q] * invk:
                    # rising: this and every later box is entered (key = entry, sorted) above its top,
                    # whose crossing z1 * invk is a float32 product, monotonic in z1: all miss
                    break
                za = za0[j] * invk
                zb = za1[j] * invk
                b_in = _fmax(g_in[j], _fmin(za, zb))
                b_out = _fmin(g_out[j], _fmax(za, zb))
                b_in = _fmax(b_in, (b_in - b_out) * inf)
                if bj < 0 or b_in < best:
                    best, bj = b_in, j
            t_out_arr[e, a] = best
            idx_out[e, a] = bj
    return t_out_arr, idx_out
