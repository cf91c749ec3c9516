"""ControlLoss perturbs the control the ego applies (CARLA's noise windows), for any driver, the
same way on every stepping path, reproducibly per seed; the expert still completes its routes.

The window check itself (applied control differs from the command inside a window, equals it
outside, and the heading follows the applied steer) is
``test_scenarios_obstacles.check_control_loss``.
"""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.agents.expert import Expert
from v2xbench.agents.route_follower import RouteFollower
from v2xbench.envs.v2x_intersection.api.observations import ego_observation
from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT
from v2xbench.envs.v2x_intersection.evaluation import infractions as inf
from v2xbench.envs.v2x_intersection.evaluation.episode import time_budget_steps
from v2xbench.envs.v2x_intersection.scenarios import build_episode
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached
from v2xbench.envs.v2x_intersection.town import get_town

SMALL = {"num_vehicles": 6, "num_parked": 4, "num_pedestrians": 4, "num_bicycles": 1}
BAD = (
    inf.COLLISION_PEDESTRIAN,
    inf.COLLISION_VEHICLE,
    inf.COLLISION_STATIC,
    inf.RED_LIGHT,
    inf.STOP_SIGN,
)


def _episode(seed: int, town: str = "Town02", params: dict | None = None):
    route, scs = build_episode("ControlLoss", get_town(town), np.random.default_rng(seed), params)
    return route, scs


def _run(seed: int, town: str = "Town02", ticks: int = 300, params: dict | None = None) -> dict:
    """Drive a ControlLoss episode with the route follower; per tick the command, the applied
    control and the ego pose."""
    world = World(make_config(town=town, **SMALL))
    route, scs = _episode(seed, town, params)
    world.reset(seed=seed, route=route, scenarios=scs)
    driver, log = RouteFollower(), {"command": [], "applied": [], "pose": []}
    for _ in range(ticks):
        world.step(driver.act(ego_observation(world)), world.default_rsu_message())
        log["command"].append(world.last_control.copy())
        log["applied"].append(world.applied_control.copy())
        log["pose"].append(np.array([*world.table.pos[0], world.table.yaw[0]]))
        if scs[0].passed:
            break
    out = {k: np.array(v) for k, v in log.items()}
    out["sc"] = scs[0]
    return out


def test_same_seed_same_perturbations_another_seed_others():
    """The points, the signs and every tick's noise come from the seed: two runs of one seed
    perturb the same ticks by the same amounts (bit for bit); another seed places the points
    elsewhere."""
    a, b, c = _run(4), _run(4), _run(5)
    noise = a["applied"] - a["command"]
    assert np.count_nonzero(noise[:, 1]) >= 6  # several ticks in windows
    np.testing.assert_array_equal(a["applied"], b["applied"])
    np.testing.assert_array_equal(a["command"], b["command"])
    np.testing.assert_array_equal(a["sc"].points, b["sc"].points)
    np.testing.assert_array_equal(a["sc"].steer_sign, b["sc"].steer_sign)
    assert not np.allclose(a["sc"].offsets, c["sc"].offsets)


def test_perturbation_moves_the_ego_and_zero_noise_does_not():
    """With the noise set to zero the applied control is the command at every tick; with CARLA's
    noise the same seed's ego takes another path after the first window."""
    zero = {"throttle_mean": 0.0, "throttle_std": 0.0, "steer_mean": 0.0, "steer_std": 0.0}
    calm, noisy = _run(4, params=zero), _run(4)
    np.testing.assert_array_equal(calm["applied"], calm["command"])
    first = int(np.flatnonzero(np.any(noisy["applied"] != noisy["command"], axis=1))[0])
    np.testing.assert_array_equal(calm["pose"][:first], noisy["pose"][:first])
    n = min(len(calm["pose"]), len(noisy["pose"]))
    assert np.abs(calm["pose"][first:n, 2] - noisy["pose"][first:n, 2]).max() > 1e-3


def test_bad_window_is_rejected():
    with pytest.raises(ValueError, match="window"):
        _episode(4, params={"window": 10.0})


@pytest.mark.parametrize("suite,nth", [("test50", 0), ("test50", 1), ("train", 0)])
def test_expert_completes_control_loss_routes(suite, nth):
    """The expert (which the noise perturbs like any agent) completes the suites' ControlLoss
    routes (the ``nth`` of each suite) without an infraction, after passing through all three
    windows."""
    spec = [r for r in load_suite_cached(suite)
            if any(s.type == "ControlLoss" for s in r.scenarios)][nth]
    world = World(make_config(town=spec.town))
    world.reset(seed=0, spec=spec)
    sc = next(s for s in world.scenarios if s.name == "ControlLoss")
    expert = Expert()
    expert.reset({})
    expert.bind(world)
    visited = set()
    for _ in range(time_budget_steps(world)):
        armed = sc.triggered
        k = sc.window_at(world.table.pos[0]) if armed else -1  # the window of this tick's move
        world.step(expert.act(None), world.default_rsu_message())
        if k >= 0:
            assert world.applied_control[1] != world.last_control[1]
            visited.add(k)
        if world.is_route_complete():
            break
    assert world.is_route_complete() and sc.passed and visited == {0, 1, 2}
    counts = world.monitor.counts
    assert not any(counts[c] for c in BAD), {
        inf.EVENT_NAMES[i]: int(n) for i, n in enumerate(counts) if n
    }


def _table_bytes(t) -> dict:
    import dataclasses

    return {f.name: getattr(t, f.name).tobytes() for f in dataclasses.fields(t)}


@pytest.mark.skipif(not HAVE_JIT, reason="numba not installed")
def test_numpy_numba_and_batched_worlds_apply_the_same_perturbation(monkeypatch):
    """One ControlLoss episode stepped on the NumPy path, on the numba path of a single world and
    in a two-world ``WorldBatch`` (its batched traffic kernel): the same applied controls and the
    same actor tables, bit for bit, every tick; the noise did act."""
    from v2xbench.envs.v2x_intersection.api import observations
    from v2xbench.envs.v2x_intersection.api.batch import WorldBatch
    from v2xbench.envs.v2x_intersection.evaluation import infractions, physics
    from v2xbench.envs.v2x_intersection.sim import world as world_module
    from v2xbench.envs.v2x_intersection.town import model
    from v2xbench.envs.v2x_intersection.traffic import pedestrians, signals
    from v2xbench.envs.v2x_intersection.traffic import vehicles as traffic
    from v2xbench.envs.v2x_intersection.v2x import rsu

    modules = (
        traffic,
        pedestrians,
        world_module,
        rsu,
        model,
        observations,
        signals,
        infractions,
        physics,
    )
    cfg = make_config(town="Town02", **SMALL)
    seed = 4
    ref = World(cfg)
    ref.reset(seed=seed, **dict(zip(("route", "scenarios"), _episode(seed))))
    one = World(cfg)
    one.reset(seed=seed, **dict(zip(("route", "scenarios"), _episode(seed))))
    batch = WorldBatch(2, config=cfg)
    for i in range(2):
        route, scs = _episode(seed)
        batch.reset_world(i, seed, route=route, scenarios=scs)
    drivers = [RouteFollower() for _ in range(4)]
    worlds = [ref, one, *batch.worlds]
    noisy = 0
    for k in range(600):
        acts = []
        for jit, w, d in zip((False, True, True, True), worlds, drivers):
            with monkeypatch.context() as m:
                for mod in modules:
                    m.setattr(mod, "HAVE_JIT", jit)
                acts.append(d.act(ego_observation(w)))
                if w is ref or w is one:
                    w.step_builtin(acts[-1])
        batch.step(np.stack(acts[2:]))
        for w in worlds[1:]:
            np.testing.assert_array_equal(
                w.applied_control, ref.applied_control, err_msg=f"tick {k}"
            )
            assert _table_bytes(w.table) == _table_bytes(ref.table), (
                f"tick {k}: actor tables differ"
            )
        noisy += int(np.any(ref.applied_control != ref.last_control))
        if ref.scenarios[0].passed:
            break
    assert noisy >= 6 and ref.scenarios[0].passed


def test_observed_yaw_rate_follows_the_applied_steer():
    """Inside a noise window the observation's yaw rate is that of the applied (perturbed) steer,
    not of the agent's command."""
    world = World(make_config(town="Town02", **SMALL))
    route, scs = _episode(4)
    world.reset(seed=4, route=route, scenarios=scs)
    driver, p = RouteFollower(), world.params
    seen = 0
    for _ in range(400):
        world.step(driver.act(ego_observation(world)), world.default_rsu_message())
        cmd, app = world.last_control, world.applied_control
        v = float(world.table.speed[0])
        obs = ego_observation(world)["ego"]
        want = v * np.tan(app[1] * p.max_steer) / p.wheelbase
        assert obs[2] == pytest.approx(want, rel=1e-5, abs=1e-6)
        if abs(app[1] - cmd[1]) > 0.01 and v > 1.0:
            seen += 1
            assert obs[2] != pytest.approx(v * np.tan(cmd[1] * p.max_steer) / p.wheelbase, rel=1e-3)
        if scs[0].passed:
            break
    assert seen > 0, "the ego never drove through a noise window"
