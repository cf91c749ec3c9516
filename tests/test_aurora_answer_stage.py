"""`v2xbench aurora answer|ask --stage N` (issue #33 item 8): the whole stage-3+ system answers
Chat-V2XBench items from the recorded frames' cameras (fused tokens at the placeholders)."""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from v2xbench.agents.aurora import answer as A
from v2xbench.agents.aurora.pairs import collate_pairs
from v2xbench.agents.aurora.pipeline import run_pipeline
from v2xbench.agents.aurora.stage0 import split_qa_items
from v2xbench.agents.aurora.system import load_system
from v2xbench.collectors.chat.export import build as build_qa

from v2xbench.cli import main


@pytest.fixture(scope="module")
def tiny_run(tiny_dataset, tmp_path_factory):
    torch.set_num_threads(1)
    base = tmp_path_factory.mktemp("aurora_answer_stage")
    data = base / "data"
    shutil.copytree(tiny_dataset, data)
    build_qa(data)
    run_pipeline(data, base / "run", scale="tiny", progress=False, say=lambda _: None)
    return data, base / "run"


def _lines(path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def test_answer_stage5_writes_one_answer_per_item_and_scores(tiny_run, tmp_path, capsys):
    data, run = tiny_run
    items, _ = split_qa_items(data, "all")
    out = tmp_path / "preds.jsonl"
    assert main(["aurora", "answer", "--run", str(run), "--stage", "5", "--data", str(data),
                 "--split", "all", "--out", str(out), "--quiet", "--threads", "1",
                 "--max-new-tokens", "8", "--batch-size", "4"]) == 0
    said = capsys.readouterr().out
    assert "stage 5 system" in said and "fused tokens" in said
    preds = _lines(out)
    assert [p["id"] for p in preds] == [it["id"] for it in items]
    assert all(isinstance(p["answer"], str) for p in preds)
    assert main(["qa", "score", str(data), str(out), "--split", "all"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["answered"] == len(items) and s["missing"] == 0 and s["per_level"]

    # a stride answers every K-th item and writes their reference, which scores without gaps
    out2 = tmp_path / "strided.jsonl"
    assert main(["aurora", "answer", "--run", str(run), "--stage", "5", "--data", str(data),
                 "--split", "all", "--out", str(out2), "--quiet", "--threads", "1",
                 "--max-new-tokens", "4", "--stride", "3"]) == 0
    capsys.readouterr()
    assert [p["id"] for p in _lines(out2)] == [it["id"] for it in items[::3]]
    ref = out2.with_name(out2.name + ".ref.jsonl")
    assert main(["qa", "score", str(ref), str(out2), "--split", "all"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["answered"] == len(items[::3]) and s["missing"] == 0

    # bad combinations are clear errors
    assert main(["aurora", "answer", "--weights", str(run), "--stage", "5", "--data",
                 str(data), "--out", str(tmp_path / "x.jsonl"), "--quiet"]) == 2
    assert "--stage chooses a stage" in capsys.readouterr().err
    with pytest.raises(ValueError, match="not both"):
        A.load_answering_system(run, None, run, "cpu")
    with pytest.raises(ValueError, match="--stage chooses a stage"):
        A.load_answering_system(None, 5, run, "cpu")
    with pytest.raises(ValueError, match="needs --run"):
        A.load_answering_system(None, 5, None, "cpu")


def test_answers_depend_on_the_images(tiny_run, capsys):
    data, run = tiny_run
    system, tok, _ = load_system(run, 5)
    items, _ = split_qa_items(data, "all")
    samples = A.frame_items(data, "all", items)
    by_frame: dict[int, int] = {}
    for i, (fid, _, _) in enumerate(samples):
        by_frame.setdefault(fid, i)
    (i, j) = list(by_frame.values())[:2]
    ds = A._pairs(system, tok, data, "all", [samples[i], samples[j]])
    a, b = ds[0], ds[1]
    assert not torch.equal(a["ego/images"], b["ego/images"])
    # the same text (a's prompt) with b's frame: cameras, roadside input, frame id
    mixed = dict(a)
    mixed.update({k: v for k, v in b.items() if k.startswith(("ego/", "rsu/"))
                  or k in ("has_rsu", "rsu_to_ego", "frame_id")})
    batch = collate_pairs([a, mixed], int(tok.pad_token_id))
    embeds, mask, ids = A.visual_embeddings(system, batch)
    assert torch.equal(ids[0], ids[1]) and torch.equal(mask[0], mask[1])
    vis = (ids[0] == system.lm.det_id) | (ids[0] == system.lm.map_id)
    assert int(vis.sum()) == system.cfg.num_det_queries + system.cfg.num_map_queries
    assert torch.equal(embeds[0, ~vis], embeds[1, ~vis])  # the text is the same
    assert not torch.allclose(embeds[0, vis], embeds[1, vis])  # the frames differ
    plain = system.lm.lm.get_input_embeddings()(ids[0])
    assert not torch.allclose(embeds[0, vis], plain[vis])  # placeholders replaced

    # generation reads those embeddings: its first token is the LM's argmax on them
    with torch.no_grad():
        logits = system.lm.lm(inputs_embeds=embeds, attention_mask=mask).logits[:, -1]
        gen = system.lm.lm.generate(inputs_embeds=embeds, attention_mask=mask, max_new_tokens=1,
                                    do_sample=False, pad_token_id=tok.pad_token_id,
                                    eos_token_id=tok.eos_token_id)
    assert torch.equal(gen[:, 0], logits.argmax(-1))

    # `aurora ask --stage 5` on a recorded frame
    it = items[i]
    assert main(["aurora", "ask", "--run", str(run), "--stage", "5", "--data", str(data),
                 "--keyframe", it["keyframe"], "--max-new-tokens", "4",
                 "--threads", "1", it["question"]]) == 0
    said = capsys.readouterr().out
    assert "stage 5 system" in said and "answer:" in said
