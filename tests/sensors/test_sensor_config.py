"""One sensor configuration (issue 30, item 5): ``camera_size``, ``camera_images`` and
``lidar_scale`` are ``EnvConfig`` fields accepted by ``gym.make``, ``parallel_env``,
``V2XTorchEnv``, ``v2xbench eval --set`` and ``v2xbench collect`` (recorded in the data set's
manifest), checked at evaluation time against what an agent declares it needs; images not asked
for are neither rendered nor in the space. Small cameras keep it fast.
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from v2xbench.agents.interface import declared_sensors, load_agent
from v2xbench.collectors.agent_sensors import apply_agent_sensors
from v2xbench.collectors.dataset.collect import CollectConfig, collect
from v2xbench.collectors.dataset.shards import load_shard
from v2xbench.collectors.eval_env import EvalEnv, copy_policy
from v2xbench.collectors.eval_summary import sensor_settings
from v2xbench.collectors.evaluate import evaluate
from v2xbench.envs.v2x_intersection import parallel_env
from v2xbench.envs.v2x_intersection.api.torchrl_env import V2XTorchEnv
from v2xbench.envs.v2x_intersection.sensors import (
    EGO_CAMERA_NAMES,
    SensorConfig,
    SensorRig,
    camera,
    shading,
)
from v2xbench.envs.v2x_intersection.sim.config import (
    CAMERA_IMAGES,
    SENSOR_FIELDS,
    make_config,
    sensor_config,
)
from v2xbench.envs.v2x_intersection.sim.world import World

import v2xbench  # noqa: F401  (registers the gym id)
from tests.test_evaluate import CFG, suite  # noqa: F401  (fixture)
from v2xbench.cli import main

torch.set_num_threads(1)
SMALL = dict(num_vehicles=3, num_parked=2, num_pedestrians=2, num_bicycles=0, route_length=80.0)
GYM_ID = "v2xbench:V2XIntersection-v0"

SENSOR_AGENT = '''
import numpy as np


class CamDriver:
    """Needs small RGB cameras and a sparse LiDAR; checks that it gets exactly those."""
    obs_mode, rsu_policy = "sensors", "none"
    sensors = {"camera_size": (32, 16), "camera_images": ("rgb",), "lidar_scale": 0.25}

    def reset(self, route_info):
        self.steps = 0

    def act(self, obs):
        for name, images in obs["cameras"].items():
            assert set(images) == {"rgb"}, (name, sorted(images))
            assert images["rgb"].shape == (16, 32, 3), images["rgb"].shape
        assert obs["lidar"]["points"].shape == (8 * 90, 6)
        self.steps += 1
        return np.array([0.5, 0.0, 0.0], np.float32)
'''


def _shapes(tree) -> dict:
    """``{path: shape}`` of a nested dict of arrays or of a Gymnasium ``Dict`` space."""
    items = tree.spaces.items() if hasattr(tree, "spaces") else tree.items()
    out = {}
    for k, v in items:
        if isinstance(v, dict) or hasattr(v, "spaces"):
            out.update({f"{k}/{p}": s for p, s in _shapes(v).items()})
        else:
            out[k] = tuple(v.shape)
    return out


# ------------------------------------------------------------------------------- the env side
def test_gym_make_takes_the_camera_size_and_the_space_matches():
    env = gym.make(GYM_ID, obs_mode="sensors", camera_size=(64, 32), lidar_scale=0.25, **SMALL)
    obs, _ = env.reset(seed=0)
    assert set(obs["cameras"]) == set(EGO_CAMERA_NAMES)
    for name in EGO_CAMERA_NAMES:
        cam, space = obs["cameras"][name], env.observation_space["cameras"][name]
        assert set(cam) == set(space.spaces) == set(CAMERA_IMAGES)
        assert cam["rgb"].shape == space["rgb"].shape == (32, 64, 3)
        assert cam["depth"].shape == cam["semantic"].shape == cam["instance"].shape == (32, 64)
    lidar_space = env.observation_space["lidar"]["points"]
    assert obs["lidar"]["points"].shape == lidar_space.shape == (720, 6)
    obs, *_ = env.step(np.array([0.5, 0.0, 0.0], np.float32))
    assert env.observation_space.contains(obs)
    assert _shapes(obs) == _shapes(env.observation_space)
    # JSON and CLI spellings of the same configuration give the same config
    assert make_config(camera_size=[64, 32]) == make_config(camera_size="64x32") == \
        make_config(camera_size=(np.int64(64), 32))


def test_unrequested_images_are_absent_and_not_rendered(monkeypatch):
    env = gym.make(GYM_ID, obs_mode="sensors", camera_size=(32, 16),
                   camera_images=["depth", "semantic"], lidar_scale=0.25, **SMALL)
    calls = []
    real = camera.shade
    monkeypatch.setattr(camera, "shade",
                        lambda *a, **k: calls.append(k.get("rgb")) or real(*a, **k))
    obs, _ = env.reset(seed=0)
    assert env.unwrapped.config.camera_images == ("depth", "semantic")
    for name in EGO_CAMERA_NAMES:
        assert set(obs["cameras"][name]) == {"depth", "semantic"}
        assert set(env.observation_space["cameras"][name].spaces) == {"depth", "semantic"}
    assert env.observation_space.contains(obs)
    assert calls and not any(calls)  # shaded for the semantic ids, without colours
    calls.clear()
    depth = gym.make(GYM_ID, obs_mode="sensors", camera_size=(32, 16), camera_images=["depth"],
                     lidar_scale=0.25, **SMALL)
    obs, _ = depth.reset(seed=0)
    assert calls == [] and set(obs["cameras"]["cam_front"]) == {"depth"}  # no shading at all
    lidar_only = gym.make(GYM_ID, obs_mode="sensors", camera_images=[], lidar_scale=0.25, **SMALL)
    obs, _ = lidar_only.reset(seed=0)
    assert "cameras" not in obs and "cameras" not in lidar_only.observation_space.spaces
    assert calls == [] and lidar_only.observation_space.contains(obs)


@pytest.mark.parametrize("jit", [True, False])
def test_a_subset_of_images_equals_the_full_render(monkeypatch, jit):
    """The ids rendered without colours (both paths) are the full render's bytes."""
    if not jit:
        monkeypatch.setattr(camera, "HAVE_JIT", False)
        monkeypatch.setattr(shading, "HAVE_JIT", False)
    w = World(make_config(town="Town01", **SMALL))
    w.reset(seed=1)
    for _ in range(5):
        w.step(np.array([0.4, 0.0, 0.0]), w.default_rsu_message())
    kw = dict(camera_size=(32, 16), rsu_camera_size=(32, 16), calibration=False,
              groundtruth=False)
    full = SensorRig(SensorConfig(**kw)).capture(w)["cameras"]
    for images in (("semantic", "instance"), ("depth",), ("rgb",)):
        part = SensorRig(SensorConfig(images=images, **kw)).capture(w)["cameras"]
        assert part.keys() == full.keys()
        for name, cam in part.items():
            assert set(cam) == set(images)
            for k in images:
                assert cam[k].tobytes() == full[name][k].tobytes(), (name, k)


def test_parallel_env_and_torchrl_env_take_the_same_fields():
    kw = dict(obs_mode="sensors", camera_size=[48, 24], camera_images=["rgb", "instance"],
              lidar_scale=0.25, **SMALL)
    pe = parallel_env(**kw)
    obs, _ = pe.reset(seed=0)
    assert set(obs["ego"]["cameras"]["cam_back"]) == {"rgb", "instance"}
    assert obs["ego"]["cameras"]["cam_back"]["rgb"].shape == (24, 48, 3)
    assert set(obs["rsu"]["camera"]) == {"rgb", "instance"}
    assert obs["rsu"]["camera"]["instance"].shape == (24, 48)
    for agent, o in obs.items():
        assert pe.observation_space(agent).contains(o), agent
    assert pe.state_space.contains(pe.state())
    env = V2XTorchEnv(num_worlds=2, info=False, **kw)
    td = env.reset()
    assert set(td["cameras", "cam_front"].keys()) == {"rgb", "instance"}
    assert td["cameras", "cam_front", "rgb"].shape == (2, 24, 48, 3)
    assert env.observation_spec["cameras", "cam_front", "rgb"].shape == (2, 24, 48, 3)
    assert td["lidar", "points"].shape == (2, 720, 6)
    td["action"] = torch.tensor([[0.5, 0.0, 0.0]] * 2)
    out = env.step(td)["next"]
    assert set(out["cameras", "cam_back"].keys()) == {"rgb", "instance"}


def test_bad_values_raise_naming_the_field():
    for kw, needle in ((dict(camera_size=(-64, 32)), r"camera_size: width: -64 is outside"),
                       (dict(camera_size=(64, 0)), r"camera_size: height: 0 is outside"),
                       (dict(camera_size=(64,)), r"camera_size: expected \(width, height\)"),
                       (dict(camera_size="128by64"), r"camera_size: expected"),
                       (dict(camera_images=["rgb", "lidar"]), r"camera_images: image: 'lidar'"),
                       (dict(camera_images=["rbg"]), r"did you mean 'rgb'"),
                       (dict(camera_images=["rgb", "rgb"]), r"camera_images: .* image twice"),
                       (dict(lidar_scale=0.0), r"lidar_scale: 0.0 is outside \(0, 2\]"),
                       (dict(lidar_scale=-1), r"lidar_scale: -1 is outside")):
        with pytest.raises(ValueError, match=needle):
            make_config(**kw)
        with pytest.raises(ValueError, match=needle):
            gym.make(GYM_ID, obs_mode="sensors", **kw)
    with pytest.raises(ValueError, match="camera_images"):
        V2XTorchEnv(num_worlds=1, obs_mode="sensors", camera_images=["radar"])
    with pytest.raises(ValueError, match="lidar_scale"):
        parallel_env(obs_mode="sensors", lidar_scale=9.0)
    assert SENSOR_FIELDS == ("camera_size", "camera_images", "lidar_scale")


# ------------------------------------------------------------------------------- evaluation
def _agent_file(tmp_path: Path, text: str = SENSOR_AGENT) -> str:
    path = tmp_path / "cam_driver.py"
    path.write_text(text)
    return f"{path}:CamDriver"


def test_eval_configures_the_env_from_the_agents_declaration(suite, tmp_path):  # noqa: F811
    spec = _agent_file(tmp_path)
    cfg = dict(CFG, max_steps=4)
    env = EvalEnv(suite, tmp_path / "out", agent=spec, max_routes=1, config=cfg)
    assert (env.config.camera_size, env.config.camera_images, env.config.lidar_scale) == \
        ((32, 16), ("rgb",), 0.25)
    assert env.overrides["camera_size"] == [32, 16]  # recorded with the run's overrides
    env.rollout(10, policy=copy_policy(), break_when_any_done=True)
    assert env.agent.steps >= 3  # its asserts on every observation held
    assert sensor_settings(env.overrides) == {"camera_images": ["rgb"], "camera_size": [32, 16],
                                              "lidar_scale": 0.25}
    env.close()


def test_eval_refuses_a_set_that_differs_from_the_declaration(
        suite, tmp_path, capsys):  # noqa: F811
    spec = _agent_file(tmp_path)
    out = tmp_path / "refused"
    with pytest.raises(ValueError, match=r"declares sensors camera_size=\[32, 16\].*"
                       r"camera_size=\[64, 32\] \(--set\).*Drop --set camera_size"):
        evaluate(spec, suite, out=out, config=dict(CFG, camera_size=[64, 32]), progress=False)
    assert not (out / "routes").exists()  # refused before any route ran
    args = ["eval", "--agent", spec, "--suite", suite, "--out", str(out), "--quiet",
            "--set", "camera_images=rgb,depth"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "declares sensors camera_images=['rgb']" in err and "['rgb', 'depth']" in err
    bad = ["eval", "--agent", "route_follower", "--suite", suite, "--out", str(out), "--quiet",
           "--set", "camera_size=[-1,5]"]
    assert main(bad) == 2  # refused up front, not in every worker
    assert "--set: config: camera_size: width: -1 is outside" in capsys.readouterr().err
    assert not out.exists()
    # the same values in another spelling agree; undeclared fields stay the user's
    same = apply_agent_sensors({"camera_size": "32x16", "num_vehicles": 3},
                               declared_sensors(load_agent(spec)), spec)
    assert same == {"camera_size": [32, 16], "camera_images": ["rgb"], "lidar_scale": 0.25,
                    "num_vehicles": 3}


def test_an_isolated_agent_reports_its_sensors(tmp_path):
    from v2xbench.collectors.agent_process import IsolatedAgent

    agent = IsolatedAgent(_agent_file(tmp_path))
    try:
        assert declared_sensors(agent) == {"camera_size": [32, 16], "camera_images": ["rgb"],
                                           "lidar_scale": 0.25}
    finally:
        agent.close()


def test_bad_sensor_declarations_are_refused(tmp_path):
    for decl, needle in (('{"camera_size": (-32, 16)}', r"sensors: config: camera_size: width"),
                         ('{"lens": "fisheye"}', r"sensors has unknown key\(s\) \['lens'\]"),
                         ('"rgb"', r"sensors must be a dict")):
        text = SENSOR_AGENT.replace(
            'sensors = {"camera_size": (32, 16), "camera_images": ("rgb",), "lidar_scale": 0.25}',
            f"sensors = {decl}")
        with pytest.raises(ValueError, match=needle):
            load_agent(_agent_file(tmp_path, text))


def test_eval_summary_and_leaderboard_show_the_declared_sensors(suite, tmp_path):  # noqa: F811
    from v2xbench.collectors.leaderboard import build_leaderboard

    out = tmp_path / "run"
    summary = evaluate(_agent_file(tmp_path), suite, out=out, max_routes=1,
                       config=dict(CFG, max_steps=3), progress=False)
    assert summary["n_results"] == 1 and summary["failed"]["error"] == 0
    assert summary["sensors"] == {"camera_images": ["rgb"], "camera_size": [32, 16],
                                  "lidar_scale": 0.25}
    run = json.loads((out / "run.json").read_text())
    assert run["fingerprint"]["components"]["config_overrides"]["camera_size"] == [32, 16]
    res = build_leaderboard([str(out)], tmp_path / "lb", plots=False)
    assert res["rows"][0]["sensors"] == summary["sensors"]
    assert "camera_size=[32, 16]" in Path(res["markdown"]).read_text()


# ------------------------------------------------------------------------------- collection
def test_collect_records_the_sensor_config_that_gym_make_reproduces(tmp_path):
    cfg = CollectConfig(max_routes=1, max_ticks=2, camera_size=(24, 12), lidar_scale=0.25,
                        sensors=("rgb", "semantic", "lidar"), env={"num_vehicles": 2})
    man = collect(cfg, tmp_path, progress=False)
    sc = man["sensor_config"]
    assert sc == {"camera_size": [24, 12], "camera_images": ["rgb", "semantic"],
                  "lidar_scale": 0.25}
    assert json.loads((tmp_path / "manifest.json").read_text())["sensor_config"] == sc
    td = load_shard(tmp_path, next(iter(man["shards"])))
    env = gym.make(GYM_ID, obs_mode="sensors", **sc, **SMALL)
    obs, _ = env.reset(seed=0)
    assert set(obs["cameras"]["cam_front"]) == set(sc["camera_images"])
    for name in EGO_CAMERA_NAMES:
        for image in sc["camera_images"]:
            assert tuple(td["cameras", name, image].shape[1:]) == obs["cameras"][name][image].shape
    assert tuple(td["lidar", "ego", "points"].shape[1:]) == obs["lidar"]["points"].shape
    assert sensor_config(make_config(**sc)) == sc
    # the collect flags are the fields: the same rules, and no second way through --set
    with pytest.raises(ValueError, match=r"CollectConfig: config: lidar_scale: 3.0 is outside"):
        CollectConfig(lidar_scale=3.0)
    with pytest.raises(ValueError, match="camera_size.*--camera-size"):
        CollectConfig(env={"camera_size": [64, 32]})
