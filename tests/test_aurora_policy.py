"""AURORA in closed loop (issue #33 items 1 and 7): the roadside unit's message over the V2X
channel, the whole system's gradients and files, and the TensorDict policy (tiny scale)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from v2xbench.agents.aurora.calib import frame_camera_tensors, rig_calib, spec_calib
from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.cqaf import rsu_to_ego
from v2xbench.agents.aurora.language import AuroraLM, add_lora, build_lm
from v2xbench.agents.aurora.planner_losses import PlanningCriterion
from v2xbench.agents.aurora.policy import IN_KEYS, policy_module
from v2xbench.agents.aurora.prompt import template_texts
from v2xbench.agents.aurora.route_input import planner_route_path, planner_route_points
from v2xbench.agents.aurora.rsu_agent import (
    HEADER_FLOATS,
    AuroraRoadside,
    deserialize_message,
    message_floats,
    received_pose,
    serialize_message,
)
from v2xbench.agents.aurora.system import AuroraSystem
from v2xbench.agents.aurora.tokenizer import train_tokenizer
from v2xbench.agents.aurora.trainer import load_weights, save_checkpoint
from v2xbench.collectors.roadside import RoadsideRunner
from v2xbench.envs.v2x_intersection.api.observations import ego_observation
from v2xbench.envs.v2x_intersection.sensors import SensorRig
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.v2x.wire import HEADER_SIZE

CFG = AuroraConfig.for_scale("tiny")
CAM = (32, 16)  # the env's camera size in these tests (the model resizes to 128 x 64)


@pytest.fixture(scope="module")
def tok():
    return train_tokenizer(template_texts() * 3, CFG.lm_vocab)


def _system(tok, seed: int = 0, fusion: bool = True) -> AuroraSystem:
    torch.manual_seed(seed)
    lm = AuroraLM(add_lora(build_lm(CFG, tok), CFG), tok, CFG.lm_width)
    return AuroraSystem(CFG, lm, fusion)


def _world(**kw) -> World:
    cfg = dict(town="Town05", obs_mode="sensors", camera_images=("rgb",), camera_size=CAM,
               num_vehicles=4, num_parked=2, num_pedestrians=2, num_bicycles=0,
               max_payload_floats=message_floats(CFG))
    w = World(make_config(**{**cfg, **kw}))
    w.reset(seed=3)
    assert w.active_rsu[0] >= 0  # this seed starts next to a roadside unit
    return w


# ---------------------------------------------------------------------- the message
def test_message_round_trip_within_float16(tok):
    roadside = AuroraRoadside(_system(tok).rsu, CFG, CAM)
    w = _world()
    from v2xbench.envs.v2x_intersection.api.observations import rsu_observation

    obs = rsu_observation(w, 0)
    msg = roadside.message(obs)
    payload = roadside.act(obs)
    assert payload.dtype == np.float32 and payload.shape == (message_floats(CFG),)
    assert np.array_equal(payload, payload.astype(np.float16).astype(np.float32))
    back = deserialize_message(payload, CFG)
    for k, v in back.items():
        if v.dtype.is_floating_point:
            ref = msg[k].float()
            tol = 1e-3 * ref.abs() + 1e-4  # float16: 11 bits of mantissa
            assert bool(((v - ref).abs() <= tol).all()), k
    k = min(CFG.cqaf_det_topk, CFG.num_det_queries)
    assert back["det_queries"].shape == (1, k, CFG.dec_width) and bool(back["det_mask"].all())
    with pytest.raises(ValueError, match="not an AURORA roadside message"):
        deserialize_message(np.zeros(20, np.float32), CFG)
    with pytest.raises(ValueError, match="floats; a message with"):
        deserialize_message(payload[:-1], CFG)
    other = AuroraConfig.for_scale("tiny", dec_width=64)
    with pytest.raises(ValueError, match="D=32"):
        deserialize_message(payload, other)


@pytest.mark.parametrize("latency", [1, 3])
def test_message_over_the_channel(tok, latency):
    """The channel counts serialized size + header, delivers latency ticks later."""
    roadside = AuroraRoadside(_system(tok).rsu, CFG, CAM)
    runner = RoadsideRunner(roadside, "custom:AuroraRoadside")
    w = _world(latency_ticks=latency)
    n = message_floats(CFG)
    sent = []
    for t in range(latency + 2):
        msg = runner.message(w)
        sent.append(msg["payload"][:msg["length"]].copy())
        w.step(np.array([0.0, 0.0, 1.0]), msg)
        obs = ego_observation(w)
        info = obs["v2x_info"]
        if t + 1 < latency:
            assert info[0] == 0.0  # nothing yet
        else:
            k = w.tick - latency  # the message sent at tick k arrives at k + latency
            assert info[0] == 1.0 and info[1] == latency and int(info[6]) == n
            assert np.array_equal(obs["v2x_payload"][:n], sent[k])
    stats = w.channel.stats()
    assert stats["messages_sent"] == latency + 2
    assert stats["bytes_sent_total"] == (latency + 2) * (HEADER_SIZE + 2 * n)


def test_lost_message_never_arrives_and_oversized_is_refused(tok):
    roadside = AuroraRoadside(_system(tok).rsu, CFG, CAM)
    runner = RoadsideRunner(roadside, "custom:AuroraRoadside")
    w = _world(loss_prob=1.0)
    for _ in range(4):
        w.step(np.array([0.0, 0.0, 1.0]), runner.message(w))
        assert ego_observation(w)["v2x_info"][0] == 0.0
    assert w.channel.stats()["messages_lost"] == 4
    small = _world(max_payload_floats=message_floats(CFG) - 1)
    with pytest.raises(ValueError, match="exceeds the limit of max_payload_floats"):
        runner.message(small)


def test_spec_calibration_and_received_pose_match_the_rig():
    w = _world()
    for _ in range(5):
        w.step(np.array([0.5, 0.1, 0.0]))
    cal = rig_calib(SensorRig().calibration(w))
    mine = spec_calib((128, 64), cal["T_world_rsu"], int(cal["rsu_unit"]))
    for branch in ("ego", "rsu"):
        for a, b in zip(frame_camera_tensors(cal, branch, (128, 64)),
                        frame_camera_tensors(mine, branch, (128, 64))):
            assert torch.allclose(a, b, atol=1e-5)
    w2 = _world()  # a message in the inbox: its pose in v2x_info is E_{r->e} of the calibration
    w2.step_builtin(np.array([0.5, 0.0, 0.0]))  # the built-in policy's message (any format
    w2.step_builtin(np.array([0.5, 0.0, 0.0]))  # carries the sender's pose in v2x_info)
    info = ego_observation(w2)["v2x_info"]
    assert info[0] == 1.0
    cal2 = rig_calib(SensorRig().calibration(w2))
    e = rsu_to_ego(cal2["T_world_ego"], cal2["T_world_rsu"])
    assert torch.allclose(received_pose(info), e, atol=1e-3)


# ---------------------------------------------------------------------- the system
def _route_rows(b: int, bend: float = 0.0, command: int = 0) -> torch.Tensor:
    """``(b, 20, 3)`` observation-style route rows every 2 m: straight on (``bend`` 0) or
    curving (``bend`` rad per metre, left > 0), with ``command`` in column 2."""
    s = torch.arange(20) * 2.0
    heading = bend * s
    step = torch.stack([torch.cos(heading), torch.sin(heading)], -1) * 2.0
    xy = torch.cat([torch.zeros(1, 2), step[:-1].cumsum(0)])
    rows = torch.cat([xy, torch.full((20, 1), float(command))], -1)
    return rows.expand(b, -1, -1).clone()


def _batch(tok, b: int = 2, with_msg: bool = True) -> dict:
    from v2xbench.agents.aurora.prompt import PLAN_QUESTION, build_prompt

    g = torch.Generator().manual_seed(1)
    w, h = CFG.image_size("ego")
    k, c2f = frame_camera_tensors(spec_calib((128, 64)), "ego", (128, 64))
    kr, c2fr = frame_camera_tensors(spec_calib((128, 64), np.eye(4) + 0.0), "rsu", (128, 64))
    texts = [build_prompt(4.0, 0, torch.eye(4), PLAN_QUESTION, num_det=CFG.num_det_queries,
                          num_map=CFG.num_map_queries, waypoint=True) for _ in range(b)]
    enc = tok(texts, padding=True, return_tensors="pt")
    return {"ego/images": torch.rand(b, 6, 3, h, w, generator=g),
            "ego/intrinsics": k.expand(b, -1, -1, -1),
            "ego/cam_to_frame": c2f.expand(b, -1, -1, -1),
            "rsu/images": torch.rand(b, 1, 3, h, w, generator=g),
            "rsu/intrinsics": kr.expand(b, -1, -1, -1),
            "rsu/cam_to_frame": c2fr.expand(b, -1, -1, -1),
            "has_rsu": torch.tensor([with_msg] * b), "rsu_to_ego": torch.eye(4).expand(b, 4, 4),
            "input_ids": enc["input_ids"], "attention_mask": enc["attention_mask"],
            "command": torch.zeros(b, dtype=torch.long), "plan_mask": torch.ones(b, dtype=bool),
            "route_points": planner_route_points(_route_rows(b), CFG),
            "route_path": planner_route_path(_route_rows(b), CFG),  # plan_frame="route"
            "ego_speed": torch.full((b,), 4.0),
            "expert_waypoints": torch.linspace(0, 10, 16).view(1, 8, 2).expand(b, 8, 2).clone(),
            "map_points": torch.zeros(b, CFG.num_map_queries, CFG.map_points, 2),
            "map_labels": torch.zeros(b, CFG.num_map_queries, dtype=torch.long),
            "map_mask": torch.zeros(b, CFG.num_map_queries, dtype=torch.bool),
            "map_closed": torch.zeros(b, CFG.num_map_queries, dtype=torch.bool),
            "agent_future": torch.zeros(b, 1, CFG.plan_waypoints, 2),
            "agent_future_mask": torch.zeros(b, 1, CFG.plan_waypoints, dtype=torch.bool)}


def test_planner_loss_reaches_the_wp_hidden_state_and_lora(tok):
    system = _system(tok).train()
    system.set_trainable(branches=False, planner=True)
    seen = {}

    def grab(module, args, output):  # the final norm's output = the hidden states at <wp>
        output.retain_grad()
        seen["h"] = output

    norm = system.lm.lm.get_base_model().model.norm
    handle = norm.register_forward_hook(grab)
    out = system(_batch(tok))
    handle.remove()
    loss, _ = PlanningCriterion(CFG)(out["plan"], _batch(tok))
    loss.backward()
    wp = _batch(tok)["input_ids"] == system.lm.wp_id
    grad = seen["h"].grad
    assert float(grad[wp].abs().sum()) > 0  # the planner's loss reaches h_wp ...
    assert float(grad[~wp].abs().sum()) == 0  # ... and only through <wp>
    lora = [p for n, p in system.named_parameters() if "lora_" in n]
    assert lora and any(p.grad is not None and float(p.grad.abs().sum()) > 0 for p in lora)
    assert all(p.grad is None for p in system.ego.parameters())  # frozen branches
    assert not system.ego.training  # and kept in eval mode
    route = list(system.planner.route.parameters())  # the route encoder learns from it too
    assert route and all(p.grad is not None for p in route)
    assert float(sum(p.grad.abs().sum() for p in route)) > 0


def test_checkpoint_and_adapters_round_trip(tok, tmp_path):
    a = _system(tok, seed=0).eval()
    with torch.no_grad():
        for p in a.parameters():  # LoRA's B starts at zero: make the adapters matter
            p.add_(0.01 * torch.randn_like(p))
    save_checkpoint(a, tmp_path / "ck.safetensors")
    b = _system(tok, seed=1).eval()
    load_weights(b, tmp_path / "ck.safetensors")
    batch = _batch(tok)
    with torch.no_grad():
        wa, wb = a(batch, plan=True)["plan"]["waypoints"], b(batch, plan=True)["plan"]["waypoints"]
    assert torch.equal(wa, wb)
    a.lm.save(tmp_path / "adapter")  # peft's own files + the bridge
    assert (tmp_path / "adapter" / "adapter_config.json").is_file()
    c = AuroraLM.load(build_lm(CFG, tok), tok, CFG.lm_width, tmp_path / "adapter")
    sa = {k: v for k, v in a.lm.state_dict().items() if "lora_" in k or "bridge" in k}
    sc = c.state_dict()
    assert sa and all(torch.equal(v, sc[k]) for k, v in sa.items())


def test_policy_module_uses_the_message_only_with_fusion(tok):
    from tensordict import TensorDict

    rng = np.random.default_rng(0)
    system = _system(tok).eval()
    n = message_floats(CFG)
    msg = AuroraRoadside(system.rsu, CFG, (128, 64)).message(
        {"camera": {"rgb": rng.integers(0, 255, (64, 128, 3), dtype=np.uint8)},
         "calibration": np.stack([np.eye(4), np.eye(4)]).astype(np.float32)})
    payload = np.zeros(n + 4, np.float32)
    payload[:n] = serialize_message(msg)
    info = np.array([1, 1, 0, 20.0, -5.0, 1.0, n, 1], np.float32)  # received, raw payload

    images = {k[1]: torch.from_numpy(rng.integers(0, 255, (1, 64, 128, 3), dtype=np.uint8))
              for k in IN_KEYS[:6]}

    def td(info, payload):
        cams = {name: {"rgb": img.clone()} for name, img in images.items()}
        return TensorDict({"cameras": cams, "ego": torch.zeros(1, 9),
                           "route": torch.zeros(1, 20, 3),
                           "v2x_info": torch.from_numpy(info)[None],
                           "v2x_payload": torch.from_numpy(payload)[None]}, batch_size=[1])

    pol = policy_module(system, tok, (128, 64))
    assert pol.in_keys == IN_KEYS and pol.out_keys == ["waypoints", "target_speed"]
    x = td(info, payload)
    with torch.no_grad():
        a = pol(x.clone())["waypoints"]
        silent = info.copy()
        silent[0] = 0.0
        b = pol(td(silent, payload))["waypoints"]
    assert a.shape == (1, CFG.plan_waypoints, 2) and not torch.equal(a, b)
    system.fusion = False  # No Fusion: the same payload changes nothing
    with torch.no_grad():
        c = pol(x.clone())["waypoints"]
        d = pol(td(silent, payload))["waypoints"]
    assert torch.equal(c, d)
    system.fusion = True
    with pytest.raises(ValueError, match=f"max_payload_floats={n}"):
        pol(td(info, payload[:HEADER_FLOATS + 10]))


def test_inference_path_gives_the_training_path_waypoints(tok):
    """Without gradients the LM runs without its vocabulary head: the same ``h_wp``."""
    system = _system(tok).eval()
    batch = _batch(tok)
    with torch.no_grad():
        fast = system(batch, plan=True)
    with torch.enable_grad():
        full = system(batch, plan=True)
    assert torch.allclose(fast["h_wp"], full["h_wp"], atol=1e-5)
    assert torch.allclose(fast["plan"]["waypoints"], full["plan"]["waypoints"], atol=1e-5)


def test_policy_gives_the_planner_the_route_points_of_its_observation(tok):
    """The policy turns ``route`` into the planner's input with the function the training
    samples use, and the waypoints follow the route (same cameras, speed and command)."""
    from tensordict import TensorDict

    rng = np.random.default_rng(1)
    system = _system(tok).eval()
    with torch.no_grad():  # an untrained encoder's effect is small: make it visible
        system.planner.route[-1].weight.mul_(50.0)
    seen, paths = [], []
    planner_forward = system.planner.forward

    def spy(*args, **kw):
        seen.append(kw["route"].clone())
        paths.append(kw["path"].clone())  # the route-frame planner's polyline (default)
        return planner_forward(*args, **kw)

    system.planner.forward = spy
    images = {k[1]: torch.from_numpy(rng.integers(0, 255, (1, 64, 128, 3), dtype=np.uint8))
              for k in IN_KEYS[:6]}

    def td(route):
        return TensorDict({"cameras": {n: {"rgb": im.clone()} for n, im in images.items()},
                           "ego": torch.zeros(1, 9), "route": route,
                           "v2x_info": torch.zeros(1, 8), "v2x_payload": torch.zeros(1, 600)},
                          batch_size=[1])

    pol = policy_module(system, tok, (128, 64))
    straight, left = _route_rows(1, command=3), _route_rows(1, bend=0.08, command=3)
    with torch.no_grad():
        a = pol(td(straight))["waypoints"]
        b = pol(td(left))["waypoints"]
        a2 = pol(td(straight))["waypoints"]
    assert torch.equal(seen[0], planner_route_points(straight, CFG))
    assert torch.equal(seen[1], planner_route_points(left, CFG))
    assert seen[0].shape == (1, CFG.plan_route_points, 2)
    assert torch.equal(paths[1], planner_route_path(left, CFG))
    assert torch.equal(a, a2) and float((a - b).abs().max()) > 1e-3


def test_policy_prompt_says_the_speed_or_unknown(tok, monkeypatch):
    """``say_speed``: the planning prompt carries the observed speed, or "unknown" (the form
    of a planner trained with speed dropout 1, docs/aurora.md "A sixth run")."""
    from tensordict import TensorDict
    from v2xbench.agents.aurora import prompt as prompt_mod

    seen = []
    real = prompt_mod.build_prompt

    def spy(speed, *args, **kw):
        seen.append(speed)
        return real(speed, *args, **kw)

    monkeypatch.setattr(prompt_mod, "build_prompt", spy)
    rng = np.random.default_rng(1)
    system = _system(tok).eval()
    ego = torch.zeros(1, 9)
    ego[0, 0] = 3.25  # SPEED
    x = TensorDict({"cameras": {k[1]: {"rgb": torch.from_numpy(rng.integers(
        0, 255, (1, 64, 128, 3), dtype=np.uint8))} for k in IN_KEYS[:6]},
        "ego": ego, "route": torch.zeros(1, 20, 3), "v2x_info": torch.zeros(1, 8),
        "v2x_payload": torch.zeros(1, message_floats(CFG))}, batch_size=[1])
    with torch.no_grad():
        policy_module(system, tok, (128, 64))(x.clone())
        policy_module(system, tok, (128, 64), say_speed=False)(x.clone())
    assert seen == [pytest.approx(3.25), None]
