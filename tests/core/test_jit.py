"""The numba kernels (``jit``) give bit-identical results to the NumPy paths they replace."""

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core import raycast
from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT
from v2xbench.envs.v2x_intersection.core.raycast import Boxes, segments_blocked
from v2xbench.envs.v2x_intersection.perception import visibility
from v2xbench.envs.v2x_intersection.perception.visibility import visible_fraction
from v2xbench.envs.v2x_intersection.sensors import (
    bev,
    camera,
    fan,
    groundtruth,
    lidar,
    scene,
    shading,
)

pytestmark = pytest.mark.skipif(not HAVE_JIT, reason="numba not installed")


def _scene(rng: np.random.Generator, n: int) -> Boxes:
    return Boxes.from_arrays(rng.uniform(-40, 40, (n, 2)), rng.uniform(0.5, 10, n), rng.uniform(0.5, 3, n),
                             rng.uniform(-np.pi, np.pi, n), rng.uniform(0.0, 4.0, n) * (rng.random(n) > 0.1))


def _both(monkeypatch, fn):
    a = fn()
    with monkeypatch.context() as m:
        m.setattr(raycast, "HAVE_JIT", False)
        m.setattr(visibility, "HAVE_JIT", False)
        m.setattr(shading, "HAVE_JIT", False)
        m.setattr(camera, "HAVE_JIT", False)
        m.setattr(fan, "HAVE_JIT", False)
        m.setattr(groundtruth, "HAVE_JIT", False)
        m.setattr(lidar, "HAVE_JIT", False)
        m.setattr(bev, "HAVE_JIT", False)
        m.setattr(scene, "HAVE_JIT", False)
        b = fn()
    return a, b


@pytest.mark.parametrize("seed", range(4))
def test_segments_blocked_matches_numpy(monkeypatch, seed):
    rng = np.random.default_rng(seed)
    boxes = _scene(rng, 60)
    ends = np.concatenate([rng.uniform(-50, 50, (300, 2)), rng.uniform(0, 3, (300, 1))], 1)
    ig = rng.integers(-1, 60, (300, 2))
    for start in (np.array([1.0, -2.0, 1.8]), np.concatenate([ends[::-1, :2], np.full((300, 1), 2.0)], 1)):
        a, b = _both(monkeypatch, lambda start=start: segments_blocked(start, ends, boxes, ig))
        np.testing.assert_array_equal(a, b)
        assert a.any() and not a.all()


@pytest.mark.parametrize("seed", range(4))
def test_visible_fraction_matches_numpy(monkeypatch, seed):
    rng = np.random.default_rng(seed)
    boxes = _scene(rng, 80)
    targets = rng.choice(80, 30, replace=False)
    for kw in ({"ignore": np.array([0])}, {"max_range": 35.0, "sensor_yaw": 0.7, "hfov": 2.0}):
        sensor = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), 1.8 if "ignore" in kw else 5.0])
        a, b = _both(monkeypatch, lambda sensor=sensor, kw=kw: visible_fraction(sensor, boxes, targets, **kw))
        np.testing.assert_array_equal(a, b)
        assert 0 < a.mean() < 1


@pytest.mark.parametrize("seed", range(3))
def test_visible_fraction_dense_scene_matches_numpy(monkeypatch, seed):
    """Crowded scenes: targets with many near boxes next to targets with few, so that the sight
    test's per-target broad phase (``jit.points_blocked_kernel``) is rebuilt between them."""
    rng = np.random.default_rng(100 + seed)
    n = 192
    center = rng.uniform(-25, 25, (n, 2))
    center[np.hypot(*center.T) < 4.0] += 6.0  # the sensor at the origin stands in the open
    boxes = Boxes.from_arrays(center, rng.uniform(0.5, 5, n), rng.uniform(0.5, 2, n),
                              rng.uniform(-np.pi, np.pi, n), rng.uniform(0.0, 3.0, n) * (rng.random(n) > 0.1))
    targets = rng.choice(len(boxes.length), 40, replace=False)
    sensor = np.array([0.0, 0.0, 1.8])
    a, b = _both(monkeypatch, lambda: visible_fraction(sensor, boxes, targets))
    np.testing.assert_array_equal(a, b)
    assert 0 < a.mean() < 1


def test_project_matches_numpy(monkeypatch):
    from v2xbench.envs.v2x_intersection.town import get_town, model

    ix = get_town("Town02").index
    rng = np.random.default_rng(0)
    xy = ix.points[rng.choice(len(ix.points), 50)] + rng.normal(0, 3, (50, 2))
    pid = ix.point_ids(np.arange(0, len(ix.length), 2))
    for kw in ({}, {"point_ids": pid}):
        a = ix.project(xy, **kw)
        with monkeypatch.context() as m:
            m.setattr(model, "HAVE_JIT", False)
            b = ix.project(xy, **kw)
            c = ix.project_near(xy[0], pid)
        for u, v in zip(a, b):
            np.testing.assert_array_equal(u, v)
        for u, v in zip(ix.project_near(xy[0], pid), c):
            np.testing.assert_array_equal(u, v)


def test_leaders_matches_numpy(monkeypatch):
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.traffic import vehicles as traffic

    w = World(make_config(town="Town01", num_vehicles=40))
    w.reset(seed=3)
    t = w.table
    t.yaw[:] += np.random.default_rng(0).normal(0, 0.3, len(t))
    idx = np.flatnonzero(t.active)
    a = traffic.leaders(t, idx)
    with monkeypatch.context() as m:
        m.setattr(traffic, "HAVE_JIT", False)
        b = traffic.leaders(t, idx)
    assert np.isfinite(a[0]).any()
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)


@pytest.mark.parametrize("town", ["Town01", "Town12"])
def test_grid_projection_matches_scan(town):
    """``jit_grid.project_grid_kernel`` gives what the full scan (``project_kernel``) gives:
    queries on the roads, far off the grid on every side, exactly on vertices, halfway between two
    (ties) and NaN."""
    from v2xbench.envs.v2x_intersection.core.jit import project_kernel
    from v2xbench.envs.v2x_intersection.core.jit_grid import project_grid_kernel
    from v2xbench.envs.v2x_intersection.evaluation.infractions import (
        _driving_grid,
        _driving_point_ids,
    )
    from v2xbench.envs.v2x_intersection.town import get_town

    t = get_town(town)
    ix, pid, grid = t.index, _driving_point_ids(t), _driving_grid(t)
    rng = np.random.default_rng(0)
    on = ix.points[rng.choice(pid, 300)]
    lo, hi = ix.points.min(0), ix.points.max(0)
    queries = np.concatenate([
        on + rng.normal(0, 4, on.shape), on[:50],  # near the roads; exactly on vertices
        0.5 * (ix.points[pid[:60]] + ix.points[pid[1:61]]),  # halfway along segments
        rng.uniform(lo - 300, hi + 300, (200, 2)),  # anywhere, off the grid too
        [[np.nan, 0.0], [lo[0] - 5000, hi[1] + 5000]],
    ])
    args = (ix.points, pid, ix.owner, ix.offset, ix.n_points, ix.gs, ix.base)
    ref = project_kernel(queries, *args)
    for k, (x, y) in enumerate(queries):
        got = project_grid_kernel(x, y, *args, *grid)
        np.testing.assert_array_equal(np.array(got, float), [ref[0][k], ref[1][k], ref[2][k]], err_msg=str(k))


def test_lane_assign_matches_numpy():
    from v2xbench.agents.expert.lanes import LaneMap
    from v2xbench.envs.v2x_intersection.town import get_town

    town = get_town("Town03")
    fast = LaneMap(town)
    slow = LaneMap(town)
    slow._dense = None
    rng = np.random.default_rng(1)
    ix = town.index
    k = rng.choice(len(ix.points), 300)
    pos = ix.points[k] + rng.normal(0, 1.5, (300, 2))
    yaw = ix.heading[k] + rng.normal(0, 0.5, 300)
    a, b = fast.assign(pos, yaw), slow.assign(pos, yaw)
    assert a[3][:, 1].any()
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)


def test_idm_matches_numpy(monkeypatch):
    from v2xbench.envs.v2x_intersection.core import dynamics

    rng = np.random.default_rng(2)
    n = 500
    v, v0 = rng.uniform(0, 20, n), rng.uniform(0, 15, n)
    gap = np.where(rng.random(n) < 0.3, np.inf, rng.uniform(-1, 60, n))
    dv = rng.normal(0, 4, n)
    for p in (dynamics.IDMParams(), dynamics.IDMParams(accel=1.0, decel=2.0, time_headway=1.0, min_gap=1.5)):
        a = dynamics.idm_accel(v, v0, gap, dv, p)
        with monkeypatch.context() as m:
            m.setattr(dynamics, "HAVE_JIT", False)
            b = dynamics.idm_accel(v, v0, gap, dv, p)
        np.testing.assert_array_equal(a, b)


def test_libm_functions_are_the_c_library_elementwise():
    """The fallbacks' transcendental functions give math's (the C library's) bits element by
    element on every CPU (NumPy's ufuncs need not, on AVX-512), broadcast like ufuncs, and
    answer NaN or inf where math raises, as NumPy does."""
    import math

    from v2xbench.envs.v2x_intersection.core import libm

    rng = np.random.default_rng(5)
    x, y = rng.uniform(-10, 10, 2000), rng.uniform(-10, 10, 2000)
    pairs = ((libm.arctan2, math.atan2, (y, x)), (libm.hypot, math.hypot, (x, y)),
             (libm.power, math.pow, (np.abs(x), np.full_like(x, 4.0))), (libm.tan, math.tan, (x,)),
             (libm.arcsin, math.asin, (x / 10,)))
    for ours, ref, args in pairs:
        got = ours(*args)
        assert got.dtype == np.float64 and got.shape == x.shape
        assert got.tobytes() == np.array([ref(*t) for t in zip(*args)]).tobytes(), ours.__name__
    assert libm.arctan2(np.ones((3, 1)), np.ones(4)).shape == (3, 4)
    assert float(libm.tan(0.5)) == math.tan(0.5)
    with np.errstate(invalid="ignore", over="ignore"):
        for ours, ufunc, args in ((libm.arcsin, np.arcsin, (2.0,)), (libm.tan, np.tan, (np.inf,)),
                                  (libm.power, np.power, (-2.0, 0.5)), (libm.power, np.power, (10.0, 400.0)),
                                  (libm.power, np.power, (-10.0, 401.0)), (libm.arctan2, np.arctan2, (np.nan, 1.0))):
            np.testing.assert_array_equal(ours(*args), ufunc(*args))


def test_window_project_matches_numpy(monkeypatch):
    from v2xbench.agents.expert import route_track
    from v2xbench.envs.v2x_intersection.suites.route_files import (
        build_episode_from_spec,
        load_suite_cached,
    )
    from v2xbench.envs.v2x_intersection.town import get_town

    spec = load_suite_cached("test50")[3]
    route, _ = build_episode_from_spec(spec)
    track = route_track.RouteTrack(get_town(spec.town), route)
    win = track.window(30, float(route.s[30]), 120.0, offsets=lambda st: 0.5 * np.sin(st / 10.0))
    rng = np.random.default_rng(4)
    pts = win.xy[rng.integers(0, len(win.xy), 200)] + rng.normal(0, 3, (200, 2))
    ang = rng.uniform(-np.pi, np.pi, 200)
    dirn = np.stack([np.cos(ang), np.sin(ang)], -1)
    for d in (None, dirn):
        a = win.project(pts, d)
        with monkeypatch.context() as m:
            m.setattr(route_track, "HAVE_JIT", False)
            b = win.project(pts, d)
        for u, v in zip(a, b):
            np.testing.assert_array_equal(u, v)


def _table_bytes(t) -> dict:
    import dataclasses

    return {f.name: getattr(t, f.name).tobytes() for f in dataclasses.fields(t)}


@pytest.mark.parametrize("town, extra",
                         [("Town01", {}), ("Town03", {}), ("Town12", {}), ("Town03", {"max_objects": 2})])
def test_world_tick_kernels_match_numpy(monkeypatch, town, extra):
    """Two worlds from one seed and one action sequence, one on the NumPy paths of the tick
    (traffic, pedestrians, monitor, observations, the built-in RSU message), one on the kernels:
    identical actor tables, generator states, events, observations and channel statistics every
    tick (signed zeros included: the bytes are compared). ``max_objects=2``: more objects seen and
    received than the observation holds (its nearest rows)."""
    from v2xbench.envs.v2x_intersection.api import observations
    from v2xbench.envs.v2x_intersection.api.observations import ego_observation
    from v2xbench.envs.v2x_intersection.evaluation import infractions, physics
    from v2xbench.envs.v2x_intersection.perception.visibility import VISIBLE_THRESHOLD
    from v2xbench.envs.v2x_intersection.sim import world as world_module
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.town import model
    from v2xbench.envs.v2x_intersection.traffic import pedestrians, signals
    from v2xbench.envs.v2x_intersection.traffic import vehicles as traffic
    from v2xbench.envs.v2x_intersection.v2x import rsu

    modules = (traffic, pedestrians, world_module, rsu, model, observations, signals, infractions, physics)
    worlds = [World(make_config(town=town, num_vehicles=40, num_pedestrians=30, jaywalk_prob=0.05, rsu_slots=2,
                                **extra)) for _ in range(2)]
    for w in worlds:
        w.reset(seed=3)
    rng = np.random.default_rng(0)
    seen_max = received_max = 0
    for k in range(300):
        a = rng.uniform([0.0, -0.3, 0.0], [1.0, 0.3, 0.3])
        out = []
        for jit, w in zip((False, True), worlds):
            with monkeypatch.context() as m:
                for mod in modules:
                    m.setattr(mod, "HAVE_JIT", jit)
                # odd ticks: the gym/batch path (the world packs its own message)
                events = w.step_builtin(a) if k % 2 else w.step(a, w.default_rsu_message())
                obs = ego_observation(w)
            if jit:
                seen_max = max(seen_max, int((w.ego_vis >= VISIBLE_THRESHOLD).sum()))
                received_max = max(received_max, 0 if w.inbox is None else len(w.inbox[2]) // 10)
            out.append((_table_bytes(w.table), events, {key: np.asarray(v).tobytes() for key, v in obs.items()
                                                        if not isinstance(v, dict)}, w.channel.stats()))
        assert out[0][0] == out[1][0], f"tick {k}: actor tables differ"
        assert worlds[0].rng.bit_generator.state == worlds[1].rng.bit_generator.state, f"tick {k}: draws differ"
        assert out[0][1] == out[1][1] and out[0][2] == out[1][2], f"tick {k}: events/observations differ"
        assert out[0][3] == out[1][3], f"tick {k}: channel statistics differ"
    assert worlds[1].table.wait.max() > 0.0  # someone queued: the stop rules ran
    if extra:  # the observation's rows were full: more were seen and received than it holds
        assert seen_max > extra["max_objects"] and received_max > extra["max_objects"]


def test_move_traffic_follows_a_replaced_generator(monkeypatch):
    """``World.move_traffic`` keeps its kernel's episode arguments (the generator's state views
    among them) and rebuilds them when the world's generator is replaced mid-episode: the kernel
    path then draws from the new generator, as the NumPy path does."""
    from v2xbench.envs.v2x_intersection.sim import world as world_module
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.traffic import pedestrians, signals
    from v2xbench.envs.v2x_intersection.traffic import vehicles as traffic

    worlds = [World(make_config(num_vehicles=30, num_pedestrians=20, jaywalk_prob=0.05)) for _ in range(2)]
    for w in worlds:
        w.reset(seed=1)
    a = np.array([0.5, 0.0, 0.0])
    for k in range(40):
        if k == 10:
            for w in worlds:
                w.rng = np.random.default_rng(99)
        for jit, w in zip((False, True), worlds):
            with monkeypatch.context() as m:
                for mod in (world_module, traffic, pedestrians, signals):
                    m.setattr(mod, "HAVE_JIT", jit)
                w.step_builtin(a)
        assert _table_bytes(worlds[0].table) == _table_bytes(worlds[1].table), f"tick {k}"
        assert worlds[0].rng.bit_generator.state == worlds[1].rng.bit_generator.state, f"tick {k}"


@pytest.mark.parametrize("town", ["Town01", "Town03"])
def test_world_reset_kernels_match_numpy(monkeypatch, town):
    """Populating a world at reset (NPC vehicles, bicycles, pedestrians: ``jit_spawn``) gives the
    same actor table and leaves the generator in the same state on both paths."""
    from v2xbench.envs.v2x_intersection.sim import world as world_module
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.traffic import spawn
    from v2xbench.envs.v2x_intersection.traffic import vehicles as traffic

    cfg = make_config(town=town, num_vehicles=60, num_bicycles=8, num_pedestrians=25)
    for seed in range(4):
        out = []
        for jit in (False, True):
            w = World(cfg)
            with monkeypatch.context() as m:
                m.setattr(world_module, "HAVE_JIT", jit)
                m.setattr(spawn, "HAVE_JIT", jit)
                m.setattr(traffic, "HAVE_JIT", jit)
                w.reset(seed=seed)
            out.append((_table_bytes(w.table), w.rng.bit_generator.state))
        assert out[0] == out[1], f"seed {seed}"


def test_pose_at_matches_numpy(monkeypatch):
    from v2xbench.envs.v2x_intersection.town import get_town

    ix = get_town("Town03").index
    rng = np.random.default_rng(1)
    lanes = rng.integers(0, len(ix.length), 200)
    s = rng.uniform(-5.0, 1.1, 200) * ix.length[lanes]
    s[:3] = (-0.0, 0.0, np.nan)
    _assert_pose_at_matches(monkeypatch, ix, lanes, s)


def _assert_pose_at_matches(monkeypatch, ix, lanes: np.ndarray, s: np.ndarray) -> None:
    from v2xbench.envs.v2x_intersection.town import model

    a = ix.pose_at(lanes, s)
    with monkeypatch.context() as m:
        m.setattr(model, "HAVE_JIT", False)
        b = ix.pose_at(lanes, s)
    for x, y in zip(a, b):
        assert x.tobytes() == y.tobytes()


def test_pose_at_at_vertices_matches_numpy(monkeypatch):
    """Arc lengths on the lanes (not clamped), at their vertices exactly and one ulp either side."""
    from v2xbench.envs.v2x_intersection.town import get_town

    ix = get_town("Town04").index
    rng = np.random.default_rng(2)
    lanes = rng.integers(0, len(ix.length), 300)
    vertex = ix.offset[lanes] + (rng.random(300) * ix.n_points[lanes]).astype(np.int64)
    at = ix.gs[vertex] - ix.base[lanes]
    s = np.concatenate([rng.random(300) * ix.length[lanes], at, np.nextafter(at, -np.inf), np.nextafter(at, np.inf)])
    _assert_pose_at_matches(monkeypatch, ix, np.tile(lanes, 4), s)


@pytest.mark.parametrize("spacing", ["even", "uneven", "repeated"])
def test_vertex_at_or_below_is_searchsorted(spacing):
    """``jit.vertex_at_or_below`` (a walk from an even-spacing estimate, bisection when the walk
    runs long) against ``np.searchsorted(side="right") - 1`` on polylines of every kind."""
    from v2xbench.envs.v2x_intersection.core.jit import vertex_at_or_below

    rng = np.random.default_rng(3)
    for trial in range(40):
        n = int(rng.integers(1, 60))
        step = {"even": np.full(n, 1.5) + rng.normal(0, 0.05, n),
                "uneven": rng.exponential(1.0, n) ** 3,
                "repeated": rng.choice([0.0, 1.0, 2.5], n)}[spacing]
        step[0] = 0.0
        base = float(rng.uniform(0, 5000))
        gs = np.concatenate([rng.uniform(-9, -1, 3), base + np.cumsum(step), base + 1e4 + np.arange(3)])
        first, last = 3, 3 + n - 1
        own = gs[first:last + 1]
        g = np.concatenate([rng.uniform(base - 2, own[-1] + 2, 50), own, np.nextafter(own, -np.inf),
                            np.nextafter(own, np.inf), [np.nan, -np.inf, np.inf]])
        want = first + np.searchsorted(own, g, side="right") - 1
        got = [vertex_at_or_below(gs, first, last, x) for x in g]
        np.testing.assert_array_equal(got, want, err_msg=f"trial {trial}")


@pytest.mark.parametrize("route_index", [0, 23])
def test_expert_forecast_kernel_matches_numpy(monkeypatch, route_index):
    """The expert drives a test50 route; at every tick its forecast is computed on the kernel and
    on the NumPy path: every array of both forecasts is equal, bit for bit."""
    import dataclasses

    from v2xbench.agents.expert import Expert, planner, prediction
    from v2xbench.collectors import jobs
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

    calls = {"n": 0, "hypotheses": 0}
    real = prediction.forecast

    def both(*args, **kwargs):
        out = []
        for jit in (False, True):
            with monkeypatch.context() as m:
                m.setattr(prediction, "HAVE_JIT", jit)
                out.append(real(*args, **kwargs))
        for f in dataclasses.fields(out[0]):
            a, b = getattr(out[0], f.name), getattr(out[1], f.name)
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), f.name
        calls["n"] += 1
        calls["hypotheses"] += int((out[1].branch >= 0).sum())
        return out[1]

    monkeypatch.setattr(planner, "forecast", both)
    spec = load_suite_cached("test50")[route_index]
    w = World(make_config(town=spec.town))
    w.reset(seed=jobs.job_seed(spec.seed, 0), spec=spec)
    agent = Expert()
    agent.reset({})
    agent.bind(w)
    for _ in range(250):
        w.step(agent.act(None), w.default_rsu_message())
    assert calls["n"] > 0 and calls["hypotheses"] > 0


@pytest.mark.parametrize("seed", range(3))
def test_ray_box_intervals_matches_numpy(monkeypatch, seed):
    rng = np.random.default_rng(seed)
    boxes = _scene(rng, 50)
    d = np.concatenate([rng.normal(size=(200, 2)), rng.normal(size=(200, 1)) * (rng.random((200, 1)) > 0.3)], 1)
    d[:5, :2] = 0.0  # vertical rays
    d[5:10, 0] = 0.0  # rays along a world axis
    for o in (np.array([0.5, -1.0, 1.5]), rng.uniform(-40, 40, (200, 3))):
        a, b = _both(monkeypatch, lambda o=o: raycast.ray_box_intervals(o, d, boxes))
        for x, y in zip(a, b):
            assert x.dtype == y.dtype == np.float32 and x.tobytes() == y.tobytes()
        assert np.isfinite(a[0]).any() and np.isinf(a[0]).any()


def test_scene_cull_matches_numpy(monkeypatch):
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    w = World(make_config(town="Town03"))
    w.reset(seed=1)
    sc = scene.build_scene(w)
    rng = np.random.default_rng(0)
    kept = 0
    for k in range(80):
        if k % 2:  # near the ego
            o = np.r_[w.table.pos[0] + rng.uniform(-30, 30, 2), 1.8]
        else:  # next to a box: circles straddling the sensor's plane and the wedge's edges
            j = rng.integers(len(sc.boxes))
            o = np.r_[sc.boxes.center[j] + rng.uniform(-1.5, 1.5, 2) * sc.radius[j], 1.8]
        args = (o, rng.uniform(-4, 4), (0.3, 1.0, np.pi)[k % 3], rng.uniform(10, 120),
                None if k % 2 else np.array([0, 3]), None if k % 5 else 60.0)
        a, b = _both(monkeypatch, lambda args=args: sc.cull(*args))
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
        kept += len(a)
    assert kept > 100


@pytest.mark.parametrize("seed", range(3))
def test_first_hit_fan_matches_numpy(monkeypatch, seed):
    rng = np.random.default_rng(seed)
    boxes = _scene(rng, 70)
    az = np.sort(rng.uniform(-np.pi, np.pi, 90))
    dirs = np.stack([np.cos(az), np.sin(az)], -1) * rng.uniform(0.5, 2.0, (90, 1))
    origin = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), 1.8])
    slopes = [np.linspace(-0.4, 0.3, 24), rng.uniform(-0.5, 0.5, (24, 90))]
    slopes[0][5] = 0.0  # a level ray: 1 / slope is inf
    for k in slopes:
        for kw in ({}, {"ignore": 3, "max_t": 30.0}):
            a, b = _both(monkeypatch, lambda k=k, kw=kw: raycast.first_hit_fan(origin, dirs, k, boxes, **kw))
            for x, y in zip(a, b):
                assert x.dtype == y.dtype and x.tobytes() == y.tobytes()
            assert (a[1] >= 0).any() and (a[1] == raycast.GROUND).any()


def test_sensor_rig_matches_numpy(monkeypatch):
    """Every camera, LiDAR, BEV and ground-truth array of the full rig: the same bytes with the
    ray-casting kernels and on the NumPy path."""
    from v2xbench.envs.v2x_intersection.sensors import SensorConfig, SensorRig
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    w = World(make_config(town="Town01"))
    w.reset(seed=0)
    for _ in range(20):
        w.step(np.array([0.4, 0.0, 0.0]), w.default_rsu_message())
    rig = SensorRig(SensorConfig(camera_size=(64, 32), rsu_camera_size=(64, 32)))

    def flat(d, prefix=""):
        out = {}
        for key, v in d.items():
            if isinstance(v, dict):
                out.update(flat(v, f"{prefix}{key}/"))
            elif isinstance(v, np.ndarray):
                out[prefix + key] = v.tobytes()
        return out

    a, b = _both(monkeypatch, lambda: flat(rig.capture(w)))
    assert a.keys() == b.keys() and len(a) > 10
    assert [key for key in a if a[key] != b[key]] == []


def test_bev_matches_numpy(monkeypatch):
    """The BEV (map channels from the ground raster, objects, stop lines) on both paths, with the
    ego at random poses, one of them off the town's raster: the same bytes."""
    from v2xbench.envs.v2x_intersection.sensors import SensorRig
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    w = World(make_config(town="Town03"))
    w.reset(seed=5)
    rig = SensorRig()
    rng = np.random.default_rng(1)
    g = rig.ground(w)
    xs = [rng.uniform(g.xmin, g.xmin + 150, 2) for _ in range(5)] + [np.array([g.xmin - 20.0, g.ymin + 10.0])]
    mapped = 0
    for xy in xs:
        w.table.pos[0], w.table.yaw[0] = xy, rng.uniform(-np.pi, np.pi)
        a, b = _both(monkeypatch, lambda: rig.capture_bev(w))
        assert a.dtype == b.dtype == np.uint8 and a.tobytes() == b.tobytes()
        mapped += bool(a[:6].any())
    assert mapped >= 3


@pytest.mark.parametrize("town", ["Town01", "Town03"])
def test_shading_kernel_matches_numpy(monkeypatch, town):
    """The six ego cameras and the RSU camera at full size, shaded on both paths: the same bytes
    (buildings with storey textures, vehicles, lamps, ground materials, sky and haze)."""
    from v2xbench.envs.v2x_intersection.sensors import SensorConfig, SensorRig
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    w = World(make_config(town=town))
    w.reset(seed=2)
    rig = SensorRig(SensorConfig())
    kinds = set()
    for _ in range(3):
        for _ in range(15):
            w.step(np.array([0.5, 0.02, 0.0]), w.default_rsu_message())

        def shoot():
            cams = {**rig.capture_ego_cameras(w), "rsu": rig.capture_rsu_camera(w)}
            kinds.update(*(np.unique(v["semantic"]).tolist() for v in cams.values()))
            return {k: v["rgb"].tobytes() + v["semantic"].tobytes() + v["instance"].tobytes() for k, v in cams.items()}

        a, b = _both(monkeypatch, shoot)
        assert [k for k in a if a[k] != b[k]] == []
    assert len(kinds) >= 6  # ground materials, sky, objects


def test_unoccluded_pixel_counts_kernel_matches_numpy(monkeypatch):
    """The ground truth's unoccluded pixel counts (every candidate in every camera, riders on
    bicycles included) on both paths: the same float64 bytes."""
    from v2xbench.envs.v2x_intersection.sensors import SensorConfig, SensorRig
    from v2xbench.envs.v2x_intersection.sensors.groundtruth import candidate_boxes
    from v2xbench.envs.v2x_intersection.sensors.rig import ego_pose
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    w = World(make_config(town="Town03", num_bicycles=12, num_pedestrians=30))
    w.reset(seed=4)
    rig = SensorRig(SensorConfig())
    total = 0.0
    for _ in range(3):
        for _ in range(12):
            w.step(np.array([0.5, 0.0, 0.0]), w.default_rsu_message())
        inst = candidate_boxes(w)["instance"]
        reqs = [(s, ego_pose(w) @ s.T_parent_body(), 1.0, inst) for s in rig.ego_cameras]
        a, b = _both(monkeypatch, lambda reqs=reqs: [x.tobytes() for x in
                                                     fan.unoccluded_pixels_many(rig.scene(w), reqs)])
        assert a == b
        total += sum(np.frombuffer(x).sum() for x in a)
    assert total > 100


def test_kernel_signal_codes_match_signals():
    from v2xbench.envs.v2x_intersection.traffic import jit_vehicles as jit_traffic
    from v2xbench.envs.v2x_intersection.traffic import signals

    ours = (jit_traffic._GREEN, jit_traffic._RED, jit_traffic._YELLOW, jit_traffic._NO_SIGNAL)
    assert ours == (signals.GREEN, signals.RED, signals.YELLOW, signals.NO_SIGNAL)


def test_bicycle_step_scalar_matches_numpy():
    from v2xbench.envs.v2x_intersection.core.dynamics import (
        VehicleParams,
        bicycle_step,
        bicycle_step_scalar,
    )

    p = VehicleParams()
    rng = np.random.default_rng(4)
    for _ in range(2000):
        x, y = rng.uniform(-500, 500, 2)
        yaw = rng.uniform(-4, 4)
        v = float(rng.choice([0.0, 24.99, 25.0, rng.uniform(0, 25)]))
        th, st, br = rng.uniform(0, 1), rng.uniform(-1, 1), float(rng.choice([0.0, 1.0, rng.uniform(0, 1)]))
        want = bicycle_step(np.float64(x), np.float64(y), np.float64(yaw), np.float64(v), th, st, br, p, 0.1)
        got = bicycle_step_scalar(x, y, yaw, v, th, st, br, p.max_accel, p.max_brake, p.drag, p.max_speed,
                                  p.max_steer, p.wheelbase, 0.1)
        assert np.array(got).tobytes() == np.array(want, np.float64).tobytes()


def test_expert_travel_time_kernel_matches_numpy(monkeypatch):
    """``junction.travel_time`` (accelerating, braking, standing, capped, zero distances) on both
    paths: the same float64 bytes, arrays and scalars."""
    from v2xbench.agents.expert import junction

    rng = np.random.default_rng(0)
    n = 20000
    d, v = rng.uniform(-5, 100, n), rng.uniform(-1, 20, n)
    a, vmax = rng.uniform(-5, 5, n), rng.uniform(0, 25, n)
    d[::7], d[::11], v[::5], v[::13] = 0.0, -0.0, 0.0, 0.04
    a[::3], a[::17], a[::19] = 0.0, 1e-3, -1e-3
    cases = [(d, v, a, vmax), (d[:50], 3.0, a[:50], 14.0), (40.0, 2.5, 1.2, 10.0), (12.0, 8.0, -4.0, 8.0),
             (d[:30], v[:30], np.float64(1.5), vmax[:30]),  # the kernel's direct path (junction._flat_args)
             (d[:30], np.float64(2.0), a[:30], 9),  # an int: broadcast as before
             (d[:30].astype(np.float32), v[:30], a[:30], 14.0)]
    for args in cases:
        x = junction.travel_time(*args)
        with monkeypatch.context() as m:
            m.setattr(junction, "HAVE_JIT", False)
            y = junction.travel_time(*args)
        assert x.shape == y.shape and x.tobytes() == y.tobytes()
    x = junction.travel_time(*cases[0])
    assert np.isinf(x).any() and (x == 0).any() and ((x > 0) & np.isfinite(x)).any()


def test_occupied_kernel_matches_numpy(monkeypatch):
    """``traffic.occupied`` on both paths, with actors placed exactly on the radius."""
    from v2xbench.envs.v2x_intersection.core.actors import ActorTable
    from v2xbench.envs.v2x_intersection.traffic import vehicles as traffic

    rng = np.random.default_rng(5)
    for _ in range(200):
        n = int(rng.integers(1, 40))
        t = ActorTable.empty(n)
        t.pos[:] = rng.uniform(-20, 20, (n, 2))
        t.active[:] = rng.random(n) < 0.7
        xy = rng.uniform(-20, 20, 2)
        radius = float(np.sqrt(np.add.reduce((t.pos[0] - xy) ** 2))) if rng.random() < 0.3 else rng.uniform(0, 15)
        got = traffic.occupied(t, xy, radius)
        with monkeypatch.context() as m:
            m.setattr(traffic, "HAVE_JIT", False)
            assert traffic.occupied(t, xy, radius) == got


@pytest.mark.parametrize("town", ["Town01", "Town03"])
def test_sight_fraction_kernel_matches_numpy(monkeypatch, town):
    """The V2X scenarios' sight-line test (``scenarios.v2x.sight_blocked``) on both paths: one eye
    and five, with and without a placed vehicle, targets near buildings and in the open."""
    from v2xbench.envs.v2x_intersection.scenarios import v2x
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    w = World(make_config(town=town))
    rng = np.random.default_rng(1)
    sb = w.static_boxes
    fractions = []
    for k in range(300):
        centre = sb[rng.integers(len(sb)), :2] + rng.uniform(-25, 25, 2)
        eyes = np.concatenate([centre + rng.uniform(-40, 40, (1 if k % 2 else 5, 2)),
                               np.full((1 if k % 2 else 5, 1), 1.6)], 1)
        targets = np.concatenate([centre + rng.uniform(-3, 3, (6, 2)), rng.uniform(0.3, 1.5, (6, 1))], 1)
        extra = [] if k % 3 == 0 else [(*(centre + rng.uniform(-15, 15, 2)), 8.0, 2.5, rng.uniform(-3, 3), 3.5)]
        got = v2x.sight_blocked(w, eyes, targets, extra)
        with monkeypatch.context() as m:
            m.setattr(v2x, "HAVE_JIT", False)
            want = v2x.sight_blocked(w, eyes, targets, extra)
        assert got == want, k
        fractions.append(got)
    assert 0.0 in fractions and 1.0 in fractions and len(set(fractions)) > 5
