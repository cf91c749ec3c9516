"""numba kernels of the ray-casting core (:mod:`.raycast`) and of occlusion (``visibility``).

The NumPy code in :mod:`.raycast` and ``perception/visibility.py`` is the reference these
kernels are tested against (bit-identical, ``tests/core/test_jit.py``) and the fallback
without numba.
"""

from __future__ import annotations

import numpy as np

from .jit import _fmax, _fmin, _njit, _njit_inline

#: m, slack of the conservative broad phases in front of exact float32 box tests
BROAD_PHASE_MARGIN = 0.05
#: rad: a field-of-view answer from the bearing's cosine is taken only this far from the edge
FOV_SURE_RAD = 1e-7


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
