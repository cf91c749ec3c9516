"""The cheap draws give what ``Generator.choice`` gives, and leave the generator in the same state."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.draws import pick, signs


@pytest.mark.parametrize("n", [1, 2, 3, 7, 100, 2**20 + 3])
def test_pick_matches_choice(n):
    seq = np.arange(n) * 3 + 1
    small = list(range(min(n, 50)))
    for seed in range(50):
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        for _ in range(5):
            assert pick(a, seq) == b.choice(seq)
            assert pick(a, small) == b.choice(small)
        assert a.random() == b.random()


def test_signs_match_choice():
    for seed in range(50):
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        assert signs(a) == b.choice([-1.0, 1.0])
        for k in (1, 2, 5, 64):
            np.testing.assert_array_equal(signs(a, k), b.choice([-1.0, 1.0], size=k))
        assert a.random() == b.random()


def test_pick_from_empty_raises():
    with pytest.raises(ValueError, match="empty"):
        pick(np.random.default_rng(0), [])


@pytest.mark.parametrize("jit", [True, False])
def test_draw_size_draws_three_scalar_uniforms(monkeypatch, jit):
    """``draw_size`` (in a kernel on the generator's state with numba, else three scalar calls):
    the numbers and the generator's state are those of three scalar ``uniform`` calls, and of one
    call with array bounds (what it did before)."""
    from v2xbench.envs.v2x_intersection.core import actors
    from v2xbench.envs.v2x_intersection.core.actors import (
        SIZE_BOUNDS,
        SIZES,
        draw_size,
        pedestrian_size,
    )
    from v2xbench.envs.v2x_intersection.core.classes import PEDESTRIAN

    monkeypatch.setattr(actors, "HAVE_JIT", jit and actors.HAVE_JIT)
    for seed in range(20):
        a, b, c = np.random.default_rng(seed), np.random.default_rng(seed), np.random.default_rng(seed)
        for kind, ((l0, l1), (w0, w1), (h0, h1)) in SIZES.items():
            got = draw_size(kind, a)
            want = (float(b.uniform(l0, l1)), float(b.uniform(w0, w1)), float(b.uniform(h0, h1)))
            want2 = tuple(c.uniform(*SIZE_BOUNDS[kind]).tolist())
            if kind == PEDESTRIAN:  # a pedestrian's draw may become a child's box (no new draws)
                want = tuple(float(v) for v in pedestrian_size(*want))
                want2 = tuple(float(v) for v in pedestrian_size(*want2))
            assert got == want == want2
            assert all(type(x) is float for x in got)
        assert a.bit_generator.state == b.bit_generator.state == c.bit_generator.state
    mt, mt2 = np.random.Generator(np.random.MT19937(1)), np.random.Generator(np.random.MT19937(1))
    assert draw_size(0, mt) == tuple(mt2.uniform(*SIZE_BOUNDS[0]).tolist())  # other bit generators too
