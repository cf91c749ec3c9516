"""The shipped route suites: coverage, V2X over-sampling, town split, and that they load."""

from __future__ import annotations

from collections import Counter

import pytest
from v2xbench.envs.v2x_intersection.route_files import (
    SUITE_DIR,
    build_episode_from_spec,
    load_suite,
)
from v2xbench.envs.v2x_intersection.scenarios import SCENARIOS
from v2xbench.envs.v2x_intersection.town import TEST_TOWNS, TRAIN_TOWNS


@pytest.fixture(scope="module")
def test50():
    return load_suite("test50")[1]


def test_test50_has_50_routes_on_the_held_out_town(test50):
    assert len(test50) == 50
    assert {r.town for r in test50} <= set(TEST_TOWNS)
    assert len({r.id for r in test50}) == 50


def test_test50_covers_all_38_types_and_oversamples_v2x(test50):
    counts = Counter(s.type for r in test50 for s in r.scenarios)
    assert set(counts) == set(SCENARIOS) and len(SCENARIOS) == 38
    v2x = sum(n for t, n in counts.items() if SCENARIOS[t].v2x)
    assert v2x >= 0.5 * sum(counts.values())
    assert all(len(r.scenarios) >= 1 for r in test50)


@pytest.mark.parametrize("suite", ["train", "val"])
def test_training_suites_share_no_town_with_test50(suite, test50):
    if not (SUITE_DIR / f"{suite}.json").exists():
        pytest.fail(f"suite {suite} is not shipped")
    routes = load_suite(suite)[1]
    assert {r.town for r in routes} <= set(TRAIN_TOWNS)
    assert not {r.town for r in routes} & {r.town for r in test50}


def test_every_test50_route_builds(test50):
    for spec in test50:
        route, scenarios = build_episode_from_spec(spec)
        assert len(scenarios) == len(spec.scenarios)
        cs = [s.conflict_s for s in scenarios]
        assert cs == sorted(cs) and 0 < cs[0] and cs[-1] < route.length
