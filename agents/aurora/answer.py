"""Ask AURORA's language model Chat-V2XBench questions: ``v2xbench aurora ask`` and ``answer``.

- :func:`ask`: one question about one recorded frame (``--keyframe <episode>_t<tick>``, any
  recorded tick of the data set): the prompt is the run-time prompt of that frame
  (:func:`~.prompt.prompt_from_record`: speed, navigation command, the active roadside unit's
  pose; never ground-truth objects) and the answer the model's greedy ``generate``.
- :func:`answer_split`: every Chat-V2XBench item of a split, answered from the item's hint-free
  ``context`` and question, written as ``{"id", "answer"}`` JSON lines, the format of
  ``v2xbench qa score REF PRED --split SPLIT`` (scores per kind, type and level).

Two models answer:

- no ``stage`` / ``weights`` (the default): the run's stage-0 language model (``RUN/stage0``, or
  ``--lm PATH``: any local Hugging Face causal LM with AURORA's tokens) on the **text prompt
  alone**: the ``<det>`` / ``<map>`` placeholders are omitted (not filled with zeros), which is
  exactly the text stage 0 trained on; the output says so.
- ``stage=3|4|5`` of a run (:func:`~.system.load_system`) or exported ``weights``
  (:func:`~.export.load_export`; both through :func:`~.eval_planning.load_model`): the **whole
  system**. Each item becomes a stage-3 sample of its recorded frame
  (:class:`~.pairs.AuroraPairs`: the ego cameras, the roadside camera, the prompt with the
  visual placeholders, no answer); the ego branch, the roadside branch's message (fusion runs,
  frames with a unit; rounded to the wire's float16, as in :mod:`.eval_planning`) and CQAF give
  the fused tokens, which replace the placeholders' input embeddings
  (:meth:`~.language.AuroraLM.embed`, :func:`visual_embeddings`), and the LoRA-adapted LM
  generates greedily from those embeddings (:func:`generate_fused`). Perception runs once per
  distinct frame of a batch.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import torch

from v2xbench.files import atomic_write

from .prompt import RUNTIME_KEYS, prompt_from_record
from .stage0 import item_prompt, load_stage0, split_qa_items
from .system import ego_outputs

KEYFRAME = re.compile(r"^(?P<episode>.+)_t(?P<tick>\d+)$")
LATER_STAGES = (3, 4, 5)
MAX_NEW_TOKENS = 192  # the longest training answers are ~150 tokens at the default vocabulary


def model_note(run: str | Path | None, path: Path) -> str:
    """Which model answers and what it sees (module docstring)."""
    later = [s for s in LATER_STAGES if run is not None and (Path(run) / f"stage{s}").is_dir()]
    what = (f"RUN has stage {', '.join(map(str, later))}: pass --stage N to answer with that "
            "stage's whole system (fused tokens)" if later else
            "the run has no stage 3-5 (fused tokens)")
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


# ---------------------------------------------------------------------- the whole system
def load_answering_system(run: str | Path | None, stage: int | None,
                          weights: str | Path | None, device: str = "cpu"):
    """``(system, tokenizer, info)`` of a run's stage 3-5 or of exported weights (module
    docstring); ``ValueError`` for a bad combination, ``FileNotFoundError`` for a missing
    folder."""
    from .eval_planning import load_model

    if weights is not None and run is not None:
        raise ValueError("aurora answer: give --run RUN --stage N or --weights DIR, not both")
    if weights is not None and stage is not None:
        raise ValueError("aurora answer: --stage chooses a stage of a run; exported weights "
                         "hold one stage")
    if weights is None and run is None:
        raise ValueError(f"aurora answer: --stage {stage} needs --run RUN")
    if stage is not None and stage not in LATER_STAGES:
        raise ValueError(f"aurora answer: --stage {stage!r} must be one of {LATER_STAGES}")
    if run is not None and not Path(run).is_dir():
        raise FileNotFoundError(f"aurora answer: run folder {run} does not exist")
    if weights is not None and not Path(weights).is_dir():
        raise FileNotFoundError(f"aurora answer: weights folder {weights} does not exist "
                                "(export one with `v2xbench aurora export`)")
    return load_model(run, weights, stage, device)


def system_note(info: dict, fusion: bool) -> str:
    """Which system answers (stage, weights file, fusion)."""
    return (f"model: stage {info.get('stage')} system {info.get('checkpoint')} (ego cameras"
            f"{' + roadside message' if fusion else ', No Fusion'} -> CQAF -> fused tokens in "
            "place of the visual placeholders -> LoRA LM, greedy)")


def frame_items(data: str | Path, split: str, items: list[dict]) -> list[tuple]:
    """``(frame_id, question, None)`` samples (:data:`~.pairs.Item`) of QA items, their frame
    being the item's ``episode`` / ``tick`` in ``split`` of ``data``."""
    from v2xbench.collectors.dataset.loader import V2XDataset

    ds = V2XDataset(data, split, keys=["command"])
    index = {sid: e for e, sid in enumerate(ds.episodes)}
    out = []
    for it in items:
        e = index.get(it["episode"])
        tick = int(it["tick"])
        if e is None or not 0 <= tick < int(ds.offsets[e + 1] - ds.offsets[e]):
            raise ValueError(f"aurora answer: item {it['id']!r}: frame {it['episode']} tick "
                             f"{tick} is not in split {split!r} of {data}")
        out.append((int(ds.offsets[e] + tick), str(it["question"]), None))
    return out


def _left_pad(ids: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Right-padded rows (:func:`~.pairs.collate_pairs`) moved to the right end (left padding,
    what generation appends to)."""
    shift = (mask.shape[1] - mask.sum(1)).tolist()
    return (torch.stack([r.roll(int(k)) for r, k in zip(ids, shift)]),
            torch.stack([r.roll(int(k)) for r, k in zip(mask, shift)]))


@torch.no_grad()
def visual_embeddings(system, batch: dict[str, torch.Tensor]
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(embeds (B, T, H), attention_mask (B, T), input_ids (B, T))`` of a
    :func:`~.pairs.collate_pairs` batch, left-padded: the LM's input embeddings with the fused
    tokens (:meth:`~.system.AuroraSystem.perceive` and CQAF, once per distinct ``frame_id``) in
    place of the ``<det>`` / ``<map>`` placeholders."""
    fids = batch["frame_id"]
    uniq, inv = torch.unique(fids, return_inverse=True)
    first = torch.stack([(fids == u).nonzero()[0, 0] for u in uniq])
    dev = next(system.parameters()).device
    sub = {k: v[first].to(dev) for k, v in batch.items()
           if k not in ("input_ids", "labels", "attention_mask")}
    per = system.perceive(sub)
    fused = system.cqaf(ego_outputs(per["ego"]), per["msg"])
    inv = inv.to(dev)
    ids, mask = _left_pad(batch["input_ids"], batch["attention_mask"])
    ids, mask = ids.to(dev), mask.to(dev)
    return system.lm.embed(ids, fused["t_det"][inv], fused["t_map"][inv]), mask, ids


@torch.no_grad()
def generate_fused(system, tokenizer, batch: dict[str, torch.Tensor], *,
                   max_new_tokens: int = MAX_NEW_TOKENS) -> list[str]:
    """Greedy answers of the whole system to a batch of question samples (no ``<wp>``; stops at
    ``</s>``, after ``max_new_tokens`` or where the model's positions end)."""
    embeds, mask, _ = visual_embeddings(system, batch)
    limit = getattr(system.lm.lm.config, "max_position_embeddings", None)
    room = max_new_tokens if limit is None else min(max_new_tokens, limit - embeds.shape[1])
    gen = system.lm.lm.generate(inputs_embeds=embeds, attention_mask=mask,
                                max_new_tokens=max(1, room), do_sample=False,
                                eos_token_id=tokenizer.eos_token_id,
                                pad_token_id=tokenizer.pad_token_id)
    return [tokenizer.decode(g, skip_special_tokens=True).strip() for g in gen]


def _pairs(system, tok, data, split: str, items: list[tuple]):
    from .pairs import AuroraPairs

    return AuroraPairs(data, split, system.cfg, tok, items, fusion=system.fusion)


def answer_frames(system, tok, data: str | Path, split: str, items: list[tuple], *,
                  max_new_tokens: int = MAX_NEW_TOKENS, batch_size: int = 32,
                  progress: bool = False) -> list[str]:
    """The whole system's answers to ``(frame_id, question, None)`` samples of ``split``
    (batched in frame order; returned in the order of ``items``)."""
    from tqdm import tqdm

    from .pairs import collate_pairs

    ds = _pairs(system, tok, data, split, items)
    order = sorted(range(len(items)), key=lambda i: items[i][0])
    out: list[str] = [""] * len(items)
    bar = tqdm(total=len(items), disable=not progress, desc="answer", dynamic_ncols=True)
    for s in range(0, len(order), batch_size):
        idx = order[s:s + batch_size]
        batch = collate_pairs([ds[i] for i in idx], int(tok.pad_token_id))
        for i, a in zip(idx, generate_fused(system, tok, batch, max_new_tokens=max_new_tokens),
                        strict=True):
            out[i] = a
        bar.update(len(idx))
    bar.close()
    return out


def ask(run: str | Path | None, data: str | Path, keyframe: str, question: str, *,
        lm: str | Path | None = None, max_new_tokens: int = MAX_NEW_TOKENS,
        device: str = "cpu", stage: int | None = None,
        weights: str | Path | None = None) -> dict:
    """Answer ``question`` about the recorded frame ``keyframe`` (module docstring): with
    ``stage`` / ``weights`` the whole system on that frame's cameras, else the stage-0 LM on
    the text prompt.

    Returns:
        ``{"answer", "prompt", "model", "note"}``.
    """
    record = frame_record(data, keyframe)
    if stage is None and weights is None:
        prompt = prompt_from_record(record, question, num_det=0, num_map=0)
        model, tok, path = load_stage0(run, lm)
        model.to(device)
        ans = generate(model, tok, [prompt], max_new_tokens=max_new_tokens, batch_size=1)[0]
        return {"answer": ans, "prompt": prompt, "model": str(path),
                "note": model_note(run, path)}
    if lm is not None:
        raise ValueError("aurora ask: --lm replaces stage 0's model; a stage-3+ system has its "
                         "own LM")
    system, tok, info = load_answering_system(run, stage, weights, device)
    m = KEYFRAME.match(keyframe)
    item = {"id": keyframe, "episode": m["episode"], "tick": int(m["tick"]),
            "question": question}
    cfg = system.cfg
    prompt = prompt_from_record(record, question, num_det=cfg.num_det_queries,
                                num_map=cfg.num_map_queries,
                                rsu_pose="record" if system.fusion else None)
    ans = answer_frames(system, tok, data, "all", frame_items(data, "all", [item]),
                        max_new_tokens=max_new_tokens, batch_size=1)[0]
    return {"answer": ans, "prompt": prompt, "model": str(info.get("checkpoint")),
            "note": system_note(info, system.fusion)}


def answer_split(run: str | Path | None, data: str | Path, split: str, out: str | Path, *,
                 chat: str | Path | None = None, lm: str | Path | None = None,
                 max_new_tokens: int = MAX_NEW_TOKENS, batch_size: int = 32,
                 device: str = "cpu", progress: bool = True, stage: int | None = None,
                 weights: str | Path | None = None, stride: int = 1) -> dict:
    """Answer every ``stride``-th hint-free Chat-V2XBench item of ``split`` (file order) into
    ``out`` (JSONL, atomically): with ``stage`` / ``weights`` the whole system on each item's
    recorded frame, else the stage-0 LM on the text prompt (module docstring). With
    ``stride > 1`` the answered items' reference lines are also written to
    ``<out>.ref.jsonl`` (``qa`` in the result), so that ``qa score`` scores only them.

    Returns:
        ``{"items", "out", "qa", "model", "note", "wall_s", "items_per_s"}``.
    """
    import json

    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise ValueError(f"aurora answer: stride={stride!r} must be an int >= 1")
    if stage is None and weights is None:
        model, tok, path = load_stage0(run, lm)
        model.to(device)
        note, name = model_note(run, path), str(path)
        items, qa_path = split_qa_items(data, split, chat)
        items = items[::stride]
        t0 = time.perf_counter()
        answers = generate(model, tok, [item_prompt(it) for it in items],
                           max_new_tokens=max_new_tokens, batch_size=batch_size,
                           progress=progress)
    else:
        if lm is not None:
            raise ValueError("aurora answer: --lm replaces stage 0's model; a stage-3+ system "
                             "has its own LM")
        system, tok, info = load_answering_system(run, stage, weights, device)
        note, name = system_note(info, system.fusion), str(info.get("checkpoint"))
        items, qa_path = split_qa_items(data, split, chat)
        items = items[::stride]
        samples = frame_items(data, split, items)
        t0 = time.perf_counter()
        answers = answer_frames(system, tok, data, split, samples,
                                max_new_tokens=max_new_tokens, batch_size=batch_size,
                                progress=progress)
    wall = time.perf_counter() - t0
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(out) as f:
        for it, a in zip(items, answers, strict=True):
            f.write(json.dumps({"id": it["id"], "answer": a}) + "\n")
    if stride > 1:
        qa_path = out.with_name(out.name + ".ref.jsonl")
        with atomic_write(qa_path) as f:
            for it in items:
                f.write(json.dumps(it) + "\n")
    return {"items": len(items), "out": str(out), "qa": str(qa_path), "model": name,
            "note": note, "wall_s": wall, "empty": sum(not a.strip() for a in answers),
            "items_per_s": len(items) / wall if wall > 0 else 0.0}


__all__ = ["KEYFRAME", "MAX_NEW_TOKENS", "answer_frames", "answer_split", "ask", "frame_items",
           "frame_record", "generate", "generate_fused", "load_answering_system", "model_note",
           "system_note", "visual_embeddings"]
