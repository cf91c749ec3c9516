"""Cheap forms of ``numpy.random.Generator`` calls used on hot paths, drawing the same numbers.

``Generator.choice`` costs about 19 us a call, most of it argument handling; for a uniform pick
from a 1-D sequence it draws ``integers(0, len(seq))`` and indexes, which costs about 3.5 us.
The functions here do exactly that, so results and the generator's state after the call are the
same as with ``choice`` (``tests/core/test_draws.py`` checks both).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

_SIGNS = np.array([-1.0, 1.0])


def pick(rng: np.random.Generator, seq: Sequence | np.ndarray):
    """``rng.choice(seq)`` for a non-empty 1-D sequence: one uniformly drawn element."""
    n = len(seq)
    if n == 0:
        raise ValueError("cannot pick from an empty sequence")
    return seq[int(rng.integers(n))]


def signs(rng: np.random.Generator, size: int | None = None):
    """``rng.choice([-1.0, 1.0], size=size)``: random signs (a float, or a ``(size,)`` array)."""
    if size is None:
        return float(_SIGNS[rng.integers(2)])
    return _SIGNS[rng.integers(0, 2, size=size)]
