"""Tests of the traffic-light phase plans."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.model import SIGNAL
from v2xbench.envs.v2x_intersection.traffic.signals import GREEN, NO_SIGNAL, RED, YELLOW, SignalPlan

TOWNS = ["Town01", "Town03", "Town12"]


@pytest.fixture(scope="module", params=TOWNS)
def town_plan(request):
    town = get_town(request.param)
    return town, SignalPlan(town)


def signal_junctions(town):
    return [j for j in town.junctions if j.control == SIGNAL]


def test_plan_covers_exactly_the_signal_lanes(town_plan):
    town, plan = town_plan
    expected = sorted(lid for j in signal_junctions(town) for g in j.phase_groups for lid in g)
    assert len(expected) > 0
    assert sorted(plan.lanes.tolist()) == expected
    states = plan.lane_states(3.0)
    assert states.shape == (len(town.lanes),)
    controlled = np.zeros(len(town.lanes), bool)
    controlled[plan.lanes] = True
    assert np.all(states[~controlled] == NO_SIGNAL)
    assert np.all(np.isin(states[controlled], [GREEN, YELLOW, RED]))


def test_at_most_one_phase_group_green_or_yellow(town_plan):
    town, plan = town_plan
    for t in np.arange(0.0, 150.0, 0.25):
        s = plan.states(t)
        for j in signal_junctions(town):
            m = plan.junction == j.id
            active = np.unique(plan.group[m][s[m] != RED])
            assert len(active) <= 1, f"junction {j.id} at t={t:.1f}: groups {active}"
            # every lane of a group shares the group's state
            for g in range(len(j.phase_groups)):
                assert len(np.unique(s[m & (plan.group == g)])) == 1


def test_every_controlled_lane_gets_green_each_cycle(town_plan):
    town, plan = town_plan
    for j in signal_junctions(town):
        m = plan.junction == j.id
        t0 = 17.3
        times = t0 + np.arange(0.0, j.cycle_s, 0.05)
        st = np.stack([plan.states(t)[m] for t in times])
        assert np.all((st == GREEN).any(0))
        assert np.all((st == YELLOW).any(0))
        # green for green_s and yellow for yellow_s of each cycle (to the sampling step)
        np.testing.assert_allclose((st == GREEN).sum(0) * 0.05, j.green_s, atol=0.11)
        np.testing.assert_allclose((st == YELLOW).sum(0) * 0.05, j.yellow_s, atol=0.11)
        # all-red clearance between phases: some instants where every approach is red
        assert np.any((st == RED).all(1))


def test_states_are_periodic_with_the_cycle(town_plan):
    town, plan = town_plan
    rng = np.random.default_rng(0)
    for j in signal_junctions(town):
        m = plan.junction == j.id
        for t in rng.uniform(0.0, 500.0, 40):
            a = plan.states(t)[m]
            for k in (1, 3):
                np.testing.assert_array_equal(plan.states(t + k * j.cycle_s)[m], a)


def test_phase_order_green_yellow_red():
    town = get_town("Town01")
    plan = SignalPlan(town)
    j = signal_junctions(town)[0]
    lane = j.phase_groups[0][0]
    k = int(np.flatnonzero(plan.lanes == lane)[0])
    times = np.arange(0.0, 2 * j.cycle_s, 0.05)
    seq = np.array([plan.states(t)[k] for t in times])
    changes = seq[np.flatnonzero(np.diff(seq)) + 1]
    # after a green always yellow, after yellow always red, after red always green
    prev = seq[np.flatnonzero(np.diff(seq))]
    for a, b in zip(prev, changes):
        assert (a, b) in ((GREEN, YELLOW), (YELLOW, RED), (RED, GREEN))


def test_junctions_are_not_synchronized():
    town = get_town("Town12")
    offsets = [j.offset_s for j in signal_junctions(town)]
    assert len(set(np.round(offsets, 6))) == len(offsets)


def test_kept_lane_states_equal_fresh_ones(town_plan):
    """lane_states reuses its last answer until the next phase boundary: every tick of a long
    run, and times on and next to the boundaries, equal a plan that never reuses (a new plan
    per call), and a time earlier than the kept one is computed afresh."""
    town, plan = town_plan
    cached = SignalPlan(town)
    ends = []
    for j in signal_junctions(town):
        period = j.green_s + j.yellow_s + j.all_red_s
        for g in range(len(j.phase_groups)):
            for b in (j.green_s, j.green_s + j.yellow_s, period):
                ends.append(g * period + b - j.offset_s)
    near = [e + d for e in ends for d in (-1e-5, -1e-7, 0.0, 1e-7, 1e-5)]
    ticks = [(k + 1) * 0.1 for k in range(3000)]
    reused = 0
    for t in ticks + sorted(t for t in near if t >= 0.0) + [0.0, 7.3, 2.0]:
        before = cached._last
        got = cached.lane_states(t)
        reused += before is not None and got is before[2]
        np.testing.assert_array_equal(got, SignalPlan(town).lane_states(t), err_msg=f"t={t}")
    assert reused > len(ticks) // 2  # the point of it: most ticks reuse


def test_lane_states_without_controlled_lanes_is_constant():
    town = next(get_town(n) for n in ("Town02", "Town04", "Town05", "Town06") if not signal_junctions(get_town(n)))
    plan = SignalPlan(town)
    a = plan.lane_states(0.0)
    assert np.all(a == NO_SIGNAL) and plan.lane_states(1e6) is a


def test_valid_until_kernel_matches_numpy(town_plan):
    from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT
    from v2xbench.envs.v2x_intersection.traffic.jit_vehicles import phase_valid_until_kernel
    from v2xbench.envs.v2x_intersection.traffic.signals import BOUNDARY_SLACK_S

    if not HAVE_JIT:
        pytest.skip("numba not installed")
    town, plan = town_plan
    for t in np.random.default_rng(1).uniform(0.0, 900.0, 200):
        got = phase_valid_until_kernel(float(t), plan._period, plan._green, plan._yellow, plan._n_groups,
                                       plan._offset, BOUNDARY_SLACK_S)
        assert t < got <= t + max(plan._period.max(), 1.0)
        assert got == pytest.approx(plan._valid_until(float(t)), rel=1e-12, abs=1e-9)


def test_force_green_overrides_one_junction_until_released():
    """A scenario override (CARLA's PriorityAtJunction): the given lanes green, the junction's
    other lanes red (the ones green at that moment yellow first), other junctions untouched,
    and the fixed-time plan back after ``release``."""
    town = get_town("Town01")
    plan, ref = SignalPlan(town), SignalPlan(town)
    j = signal_junctions(town)[0]
    mine = [lid for g in j.phase_groups for lid in g]
    t0 = 1.0
    green_now = [lid for lid in mine if ref.lane_states(t0)[lid] == GREEN]
    target = next(g for g in j.phase_groups if not set(g) & set(green_now))  # red at t0
    plan.force_green(target, t0)
    others = [lid for lid in mine if lid not in target]
    rest = np.setdiff1d(plan.lanes, mine)
    for t in (t0, t0 + j.yellow_s - 0.1, t0 + j.yellow_s + 0.1, t0 + 200.0):
        s = plan.lane_states(t)
        assert (s[target] == GREEN).all()
        want = YELLOW if t < t0 + j.yellow_s else RED
        assert all(s[lid] == (want if lid in green_now else RED) for lid in others)
        np.testing.assert_array_equal(s[rest], ref.lane_states(t)[rest])
    assert (plan.lane_states(t0 - 0.5) == ref.lane_states(t0 - 0.5)).all()  # not before it starts
    plan.release()
    np.testing.assert_array_equal(plan.lane_states(t0 + 200.0), ref.lane_states(t0 + 200.0))
    with pytest.raises(ValueError, match="not signal-controlled"):
        plan.force_green([int(rest.max()) + 10_000], t0)
    other = signal_junctions(town)[1]
    with pytest.raises(ValueError, match="one junction at a time"):
        plan.force_green([mine[0], other.phase_groups[0][0]], t0)


def test_world_reset_ends_an_override():
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    world = World(make_config(town="Town01", num_vehicles=2, num_pedestrians=0, num_parked=0,
                              num_bicycles=0))
    world.reset(seed=0)
    j = signal_junctions(world.town)[0]
    world.signals.force_green(j.phase_groups[1], 0.0)
    world.reset(seed=0)
    assert world.signals._forced is None
