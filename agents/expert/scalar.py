"""Scalar helpers for the expert's per-tick Python: NumPy's functions on one number cost
~5-8 us a call (``np.clip``'s dispatch through ``fromnumeric``), Python's comparisons ~50 ns."""

from __future__ import annotations


def clip(x, lo, hi=None):
    """``np.clip(x, lo, hi)`` for one number, with its results: ``x`` itself where it lies within
    the bounds (a signed zero kept, NaN passed through), else the bound it crossed; ``hi=None``
    clips only from below."""
    if x < lo:
        return lo
    if hi is not None and x > hi:
        return hi
    return x
