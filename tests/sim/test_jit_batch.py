"""``jit_batch``: one kernel call moves (``TrafficBatch``) and perceives (``PerceiveBatch``) for the
worlds of a batch exactly as one call per world does, through resets, partial steps, a replaced
generator and forced fallbacks."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.api.batch import WorldBatch
from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT

pytestmark = pytest.mark.skipif(not HAVE_JIT, reason="numba not installed")


def _state(b: WorldBatch) -> list:
    out = []
    for w in b.worlds:
        t = w.table
        out += [t.pos.copy(), t.speed.copy(), t.lane.copy(), t.s.copy(), t.path_s.copy(), t.active.copy(),
                np.array(w._respawn), w.ego_vis.copy(), w.rsu_vis.copy(), w.active_rsu.copy()]
    return out + [{k: v.copy() for k, v in b.obs.items()}, b.reward.copy()]


def _drive(batched: bool, break_after: int | None = None) -> list:
    b = WorldBatch(4, town="Town01", num_vehicles=25, num_pedestrians=10, jaywalk_prob=0.2, rsu_slots=2)
    if not batched:
        b._traffic = b._perceive = None
    b.reset([10, 11, 12, 13])
    rng = np.random.default_rng(0)
    states = []
    for k in range(120):
        if break_after is not None and k == break_after:  # lists that cannot take the worlds' arguments
            for part in (b._traffic, b._perceive):
                part.args.entries = lambda w: (object(),)  # numba cannot type it
        actions = rng.uniform([0.0, -0.3, 0.0], [1.0, 0.3, 0.2], (4, 3))
        active = np.ones(4, bool)
        if k % 7 == 3:
            active[k % 4] = False  # a partial step, as Gymnasium's autoreset makes
        if k == 40:
            b.worlds[2].rng = np.random.default_rng(99)  # a replaced generator: arguments rebuilt
        b.step(actions, active=active)
        for i in np.flatnonzero(b.terminated | b.truncated):
            b.reset_world(int(i), 100 + k)
        if k == 60:
            b.reset_world(1, 7)  # a reset mid-run: new table, new arguments
        states.append(_state(b))
    return states


def _same(a: list, b: list) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        for u, v in zip(x, y):
            if isinstance(u, dict):
                for key in u:
                    np.testing.assert_array_equal(u[key], v[key])
            else:
                np.testing.assert_array_equal(u, v)


def test_batch_kernel_matches_one_call_per_world():
    _same(_drive(True), _drive(False))


def test_fallback_when_the_lists_cannot_hold_the_arguments():
    states = _drive(True, break_after=50)
    _same(states, _drive(False))


def test_one_world_batches_match_the_kernels_called_directly(monkeypatch):
    """World.move_traffic and World.perceive go through one-world batches; with those broken
    they call the kernels with all their arguments: the same runs."""
    from v2xbench.envs.v2x_intersection.sim import jit_batch

    def run() -> list:
        b = WorldBatch(1, town="Town03", num_vehicles=20, num_pedestrians=8, rsu_slots=2)
        b.reset([5])
        out = []
        for k in range(150):
            b.step(np.array([[0.6, 0.1 * np.sin(k / 9), 0.0]]))
            if b.terminated[0] or b.truncated[0]:
                b.reset_world(0, 6 + k)
            out.append(_state(b))
        return out

    direct = run()
    with monkeypatch.context() as m:
        m.setattr(jit_batch.ArgLists, "sync", lambda self, ids: False)
        m.setattr(jit_batch.ListOf, "get", lambda self, item: None)
        _same(direct, run())



@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_copies_continue_as_the_original(how):
    """A copied or unpickled env or batch (whose typed lists are not copied but rebuilt) runs on
    exactly as a fresh run with the same seeds and actions."""
    import copy
    import pickle

    import gymnasium as gym

    clone = copy.deepcopy if how == "deepcopy" else (lambda x: pickle.loads(pickle.dumps(x)))
    a = np.full((3, 3), 0.4)
    a[:, 1] = 0.05

    def batch():
        b = WorldBatch(3, num_pedestrians=10)
        b.reset([1, 2, 3])
        for _ in range(5):
            b.step(a)
        return b

    c, ref = clone(batch()), batch()
    for _ in range(40):
        c.step(a)
        ref.step(a)
    _same([_state(c)], [_state(ref)])

    def env():
        e = gym.make("V2XIntersection-v0", num_pedestrians=10)
        e.reset(seed=4)
        for _ in range(5):
            e.step(a[0].astype(np.float32))
        return e

    e, ref_e = clone(env()), env()
    for _ in range(40):
        o1, o2 = e.step(a[0].astype(np.float32))[0], ref_e.step(a[0].astype(np.float32))[0]
        for k in o1:
            np.testing.assert_array_equal(o1[k], o2[k])


def test_packed_args_rebuild_only_when_the_key_changes():
    import copy

    from v2xbench.envs.v2x_intersection.core.jit_args import PackedArgs

    a, b = np.arange(3.0), np.arange(4.0)
    p = PackedArgs()
    built = []

    def build(x):
        built.append(x)
        return (x, 1.5)

    first = p.get((a,), lambda: build(a))
    assert p.get((a,), lambda: build(a)) is first and len(built) == 1  # same key: the same list
    other = p.get((b,), lambda: build(b))
    assert other is not first and len(built) == 2
    assert np.array_equal(other[0][0], b) and other[0][1] == 1.5
    assert p.get((b, a), lambda: build(b)) is not other  # a longer key is another key
    q = copy.deepcopy(p)  # typed lists cannot be copied: a copy rebuilds on use
    assert q._list is None


def test_list_of_rebuilds_only_for_another_item_and_gives_up_on_items_it_cannot_hold():
    import copy

    from v2xbench.envs.v2x_intersection.core.jit_args import ListOf

    a, b = (np.arange(3.0), 1.5), (np.arange(4.0), 2.5)
    one = ListOf()
    first = one.get(a)
    assert one.get(a) is first and np.array_equal(first[0][0], a[0]) and first[0][1] == 1.5
    other = one.get(b)
    assert other is not first and np.array_equal(other[0][0], b[0])
    assert copy.deepcopy(one)._list is None  # a copy rebuilds on use
    bad = ListOf()
    assert bad.get(({"not": "numba"},)) is None and bad.broken
    assert bad.get(a) is None  # broken for good: the caller keeps its fallback


def test_objects_observation_after_a_copy_reads_the_copy():
    """The packed observation arguments of a deep-copied world are the copy's own arrays."""
    import copy

    from v2xbench.envs.v2x_intersection.api.observations import ego_observation

    b = WorldBatch(1, town="Town01", num_vehicles=10)
    b.reset([3])
    for _ in range(5):
        b.step(np.array([[0.6, 0.0, 0.0]]))
    w = b.worlds[0]
    before = ego_observation(w)
    twin = copy.deepcopy(w)
    twin.table.pos[1:] += 5.0  # moves the others in the copy only
    assert np.array_equal(ego_observation(w)["objects"], before["objects"])
    assert not np.array_equal(ego_observation(twin)["objects"], before["objects"])


def test_one_world_perception_outputs_are_rewritten_each_tick():
    """The one-world perception writes into per-episode output arrays (no arrays returned): the
    world's ``ego_vis`` is the same array from tick to tick, holding the new tick's values, and a
    new episode gets new arrays."""
    import gymnasium as gym

    if not HAVE_JIT:
        pytest.skip("numba path only")
    env = gym.make("V2XIntersection-v0", suite="test50", route_index=0)
    env.reset(seed=0)
    w = env.unwrapped.world
    first, kept = w.ego_vis, w.ego_vis.copy()
    for _ in range(80):  # until what the ego sees changes (it does within a few seconds)
        env.step(np.array([0.6, 0.0, 0.0], np.float32))
        assert w.ego_vis is first
        if not np.array_equal(w.ego_vis, kept):
            break
    assert not np.array_equal(w.ego_vis, kept)
    w.perceive()
    assert w.ego_vis is first
    env.reset(seed=1)
    assert w.ego_vis is not first
