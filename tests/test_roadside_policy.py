"""Custom roadside policies (issue 30, item 1): a pluggable message format and ``eval`` running an
agent's own roadside policy.

- a raw payload (format 1) reaches the ego's ``v2x_payload`` exactly, after the latency, with its
  length, age and sender pose in ``v2x_info``, and leaves ``v2x_objects`` empty (before, only
  object lists were decoded and a 20-float payload became two bogus objects); an object list
  (format 0, or no format key) still decodes as before; numba and NumPy agree;
- an oversized message raises naming ``max_payload_floats``, never cut;
- ``v2xbench eval`` runs an agent whose ``rsu_policy`` is an object in the roadside unit's place
  (in process, in workers, isolated), records its BPS from the bytes the channel counted and names
  it ``custom:<ClassName>`` in the summary and the fingerprint;
- the grown observation stays inside its space: PettingZoo (objects, bev, sensors), Gymnasium and
  the batched TorchRL env.
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from v2xbench.collectors.eval_env import EvalEnv, copy_policy
from v2xbench.collectors.evaluate import evaluate
from v2xbench.collectors.roadside import to_message
from v2xbench.envs.v2x_intersection import parallel_env
from v2xbench.envs.v2x_intersection.api import observations as O
from v2xbench.envs.v2x_intersection.api.torchrl_env import V2XTorchEnv
from v2xbench.envs.v2x_intersection.core.geometry import (
    local_to_world_2d,
    world_to_local_2d,
    wrap_angle,
)
from v2xbench.envs.v2x_intersection.v2x.channel import ChannelConfig, message_space
from v2xbench.envs.v2x_intersection.v2x.jit_wire import decode_kernel
from v2xbench.envs.v2x_intersection.v2x.wire import (
    FORMAT_OBJECTS,
    FORMAT_RAW,
    HEADER_SIZE,
    NUM_OBJECT_FIELDS,
    decode_frame,
    decode_message,
    encode_message,
    pack_objects,
)

from tests.test_evaluate import CFG, suite  # noqa: F401  (fixture)

SMALL = dict(num_vehicles=8, num_parked=4, num_pedestrians=4, num_bicycles=1, route_length=150.0)
INFO = {name: k for k, name in enumerate(O.V2X_INFO_FEATURES)}
GO = np.array([0.3, 0.0, 0.0], np.float32)
VALUES = [1.5, -2.25, 7.0]  # exact in float16

ROADSIDE_AGENT = '''
import numpy as np


class ThreeFloats:
    """Sends [1.5, -2.25, unit id] every tick a unit serves the ego."""

    def reset(self, route_info):
        self.route_points = len(route_info["route_points"])

    def act(self, rsu_obs):
        return np.array([1.5, -2.25, rsu_obs["unit"][0]], np.float32)


class Oversized:
    """One float more than a message holds."""

    def act(self, rsu_obs):
        return np.ones(321)


class Listener:
    """Drives on; fails its route if a received message is not ThreeFloats's raw payload."""

    obs_mode, privileged = "objects", False

    def __init__(self, roadside="three"):
        self.rsu_policy = ThreeFloats() if roadside == "three" else Oversized()
        self.received = 0

    def reset(self, route_info):
        pass

    def act(self, obs):
        info, raw = obs["v2x_info"], obs["v2x_payload"]
        if info[0] > 0:
            length, fmt, n_objects = int(info[6]), int(info[7]), info[2]
            if (length, fmt, n_objects) != (3, 1, 0) or raw[:2].tolist() != [1.5, -2.25]:
                raise AssertionError(f"unexpected message: info {info}, payload {raw[:4]}")
            if obs["v2x_objects"].any():
                raise AssertionError("a raw payload was decoded as objects")
            self.received += 1
        return np.array([0.4, 0.0, 0.0], np.float32)
'''


def _served_env(**cfg):
    """A PettingZoo env reset on a seed whose route starts with a unit serving the ego."""
    env = parallel_env(**{**SMALL, **cfg})
    for seed in range(30):
        obs, _ = env.reset(seed=seed)
        if env.world.active_rsu[0] >= 0:
            return env, obs
    pytest.skip("no active unit at the start of seeds 0..29")


def _raw_message(values, m: int, fmt: int = FORMAT_RAW) -> dict:
    payload = np.zeros(m, np.float32)
    payload[: len(values)] = values
    return {"length": len(values), "payload": payload, "format": fmt}


def _unit_in_ego_frame(w, unit: int) -> np.ndarray:
    x, y, _, yaw = w.rsus.pose[unit]
    t = w.table
    xy = world_to_local_2d(np.array([[x, y]]), t.pos[0], float(t.yaw[0]))[0]
    return np.array([xy[0], xy[1], wrap_angle(yaw - t.yaw[0])])


def _inside(space, obs) -> list[str]:
    return [k for k, s in space.spaces.items() if not s.contains(obs[k])]


# ---------------------------------------------------------------------------- the format


@pytest.mark.parametrize("jit", [True, False], ids=["numba", "numpy"])
def test_raw_payload_reaches_the_ego_after_the_latency(monkeypatch, jit):
    env, _ = _served_env(latency_ticks=2)
    w = env.world
    if not jit:
        monkeypatch.setattr(O, "HAVE_JIT", False)
    m = w.channel_config.max_payload_floats
    sender = int(w.active_rsu[0])
    obs, *_ = env.step({"ego": GO, "rsu": _raw_message(VALUES, m)})
    assert obs["ego"]["v2x_info"][INFO["received"]] == 0  # 1 tick after sending: still in flight
    assert not obs["ego"]["v2x_payload"].any()
    assert w.channel.bytes_sent_total == HEADER_SIZE + 3 * 2 == 22  # 3 float16 + the header
    obs, *_ = env.step({"ego": GO})  # nothing sent on this tick
    e = obs["ego"]
    info = e["v2x_info"]
    assert info[INFO["received"]] == 1 and info[INFO["age_ticks"]] == 2
    assert info[INFO["payload_length"]] == 3 and info[INFO["payload_format"]] == FORMAT_RAW
    assert e["v2x_payload"][:3].tolist() == VALUES and not e["v2x_payload"][3:].any()
    assert info[INFO["num_objects"]] == 0 and not e["v2x_objects"].any()
    np.testing.assert_allclose(info[[INFO["rsu_x"], INFO["rsu_y"], INFO["rsu_yaw"]]],
                               _unit_in_ego_frame(w, sender), rtol=1e-5, atol=1e-3)
    assert _inside(env.observation_space("ego"), e) == []
    assert w.channel.bytes_sent_total == 22


def test_raw_payload_is_never_decoded_as_objects():
    """20 floats are two objects' worth: as a raw payload they stay out of ``v2x_objects``; sent
    as an object list (format 0) the same floats are decoded."""
    values = np.arange(1, 21, dtype=np.float32)
    got = {}
    for fmt in (FORMAT_RAW, FORMAT_OBJECTS):
        env, _ = _served_env()
        obs, *_ = env.step({"ego": GO, "rsu": _raw_message(values, 320, fmt)})
        got[fmt] = obs["ego"]
    raw, objects = got[FORMAT_RAW], got[FORMAT_OBJECTS]
    assert np.array_equal(raw["v2x_payload"][:20], values) and not raw["v2x_objects"].any()
    assert raw["v2x_info"][INFO["num_objects"]] == 0
    assert np.array_equal(objects["v2x_payload"], raw["v2x_payload"])  # the same floats
    assert objects["v2x_info"][INFO["num_objects"]] == 2 and objects["v2x_objects"][:2, 0].all()


def test_float32_payload_arrives_exactly_at_full_length():
    env, _ = _served_env(encoding="float32")
    m = env.world.channel_config.max_payload_floats
    values = np.random.default_rng(0).uniform(-1e4, 1e4, m).astype(np.float32)
    obs, *_ = env.step({"ego": GO, "rsu": _raw_message(values, m)})
    e = obs["ego"]
    assert e["v2x_payload"].tobytes() == values.tobytes()
    assert e["v2x_info"][INFO["payload_length"]] == m
    assert env.world.channel.bytes_sent_total == HEADER_SIZE + 4 * m


@pytest.mark.parametrize("with_key", [True, False], ids=["format_0", "no_format_key"])
def test_object_list_payload_still_decodes(with_key):
    env, _ = _served_env()
    w = env.world
    unit = int(w.active_rsu[0])
    rows = np.array([[2, 5.0, -3.0, 0.5, 0.6, 0.6, 1.7, 1.0, 0.0, 11],
                     [0, 20.0, 4.0, -1.0, 4.5, 1.9, 1.5, 0.0, 2.0, 12]], np.float32)
    length, payload = pack_objects(rows, w.channel_config.max_payload_floats)
    msg = {"length": length, "payload": payload}
    if with_key:
        msg["format"] = FORMAT_OBJECTS
    obs, *_ = env.step({"ego": GO, "rsu": msg})
    e = obs["ego"]
    info = e["v2x_info"]
    assert info[INFO["num_objects"]] == 2 and info[INFO["payload_format"]] == FORMAT_OBJECTS
    assert info[INFO["payload_length"]] == 2 * NUM_OBJECT_FIELDS
    sent = payload[:length].astype(np.float16).astype(np.float32)
    assert np.array_equal(e["v2x_payload"][:length], sent)
    # each object moved from the unit's ground frame to the ego's
    x, y, _, yaw = w.rsus.pose[unit]
    t = w.table
    rsu_xy = sent.reshape(2, -1)[:, 1:3].astype(np.float64)
    world_xy = local_to_world_2d(rsu_xy, np.array([x, y]), yaw)
    ego_xy = world_to_local_2d(world_xy, t.pos[0], float(t.yaw[0]))
    v = e["v2x_objects"]
    assert v[:2, 0].tolist() == [1.0, 1.0] and not v[2:].any()
    assert v[:2, 1].tolist() == [2.0, 0.0]  # class ids
    np.testing.assert_allclose(v[:2, 2:4], ego_xy, atol=1e-3)


def test_numba_and_numpy_agree_on_raw_and_object_payloads(monkeypatch):
    env, _ = _served_env()
    w = env.world
    m = w.channel_config.max_payload_floats
    for msg in (_raw_message(VALUES * 7, m), _raw_message(np.arange(30.0), m, FORMAT_OBJECTS)):
        env.step({"ego": GO, "rsu": msg})
        monkeypatch.setattr(O, "HAVE_JIT", True)
        a = O.ego_observation(w)
        monkeypatch.setattr(O, "HAVE_JIT", False)
        b = O.ego_observation(w)
        for k in ("v2x_objects", "v2x_info", "v2x_payload"):
            assert a[k].tobytes() == b[k].tobytes(), k


def test_wire_carries_the_format_in_the_header():
    p = np.array(VALUES, np.float32)
    plain = encode_message(3, 9, p)
    assert encode_message(3, 9, p, fmt=FORMAT_OBJECTS) == plain  # object lists: bytes as before
    assert plain[3] == 1  # the float16 code alone
    for enc, code in (("float16", 1), ("float32", 2)):
        raw = encode_message(3, 9, p, enc, fmt=FORMAT_RAW)
        assert raw[3] == code | FORMAT_RAW << 4 and len(raw) == len(encode_message(3, 9, p, enc))
        sender, tick, payload, fmt = decode_frame(raw)
        assert (sender, tick, payload.tolist(), fmt) == (3, 9, VALUES, FORMAT_RAW)
        assert decode_message(raw)[2].tolist() == VALUES
        ok, s2, t2, p2 = decode_kernel(np.frombuffer(raw, np.uint8), HEADER_SIZE)
        assert ok and (s2, t2, p2.tolist()) == (3, 9, VALUES)
    bad = bytearray(plain)
    bad[3] = 1 | 5 << 4  # an unknown format (the CRC does not cover it being wrong here)
    with pytest.raises(ValueError, match="unknown payload format 5"):
        decode_frame(bytes(bad))
    assert not decode_kernel(np.frombuffer(bytes(bad), np.uint8), HEADER_SIZE)[0]
    with pytest.raises(ValueError, match="format"):
        encode_message(3, 9, p, fmt=7)
    assert message_space(ChannelConfig(max_payload_floats=16))["format"].n == 2


# ---------------------------------------------------------------------------- the limit


def test_oversized_messages_raise_naming_the_limit():
    env, _ = _served_env()
    m = env.world.channel_config.max_payload_floats
    msg = _raw_message(VALUES, m)
    msg["length"] = m + 1
    with pytest.raises(ValueError, match=f"oversized message.*max_payload_floats={m}"):
        env.step({"ego": GO, "rsu": msg})
    cfg = ChannelConfig(max_payload_floats=8)
    with pytest.raises(ValueError, match=r"roadside policy P: oversized message of 9 floats.*"
                                         r"max_payload_floats=8"):
        to_message(np.ones(9), cfg, "P")
    full = to_message(np.arange(8.0), cfg, "P")  # at the limit: all of it, as a raw payload
    assert full["length"] == 8 and full["format"] == FORMAT_RAW
    assert full["payload"].tolist() == list(range(8))
    assert to_message(None, cfg, "P") is None and to_message([], cfg, "P") is None
    with pytest.raises(ValueError, match="holds 2 floats"):
        to_message({"length": 3, "payload": np.ones(2)}, cfg, "P")
    with pytest.raises(ValueError, match="bytes"):
        to_message(b"\x00\x01", cfg, "P")
    with pytest.raises(ValueError, match="1-D"):
        to_message(np.ones((2, 2)), cfg, "P")
    with pytest.raises(ValueError, match="NaN"):
        to_message([1.0, np.nan], cfg, "P")
    with pytest.raises(ValueError, match="out of range"):
        to_message([2e4], cfg, "P")


# ---------------------------------------------------------------------------- eval


@pytest.fixture(scope="module")
def agent_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("roadside") / "roadside_agent.py"
    path.write_text(ROADSIDE_AGENT)
    return path


def _results(out: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted((out / "routes").glob("*.json"))]


def test_eval_runs_the_agents_roadside_policy(suite, agent_file, tmp_path, capsys):  # noqa: F811
    out = tmp_path / "listener"
    spec = f"{agent_file}:Listener"
    summary = evaluate(spec, suite, out=out, config=CFG, progress=False)
    assert summary["rsu_policy"] == "custom:ThreeFloats"
    assert "roadside policy `custom:ThreeFloats`" in (out / "summary.md").read_text()
    results = _results(out)
    assert len(results) == 3 and all(r["error"] is None for r in results), results[0]["error"]
    for r in results:
        sent, secs = r["record"]["bytes_sent"], r["record"]["sim_seconds"]
        assert sent > 0 and sent % 22 == 0  # 3-float messages of 22 bytes each
        assert r["metrics"]["bps"] == pytest.approx(sent / secs)
    assert summary["metrics"]["bps"] > 0
    run = json.loads((out / "run.json").read_text())
    assert run["rsu_policy"] == "custom:ThreeFloats"
    road = run["fingerprint"]["components"]["roadside"]
    assert road["policy"] == "custom:ThreeFloats" and list(road["code"]) == ["roadside_agent.py"]
    with pytest.raises(ValueError, match="conflicts with the agent's own roadside policy"):
        evaluate(spec, suite, out=tmp_path / "conflict", config={**CFG, "rsu_policy": "none"},
                 progress=False)


@pytest.mark.parametrize("isolate", [False, True], ids=["in_process", "isolated"])
def test_eval_env_sends_one_message_per_served_tick(suite, agent_file, tmp_path,  # noqa: F811
                                                    isolate):
    env = EvalEnv(suite, tmp_path / "env", agent=f"{agent_file}:Listener", max_routes=1,
                  config=CFG, isolate=isolate)
    assert env.config.rsu_policy == "none"  # the built-in policy stays off
    policy = env._roadside.policy  # ThreeFloats, or the proxy of the one in the agent's process
    calls = []
    act = policy.act
    policy.act = lambda rsu_obs: calls.append(rsu_obs["unit"][0]) or act(rsu_obs)
    env.rollout(CFG["max_steps"] + 5, policy=copy_policy(), break_when_any_done=True)
    env.close()
    (r,) = _results(tmp_path / "env")
    assert r["error"] is None
    assert r["record"]["bytes_sent"] == 22 * len(calls) > 0  # one 22-byte message per call
    if not isolate:
        assert env.agent.received > 0 and env.agent.rsu_policy.route_points > 0  # reset ran


def test_oversized_roadside_message_fails_the_route(suite, agent_file, tmp_path):  # noqa: F811
    env = EvalEnv(suite, tmp_path / "big", agent=f"{agent_file}:Listener", max_routes=1,
                  config=CFG, agent_config={"roadside": "oversized"})
    env.rollout(5, policy=copy_policy(), break_when_any_done=True)
    env.close()
    (r,) = _results(tmp_path / "big")
    assert r["ended_by"] == "error" and "max_payload_floats=320" in r["error"]
    assert "roadside policy custom:Oversized" in r["error"]
    assert r["record"]["bytes_sent"] == 0  # nothing was cut and sent


def test_bad_rsu_policy_is_refused_up_front(tmp_path):
    from v2xbench.agents.interface import complete_agent

    class Named:
        rsu_policy = "broadcast"

        def reset(self, info): ...
        def act(self, obs): ...

    class NoAct(Named):
        rsu_policy = object()

    with pytest.raises(ValueError, match="rsu_policy='broadcast' must be one of"):
        complete_agent(Named(), "named", False)
    with pytest.raises(ValueError, match="without an act"):
        complete_agent(NoAct(), "noact", False)


# ---------------------------------------------------------------------------- spaces


@pytest.mark.parametrize("mode", ["objects", "bev", "sensors"])
def test_pettingzoo_payload_in_every_mode_stays_in_its_space(mode):
    env, obs = _served_env(obs_mode=mode)
    m = env.world.channel_config.max_payload_floats
    space = env.observation_space("ego")
    assert space["v2x_payload"].shape == (m,) and space["v2x_info"].shape == (8,)
    assert _inside(space, obs["ego"]) == []
    for _ in range(3):
        obs, *_ = env.step({"ego": GO, "rsu": _raw_message(VALUES, m)})
        assert _inside(space, obs["ego"]) == []
    assert obs["ego"]["v2x_payload"][:3].tolist() == VALUES


def test_gym_and_batched_torchrl_carry_the_builtin_payload():
    torch.set_num_threads(1)
    env = gym.make("v2xbench:V2XIntersection-v0")
    seen = 0
    for seed in range(10):
        obs, _ = env.reset(seed=seed)
        for _ in range(5):
            obs, *_ = env.step(GO)
            assert env.observation_space.contains(obs)
            info = obs["v2x_info"]
            n = int(info[INFO["payload_length"]])
            assert n == int(info[INFO["num_objects"]]) * NUM_OBJECT_FIELDS  # share_objects
            assert info[INFO["payload_format"]] == FORMAT_OBJECTS
            assert not obs["v2x_payload"][n:].any()
            seen += n > 0
        if seen:
            break
    assert seen > 0
    tenv = V2XTorchEnv(num_worlds=2, info=False)
    space = O.ego_space(tenv.config)
    assert tenv.observation_spec["v2x_payload"].shape == (2, space["v2x_payload"].shape[0])
    tenv.set_seed(0)
    td = tenv.rollout(4)
    payload, info = td["next", "v2x_payload"].numpy(), td["next", "v2x_info"].numpy()
    assert (np.abs(payload) <= space["v2x_payload"].high[0]).all()
    assert all(space["v2x_info"].contains(i) for i in info.reshape(-1, info.shape[-1]))
    assert (info[..., INFO["payload_length"]] > 0).any()
