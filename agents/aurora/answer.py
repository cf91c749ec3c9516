"""Ask AURORA's language model Chat-V2XBench questions: ``v2xbench aurora ask`` and ``answer``.

- :func:`ask`: one question about one recorded frame (``--keyframe <episode>_t<tick>``, any
  recorded tick of the data set): the prompt is the run-time prompt of that frame
  (:func:`~.prompt.prompt_from_record`: speed, navigation command, the active roadside unit's
  pose; never ground-truth objects) and the answer the model's greedy ``generate``.
- :func:`answer_split`: every Chat-V2XBench item of a split, answered from the item's hint-free
  ``context`` and question, written as ``{"id", "answer"}`` JSON lines, the format of
  ``v2xbench qa score REF PRED --split SPLIT`` (scores per kind, type and level).

The model, for now, is the run's stage-0 language model (``RUN/stage0``, or ``--lm PATH``: any
local Hugging Face causal LM with AURORA's tokens) on the **text prompt alone**: the ``<det>`` /
``<map>`` placeholders are omitted (not filled with zeros), which is exactly the text stage 0
trained on. The fused visual tokens enter with stage 3; until answering is wired to a stage-3
model, the output says which model answered and that it saw no visual tokens.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import torch

from v2xbench.files import atomic_write

from .prompt import RUNTIME_KEYS, prompt_from_record
from .stage0 import item_prompt, load_stage0, split_qa_items

KEYFRAME = re.compile(r"^(?P<episode>.+)_t(?P<tick>\d+)$")
LATER_STAGES = (3, 4, 5)
MAX_NEW_TOKENS = 192  # the longest training answers are ~150 tokens at the default vocabulary


def model_note(run: str | Path | None, path: Path) -> str:
    """Which model answers and what it sees (module docstring)."""
    later = [s for s in LATER_STAGES if run is not None and (Path(run) / f"stage{s}").is_dir()]
    what = (f"RUN has stage {', '.join(map(str, later))}, but answering with fused tokens is "
            "not wired yet" if later else "the run has no stage 3-5 (fused tokens)")
    return (f"model: {path} (language model alone, text prompt; {what}: the visual "
            "placeholders are omitted)")


@torch.no_grad()
def generate(model, tokenizer, prompts: list[str], *, max_new_tokens: int = MAX_NEW_TOKENS,
             batch_size: int = 32, progress: bool = False) -> list[str]:
    """Greedy answers to ``prompts`` (left-padded batches, sorted by length; stops at ``</s>``
    or after ``max_new_tokens``, fewer where the model's positions end)."""
    if max_new_tokens < 1 or batch_size < 1:
        raise ValueError(f"generate: max_new_tokens={max_new_tokens} and batch_size="
                         f"{batch_size} must be >= 1")
    from tqdm import tqdm

    enc = [tokenizer(p)["input_ids"] for p in prompts]
    order = sorted(range(len(prompts)), key=lambda i: len(enc[i]))
    out: list[str] = [""] * len(prompts)
    device = next(model.parameters()).device
    bar = tqdm(total=len(prompts), disable=not progress, desc="answer", dynamic_ncols=True)
    for s in range(0, len(order), batch_size):
        idx = order[s:s + batch_size]
        width = max(len(enc[i]) for i in idx)
        ids = torch.full((len(idx), width), tokenizer.pad_token_id, dtype=torch.long)
        mask = torch.zeros_like(ids)
        for r, i in enumerate(idx):
            ids[r, width - len(enc[i]):] = torch.tensor(enc[i])
            mask[r, width - len(enc[i]):] = 1
        limit = getattr(model.config, "max_position_embeddings", None) or width + max_new_tokens
        gen = model.generate(input_ids=ids.to(device), attention_mask=mask.to(device),
                             max_new_tokens=max(1, min(max_new_tokens, limit - width)),
                             do_sample=False,
                             eos_token_id=tokenizer.eos_token_id,
                             pad_token_id=tokenizer.pad_token_id)
        for r, i in enumerate(idx):
            out[i] = tokenizer.decode(gen[r, width:], skip_special_tokens=True).strip()
        bar.update(len(idx))
    bar.close()
    return out


def frame_record(data: str | Path, keyframe: str):
    """The run-time keys (:data:`~.prompt.RUNTIME_KEYS`) of a recorded frame
    ``<episode>_t<tick>``; ``ValueError`` naming the id when it is malformed or not recorded."""
    from v2xbench.collectors.dataset.shards import load_manifest, load_shard

    m = KEYFRAME.match(keyframe)
    if m is None:
        raise ValueError(f"aurora ask: keyframe {keyframe!r} is not <episode>_t<tick> "
                         "(e.g. train_000_s0_t00120)")
    ep, tick = m["episode"], int(m["tick"])
    if ep not in load_manifest(data).get("shards", {}):
        raise ValueError(f"aurora ask: keyframe {keyframe!r}: episode {ep!r} is not in {data}")
    td = load_shard(data, ep).select(*RUNTIME_KEYS)
    if tick >= td.batch_size[0]:
        raise ValueError(f"aurora ask: keyframe {keyframe!r}: {ep} has {td.batch_size[0]} "
                         f"frames (ticks 0-{td.batch_size[0] - 1})")
    return td[tick]


def ask(run: str | Path | None, data: str | Path, keyframe: str, question: str, *,
        lm: str | Path | None = None, max_new_tokens: int = MAX_NEW_TOKENS,
        device: str = "cpu") -> dict:
    """Answer ``question`` about the recorded frame ``keyframe`` (module docstring).

    Returns:
        ``{"answer", "prompt", "model", "note"}``.
    """
    record = frame_record(data, keyframe)
    prompt = prompt_from_record(record, question, num_det=0, num_map=0)
    model, tok, path = load_stage0(run, lm)
    model.to(device)
    ans = generate(model, tok, [prompt], max_new_tokens=max_new_tokens, batch_size=1)[0]
    return {"answer": ans, "prompt": prompt, "model": str(path), "note": model_note(run, path)}


def answer_split(run: str | Path | None, data: str | Path, split: str, out: str | Path, *,
                 chat: str | Path | None = None, lm: str | Path | None = None,
                 max_new_tokens: int = MAX_NEW_TOKENS, batch_size: int = 32,
                 device: str = "cpu", progress: bool = True) -> dict:
    """Answer every hint-free Chat-V2XBench item of ``split`` into ``out`` (JSONL, atomically).

    Returns:
        ``{"items", "out", "qa", "model", "note", "wall_s", "items_per_s"}``.
    """
    import json

    items, qa_path = split_qa_items(data, split, chat)
    model, tok, path = load_stage0(run, lm)
    model.to(device)
    t0 = time.perf_counter()
    answers = generate(model, tok, [item_prompt(it) for it in items],
                       max_new_tokens=max_new_tokens, batch_size=batch_size, progress=progress)
    wall = time.perf_counter() - t0
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(out) as f:
        for it, a in zip(items, answers, strict=True):
            f.write(json.dumps({"id": it["id"], "answer": a}) + "\n")
    return {"items": len(items), "out": str(out), "qa": str(qa_path), "model": str(path),
            "note": model_note(run, path), "wall_s": wall,
            "items_per_s": len(items) / wall if wall > 0 else 0.0}


__all__ = ["KEYFRAME", "MAX_NEW_TOKENS", "answer_split", "ask", "frame_record", "generate",
           "model_note"]
