"""Train/serve parity of the cooperative baselines' ego inputs (UniV2X: camera, CoDriving: LiDAR).

An episode of a tiny collected data set is replayed tick for tick through the evaluation env
(``collectors.eval_env.EvalEnv``: sensors mode, the method's own roadside policy speaking through
the channel) with the episode's recorded executed controls: the world is deterministic given its
seed and the controls, so the replay's ego poses equal the recorded ones exactly (checked first).
At every tick the closed-loop driver's inputs are then compared with the data set's sample of the
same tick (``UniV2XFrames`` / ``CoDrivingFrames``), with tiny randomly initialised models.

What the replay shows, and what these tests pin:

- camera images after ``model_images``, intrinsics, ``cam_to_frame``, the ego LiDAR points,
  ``command``, ``ego_speed`` and ``route_points`` are the data set's, bit for bit (geometry up to
  float32 rounding); ``E_{r->e}`` from ``v2x_info`` (float32) equals the calibration's to 1e-4 m;
- the message is the roadside's of the previous tick (``latency_ticks = 1``) with its float16
  rounding, so the ego half plans exactly as on the data set's batch fed that message;
- UniV2X's samples pair the ego's tick t with the roadside's tick t - 1 (``msg_latency_ticks``,
  default 1) and no message at an episode's first tick, as closed loop delivers them (until
  2026-11-28 they paired it with the same tick: every closed-loop message was one tick older
  than any trained on; measured then: the waypoints moved 0.01 m median, 0.19 m at most);
- CoDriving's roadside rebuilds the ego's route rows for its request (``request.route_ahead``)
  with the env's route-progress rule (the furthest route point within 3 m, ``EventMonitor``), so
  they are the observation's rows that training builds the request from (until 2026-11-28 it
  anchored on the nearest route point: 2-3 points, 2-3.5 m, behind).
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from v2xbench.agents.aurora.cqaf import rsu_to_ego
from v2xbench.agents.aurora.data import collate
from v2xbench.agents.aurora.rsu_agent import to_wire
from v2xbench.agents.baselines.common.policy import planning_inputs
from v2xbench.collectors import jobs as J
from v2xbench.collectors.dataset.loader import V2XDataset
from v2xbench.envs.v2x_intersection.core.geometry import world_to_local_2d

from tests import baselines_common as bc

torch.set_num_threads(1)
EPISODE = 0  # train_000_s0 of the tiny suite: a unit serves the ego from tick 0 (ControlLoss)
E_ATOL = 1e-4  # m: v2x_info's rsu_x / rsu_y are float32 (ulp 7.6e-6 m below 64 m)
F16 = dict(rtol=2.0 ** -10, atol=1e-4)  # one float16 ulp: messages are float16 on the wire


class ReplayAgent:
    """Drives the recorded executed controls and keeps every observation it gets."""

    obs_mode, privileged = "sensors", False

    def __init__(self, controls: np.ndarray, sensors: dict, floats: int, roadside) -> None:
        self.controls, self.sensors, self.rsu_policy = controls, sensors, roadside
        self.channel = {"max_payload_floats": int(floats)}
        self.obs: list[dict] = []
        self.route_info: dict = {}

    def reset(self, route_info: dict) -> None:
        self.obs, self.route_info = [], route_info

    def act(self, obs: dict) -> np.ndarray:
        self.obs.append(copy.deepcopy(obs))
        return self.controls[min(len(self.obs) - 1, len(self.controls) - 1)]


class RecordingRoadside:
    """The method's roadside policy, keeping the unit observations it was asked about."""

    def __init__(self, policy) -> None:
        self.policy, self.seen = policy, []

    def reset(self, route_info: dict) -> None:
        self.policy.reset(route_info)

    def act(self, rsu_obs: dict):
        self.seen.append(copy.deepcopy(rsu_obs))
        return self.policy.act(rsu_obs)


def replay(data: Path, sensors: dict, floats: int, roadside,
           tmp: Path) -> tuple[ReplayAgent, np.ndarray]:
    """``(agent, ego poses (T, 3) of the replay)``: episode :data:`EPISODE` of ``data`` driven
    through ``EvalEnv`` with its recorded executed controls; the recorded poses must match."""
    from v2xbench.collectors.eval_env import EvalEnv

    man = json.loads((data / "manifest.json").read_text())
    ds = V2XDataset(data, "all", keys=["control", "ego_pose"])
    meta, rec = ds.meta[EPISODE], ds.shard(EPISODE)
    agent = ReplayAgent(rec["control"].numpy(), sensors, floats, roadside)
    job = J.Job(ds.episodes[EPISODE], int(meta["route_index"]), int(meta["seed_index"]))
    env = EvalEnv(man["config"]["suite"], tmp, agent=lambda: agent, jobs=[job],
                  config=man["config"]["env"])
    try:
        td, w, poses = env.reset(), env.world, []
        for t in range(len(agent.controls)):
            poses.append([w.table.pos[0, 0], w.table.pos[0, 1], w.table.yaw[0]])
            if t + 1 < len(agent.controls):
                td["action"] = td["agent_action"]
                td = env.step(td)["next"]
    finally:
        env.close()
    poses = np.asarray(poses, np.float64)
    assert len(agent.obs) == len(poses)
    assert np.array_equal(poses, rec["ego_pose"].numpy()), "the replay left the recorded episode"
    return agent, poses


# ------------------------------------------------------------------------------------ UniV2X
@pytest.fixture(scope="module")
def univ2x(tiny_dataset, tmp_path_factory):
    """``(model, cfg, driver, data-set samples, observations)`` of the replayed episode."""
    from v2xbench.agents.baselines.univ2x.config import UniV2XConfig
    from v2xbench.agents.baselines.univ2x.data import UniV2XFrames
    from v2xbench.agents.baselines.univ2x.model import UniV2X
    from v2xbench.agents.baselines.univ2x.policy import UniV2XDriver, UniV2XRoadside

    torch.manual_seed(0)
    cfg = UniV2XConfig.for_scale("tiny")
    model = UniV2X(cfg).eval()
    ds = UniV2XFrames(tiny_dataset, "all", cfg)
    size = ds.recorded_size  # 32 x 16: resized to the model's 64 x 32 on both sides
    agent, _ = replay(tiny_dataset, {"camera_size": size, "camera_images": ("rgb",)},
                      cfg.message_floats(), UniV2XRoadside(model.rsu, cfg, size),
                      tmp_path_factory.mktemp("univ2x_replay"))
    off = int(ds.ego.ds.offsets[EPISODE])
    samples = [ds[off + t] for t in range(len(agent.obs))]
    return model, cfg, UniV2XDriver(model.ego, cfg, size), samples, agent.obs


def test_univ2x_closed_loop_ego_inputs_equal_the_data_sets(univ2x):
    from v2xbench.agents.aurora.data import model_images
    from v2xbench.envs.v2x_intersection.sensors import EGO_CAMERA_NAMES

    model, cfg, driver, samples, observations = univ2x
    assert not bool(samples[0]["has_rsu"]), "no message before the unit's first one arrives"
    assert all(bool(s["has_rsu"]) for s in samples[1:]), "the episode should have a unit throughout"
    with torch.no_grad():
        for t, (obs, s) in enumerate(zip(observations, samples)):
            rgb = torch.stack([torch.as_tensor(obs["cameras"][n]["rgb"])
                               for n in EGO_CAMERA_NAMES])
            assert torch.equal(model_images(rgb, tuple(cfg.image_size)), s["ego/images"]), t
            assert torch.equal(driver.intrinsics[0], s["ego/intrinsics"])
            assert torch.allclose(driver.cam_to_frame[0], s["ego/cam_to_frame"], atol=1e-6)
            p = planning_inputs(obs, cfg)
            assert int(p["command"][0]) == int(s["command"]), t
            assert float(p["ego_speed"][0]) == float(s["ego_speed"]), t
            assert torch.equal(p["route_points"][0], s["route_points"]), t
            msg, e, has = driver._message(obs)
            if t == 0:  # nothing received yet: the roadside's first message arrives at tick 1
                assert not has
                continue
            assert has and torch.allclose(e[0], s["rsu_to_ego"], atol=E_ATOL), t
            prev, _, _ = model.message(collate([s]))  # sensed at t - 1 (latency_ticks = 1)
            for k, v in msg.items():
                assert torch.allclose(v.float(), prev[k].float(), **F16), (t, k)
            wps, _ = driver.plan(obs)
            want = model.ego(collate([s]), prev, s["rsu_to_ego"][None], torch.tensor([True]))
            assert np.allclose(wps, want["waypoints"][0].numpy(), atol=1e-5), t


def test_univ2x_samples_carry_the_roadside_inputs_of_the_channels_latency(univ2x, tiny_dataset):
    import dataclasses

    from v2xbench.agents.baselines.univ2x.data import UniV2XFrames

    _, cfg, _, samples, _ = univ2x
    assert cfg.msg_latency_ticks == 1
    same = UniV2XFrames(tiny_dataset, "all", dataclasses.replace(cfg, msg_latency_ticks=0))
    off = int(same.ego.ds.offsets[EPISODE])
    changed = 0
    for t in range(1, len(samples)):
        before, now = same[off + t - 1], same[off + t]
        for k in ("rsu/images", "rsu/intrinsics", "rsu/cam_to_frame", "rsu/det_boxes",
                  "rsu/det_mask"):
            assert torch.equal(samples[t][k], before[k]), (t, k)  # the unit's tick t - 1
        assert torch.equal(samples[t]["ego/images"], now["ego/images"]), t  # the ego's tick t
        changed += not torch.equal(now["rsu/images"], before["rsu/images"])
    assert changed > 0  # the roadside view moves: the latency matters
    assert bool(same[off]["has_rsu"]) and not bool(samples[0]["has_rsu"])
    # every episode's first tick, not only the data set's: no message yet
    lagged = UniV2XFrames(tiny_dataset, "all", cfg)
    starts = [int(o) for o in lagged.ego.ds.offsets[:-1]]
    assert len(starts) > 1
    assert not any(bool(lagged[i]["has_rsu"]) for i in starts)
    assert all(bool(lagged[i + 1]["has_rsu"]) == bool(same[i]["has_rsu"]) for i in starts)


# ---------------------------------------------------------------------------------- CoDriving
@pytest.fixture(scope="module")
def codriving(tmp_path_factory):
    """``(model, cfg, driver, samples, observations, request rows, unit observations, data
    folder)`` of the replayed episode of the tiny LiDAR data set (``samples``: message age 0); ``request rows[t]`` are the ego-frame route rows
    the closed-loop roadside built its request from at tick ``t`` (as
    :class:`CoDrivingRoadside` does, from the unit observation ``t``)."""
    from v2xbench.agents.baselines.codriving.config import CoDrivingConfig
    from v2xbench.agents.baselines.codriving.data import CoDrivingFrames
    from v2xbench.agents.baselines.codriving.model import CoDriving
    from v2xbench.agents.baselines.codriving.policy import (
        CoDrivingDriver,
        CoDrivingRoadside,
        ego_pose_of,
    )
    from v2xbench.agents.baselines.codriving.request import route_ahead

    data = bc.collect_lidar(tmp_path_factory.mktemp("codriving_lidar"))
    torch.manual_seed(0)
    cfg = CoDrivingConfig.for_scale("tiny")
    model = CoDriving(cfg).eval()
    with torch.no_grad():
        model.rsu.confidence[-1].bias.fill_(5.0)  # confident everywhere: the request chooses
    scale = json.loads((data / "manifest.json").read_text())["config"]["lidar_scale"]
    roadside = RecordingRoadside(CoDrivingRoadside(model.rsu, cfg, scale))
    agent, _ = replay(data, {"camera_images": (), "lidar_scale": scale}, cfg.message_floats(),
                      roadside, tmp_path_factory.mktemp("codriving_replay"))
    ds = CoDrivingFrames(data, "all", cfg, delay=0)
    off = int(ds.ds.offsets[EPISODE])
    samples = [ds[off + t] for t in range(len(agent.obs))]
    rows, progress = [], 0
    for i, rsu_obs in enumerate(roadside.seen):  # one per step: ticks 0 .. T - 2
        t_world_ego, _ = ego_pose_of(rsu_obs)
        xy = t_world_ego[:2, 3]  # as the policy: the first call sees the env before its step
        world, progress = route_ahead(agent.route_info["route_points"], xy, progress, cfg,
                                      advance=i > 0)
        yaw = math.atan2(t_world_ego[1, 0], t_world_ego[0, 0])
        rows.append(torch.from_numpy(world_to_local_2d(world, xy, yaw).astype(np.float32)))
    return model, cfg, CoDrivingDriver(model.ego, cfg, scale), samples, agent.obs, rows, \
        roadside.seen, data


def test_codriving_closed_loop_ego_inputs_equal_the_data_sets(codriving):
    from v2xbench.agents.baselines.codriving.policy import ego_pose_of
    from v2xbench.agents.baselines.codriving.request import request_map
    from v2xbench.agents.baselines.v2x_vit.data import lidar_points

    model, cfg, driver, samples, observations, rows, seen, _ = codriving
    assert all(bool(s["has_rsu"]) for s in samples), "the episode should have a unit throughout"
    sent_any = 0
    with torch.no_grad():
        for t, (obs, s) in enumerate(zip(observations, samples)):
            pts, mask = lidar_points(obs["lidar"]["points"], int(obs["lidar"]["count"]),
                                     driver.t_ego_lidar)
            assert torch.equal(mask, s["ego/point_mask"]), t
            assert torch.allclose(pts[mask], s["ego/points"][mask], atol=1e-5), t
            p = planning_inputs(obs, cfg)
            assert int(p["command"][0]) == int(s["command"]), t
            assert float(p["ego_speed"][0]) == float(s["ego_speed"]), t
            assert torch.equal(p["route_points"][0], s["route_points"]), t
            received, sent, e = driver._message(obs)
            if t == 0:  # the first message arrives at tick 1
                assert not sent.any()
                continue
            assert torch.allclose(e[0], s["rsu_to_ego"], atol=E_ATOL), t
            # the roadside of tick t - 1 (the data set's points) given the request it built then
            prev = samples[t - 1]
            e_req = rsu_to_ego(*ego_pose_of(seen[t - 1]))
            r = model.rsu(prev["rsu/points"][None], prev["rsu/point_mask"][None],
                          request_map(rows[t - 1][None], e_req[None], cfg))
            want = to_wire({"features": r["features"]})["features"] * r["sent"][:, None]
            assert torch.equal(sent, r["sent"]), t
            assert torch.allclose(received, want, **F16), t
            sent_any += int(sent.sum())
            wps, _ = driver.plan(obs)
            ref = model.ego(collate([s]), received, sent, s["rsu_to_ego"][None])
            assert np.allclose(wps, ref["waypoints"][0].numpy(), atol=1e-5), t
    assert sent_any > 0, "the roadside sent no cell: nothing was compared"


def test_codriving_roadside_requests_the_cells_training_requests(codriving):
    _, _, _, samples, _, rows, _, _ = codriving
    with torch.no_grad():
        for t, r in enumerate(rows):
            assert torch.allclose(r, samples[t]["route"], atol=1e-3), t


def test_codriving_training_samples_carry_the_message_closed_loop_delivers(codriving):
    """The training samples (message ages drawn from ``msg_latency_ticks`` = 1 to
    ``train_max_delay`` = 1 at ``tiny``) pair tick t with the roadside LiDAR of tick t - 1, the
    one closed loop's message at t was made from (the test above), and no message at tick 0
    (closed loop's first message arrives at tick 1)."""
    from v2xbench.agents.baselines.codriving.data import CoDrivingFrames

    _, cfg, _, samples, observations, _, _, data = codriving
    assert (cfg.msg_latency_ticks, cfg.train_max_delay) == (1, 1)
    train = CoDrivingFrames(data, "all", cfg, delay=None)
    off = int(train.ds.offsets[EPISODE])
    assert not bool(train[off]["has_rsu"])
    for t in range(1, len(observations)):
        s = train[off + t]
        assert bool(s["has_rsu"]) and int(s["age"]) == 1, t
        assert torch.equal(s["rsu/point_mask"], samples[t - 1]["rsu/point_mask"]), t
        assert torch.equal(s["rsu/points"], samples[t - 1]["rsu/points"]), t
