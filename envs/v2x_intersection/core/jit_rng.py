"""NumPy's ``Generator(PCG64)`` draws inside numba kernels, from the generator's own state.

A kernel that must draw random numbers cannot take the world's ``numpy.random.Generator`` cheaply
(numba unboxes a Generator in ~25 us). Instead :func:`generator_state` hands the kernel two small
arrays that *alias* the bit generator's C state: ``words (4,) uint64`` = the 128-bit PCG state and
increment (low word first), and ``buf (2,) uint32`` = ``has_uint32`` and the buffered 32-bit half.
The functions here advance that state exactly as NumPy does, so a kernel's draws are the numbers
the generator would have returned, and the generator continues from where the kernel left it
(``tests/core/test_jit_rng.py`` interleaves both).

Replicated (NumPy 2.x, ``numpy/random/src``):

- ``pcg64_random_r``: one LCG step of the 128-bit state (multiplier
  ``0x2360ED051FC65DA44385DF649FCCF645``), then the XSL-RR output of the new state;
- ``next_double``: ``(next64 >> 11) * 2**-53`` (``random()``, ``uniform(low, high)`` =
  ``low + (high - low) * next_double``);
- ``next_uint32``: the buffered upper half of a 64-bit draw (``has_uint32`` / ``uinteger``);
- ``integers(0, n)`` for ``n <= 2**32``: Lemire's bounded method on ``next_uint32``, nothing drawn
  for ``n == 1``.
"""

from __future__ import annotations

import ctypes

import numpy as np

from .jit import _njit_inline

_MUL_HI = np.uint64(2549297995355413924)
_MUL_LO = np.uint64(4865540595714422341)
_M32 = np.uint64(0xFFFFFFFF)
_S32 = np.uint64(32)
_S58 = np.uint64(58)
_S11 = np.uint64(11)
_S64 = np.uint64(64)
_ONE = np.uint64(1)
_ZERO = np.uint64(0)
_INV53 = 1.0 / 9007199254740992.0
_VIEWS: dict[int, tuple] = {}  # id(rng) -> (rng, words, buf); holding rng keeps its id unique
_MAX_VIEWS = 256  # generators: more than the worlds of one process (~12 kB each with their views)


def generator_state(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``(words (4,) uint64, buf (2,) uint32)`` views of ``rng``'s PCG64 state (see the module
    docstring). The views alias the generator's memory: keep ``rng`` alive as long as them.

    Raises:
        TypeError: ``rng``'s bit generator is not ``PCG64`` (what ``np.random.default_rng`` makes).
    """
    bg = rng.bit_generator
    if type(bg) is not np.random.PCG64:
        raise TypeError(f"kernel draws need a PCG64 generator, got {type(bg).__name__}")
    addr = bg.ctypes.state_address  # pcg64_state {pcg64_random_t *pcg_state; int has_uint32; uint32_t uinteger}
    pcg = ctypes.c_void_p.from_address(addr).value  # pcg64_random_t {uint128 state; uint128 inc}
    words = np.ctypeslib.as_array((ctypes.c_uint64 * 4).from_address(pcg))
    buf = np.ctypeslib.as_array((ctypes.c_uint32 * 2).from_address(addr + ctypes.sizeof(ctypes.c_void_p)))
    return words, buf


def state_views(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """:func:`generator_state`, cached for the last few generators (making the views costs ~6 us)."""
    hit = _VIEWS.get(id(rng))
    if hit is not None and hit[0] is rng:
        return hit[1], hit[2]
    words, buf = generator_state(rng)
    if len(_VIEWS) >= _MAX_VIEWS:
        del _VIEWS[next(iter(_VIEWS))]
    _VIEWS[id(rng)] = (rng, words, buf)
    return words, buf


@_njit_inline
def _mul64(a, b):  # pragma: no cover
    """Full 64 x 64 -> 128-bit product ``(hi, lo)`` of two uint64."""
    a_lo, a_hi = a & _M32, a >> _S32
    b_lo, b_hi = b & _M32, b >> _S32
    p0 = a_lo * b_lo
    p1 = a_lo * b_hi
    p2 = a_hi * b_lo
    p3 = a_hi * b_hi
    mid = (p0 >> _S32) + (p1 & _M32) + (p2 & _M32)
    lo = (p0 & _M32) | ((mid & _M32) << _S32)
    hi = p3 + (p1 >> _S32) + (p2 >> _S32) + (mid >> _S32)
    return hi, lo


@_njit_inline
def next64(words):  # pragma: no cover
    """``pcg64_random_r``: advance the state and return the next uint64."""
    s_lo, s_hi = words[0], words[1]
    hi, lo = _mul64(s_lo, _MUL_LO)
    hi = hi + s_lo * _MUL_HI + s_hi * _MUL_LO
    lo2 = lo + words[2]
    carry = _ONE if lo2 < lo else _ZERO
    hi = hi + words[3] + carry
    words[0], words[1] = lo2, hi
    x = hi ^ lo2
    r = hi >> _S58
    return (x >> r) | (x << ((_S64 - r) & np.uint64(63)))


@_njit_inline
def next_double(words):  # pragma: no cover
    """``Generator.random()``: a float64 in ``[0, 1)``."""
    return np.float64(next64(words) >> _S11) * _INV53


@_njit_inline
def uniform(words, low, high):  # pragma: no cover
    """``Generator.uniform(low, high)`` (scalars)."""
    return low + (high - low) * next_double(words)


@_njit_inline
def next_uint32(words, buf):  # pragma: no cover
    """``pcg64_next32``: the buffered upper half of the last 64-bit draw, else a new draw."""
    if buf[0] != 0:
        buf[0] = 0
        return np.uint64(buf[1])
    v = next64(words)
    buf[0] = 1
    buf[1] = np.uint32(v >> _S32)
    return v & _M32


@_njit_inline
def integers(words, buf, n):  # pragma: no cover
    """``Generator.integers(n)`` = ``integers(0, n)`` for ``1 <= n <= 2**32`` (int64 result)."""
    rng = np.uint64(n - 1)
    if rng == _ZERO:
        return np.int64(0)
    if rng == _M32:
        return np.int64(next_uint32(words, buf))
    excl = rng + _ONE
    m = next_uint32(words, buf) * excl
    left = m & _M32
    if left < excl:
        threshold = (_M32 - rng) % excl
        while left < threshold:
            m = next_uint32(words, buf) * excl
            left = m & _M32
    return np.int64(m >> _S32)
