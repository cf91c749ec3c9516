"""The cheap draws give what ``Generator.choice`` gives, and leave the generator in the same state."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.draws import pick, signs


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


def test_draw_size_draws_three_scalar_uniforms():
    """``draw_size`` draws its three sizes in one call; the numbers and the generator's state
    are those of three scalar ``uniform`` calls (what it did before)."""
    from v2xbench.envs.v2x_intersection.actors import SIZES, draw_size

    for seed in range(20):
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        for kind, ((l0, l1), (w0, w1), (h0, h1)) in SIZES.items():
            assert draw_size(kind, a) == (float(b.uniform(l0, l1)), float(b.uniform(w0, w1)),
                                          float(b.uniform(h0, h1)))
        assert a.bit_generator.state == b.bit_generator.state
