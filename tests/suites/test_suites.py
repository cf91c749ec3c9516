"""The shipped route suites: coverage, V2X over-sampling, town split, and that they load."""

from __future__ import annotations

import copy
import json
import re
from collections import Counter

import pytest
from v2xbench.envs.v2x_intersection.scenarios import SCENARIOS
from v2xbench.envs.v2x_intersection.suites.route_files import (
    SUITE_DIR,
    build_episode_from_spec,
    load_suite,
)
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


# ------------------------------------------------------------------------- suite validation
@pytest.mark.parametrize("name", ["train", "val", "test50"])
def test_shipped_suites_load_to_the_same_routes(name):
    """Validation changes nothing: every shipped route comes back as written (``to_dict``)."""
    raw = json.loads((SUITE_DIR / f"{name}.json").read_text())
    split, routes = load_suite(name)
    assert split == raw["split"]
    assert [r.to_dict() for r in routes] == raw["routes"]


def _small_suite(n: int = 4) -> dict:
    raw = json.loads((SUITE_DIR / "test50.json").read_text())
    return {**raw, "routes": copy.deepcopy(raw["routes"][:n])}


def _speed(d):
    # routes[3] of test50 is ControlLoss then BlockedIntersection; routes[2] has HighwayExit (speed)
    d["routes"][2]["scenarios"][0]["params"] = {"speed": 1e9}


@pytest.mark.parametrize(
    "mutate,match",
    [
        (lambda d: d.pop("routes"), "routes: missing required field"),
        (lambda d: d.update(routes=[]), "routes: the suite has no routes"),
        (lambda d: d.update(routes={"a": 1}), "routes: expected a list of routes, got dict"),
        (
            lambda d: [r.update(seed=-5) for r in d["routes"]],
            r"routes\[0\].seed: -5 is outside \[0, ",
        ),
        (lambda d: d.update(seed=-5), "seed: unknown field"),
        (lambda d: d.update(format="v2xbench-suite/0"), "format: 'v2xbench-suite/0' is not"),
        (lambda d: d.update(split="../x"), "split: '../x' must be letters"),
        (
            lambda d: d["routes"][3].update(id=d["routes"][1]["id"]),
            r"routes\[3\].id: 'test50_001' repeats routes\[1\].id",
        ),
        (_speed, r"routes\[2\].scenarios\[0\].params.speed: 1000000000.0 is outside \[0, 30\] m/s"),
        (
            lambda d: d["routes"][1]["scenarios"][0]["site"].update(s_on_key=float("nan")),
            r"routes\[1\].scenarios\[0\].site.s_on_key: nan is not a finite number",
        ),
        (
            lambda d: d["routes"][2]["waypoints"].__setitem__(3, [5000.0, 5000.0]),
            r"routes\[2\].waypoints\[3\]: waypoint .* m from the route",
        ),
    ],
)
def test_bad_suite_is_refused_naming_file_and_field(tmp_path, mutate, match):
    d = _small_suite()
    mutate(d)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=rf"^suite {re.escape(str(path))}: {match}"):
        load_suite(path)


def test_suite_that_is_not_a_suite(tmp_path):
    path = tmp_path / "list.json"
    path.write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"suite .*list.json: expected a JSON object, got list"):
        load_suite(path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match=r"suite .*list.json: not valid JSON"):
        load_suite(path)
    with pytest.raises(FileNotFoundError, match=r"suite .*absent.json: no such file"):
        load_suite(tmp_path / "absent.json")


def test_bad_suite_fails_evaluation_before_any_job(tmp_path):
    from v2xbench.collectors.evaluate import evaluate

    d = _small_suite(2)
    for r in d["routes"]:
        r["seed"] = -5
    path = tmp_path / "neg_seed.json"
    path.write_text(json.dumps(d))
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=r"routes\[0\].seed: -5 is outside"):
        evaluate("route_follower", str(path), seeds=1, workers=1, out=out, progress=False)
    assert not out.exists() or not any(out.rglob("*.json"))
