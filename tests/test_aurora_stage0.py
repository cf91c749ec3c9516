"""AURORA stage 0 (language-model pre-training), `aurora ask` and `aurora answer`, end to end at
the tiny scale on the tiny collected data set."""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from transformers import AutoModelForCausalLM
from v2xbench.agents.aurora.answer import ask
from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.language import build_lm, load_lm
from v2xbench.agents.aurora.stage0 import (
    CausalLMTrainee,
    base_lm_dir,
    find_base_lm,
    item_prompt,
    split_qa_items,
    train_stage0,
)
from v2xbench.agents.aurora.tokenizer import load_tokenizer
from v2xbench.agents.aurora.trainer import load_weights
from v2xbench.collectors.chat.export import build, load_items

from v2xbench.cli import main

CFG = AuroraConfig.for_scale("tiny")


@pytest.fixture(scope="module")
def data(tiny_dataset, tmp_path_factory):
    """A copy of the session's tiny data set with its QA items (the shared one stays without:
    the pipeline test needs a data set that has none yet)."""
    root = tmp_path_factory.mktemp("stage0") / "data"
    shutil.copytree(tiny_dataset, root)
    build(root, seed=0)
    return root


@pytest.fixture(scope="module")
def run(data, tmp_path_factory):
    """Stage 0 at tiny through the CLI: stopped after 10 steps, then resumed to the end."""
    out = tmp_path_factory.mktemp("aurora_run")
    args = ["aurora", "train", "--stage", "0", "--data", str(data), "--out", str(out),
            "--scale", "tiny", "--quiet"]
    assert main(args + ["--max-steps", "10"]) == 0
    state = json.loads((out / "stage0" / "state.json").read_text())
    assert state["step"] == 10 and not state["done"]
    assert main(args) == 0
    return out


def _log(run_dir):
    lines = (run_dir / "stage0" / "log.jsonl").read_text().splitlines()
    return [json.loads(line) for line in lines]


def test_stage0_trains_on_the_train_split_and_the_loss_falls(run, data):
    st = run / "stage0"
    state = json.loads((st / "state.json").read_text())
    assert state["done"] and state["step"] == state["total_steps"] > 10
    log = _log(run)
    assert [r["step"] for r in log] == list(range(1, state["total_steps"] + 1))
    first = sum(r["loss"] for r in log[:5]) / 5
    last = sum(r["loss"] for r in log[-5:]) / 5
    assert last < first - 0.5, (first, last)
    assert all("answer" in r for r in log)
    for f in ("loss.png", "checkpoint.safetensors", "optimizer.pt", "train_summary.json",
              "config.json", "model.safetensors", "tokenizer.json"):
        assert (st / f).is_file(), f
    info = json.loads((st / "aurora.json").read_text())
    items = load_items(data)
    train = [it for it in items if it["split"] == "train"]
    assert 0 < len(train) < len(items)  # one of the two routes is val
    assert info["documents"] == len(train) and info["split"] == "train"
    assert info["tokens"] == info["blocks"] * CFG.lm_pretrain_block


def test_resumed_run_equals_an_uninterrupted_one(run, data, tmp_path):
    train_stage0(data, tmp_path, scale="tiny", progress=False)
    assert [r["loss"] for r in _log(tmp_path)] == [r["loss"] for r in _log(run)]


def test_from_pretrained_round_trip(run):
    st = run / "stage0"
    lm, tok = load_lm(st)  # AutoModelForCausalLM.from_pretrained(RUN/stage0) + tokenizer
    assert base_lm_dir(run, find_base_lm(run)) == st
    trainee = CausalLMTrainee(build_lm(CFG, load_tokenizer(st)))
    load_weights(trainee, st / "checkpoint.safetensors")  # the trainer's own checkpoint
    ids = torch.tensor([tok("Ego speed: 3.0 m/s; navigation command: turn left.")["input_ids"]])
    lm.eval()
    trainee.eval()
    with torch.no_grad():
        a = lm(input_ids=ids).logits
        b = trainee({"input_ids": ids})
        c = AutoModelForCausalLM.from_pretrained(str(st))(input_ids=ids).logits
    assert torch.equal(a, b) and torch.equal(a, c)
    fresh = build_lm(CFG, tok)
    with torch.no_grad():
        assert not torch.allclose(fresh(input_ids=ids).logits, a)
    with pytest.raises(FileNotFoundError, match="no stage-0 language model"):
        find_base_lm(run / "elsewhere")


def test_one_place_resolves_the_base_lm(run, tmp_path):
    """``find_base_lm``: --lm wins over RUN/stage0; a run without stage 0 gives None only when
    not required; stage 3's ``base_lm`` and ``load_stage0`` go through it."""
    from v2xbench.agents.aurora.stage0 import load_stage0
    from v2xbench.agents.aurora.stages import base_lm
    from v2xbench.agents.aurora.system import resolve_lm_path

    st = run / "stage0"
    assert find_base_lm(run) == {"source": "stage0", "path": "stage0"}
    given = find_base_lm(tmp_path, st)
    assert given == {"source": "given", "path": str(st.resolve())}
    assert find_base_lm(tmp_path, required=False) is None
    with pytest.raises(FileNotFoundError, match="config.json missing"):
        find_base_lm(run, tmp_path)
    with pytest.raises(ValueError, match="run folder or --lm"):
        find_base_lm(None)
    assert base_lm(run, tmp_path, CFG, None, 0) == find_base_lm(run)
    assert base_lm(tmp_path, tmp_path, CFG, st, 0) == given
    assert resolve_lm_path(run, {"lm": find_base_lm(run)}) == st
    assert load_stage0(None, st)[2] == st.resolve()


def test_stage0_refuses_hinted_files_and_other_settings(run, data, tmp_path):
    old = tmp_path / "qa.jsonl"
    rows = [{k: v for k, v in it.items() if k not in ("hints", "split")} for it in load_items(data)]
    old.write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(ValueError, match="before the hint-free export"):
        train_stage0(data, tmp_path / "r", scale="tiny", chat=old, progress=False)
    with pytest.raises(ValueError, match="other settings.*seed"):
        train_stage0(data, run, scale="tiny", seed=1, progress=False)
    with pytest.raises(FileNotFoundError, match="qa build"):
        split_qa_items(data, "train", tmp_path / "none")


def test_ask_answers_from_the_runtime_prompt(run, data, tmp_path, capsys):
    item = next(it for it in load_items(data) if it["split"] == "val")
    r = ask(run, data, item["keyframe"], item["question"])
    assert isinstance(r["answer"], str) and "no stage 3-5" in r["note"]
    assert r["prompt"] == item_prompt(item)  # = the export's hint-free context + question
    assert "<det>" not in r["prompt"] and "ground truth" not in r["prompt"]
    # --lm: any local Hugging Face causal-LM folder, here a copy of the stage-0 model
    other = tmp_path / "lm"
    shutil.copytree(run / "stage0", other)
    assert ask(None, data, item["keyframe"], item["question"], lm=other)["answer"] == r["answer"]
    capsys.readouterr()
    assert main(["aurora", "ask", "--run", str(run), "--data", str(data), "--keyframe",
                 item["keyframe"], item["question"]]) == 0
    out = capsys.readouterr().out
    assert "answer:" in out and "visual placeholders are omitted" in out
    for bad, needle in (("nonsense", "is not <episode>_t<tick>"),
                        ("train_000_s0_t99999", "train_000_s0 has 41 frames (ticks 0-40)"),
                        ("nowhere_t00010", "episode 'nowhere' is not in")):
        assert main(["aurora", "ask", "--run", str(run), "--data", str(data), "--keyframe", bad,
                     "Why?"]) == 2
        assert needle in capsys.readouterr().err


def test_answers_file_scores_with_qa_score(run, data, tmp_path, capsys):
    preds = tmp_path / "preds.jsonl"
    assert main(["aurora", "answer", "--run", str(run), "--data", str(data), "--split", "val",
                 "--out", str(preds), "--quiet", "--batch-size", "8"]) == 0
    val = [it for it in load_items(data) if it["split"] == "val"]
    rows = [json.loads(line) for line in preds.read_text().splitlines()]
    assert [r["id"] for r in rows] == [it["id"] for it in val]
    assert all(isinstance(r["answer"], str) for r in rows)
    capsys.readouterr()
    assert main(["qa", "score", str(data), str(preds), "--split", "val"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["answered"] == len(val) and s["missing"] == 0
    levels = {it["level"] for it in val}  # every level the split holds is scored on its own
    assert set(s["per_level"]) == levels and len(levels) >= 3
    assert main(["aurora", "answer", "--run", str(run), "--data", str(data), "--split", "test",
                 "--out", str(preds), "--quiet"]) == 2
    assert "no QA item of split 'test'" in capsys.readouterr().err


def test_stage0_hyper_parameters_per_scale():
    for scale in ("tiny", "default", "paper"):
        cfg = AuroraConfig.for_scale(scale)
        hp = cfg.stage_hparams(0)
        assert hp is cfg.stage0 and hp.epochs >= 1 and cfg.lm_pretrain_block <= cfg.lm_max_len
    assert AuroraConfig.for_scale("default").stage0.frame_stride > 1  # fits the CPU budget
    with pytest.raises(ValueError, match="unknown stage 6"):
        CFG.stage_hparams(6)
    too_long = CFG.lm_max_len + 1
    with pytest.raises(ValueError, match=f"lm_pretrain_block={too_long} must be"):
        AuroraConfig.for_scale("tiny", lm_pretrain_block=too_long)
    # runs written before stage 0 existed still read back (stage0 from the scale)
    d = CFG.to_dict()
    d.pop("stage0")
    d.pop("lm_pretrain_block")
    assert AuroraConfig.from_dict(d) == CFG
