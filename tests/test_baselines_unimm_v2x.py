"""UniMM-V2X baseline (issue #34): MoE routing and balance loss, motion targets from the data
set's future frames, the prediction-level fusion, the message's bytes through the channel, bad
input, overfitting two samples, and `v2xbench baselines train unimm_v2x` -> `v2xbench eval`."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch
from v2xbench.agents.baselines.unimm_v2x.config import UniMMV2XConfig
from v2xbench.agents.baselines.unimm_v2x.message import (
    check_message,
    deserialize_message,
    empty_message,
    rsu_message,
    serialize_message,
)
from v2xbench.agents.baselines.unimm_v2x.model import RoadsideNet, UniMMV2X
from v2xbench.agents.baselines.unimm_v2x.moe import MoEFFN, balance_loss
from v2xbench.agents.baselines.unimm_v2x.motion import MotionFusion
from v2xbench.envs.v2x_intersection.v2x.channel import ChannelConfig, validate_message

from tests import baselines_common as bc
from v2xbench.cli import main

torch.set_num_threads(1)
CFG = UniMMV2XConfig.for_scale("tiny")


def test_moe_routes_each_token_to_its_top_k_experts_with_gates_summing_to_one():
    torch.manual_seed(0)
    moe = MoEFFN(8, 16, num_experts=4, top_k=2)
    x = torch.randn(64, 8)
    probs, idx, gates = moe.route(x)
    assert torch.allclose(probs.sum(-1), torch.ones(64), atol=1e-6)  # router weights sum to 1
    assert torch.allclose(gates.sum(-1), torch.ones(64), atol=1e-6)
    assert torch.equal(idx, probs.topk(2, -1).indices)  # the two most probable experts
    y, bal = moe(x)
    # the output of a token is the gated sum of exactly its top-k experts' outputs
    for t in (0, 17, 63):
        want = sum(gates[t, s] * moe.experts[int(idx[t, s])](x[t]) for s in range(2))
        assert torch.allclose(y[t], want, atol=1e-5)
    assert int(moe.last_load.sum()) == 64 * 2
    (y.pow(2).mean() + bal).backward()
    for e, expert in enumerate(moe.experts):  # every expert receives gradient over the batch
        assert expert[0].weight.grad is not None and expert[0].weight.grad.abs().sum() > 0, e
    assert moe.router.weight.grad.abs().sum() > 0
    y2, _ = moe(x, mask=torch.arange(64) < 10)  # padding tokens are not routed: zero output
    assert torch.equal(y2[10:], torch.zeros(54, 8)) and int(moe.last_load.sum()) == 20
    with pytest.raises(ValueError, match="top_k=5"):
        MoEFFN(8, 16, num_experts=4, top_k=5)


def test_balance_loss_is_minimal_for_uniform_routing():
    e, n = 4, 8
    uniform = torch.full((n, e), 1.0 / e)
    spread = torch.arange(n)[:, None] % e  # every expert gets the same load
    assert float(balance_loss(uniform, spread, e)) == pytest.approx(0.0, abs=1e-9)
    skewed = torch.softmax(torch.tensor([[3.0, 0.0, 0.0, 0.0]]).expand(n, -1), -1)
    assert float(balance_loss(skewed, torch.zeros(n, 1, dtype=torch.long), e)) > 0.5
    assert float(balance_loss(uniform, torch.zeros(n, 1, dtype=torch.long), e)) > 0.0
    # gradient descent on the balance loss alone moves a skewed router towards uniform
    torch.manual_seed(0)
    moe = MoEFFN(8, 16, num_experts=e, top_k=1)
    with torch.no_grad():
        moe.router.bias.copy_(torch.tensor([4.0, 0.0, 0.0, 0.0]))
    x = torch.randn(128, 8)
    opt = torch.optim.SGD(moe.router.parameters(), lr=1.0)
    first = None
    for _ in range(100):
        probs, idx, _ = moe.route(x)
        loss = balance_loss(probs, idx, e)
        first = float(loss.detach()) if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 0.2 * first


def test_motion_targets_follow_an_agent_through_the_future_frames(tiny_dataset):
    from v2xbench.agents.baselines.unimm_v2x.data import UniMMV2XFrames

    ds = UniMMV2XFrames(tiny_dataset, "all", CFG, stride=1)
    fid = int(ds.frame_ids[0])
    fut, known = ds.motion_targets(fid)
    e, t = ds.future.locate(fid)
    boxes, ids, mask, pose = ds._frame(e, t)
    assert known.any(), "no agent of the first frame has a known future"
    r, s = (int(v) for v in known.nonzero()[0])
    from v2xbench.agents.aurora.data import in_range

    own = ids[mask & in_range(boxes[:, :3], ds.range)][r]
    b2, ids2, mask2, pose2 = ds._frame(e, t + (s + 1) * 5)  # 0.5 s a step at 10 Hz
    j = int(np.nonzero((ids2 == own) & mask2)[0][0])
    world = pose2 @ np.r_[b2[j, :3], 1.0]  # the same actor, later, through the world frame
    assert np.allclose(fut[r, s].numpy(), (np.linalg.inv(pose) @ world)[:2], atol=1e-3)
    last = len(ds.future) - 1  # the last frame of the last episode: no future at all
    assert not ds.motion_targets(last)[1].any()


def test_prediction_fusion_joins_the_roadside_motion_query_of_the_same_agent():
    torch.manual_seed(0)
    fusion = MotionFusion(CFG)
    q, k, d = CFG.num_queries, CFG.msg_topk, CFG.width
    match = torch.full((1, q), -1)
    match[0, 2] = 4  # ego agent 2 is roadside agent 4
    appended = torch.zeros(1, k, dtype=torch.bool)
    appended[0, 1] = True  # roadside agent 1 was appended at slot q + 1
    partner = fusion.partners(match, appended)
    assert partner[0, 2] == 4 and partner[0, q + 1] == 1 and (partner >= 0).sum() == 2
    mq = torch.randn(1, q + k, d)
    rsu = torch.randn(1, k, d)
    out = fusion(mq, rsu, torch.ones(1, k), partner, torch.eye(4)[None])
    changed = (out - mq).abs().sum(-1)[0] > 0
    assert changed[2] and changed[q + 1] and int(changed.sum()) == 2
    rsu2 = rsu.clone()
    rsu2[0, 4] += 1.0  # only the partner's query reaches agent 2
    out2 = fusion(mq, rsu2, torch.ones(1, k), partner, torch.eye(4)[None])
    diff = (out2 - out).abs().sum(-1)[0] > 0
    assert diff[2] and int(diff.sum()) == 1


def _rsu_payload() -> tuple[np.ndarray, dict]:
    torch.manual_seed(0)
    net = RoadsideNet(CFG).eval()
    k = torch.tensor([[32.0, 0, 32], [0, 32, 16], [0, 0, 1]])[None, None]
    c2f = torch.eye(4)
    c2f[:3, :3] = torch.tensor([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    with torch.no_grad():
        out = net({"images": torch.rand(1, 1, 3, 32, 64), "intrinsics": k,
                   "cam_to_frame": c2f[None, None]})
    return serialize_message(rsu_message(out, CFG)), rsu_message(out, CFG)


def test_message_bytes_are_what_the_channel_counts():
    payload, msg = _rsu_payload()
    f = CFG.message_floats()
    assert payload.shape == (f,) and f == 6 + CFG.msg_topk * (4 + 2 * CFG.width) + 8 * 8
    bc.assert_channel_counts(payload, f)
    back = deserialize_message(payload, CFG)
    for key in ("queries", "motion", "ref", "scores", "occ"):
        assert torch.allclose(back[key], msg[key].to(torch.float16).float(), atol=1e-6), key
    assert not torch.allclose(back["queries"], back["motion"])  # two different levels sent
    with pytest.raises(ValueError, match="oversized"):
        validate_message({"length": f, "payload": payload}, ChannelConfig(max_payload_floats=f - 1))


def test_bad_input_raises_a_clear_error():
    payload, msg = _rsu_payload()
    with pytest.raises(ValueError, match="not a UniMM-V2X roadside message"):
        deserialize_message(np.r_[2025.0, payload[1:]], CFG)  # a UniV2X message
    with pytest.raises(ValueError, match="K=3"):
        deserialize_message(serialize_message({k: v[:, :3] if k != "occ" else v
                                               for k, v in msg.items()}), CFG)
    with pytest.raises(ValueError, match="floats; a message of these sizes"):
        deserialize_message(payload[:-1], CFG)
    bad = dict(empty_message(CFG, 1), motion=torch.zeros(1, CFG.msg_topk, CFG.width + 1))
    with pytest.raises(ValueError, match=r"motion has shape \(1, 6, 33\); expected \(1, 6, 32\)"):
        check_message(bad, CFG)
    model = UniMMV2X(CFG)
    with pytest.raises(ValueError, match="motion has shape"):
        model.ego({}, bad, torch.eye(4)[None], torch.zeros(1, dtype=torch.bool))
    with pytest.raises(ValueError, match="unknown UniMM-V2X scale 'huge'"):
        UniMMV2XConfig.for_scale("huge")
    with pytest.raises(ValueError, match="moe_topk=5 exceeds num_experts=4"):
        UniMMV2XConfig.for_scale("tiny", moe_topk=5)
    with pytest.raises(ValueError, match="max_payload_floats <= 65535"):
        UniMMV2XConfig.for_scale("tiny", msg_topk=16, width=2048, heads=2)
    from v2xbench.agents.baselines.unimm_v2x.policy import UniMMV2XDriver

    driver = UniMMV2XDriver(model.ego, CFG, (32, 16))
    f = CFG.message_floats()
    with pytest.raises(ValueError, match=f"--set max_payload_floats={f}"):
        driver._message({"v2x_payload": np.zeros(f - 1, np.float32), "v2x_info": np.zeros(8)})
    assert main(["baselines", "train", "unimm_v2x", "--data", "/nonexistent", "--out",
                 "/tmp/x", "--scale", "tiny"]) == 2


def test_tiny_model_overfits_two_samples(tiny_dataset):
    from v2xbench.agents.baselines.unimm_v2x.data import UniMMV2XFrames
    from v2xbench.agents.baselines.unimm_v2x.losses import UniMMV2XCriterion

    batch = bc.unit_batch(UniMMV2XFrames(tiny_dataset, "all", CFG, stride=5))
    torch.manual_seed(0)
    losses, history = bc.overfit(UniMMV2X(CFG), UniMMV2XCriterion(CFG), batch)
    motion, parts = [p["motion"] for p in history], history[-1]
    assert parts["rsu_cls"] > 0 and parts["moe"] >= 0
    seen = [m for m in motion if m > 0]  # steps where fused agents matched agents with futures
    assert len(seen) >= 20, motion[::5]  # the motion head is supervised ...
    assert np.mean(seen[-10:]) < 0.5 * np.mean(seen[:10]), seen[::5]  # ... and learns
    assert losses[-1] < 0.5 * losses[0], losses[::10]


def test_cli_trains_resumes_and_drives_a_route(tiny_dataset, tmp_path, capsys):
    from v2xbench.agents.baselines.unimm_v2x.train import load_run

    data, run = tmp_path / "data", tmp_path / "run"
    shutil.copytree(tiny_dataset, data)
    base, log = bc.train_and_resume("unimm_v2x", data, run, capsys)
    assert log[-1]["motion"] >= 0 and log[-1]["moe"] >= 0  # the new loss parts are logged
    assert "unimm_v2x train" in bc.refused_error(base, capsys)
    model, cfg, info = load_run(run)
    assert isinstance(cfg, UniMMV2XConfig) and info["camera_size"] == [32, 16]
    bc.drive_one_route("unimm_v2x", run, tmp_path, cfg.message_floats(), "UniMMV2XRoadside")


def test_shipped_weights_load_and_drive(tmp_path):
    bc.assert_shipped_weights("unimm_v2x", "UniMMV2XRoadside", tmp_path)
