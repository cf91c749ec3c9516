"""Elementwise transcendental functions computed by the C library, for the NumPy fallbacks of
the numba kernels.

numba compiles ``np.arctan2``, ``np.power``, ``np.tan``, ``np.hypot``, ``np.arcsin`` ... on
scalars to calls of the C library (glibc's ``atan2``, ``pow``, ...), as Python's :mod:`math`
does. NumPy's own ufuncs give the same bits on most CPUs, but not on CPUs with AVX-512, where
NumPy dispatches float64 ``arctan2``, ``power``, ``exp``, ``log``, ``tan``, ``hypot``,
``arcsin`` and others to its SIMD (SVML) code, which can differ from glibc by an ulp or two
(measured on one such machine: ``arctan2`` differed on 7.6 % of random inputs, ``power`` on
5.4 %; ``sin``, ``cos`` and ``sqrt`` on none). A few ulps in a heading or an IDM acceleration
grow, tick by tick, into different actor tables, so the NumPy paths that repeat a kernel's
arithmetic call these instead of the ufuncs: on every CPU they give the kernels' bits.

They are slow next to a ufunc (a Python call per element) and are meant for the fallbacks
only, which run when numba is missing or ``V2XBENCH_NO_JIT=1`` is set, over a few dozen
elements a tick.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = ["arcsin", "arctan2", "hypot", "power", "tan"]


def _pow(a: float, b: float) -> float:
    """``math.pow`` with NumPy's answers where ``math`` raises (domain: NaN, overflow: inf)."""
    try:
        return math.pow(a, b)
    except ValueError:
        return math.nan
    except OverflowError:
        return math.copysign(math.inf, a) if float(b).is_integer() and int(b) % 2 else math.inf


def _asin(a: float) -> float:
    """``math.asin`` with NaN outside ``[-1, 1]`` (as ``np.arcsin``)."""
    try:
        return math.asin(a)
    except ValueError:
        return math.nan


def _tan(a: float) -> float:
    """``math.tan`` with NaN for infinities (as ``np.tan``)."""
    try:
        return math.tan(a)
    except ValueError:
        return math.nan


def _elementwise(fn: Callable[..., float], nin: int) -> Callable[..., np.ndarray]:
    ufunc = np.frompyfunc(fn, nin, 1)

    def apply(*args: np.ndarray | float) -> np.ndarray:
        out = ufunc(*(np.asarray(a, dtype=np.float64) for a in args))
        return np.asarray(out, dtype=np.float64)

    apply.__name__ = fn.__name__.lstrip("_")
    apply.__doc__ = f"Elementwise C-library ``{apply.__name__}`` on float64 arrays (broadcasting like a ufunc)."
    return apply


arctan2 = _elementwise(math.atan2, 2)
power = _elementwise(_pow, 2)
hypot = _elementwise(math.hypot, 2)
tan = _elementwise(_tan, 1)
arcsin = _elementwise(_asin, 1)
