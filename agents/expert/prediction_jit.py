"""numba kernel of the lane-following part of :func:`.prediction.forecast` (same float operations
in the same order, so the NumPy and kernel paths agree bit for bit; ``tests/core/test_jit.py``)."""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT, _njit, _np_max, _np_min

__all__ = ["HAVE_JIT", "lane_forecast_kernel", "travel_time_kernel"]


@_njit
def lane_forecast_kernel(br, s0, lat0, v, accel, length, bike, taus, lat_decay, lane_signal, br_stop_s,
                         br_stop_lane, br_stop_sign, br_n, br_start, br_pts, br_cos, br_sin, red,
                         yellow):  # pragma: no cover
    """Hypotheses on lane branches ``br`` from arc length ``s0`` with lateral offset ``lat0``,
    speed ``v`` and acceleration ``accel`` (clipped as in ``forecast``): whether each stops at
    its stop line (``prediction.will_stop``), then its poses at ``taus``.

    Returns:
        ``(pos (H, T, 2), dirn (H, T, 2), stops (H,))``.
    """
    h, t = br.shape[0], taus.shape[0]
    pos = np.empty((h, t, 2))
    dirn = np.empty((h, t, 2))
    stops = np.zeros(h, np.bool_)
    for k in range(h):
        vk = v[k]
        a = accel[k]
        if a == a:  # np.clip(a, -8, 2); NaN stays
            a = a if a > -8.0 else -8.0
            a = a if a < 2.0 else 2.0
        if a > 0 and vk > 12.0:
            a = 0.0
        half = 0.5 * length[k]
        t_stop = vk / _np_max(-a, 1e-6) if a < 0 else np.inf
        b = br[k]
        stop_s = br_stop_s[b]
        lane = br_stop_lane[b]
        d = stop_s - s0[k] - half
        ahead = np.isfinite(stop_s) and d > -1.0
        sig = lane_signal[lane] if lane >= 0 else -1
        req = vk * vk / (2.0 * _np_max(d, 0.3))
        sign = ahead and br_stop_sign[b] and sig < 0
        departing = sign and d < 4.0 and vk < 3.0 and a > 0.2
        rule = sig == red or (sig == yellow and req < 3.0) or (sign and not departing)
        behaving = req < 3.0 or a < -0.6 * req
        if sign and not departing and not (req < 1.5 or a < -0.5):  # prediction.SIGN_GENTLE
            behaving = False
        st = ahead and rule and behaving
        stops[k] = st
        cap = _np_max(stop_s - half - 0.5 if st else np.inf, s0[k])
        n, start = br_n[b], br_start[b]
        lk = lat0[k]
        sgn = 1.0 if lk > 0.0 else (-1.0 if lk < 0.0 else (0.0 if lk == 0.0 else lk))  # np.sign
        for j in range(t):
            te = _np_min(taus[j], t_stop)
            sigma = _np_min(s0[k] + vk * te + 0.5 * a * te * te, cap)
            f = _np_max(sigma, 0.0)
            i0 = min(np.int64(np.floor(f)), n - 1)
            i1 = min(i0 + 1, n - 1)
            w = _np_max(f - i0, 0.0)
            q0, q1 = start + i0, start + i1
            dc, ds = br_cos[q0], br_sin[q0]
            if i1 == i0:
                px, py = br_pts[q0, 0] + w * dc, br_pts[q0, 1] + w * ds
            else:
                px = br_pts[q0, 0] + w * (br_pts[q1, 0] - br_pts[q0, 0])
                py = br_pts[q0, 1] + w * (br_pts[q1, 1] - br_pts[q0, 1])
            lat = lk if bike[k] else sgn * _np_max(abs(lk) - lat_decay * taus[j], 0.0)
            pos[k, j, 0] = px + lat * -ds
            pos[k, j, 1] = py + lat * dc
            dirn[k, j, 0], dirn[k, j, 1] = dc, ds
    return pos, dirn, stops


@_njit
def travel_time_kernel(d, v, a, vmax):  # pragma: no cover
    """``junction.travel_time`` element by element on broadcast 1-D float64 inputs (the NumPy
    path's operations in its order; only IEEE arithmetic and ``sqrt``, so the bits agree)."""
    out = np.empty(d.shape[0])
    inf = np.inf
    for i in range(d.shape[0]):
        di, vi = _np_max(d[i], 0.0), _np_max(v[i], 0.0)
        ai, vm = a[i], _np_max(vmax[i], vi)
        pos = ai > 1e-3
        t_acc = (vm - vi) / _np_max(ai, 1e-3) if pos else 0.0
        d_acc = vi * t_acc + 0.5 * ai * (t_acc * t_acc)
        disc = _np_max(vi * vi + 2.0 * ai * di, 0.0)
        if pos:
            t_short = (-vi + np.sqrt(disc)) / _np_max(ai, 1e-3)
            t = t_short if di <= d_acc else t_acc + (di - d_acc) / _np_max(vm, 1e-3)
        elif ai < -1e-3:
            t = (-vi + np.sqrt(disc)) / _np_min(ai, -1e-3) if vi * vi + 2.0 * ai * di >= 0.0 else inf
        elif vi > 0.05:
            t = di / _np_max(vi, 1e-6)
        else:
            t = 0.0 if di <= 0.0 else inf
        out[i] = 0.0 if di <= 0.0 else t
    return out
