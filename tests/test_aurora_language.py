"""AURORA language model (issue #33): BPE tokenizer, tiny Llama LM, LoRA, fused visual tokens,
the ``<wp>`` hidden state, save / load round trips and the ground-truth-free run-time prompt."""

from __future__ import annotations

import json
import math
import random

import numpy as np
import pytest
import torch
from transformers import LlamaForCausalLM
from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.cqaf import rsu_to_ego
from v2xbench.agents.aurora.language import (
    AuroraLM,
    add_lora,
    build_lm,
    collate_text,
    encode_qa,
    lm_config,
    load_lm,
    save_lm,
)
from v2xbench.agents.aurora.planners import build_planner
from v2xbench.agents.aurora.prompt import (
    RUNTIME_KEYS,
    build_prompt,
    prompt_from_record,
    template_texts,
)
from v2xbench.agents.aurora.tokenizer import (
    DET,
    MAP,
    SPECIAL_TOKENS,
    WP,
    load_tokenizer,
    qa_texts,
    train_tokenizer,
)
from v2xbench.collectors.chat import templates
from v2xbench.envs.v2x_intersection.core.classes import CLASS_NAMES
from v2xbench.envs.v2x_intersection.core.geometry import pose_matrix

torch.set_num_threads(1)

CFG = AuroraConfig.for_scale("tiny")
T_WORLD_EGO = pose_matrix(100.0, 50.0, 0.0, math.pi / 2)
T_WORLD_RSU = pose_matrix(100.0, 80.0, 5.0, math.pi, math.radians(12.0), math.radians(1.0))


def corpus(n: int = 300) -> list[str]:
    """Generated Chat-V2XBench-like strings (questions, answers, run-time prompts)."""
    rng = random.Random(0)
    qs = [q for v in templates.QUESTIONS.values() for q in v if "{" not in q]
    out = template_texts()
    for _ in range(n):
        speed, path = rng.choice(list(templates.SPEED.values())), rng.choice(
            list(templates.PATH.values()))
        cls = rng.choice(list(templates.CLASS.values()))
        out.append(f"{rng.choice(qs)}\nThe ego should {speed} and {path}: a {cls} is "
                   f"{rng.uniform(2, 60):.1f} m ahead, moving at {rng.uniform(0, 15):.1f} m/s.")
    return out


@pytest.fixture(scope="module")
def tok():
    return train_tokenizer(corpus(), CFG.lm_vocab)


def fresh_lm(tok, seed: int = 0):
    torch.manual_seed(seed)
    return build_lm(CFG, tok)


def batch(tok, b: int = 2, seed: int = 0) -> dict[str, torch.Tensor]:
    """Two planning prompts with answers, and random fused tokens."""
    g = torch.Generator().manual_seed(seed)
    e = rsu_to_ego(T_WORLD_EGO, T_WORLD_RSU)
    rows = []
    for i in range(b):
        p = build_prompt(3.0 + i, i % 6, e if i % 2 == 0 else None, "What should the ego do?",
                         num_det=CFG.num_det_queries, num_map=CFG.num_map_queries, waypoint=True)
        rows.append(encode_qa(tok, p, "Keep the current speed and follow the lane.",
                              CFG.lm_max_len))
    out = collate_text(rows, tok.pad_token_id)
    out["det_tokens"] = torch.randn(b, CFG.num_det_queries, CFG.lm_width, generator=g)
    out["map_tokens"] = torch.randn(b, CFG.num_map_queries, CFG.lm_width, generator=g)
    return out


# ---------------------------------------------------------------------- tokenizer
def test_tokenizer_special_tokens_and_round_trip(tok, tmp_path):
    assert len(tok) == CFG.lm_vocab
    ids = tok.convert_tokens_to_ids(list(SPECIAL_TOKENS))
    assert ids == list(range(len(SPECIAL_TOKENS)))
    enc = tok(f"{DET}{DET}{MAP} turn left {WP}")["input_ids"]
    assert enc[0] == tok.bos_token_id and enc[1:4] == ids[3:4] * 2 + ids[4:5]
    assert enc[-1] == tok.convert_tokens_to_ids(WP)
    text = "Ego speed: 3.5 m/s; navigation command: turn left."
    assert tok.decode(tok(text, add_special_tokens=False)["input_ids"]) == text
    tok.save_pretrained(str(tmp_path))
    tok2 = load_tokenizer(tmp_path)
    assert tok2(text)["input_ids"] == tok(text)["input_ids"]
    assert tok2.convert_tokens_to_ids(list(SPECIAL_TOKENS)) == ids
    with pytest.raises(ValueError, match="vocab_size=100"):
        train_tokenizer(["a"], 100)


def test_qa_texts_train_split_without_context(tmp_path):
    man = {"config": {}, "episodes": [], "shards": {"ep_a": {"split": "train"},
                                                    "ep_b": {"split": "val"}}}
    (tmp_path / "manifest.json").write_text(json.dumps(man))
    (tmp_path / "chat").mkdir()
    items = [{"episode": "ep_a", "question": "Q1?", "answer": "A1.",
              "context": "- pedestrian #44 at (-14.71, -11.29)"},
             {"episode": "ep_b", "question": "Q2?", "answer": "A2.", "context": "x"}]
    (tmp_path / "chat" / "qa.jsonl").write_text("".join(json.dumps(i) + "\n" for i in items))
    assert list(qa_texts(tmp_path, "train")) == ["Q1?\nA1."]
    assert len(list(qa_texts(tmp_path, "all"))) == 2
    (tmp_path / "chat" / "qa.jsonl").write_text('{"episode": "ep_a"}\n')
    with pytest.raises(ValueError, match=r"qa.jsonl:1: not a QA item"):
        list(qa_texts(tmp_path))


# ---------------------------------------------------------------------- LM and LoRA
def test_lm_size_and_from_pretrained_round_trip(tok, tmp_path):
    lm = fresh_lm(tok)
    n = sum(p.numel() for p in lm.parameters())
    assert 20_000 < n < 200_000  # tiny
    assert lm.config.hidden_size == CFG.lm_width and lm.config.num_hidden_layers == CFG.lm_layers
    save_lm(lm, tok, tmp_path / "lm")
    lm2, tok2 = load_lm(tmp_path / "lm")
    b = batch(tok)
    assert torch.equal(collate_text([encode_qa(tok2, "hello", None, 64)], 0)["input_ids"],
                       collate_text([encode_qa(tok, "hello", None, 64)], 0)["input_ids"])
    lm.eval()
    lm2.eval()
    with torch.no_grad():
        a = lm(input_ids=b["input_ids"], attention_mask=b["attention_mask"]).logits
        c = lm2(input_ids=b["input_ids"], attention_mask=b["attention_mask"]).logits
    assert torch.allclose(a, c, atol=1e-6)
    with pytest.raises(FileNotFoundError, match="config.json"):
        load_lm(tmp_path)
    default = AuroraConfig.for_scale("default")
    big = lm_config(default, train_tokenizer(corpus(50), 512))
    big.vocab_size = default.lm_vocab  # as trained on the full Chat-V2XBench text
    with torch.device("meta"):  # count without allocating
        params = sum(p.numel() for p in LlamaForCausalLM(big).parameters())
    assert 2e6 < params < 10e6  # "a few million" at default


def test_lora_keeps_base_weights_and_trains_adapters(tok):
    model = AuroraLM(add_lora(fresh_lm(tok), CFG), tok, CFG.lm_width)
    base = {n: p.detach().clone() for n, p in model.lm.named_parameters() if "lora_" not in n}
    lora = {n: p.detach().clone() for n, p in model.lm.named_parameters() if "lora_" in n}
    assert lora and all(not p.requires_grad for n, p in model.lm.named_parameters()
                        if "lora_" not in n)
    assert {n.rsplit(".", 3)[0].rsplit(".", 1)[-1] for n in lora} == set(CFG.lora_targets)
    wp_before = model.bridge.wp_embed.detach().clone()
    opt = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad], lr=1e-2)
    out = model(**batch(tok))
    assert out["loss"] is not None and bool(out["has_wp"].all())
    (out["loss"] + out["h_wp"].square().mean()).backward()
    opt.step()
    after = dict(model.lm.named_parameters())
    assert all(torch.equal(after[n], v) for n, v in base.items())  # base frozen
    changed = [n for n, v in lora.items() if not torch.equal(after[n], v)]
    assert any("lora_B" in n for n in changed)
    assert not torch.equal(model.bridge.wp_embed, wp_before)  # <wp>'s embedding learns


def test_gradient_flows_from_planner_loss_through_wp_to_fused_tokens(tok):
    model = AuroraLM(add_lora(fresh_lm(tok), CFG), tok, CFG.lm_width)
    planner = build_planner(CFG, model.hidden)
    b = batch(tok)
    det = b.pop("det_tokens").requires_grad_(True)
    mp = b.pop("map_tokens").requires_grad_(True)
    out = model(**b, det_tokens=det, map_tokens=mp)
    h_wp = out["h_wp"]
    h_wp.retain_grad()
    gt = torch.stack([torch.arange(1, 7) * 2.0, torch.zeros(6)], -1).expand(2, 6, 2)
    route = torch.zeros(2, CFG.plan_route_points, 2)  # straight ahead
    route[..., 0] = torch.arange(1, CFG.plan_route_points + 1) * CFG.plan_route_spacing
    path = torch.stack([torch.arange(40) * 2.0, torch.zeros(40)], -1).expand(2, -1, -1)
    plan = planner(h_wp, torch.tensor([3, 1]), gt, route=route, path=path)  # plan_frame="route"
    (plan["waypoints"] - gt).abs().mean().backward()  # the planner's L1
    assert float(h_wp.grad.abs().sum()) > 0
    assert bool((det.grad.abs().sum(-1) > 0).all())  # every fused detection token
    assert bool((mp.grad.abs().sum(-1) > 0).all())  # every fused map token


def test_placeholders_must_match_the_tokens(tok):
    model = AuroraLM(fresh_lm(tok), tok, CFG.lm_width)
    b = batch(tok)
    b["det_tokens"] = b["det_tokens"][:, 1:]
    with pytest.raises(ValueError, match=r"<det> placeholders but 15 <det> tokens"):
        model(**b)
    other = AuroraLM(fresh_lm(tok), tok, CFG.lm_width + 8)  # a wider token stream is projected
    b = batch(tok)
    b["det_tokens"] = torch.randn(2, CFG.num_det_queries, CFG.lm_width + 8)
    b["map_tokens"] = torch.randn(2, CFG.num_map_queries, CFG.lm_width + 8)
    assert other(**b)["h_wp"].shape == (2, CFG.lm_width)
    with pytest.raises(ValueError, match="exceed lm_max_len"):
        encode_qa(tok, DET * CFG.lm_max_len, "x", CFG.lm_max_len)


def test_adapters_round_trip(tok, tmp_path):
    lm = fresh_lm(tok)
    save_lm(lm, tok, tmp_path / "base")  # the base LM of stage 0
    model = AuroraLM(add_lora(lm, CFG), tok, CFG.lm_width)
    opt = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad], lr=1e-2)
    model(**batch(tok))["loss"].backward()
    opt.step()
    model.save(tmp_path / "adapter")
    names = {p.name for p in (tmp_path / "adapter").iterdir()}
    assert {"adapter_model.safetensors", "adapter_config.json", "bridge.safetensors"} <= names
    base2, tok2 = load_lm(tmp_path / "base")
    loaded = AuroraLM.load(base2, tok2, CFG.lm_width, tmp_path / "adapter")
    untrained = AuroraLM(add_lora(load_lm(tmp_path / "base")[0], CFG), tok, CFG.lm_width)
    b = batch(tok, seed=3)
    for m in (model, loaded, untrained):
        m.eval()
    with torch.no_grad():
        a, c, u = model(**b), loaded(**b), untrained(**b)
    assert torch.allclose(a["h_wp"], c["h_wp"], atol=1e-6)
    assert torch.allclose(a["logits"], c["logits"], atol=1e-5)
    assert not torch.allclose(a["h_wp"], u["h_wp"], atol=1e-4)  # the adapters matter
    assert any(p.requires_grad for n, p in loaded.lm.named_parameters() if "lora_" in n)


# ---------------------------------------------------------------------- run-time prompt
class Spy(dict):
    """A nested dict that records the keys read from it."""

    def __init__(self, data: dict, log: list, prefix: tuple = ()) -> None:
        super().__init__({k: Spy(v, log, prefix + (k,)) if isinstance(v, dict) else v
                          for k, v in data.items()})
        self.log, self.prefix = log, prefix

    def __getitem__(self, key):
        self.log.append(self.prefix + (key,))
        return super().__getitem__(key)


def test_runtime_prompt_holds_no_ground_truth_object():
    pedestrian = CLASS_NAMES.index("pedestrian")
    box = [37.21, -12.34, 0.0, 0.61, 0.73, 1.83, 0.3, 1.37, 0.0]  # x, y, z, l, w, h, yaw, vx, vy
    gt = {"boxes": np.array([box], np.float32), "class": np.array([pedestrian]),
          "id": np.array([4242]), "mask": np.array([True])}
    record = {"ego_speed": np.float32(7.25), "command": np.int64(1), "light_state": np.int64(2),
              "calib": {"T_world_ego": T_WORLD_EGO, "T_world_rsu": T_WORLD_RSU,
                        "rsu_unit": np.int64(2)},
              "gt": {"ego": gt, "rsu": gt, "fused": gt},
              "expert_waypoints": np.array([[3.91, 0.17]] * 8, np.float32),
              "obs": {"objects": np.array([box], np.float32)}}
    log: list = []
    prompt = prompt_from_record(Spy(record, log), "What should the ego do now?",
                                num_det=CFG.num_det_queries, num_map=CFG.num_map_queries,
                                waypoint=True)
    runtime = {k if isinstance(k, tuple) else (k,) for k in RUNTIME_KEYS}
    groups = {k[:i] for k in runtime for i in range(1, len(k))}  # e.g. ("calib",) on the way
    assert set(log) <= runtime | groups, log  # nothing but speed, command and the unit's pose
    assert runtime <= set(log)
    assert "7.2 m/s" in prompt and "turn left" in prompt and prompt.endswith(WP)
    e = rsu_to_ego(T_WORLD_EGO, T_WORLD_RSU)
    assert f"position ({float(e[0, 3]):.1f}, {float(e[1, 3]):.1f}) m" in prompt
    assert prompt.count(DET) == CFG.num_det_queries and prompt.count(MAP) == CFG.num_map_queries
    low = prompt.lower()
    for value in ("37.2", "12.3", "4242", "0.61", "0.73", "1.83", "1.37", "3.91"):
        assert value not in prompt
    for word in (*CLASS_NAMES, *templates.CLASS.values(), "ground truth", "object", "#", "red"):
        assert word.replace("_", " ") not in low and word not in low
    # a lost message: no pose at all
    lost = prompt_from_record(record, num_det=1, num_map=1, rsu_pose=None)
    assert "no message received" in lost and "position (" not in lost
    with pytest.raises(ValueError, match="no 'command'"):
        prompt_from_record({"ego_speed": 1.0, "calib": record["calib"]}, num_det=1, num_map=1)
