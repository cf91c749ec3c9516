"""Kernel draws (``jit_rng``) are the numbers NumPy's ``Generator`` would have drawn, and leave
the generator where NumPy would have."""

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT
from v2xbench.envs.v2x_intersection.core.jit_rng import generator_state, state_views

pytestmark = pytest.mark.skipif(not HAVE_JIT, reason="numba not installed")

if HAVE_JIT:
    import numba
    from v2xbench.envs.v2x_intersection.core.jit_rng import integers, next_double, uniform

    @numba.njit
    def _draws(words, buf, ops, args):
        out = np.empty(len(ops))
        for k in range(len(ops)):
            if ops[k] == 0:
                out[k] = next_double(words)
            elif ops[k] == 1:
                out[k] = integers(words, buf, np.int64(args[k]))
            else:
                out[k] = uniform(words, 2.0, args[k])
        return out


def _numpy_draws(rng, ops, args):
    return np.array([rng.random() if o == 0 else (rng.integers(int(a)) if o == 1 else rng.uniform(2.0, a))
                     for o, a in zip(ops, args)], float)


@pytest.mark.parametrize("seed", range(20))
def test_kernel_draws_match_generator(seed):
    meta = np.random.default_rng(1000 + seed)
    ops = meta.integers(0, 3, 400)
    args = np.where(ops == 1, meta.integers(1, 40, 400), meta.uniform(3, 9, 400)).astype(np.float64)
    ints = ops == 1
    args[ints & (meta.random(400) < 0.1)] = 1  # integers(1) draws nothing
    args[ints & (meta.random(400) < 0.05)] = 2 ** 32  # the full 32-bit range
    args[ints & (meta.random(400) < 0.05)] = 3_000_000_000  # rejections happen
    ours, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
    theirs.integers(5)  # a buffered 32-bit half is pending on both sides
    ours.integers(5)
    words, buf = generator_state(ours)
    np.testing.assert_array_equal(_draws(words, buf, ops, args), _numpy_draws(theirs, ops, args))
    assert ours.bit_generator.state == theirs.bit_generator.state
    # NumPy draws on from where the kernel left off, and the kernel from where NumPy did
    assert ours.random() == theirs.random() and ours.integers(7) == theirs.integers(7)
    np.testing.assert_array_equal(_draws(words, buf, ops[:50], args[:50]), _numpy_draws(theirs, ops[:50], args[:50]))
    assert ours.bit_generator.state == theirs.bit_generator.state


def test_array_draws_are_scalar_draws_in_order():
    """The kernels replace ``rng.random(n)`` and ``rng.integers(0, 2, size=n)`` by ``n`` scalar draws."""
    for seed in range(10):
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        a.integers(3), b.integers(3)
        np.testing.assert_array_equal(a.integers(0, 2, size=5), [b.integers(2) for _ in range(5)])
        np.testing.assert_array_equal(a.random(4), [b.random() for _ in range(4)])
        assert a.bit_generator.state == b.bit_generator.state


def test_state_views_are_cached_per_generator_and_checked():
    rng = np.random.default_rng(0)
    w1, b1 = state_views(rng)
    w2, _ = state_views(rng)
    assert w1 is w2
    assert state_views(np.random.default_rng(0))[0] is not w1
    with pytest.raises(TypeError, match="PCG64"):
        generator_state(np.random.Generator(np.random.MT19937(0)))
