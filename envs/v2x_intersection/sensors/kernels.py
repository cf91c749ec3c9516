"""numba kernels of the sensors, each repeating a NumPy path of its module:

- ray casting: :func:`cull_kernel` (``Scene.cull``) and :func:`cast_fan_kernel` (cull, prepared
  boxes and ``jit.first_hit_fan_kernel`` in one call, ``Scene.cast_fan``);
- cameras: :func:`camera_hits_kernel` (rays finished into hit points, ``camera._cast``) and
  :func:`shade_kernel` (all of ``shading.shade`` but the fog's ``exp`` and the sky's power, which
  stay NumPy calls so that both paths use the same transcendental functions);
- LiDAR: :func:`lidar_points_kernel` and :func:`lidar_returns_kernel`;
- ground truth: :func:`unoccluded_counts_kernel` and :func:`instance_counts_kernel`;
- BEV: :func:`bev_ground_kernel` (map channels) and :func:`fill_boxes_kernel` (objects).

Every operation is repeated in float32 as NumPy does it: Python-float constants are cast to
float32 first (NumPy treats them as weak scalars, numba would promote to float64), comparisons
included. ``tests/core/test_jit.py`` compares the outputs of both paths byte for byte.
"""

from __future__ import annotations

import numpy as np

from ..core.jit import _njit, _njit_inline
from ..core.jit_raycast import first_hit_fan_kernel, ray_box_interval

_F = np.float32


@_njit_inline
def _face(geo, j, x, y, z):  # pragma: no cover
    """``shading.surface``'s box-frame coordinates ``u, v, w`` of a point on box ``j`` (``geo``:
    ``scene.geo``), the face it lies on and whether that is an x / y face."""
    one, zero, half = _F(1.0), _F(0.0), _F(0.5)
    c, s = geo[j, 0], geo[j, 1]
    dx, dy = x - geo[j, 2], y - geo[j, 3]
    u = (c * dx + s * dy) * geo[j, 4]
    v = (c * dy - s * dx) * geo[j, 5]
    wz = (z - geo[j, 6]) * geo[j, 7]
    au, av, aw = abs(u), abs(v), abs(_F(2.0) * wz - one)
    xf = au >= av and au >= aw
    yf = not xf and av >= aw
    if xf:
        face = 1 if u < zero else 0
    elif yf:
        face = 3 if v < zero else 2
    else:
        face = 5 if wz < half else 4
    return u, v, wz, face, xf, yf


@_njit_inline
def _ground_cell(x, y, xmin, ymin, inv, h, w):  # pragma: no cover
    """``GroundRaster.flat_index`` for one point (float32 or float64, as the caller's path):
    ``(row, col)``, ``(-1, -1)`` outside."""
    cx = np.int64(np.floor((x - xmin) * inv))
    ry = np.int64(np.floor((y - ymin) * inv))
    if 0 <= cx < w and 0 <= ry < h:
        return ry, cx
    return -1, -1


@_njit
def lidar_returns_kernel(p, d, idx, geo, normals, sem_box, inst_box, class_refl, code, xmin, ymin, inv, terrain,
                         material_sem, material_refl):  # pragma: no cover
    """:func:`.shading.lidar_returns`: intensity, semantic and instance id of each return.

    Args:
        p, d, idx: as ``lidar_returns``. geo, normals, sem_box, inst_box: the scene's arrays.
        class_refl: reflectivity per semantic class. code, xmin, ymin, inv, terrain: the ground
            raster (float32 ``xmin``, ``ymin``, ``inv``) and the material outside it.
        material_sem, material_refl: lookups per material.
    """
    m = idx.shape[0]
    inten = np.empty(m, np.float32)
    sem = np.empty(m, np.uint8)
    inst = np.zeros(m, np.int32)
    h, w = code.shape
    zero, one = _F(0.0), _F(1.0)
    for i in range(m):
        j = idx[i]
        if j >= 0:
            face = _face(geo, j, p[i, 0], p[i, 1], p[i, 2])[3]
            acc = normals[j, face, 0] * d[i, 0]
            acc += normals[j, face, 1] * d[i, 1]
            acc += normals[j, face, 2] * d[i, 2]
            sem[i] = sem_box[j]
            inst[i] = inst_box[j]
            x = class_refl[sem[i]] * abs(acc)
        else:
            ry, cx = _ground_cell(p[i, 0], p[i, 1], xmin, ymin, inv, h, w)
            mat = code[ry, cx] if ry >= 0 else terrain
            sem[i] = material_sem[mat]
            x = material_refl[mat] * abs(d[i, 2])
        inten[i] = zero if x < zero else (one if x > one else x)
    return inten, sem, inst


@_njit
def shade_kernel(p, dz, keep, idx, sky, geo, style, colors, light, sem_box, inst_box, repeat, storey_a, storey_b,
                 tex_n, fixed, emissive, atlas_rgb, atlas_mode, code, ground_rgb, xmin, ymin, inv, terrain,
                 terrain_rgb, material_sem, haze, sky_sem, terrain_sem, ground_id, inst_none,
                 want_rgb=True):  # pragma: no cover
    """``shade``'s colours, semantic and instance ids (see :func:`.shading.shade`).

    Args:
        p, dz, idx, sky: as ``shade`` (``sky`` filled for the misses). keep: ``exp(-dist / FOG_DIST)``.
        geo ... inst_box: the scene's arrays (``colors (N * 3, 3)``, ``light (N * 6,)``).
        repeat, storey_a, storey_b, tex_n, fixed, emissive, atlas_rgb, atlas_mode: the texture atlas.
        code, ground_rgb, xmin, ymin, inv: the ground raster (``ground_rgb (H * W, 3)``, float32
            ``xmin``, ``ymin``, ``inv = 1 / mpp``). terrain, terrain_rgb: material outside it.
        material_sem, haze, sky_sem, terrain_sem: lookups. ground_id: ``raycast.GROUND``.
        want_rgb: compute the colours (``False``: only the ids; ``rgb`` comes back ``(0, 3)``).
    """
    m = idx.shape[0]
    rgb_out = np.empty((m if want_rgb else 0, 3), np.uint8)
    sem = np.empty(m, np.uint8)
    inst = np.full(m, inst_none, np.int32)
    h, w = code.shape
    half, one, zero = _F(0.5), _F(1.0), _F(0.0)
    tf = _F(tex_n)
    inv255 = _F(1 / 255)
    shadow_z, shadow = _F(0.35), _F(0.82)
    cap = _F(255.0)
    col3 = np.empty(3, np.float32)
    for i in range(m):
        j = idx[i]
        k = keep[i]
        if not want_rgb:  # the ids only
            if j >= 0:
                sem[i] = sem_box[j]
                inst[i] = inst_box[j]
            elif j == ground_id:
                ry, cx = _ground_cell(p[i, 0], p[i, 1], xmin, ymin, inv, h, w)
                sem[i] = material_sem[code[ry, cx] if ry >= 0 else terrain]
            else:
                sem[i] = sky_sem if dz[i] >= zero else terrain_sem
            continue
        if j >= 0:
            z = p[i, 2]
            u, v, wz, face, xf, yf = _face(geo, j, p[i, 0], p[i, 1], z)
            ta = (v if xf else u) * half + half
            tb = (one - wz) if (xf or yf) else v * half + half
            st = style[j]
            if repeat[st] and face < 4:
                along = v / geo[j, 5] if xf else u / geo[j, 4]
                ta = (along / storey_a) % one
                tb = one - (z / storey_b) % one
            cc = np.int64(ta * tf)
            rr = np.int64(tb * tf)
            cc = min(max(cc, 0), tex_n - 1)
            rr = min(max(rr, 0), tex_n - 1)
            texel = ((st * 6 + face) * tex_n + rr) * tex_n + cc
            mode = atlas_mode[texel]
            base = j * 3 + min(mode, 2)
            lit = light[j * 6 + face]
            if face < 4 and z < shadow_z:
                lit *= shadow
            if mode == emissive:
                lit = one
            for q in range(3):
                tex = atlas_rgb[texel, q]
                col3[q] = (tex if mode >= fixed else colors[base, q] * (tex * inv255)) * lit
            sem[i] = sem_box[j]
            inst[i] = inst_box[j]
        elif j == ground_id:
            ry, cx = _ground_cell(p[i, 0], p[i, 1], xmin, ymin, inv, h, w)
            if ry >= 0:
                mat = code[ry, cx]
                for q in range(3):
                    col3[q] = _F(ground_rgb[ry * w + cx, q])
            else:
                mat = terrain
                for q in range(3):
                    col3[q] = _F(terrain_rgb[q])
            sem[i] = material_sem[mat]
        else:
            up = dz[i] >= zero
            for q in range(3):
                col3[q] = sky[i, q]
            sem[i] = sky_sem if up else terrain_sem
            k = one if up else zero
        for q in range(3):
            x = col3[q] * k + haze[q] * (one - k)
            rgb_out[i, q] = np.uint8(x if x < cap else cap)
    return rgb_out, sem, inst


@_njit_inline
def _finish_ray(tt, jj, sel, kk, mt, ground, oz, no_hit, ground_id):  # pragma: no cover
    """One fan ray after ``raycast._finish``: ``(t, scene box index, ground_id or no_hit)`` from
    the fan kernel's ``tt``, ``jj`` (a position in ``sel``, the scene indices of the boxes cast
    against) and the ray's slope ``kk`` and far cut ``mt``, with the ground plane (a box wins a
    tie) and the far cut applied."""
    ii = sel[jj] if jj >= 0 else no_hit
    if np.isinf(tt):
        ii = no_hit
    if ground:
        tg = oz / -kk if kk < _F(0.0) else _F(np.inf)
        if tg < tt:
            tt, ii = tg, ground_id
    if tt > mt:
        tt, ii = mt, no_hit
    return tt, ii


@_njit
def lidar_points_kernel(t, j, sel, k, ground, oz, max_t, k64, norm64, cs, c, s, ox, oy, no_hit, ground_id,
                        geo, normals, sem_box, inst_box, class_refl, code, xmin, ymin, inv, terrain, material_sem,
                        material_refl):  # pragma: no cover
    """The end of ``lidar.capture_lidar`` on the numba path: the fan's rays finished
    (:func:`_finish_ray`), the returns in row-major order as sensor-frame points with their
    world hit points and directions, shaded by :func:`lidar_returns_kernel`.

    Args:
        k64, norm64: per channel slope and 3D length per horizontal metre (float64). cs: ``(A, 2)``
            float32 cos / sin of the azimuths. c, s, ox, oy, oz: float32 yaw cos / sin and origin.
        The rest: as :func:`camera_hits_kernel` and :func:`lidar_returns_kernel`.

    Returns:
        ``(points (P, 6) float32, range image (E, A) float32)``.
    """
    e_n, a_n = t.shape
    t, j, k, max_t = t.ravel(), j.ravel(), k.ravel(), max_t.ravel()
    th = np.empty(e_n * a_n, np.float32)
    ei = np.empty(e_n * a_n, np.int64)
    ai = np.empty(e_n * a_n, np.int64)
    idx = np.empty(e_n * a_n, np.int64)
    n = 0
    for e in range(e_n):
        for a in range(a_n):
            f = e * a_n + a
            tt, ii = _finish_ray(t[f], j[f], sel, k[f], max_t[f], ground, oz, no_hit, ground_id)
            if ii != no_hit:
                th[n], ei[n], ai[n], idx[n] = tt, e, a, ii
                n += 1
    pts = np.empty((n, 6), np.float32)
    pw = np.empty((n, 3), np.float32)
    dw = np.empty((n, 3), np.float32)
    rng = np.zeros((e_n, a_n), np.float32)
    for q in range(n):
        kk, nn = np.float32(k64[ei[q]]), np.float32(norm64[ei[q]])
        ca, sa = cs[ai[q], 0], cs[ai[q], 1]
        x, y, z = th[q] * ca, th[q] * sa, th[q] * kk
        pts[q, 0], pts[q, 1], pts[q, 2] = x, y, z
        dw[q, 0] = (c * ca - s * sa) / nn
        dw[q, 1] = (s * ca + c * sa) / nn
        dw[q, 2] = kk / nn
        pw[q, 0] = c * x - s * y + ox
        pw[q, 1] = s * x + c * y + oy
        pw[q, 2] = z + oz
        rng[ei[q], ai[q]] = th[q] * nn
    inten, sem, inst = lidar_returns_kernel(pw, dw, idx[:n], geo, normals, sem_box, inst_box, class_refl, code, xmin,
                                            ymin, inv, terrain, material_sem, material_refl)
    for q in range(n):
        pts[q, 3], pts[q, 4], pts[q, 5] = inten[q], _F(sem[q]), _F(inst[q])
    return pts, rng


@_njit
def camera_hits_kernel(t, j, sel, k, ground, oz, max_t, pix, dirs, norm, dpt, c, s, ox, oy, far, no_hit,
                       ground_id, p, dist, idx, depth):  # pragma: no cover
    """The end of ``camera._cast`` on the numba path: the fan's box hits (:func:`cast_fan_kernel`:
    ``t``, ``j``, ``sel``, slopes ``k``) with the ground plane (when ``ground``: sensor height
    ``oz`` >= 0) and the far cut ``max_t (E, A)`` applied as ``raycast._finish`` does, gathered
    per pixel (``pix``) and turned into scene box indices, hit points and depths (all float32 as
    the NumPy path).

    Writes ``p (P, 3)``, ``dist (P,)``, ``idx (P,)``, ``depth (P,)`` (the caller's buffers, e.g.
    one camera's rows of a batch).
    """
    n_pix = pix.shape[0]
    t, j, k, max_t = t.ravel(), j.ravel(), k.ravel(), max_t.ravel()
    zero = _F(0.0)
    for q in range(n_pix):
        f = pix[q]
        tt, ii = _finish_ray(t[f], j[f], sel, k[f], max_t[f], ground, oz, no_hit, ground_id)
        hit = ii != no_hit
        if not hit:
            tt = zero
        d = tt * norm[q]
        dist[q] = d
        idx[q] = ii
        d0, d1 = dirs[q, 0], dirs[q, 1]
        p[q, 0] = (c * d0 - s * d1) * d + ox
        p[q, 1] = (s * d0 + c * d1) * d + oy
        p[q, 2] = dirs[q, 2] * d + oz
        depth[q] = tt * dpt[q] if hit else far


@_njit
def _search(a, x, right):  # pragma: no cover
    """``np.searchsorted(a, x, "right" if right else "left")`` for increasing ``a``, non-NaN ``x``."""
    lo, hi = 0, a.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] < x or (right and a[mid] == x):
            lo = mid + 1
        else:
            hi = mid
    return lo


@_njit
def unoccluded_counts_kernel(o, d, start, c_, s_, bx, by, hl, hw, z0t, z1t, max_t_col, box_inst, z0, height, oz,
                             col_c, neg_row_s, cumw, instances):  # pragma: no cover
    """``fan._counts`` with its selection (``fan.unoccluded_pixels_many``) for one camera, the
    column intervals (``raycast.ray_box_intervals`` of the columns' vertical planes and the
    boxes made infinitely tall) computed for its own instances' boxes only.

    Args:
        o, d, c_ ... z1t: ``ray_box_intervals``'s set-up of every camera's columns (rows
            ``start .. start + A`` are this camera's) against the ``B`` candidate boxes.
        max_t_col: ``(A,)``. box_inst: each box's instance. z0, height: the boxes' (float64).
        oz: camera height. col_c, neg_row_s, cumw: the fan's (``-row_s``, increasing).
        instances: ``(M,)`` unique ids.

    Returns:
        ``(M,)`` float64 weighted pixel counts.
    """
    a_n, b_n = max_t_col.shape[0], box_inst.shape[0]
    io0 = o.shape[0] > 1
    mine = np.zeros(b_n, np.bool_)  # np.isin(box_inst, instances)
    for b in range(b_n):
        for m in range(instances.shape[0]):
            if box_inst[b] == instances[m]:
                mine[b] = True
                break
    cols = np.empty(a_n * b_n, np.int64)
    bis = np.empty(a_n * b_n, np.int64)
    n = 0
    t_in = np.empty((a_n, b_n), np.float32)
    t_out = np.empty((a_n, b_n), np.float32)
    for c in range(a_n):
        i = start + c
        for b in range(b_n):
            if not mine[b]:
                continue
            v, w = ray_box_interval(o, d, i if io0 else 0, i, c_[b], s_[b], bx[b], by[b], hl[b], hw[b], z0t[b], z1t[b])
            t_in[c, b], t_out[c, b] = v, w
            if np.isfinite(v) and v < max_t_col[c]:
                cols[n], bis[n] = c, b
                n += 1
    out = np.zeros(instances.shape[0])
    if n == 0:
        return out
    r0 = np.empty(n, np.int64)
    r1 = np.empty(n, np.int64)
    comp = np.empty(n, np.int64)
    inf = np.inf
    for q in range(n):
        c, b = cols[q], bis[q]
        ai, ao = np.float64(t_in[c, b]), np.float64(t_out[c, b])
        dz0 = z0[b] - oz
        dz1 = dz0 + height[b]
        if ai > 0:
            lo_in, hi_in = dz0 / ai, dz1 / ai
        else:
            lo_in = -inf if dz0 <= 0 else inf
            hi_in = inf if dz1 >= 0 else -inf
        lo_out, hi_out = dz0 / ao, dz1 / ao
        klo = (lo_out if lo_in != lo_in else (lo_in if (lo_out != lo_out or lo_in < lo_out) else lo_out)) / col_c[c]
        khi = (hi_out if hi_in != hi_in else (hi_in if (hi_out != hi_out or hi_in > hi_out) else hi_out)) / col_c[c]
        r0[q] = _search(neg_row_s, -khi, False)
        r1[q] = max(_search(neg_row_s, -klo, True), r0[q])
        comp[q] = (box_inst[b] * (a_n + 1) + c) * b_n + b
    order = np.argsort(comp)  # unique keys: (instance, column, box)
    prev_key, prev_r0, prev_r1 = -1, 0, 0
    cur_inst, slot = -1, -1
    for w in range(n):
        q = order[w]
        c, b = cols[q], bis[q]
        key = box_inst[b] * (a_n + 1) + c
        total = cumw[r1[q], c] - cumw[r0[q], c]
        if key == prev_key:  # a second box of the same instance in this column: remove the overlap
            lo = max(r0[q], prev_r0)
            hi = max(min(r1[q], prev_r1), lo)
            total -= cumw[hi, c] - cumw[lo, c]
        prev_key, prev_r0, prev_r1 = key, r0[q], r1[q]
        if box_inst[b] != cur_inst:
            cur_inst = box_inst[b]
            slot = -1
            for m in range(instances.shape[0]):
                if instances[m] == cur_inst:
                    slot = m
                    break
            if slot >= 0:
                out[slot] = 0.0
        if slot >= 0:
            out[slot] += total
    return out


@_njit
def instance_counts_kernel(instances, values, offset):  # pragma: no cover
    """``groundtruth._count``: how often each of ``instances (M,)`` occurs in ``values`` (1-D
    non-negative instance ids, integer or float; ids >= ``offset`` are static objects)."""
    max_a = max_s = -1  # tables only as large as the asked ids: other values are skipped
    for m in range(instances.shape[0]):
        k = instances[m]
        if k >= offset:
            max_s = max(max_s, k - offset)
        else:
            max_a = max(max_a, k)
    ca = np.zeros(max_a + 1, np.int64)
    cs = np.zeros(max_s + 1, np.int64)
    for v in values:
        if v >= offset:
            k = np.int64(v - offset)
            if k <= max_s:
                cs[k] += 1
        else:
            k = np.int64(v)
            if k <= max_a:
                ca[k] += 1
    out = np.zeros(instances.shape[0], np.int64)
    for m in range(instances.shape[0]):
        k = instances[m]
        out[m] = cs[k - offset] if k >= offset else ca[k]
    return out


@_njit
def fill_boxes_kernel(out, chans, boxes, ex, ey, c, s, yaw, mpp):  # pragma: no cover
    """``bev._fill_boxes``: set ``out[chans[i], r, k]`` for the BEV pixels whose centres lie in box
    ``i`` (``boxes (N, 5)``: x, y, length, width, yaw; ``c``, ``s``: the ego yaw's cos / sin from
    NumPy), each box's pixel window from its ego-frame extent (float64, the NumPy path's
    operations)."""
    n = out.shape[1]
    half = n / 2
    for i in range(boxes.shape[0]):
        d0, d1 = boxes[i, 0] - ex, boxes[i, 1] - ey
        bx, by = c * d0 + s * d1, c * d1 - s * d0
        rel = boxes[i, 4] - yaw
        hl, hw = max(boxes[i, 2], mpp) / 2, max(boxes[i, 3], mpp) / 2
        cr, sr = np.cos(rel), np.sin(rel)
        e0 = abs(cr) * hl + abs(sr) * hw
        e1 = abs(sr) * hl + abs(cr) * hw
        r0 = int(min(max(np.floor(half - 0.5 - (bx + e0) / mpp), 0), n))
        r1 = int(min(max(np.ceil(half - 0.5 - (bx - e0) / mpp) + 1, 0), n))
        k0 = int(min(max(np.floor(half - 0.5 - (by + e1) / mpp), 0), n))
        k1 = int(min(max(np.ceil(half - 0.5 - (by - e1) / mpp) + 1, 0), n))
        for r in range(r0, r1):
            x = (half - r - 0.5) * mpp - bx
            for k in range(k0, k1):
                y = (half - k - 0.5) * mpp - by
                if abs(cr * x + sr * y) <= hl and abs(cr * y - sr * x) <= hw:
                    out[chans[i], r, k] |= 1


@_njit
def cull_kernel(center, radius, active, ox, oy, yaw, half_fov, max_range, max_depth, exclude):  # pragma: no cover
    """:meth:`.scene.Scene.cull`'s tests per box (float64, the NumPy path's operations; ``max_depth``
    ``inf``: no depth test). Returns the kept box indices, increasing."""
    n = center.shape[0]
    keep = np.zeros(n, np.bool_)
    ca, sa = np.cos(yaw), np.sin(yaw)
    two_pi = 2 * np.pi
    # shortcuts for a wedge narrower than a half plane, decided with a margin far above rounding
    # (1e-9 relative) so that they agree with the exact angle test: a bounding circle wholly
    # behind the sensor is out; a centre inside the wedge is in
    narrow = half_fov < np.pi / 2 - 1e-6
    tan_h = np.tan(half_fov) if narrow else 0.0
    for i in range(n):
        if not active[i]:
            continue
        rx, ry = center[i, 0] - ox, center[i, 1] - oy
        dist = np.hypot(rx, ry)
        r = radius[i]
        if not dist - r < max_range:
            continue
        if max_depth < np.inf and not rx * ca + ry * sa - r < max_depth:
            continue
        if half_fov < np.pi and dist > r:
            if narrow:
                fwd = rx * ca + ry * sa
                if fwd < -r - 1e-9 * dist:
                    continue
                if fwd > 0.0 and abs(ry * ca - rx * sa) <= fwd * tan_h * (1.0 - 1e-9) - 1e-9 * dist:
                    keep[i] = True
                    continue
            ang = abs((np.arctan2(ry, rx) - yaw + np.pi) % two_pi - np.pi)
            slack = np.arcsin(min(max(r / max(dist, 1e-9), 0.0), 1.0))
            if not ang <= half_fov + slack:
                continue
        keep[i] = True
    for e in exclude:
        keep[e] = False
    return np.flatnonzero(keep)


@_njit
def cast_fan_kernel(center, length, width, z0, height, cos_yaw, sin_yaw, radius, active, ox, oy, oz, yaw, half_fov,
                    max_range, max_depth, exclude, cos_a, sin_a, k, max_t):  # pragma: no cover
    """A sensor's fan against the scene in one call: :func:`cull_kernel`, the culled boxes'
    ``raycast._Prepared`` terms (relative to the origin ``ox, oy``; ``cos_yaw``, ``sin_yaw``: the
    scene boxes' float64 trig from NumPy) and ``jit.first_hit_fan_kernel`` on the columns'
    directions ``(cos_a, sin_a)`` (float64 from NumPy) normalized as ``raycast._fan_setup`` does
    and the slopes ``k (E, A)`` float32, with the ground (from ``oz >= 0``) and the far cut
    ``max_t (E, A)`` of the caller's finishing step.

    Returns:
        ``(t (E, A), j (E, A), sel)``: ``first_hit_fan_kernel``'s outputs, ``j`` indexing ``sel``,
        the scene indices of the boxes cast against (the culled boxes are all solid).
    """
    sel = cull_kernel(center, radius, active, ox, oy, yaw, half_fov, max_range, max_depth, exclude)
    n = sel.shape[0]
    c, s = np.empty(n, _F), np.empty(n, _F)
    bx, by = np.empty(n, _F), np.empty(n, _F)
    hl, hw = np.empty(n, _F), np.empty(n, _F)
    za, zb = np.empty(n, _F), np.empty(n, _F)
    for q in range(n):
        i = sel[q]
        c64, s64 = cos_yaw[i], sin_yaw[i]
        rx, ry = center[i, 0] - ox, center[i, 1] - oy
        c[q], s[q] = _F(c64), _F(s64)
        bx[q] = _F(c64 * rx + s64 * ry)
        by[q] = _F(-s64 * rx + c64 * ry)
        hl[q], hw[q] = _F(0.5 * length[i]), _F(0.5 * width[i])
        za[q], zb[q] = _F(z0[i]), _F(z0[i] + height[i])
    a_n = cos_a.shape[0]
    u = np.empty((a_n, 2), _F)
    for a in range(a_n):
        norm = np.sqrt(cos_a[a] * cos_a[a] + sin_a[a] * sin_a[a])
        u[a, 0], u[a, 1] = _F(cos_a[a] / norm), _F(sin_a[a] / norm)
    if n == 0 or a_n == 0 or k.shape[0] == 0:
        return (np.full(k.shape, np.inf, _F), np.full(k.shape, -1, np.int64), sel)
    t, j = first_hit_fan_kernel(u, k, c, s, bx, by, hl, hw, za, zb, _F(oz), oz >= 0, max_t)
    return t, j, sel


@_njit
def bev_ground_kernel(bits, lx, ly, ex, ey, c, s, half, xmin, ymin, inv, n_channels):  # pragma: no cover
    """The map channels of ``bev.capture_bev``: per BEV pixel the world point ``(ex + c lx - s ly
    - half, ey + s lx + c ly - half)`` (float64, the NumPy path's order), its ground raster cell
    (``GroundRaster.flat_index``) and that cell's channel bits (``bits (H, W)`` uint16, 0
    outside), unpacked into ``(n_channels, n, n)`` uint8."""
    n_r, n_c = lx.shape
    h, w = bits.shape
    px = np.zeros((n_r, n_c), np.uint16)
    for r in range(n_r):
        for q in range(n_c):
            x = ex + c * lx[r, q] - s * ly[r, q] - half
            y = ey + s * lx[r, q] + c * ly[r, q] - half
            row, col = _ground_cell(x, y, xmin, ymin, inv, h, w)
            if row >= 0:
                px[r, q] = bits[row, col]
    out = np.empty((n_channels, n_r, n_c), np.uint8)
    for ch in range(n_channels):
        for r in range(n_r):
            for q in range(n_c):
                out[ch, r, q] = (px[r, q] >> ch) & 1
    return out
