"""Stage 0: pre-train AURORA's language model on the Chat-V2XBench text of the train split.

No pretrained language model can be downloaded here, so stage 0 stands in for one (the paper
starts from Vicuna-7B): ``v2xbench aurora train --stage 0 --data DATA --out RUN``

1. reads the hint-free QA items of the ``train`` split (``DATA/chat/qa.jsonl`` or ``--chat``;
   ``v2xbench qa build``): every item is a document ``<s> prompt answer</s>`` whose prompt is the
   run-time prompt without visual placeholders (:func:`~.prompt.prompt_text` of the item's
   hint-free ``context`` and its question; the same text ``v2xbench aurora ask`` gives the
   model when a run has no fused tokens);
2. trains the byte-level BPE tokenizer (:func:`~.tokenizer.train_tokenizer`, ``cfg.lm_vocab``
   entries) on those documents of the whole split and the fixed prompt phrases;
3. pre-trains the Llama LM (:func:`~.language.build_lm`) with the next-token loss over every
   token (``loss``; ``answer`` logs the loss on answer tokens alone) on the documents, shuffled
   with the seed and packed into blocks of ``cfg.lm_pretrain_block`` tokens (no padding; a
   block may hold the end of one document and the start of the next, as in GPT pre-training),
   with :func:`~.trainer.fit` (AdamW, warm-up + cosine, clipping, JSONL log, loss plot, atomic
   safetensors checkpoints, exact resume) and the stage's hyper-parameters
   (``cfg.stage_hparams(0)``; its ``frame_stride`` keeps every k-th QA item);
4. writes the model and the tokenizer into ``RUN/stage0/`` with ``save_pretrained`` after every
   call (also when stopped by ``--max-steps``), so that ``from_pretrained(RUN/stage0)`` (
   :func:`~.language.load_lm`) loads it like any local Hugging Face causal LM.

Later stages take their base LM from :func:`find_base_lm` (the one place that resolves it):
``RUN/stage0``, or a local Hugging Face
causal-LM folder given with ``--lm PATH`` (it must hold AURORA's special tokens; see
:func:`~.language.load_lm`).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader, Dataset

from v2xbench.files import atomic_write_json
from v2xbench.locks import dir_lock

from .config import AuroraConfig, same_config
from .language import IGNORE, build_lm, encode_qa, load_lm, save_lm
from .prompt import prompt_text, template_texts
from .tokenizer import load_tokenizer, train_tokenizer

STAGE = 0
RUN_FILE = "aurora.json"
RUN_FORMAT = "v2xbench-aurora-run/1"


# ---------------------------------------------------------------------- text
def split_qa_items(data: str | Path, split: str = "train", chat: str | Path | None = None
                   ) -> tuple[list[dict], Path]:
    """The hint-free Chat-V2XBench items of ``split`` and the ``qa.jsonl`` they came from.

    ``chat``: a folder holding ``qa.jsonl`` (``qa build --out``) or the file; default
    ``DATA/chat/qa.jsonl``.

    Raises:
        FileNotFoundError: no ``qa.jsonl``. ValueError: a file written before the hint-free
            export (its ``context`` holds ground-truth hints), or no item in ``split``.
    """
    from v2xbench.collectors.chat.export import is_hint_free, load_items, split_items

    path = Path(chat) if chat is not None else Path(data) / "chat" / "qa.jsonl"
    if path.is_dir():
        path = path / "qa.jsonl"
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: build the QA text with `v2xbench qa build "
                                f"{data}` (or `--out DIR` and pass --chat DIR)")
    items = load_items(path)
    if not is_hint_free(items):
        raise ValueError(f"{path} was built before the hint-free export (its prompts' context "
                         "holds ground-truth objects); build it again with `v2xbench qa build`")
    return split_items(items, split, str(path)), path


def item_prompt(item: dict) -> str:
    """The text-only run-time prompt of a QA item (no visual placeholders)."""
    return prompt_text(item["context"], item["question"], num_det=0, num_map=0)


def documents(items: list[dict], stride: int = 1) -> list[tuple[str, str]]:
    """``(prompt, answer)`` of every ``stride``-th item."""
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise ValueError(f"stage 0: item stride {stride!r} must be an int >= 1")
    return [(item_prompt(it), it["answer"]) for it in items[::stride]]


def tokenizer_corpus(docs: list[tuple[str, str]]) -> list[str]:
    """The tokenizer's training text: the documents and the fixed run-time prompt phrases."""
    return [f"{p} {a}" for p, a in docs] + template_texts()


def pack(tokenizer, docs: list[tuple[str, str]], block: int, seed: int
         ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(ids, answer)`` ``(N, block)``: the documents (``<s> prompt answer</s>``, shuffled by
    ``seed``) concatenated and cut into blocks (a document may span two blocks; the last
    partial block is dropped); ``answer`` marks answer tokens (and ``</s>``).

    Raises:
        ValueError: fewer tokens than one block.
    """
    order = np.random.default_rng(seed).permutation(len(docs))
    ids: list[int] = []
    ans: list[bool] = []
    for k in order:
        x, y = encode_qa(tokenizer, docs[k][0], docs[k][1], max_len=sys.maxsize)
        ids += x
        ans += [v != IGNORE for v in y]
    n = len(ids) // block
    if n == 0:
        raise ValueError(f"stage 0: {len(docs)} documents give {len(ids)} tokens, fewer than "
                         f"one block of {block}")
    ids_t = torch.tensor(ids[:n * block], dtype=torch.long).view(n, block)
    ans_t = torch.tensor(ans[:n * block], dtype=torch.bool).view(n, block)
    return ids_t, ans_t


class PackedText(Dataset):
    """Map-style data set of packed token blocks: ``{"input_ids", "answer"}`` per block."""

    def __init__(self, ids: torch.Tensor, answer: torch.Tensor) -> None:
        if ids.shape != answer.shape or ids.dim() != 2:
            raise ValueError(f"PackedText: ids {tuple(ids.shape)} and answer "
                             f"{tuple(answer.shape)} must be the same (N, block)")
        self.ids, self.answer = ids, answer

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {"input_ids": self.ids[i], "answer": self.answer[i]}


# ---------------------------------------------------------------------- model and loss
class CausalLMTrainee(nn.Module):
    """A causal LM as :func:`~.trainer.fit` trains it: ``forward(batch)`` gives the logits.

    With tied input / output embeddings the state dict leaves out ``lm.lm_head.weight`` (a
    second name of the embedding table; safetensors refuses shared tensors) and
    :meth:`load_state_dict` restores the tie.
    """

    HEAD = "lm.lm_head.weight"
    EMBED = "lm.model.embed_tokens.weight"

    def __init__(self, lm: nn.Module) -> None:
        super().__init__()
        self.lm = lm

    @property
    def tied(self) -> bool:
        return self.lm.get_output_embeddings().weight is self.lm.get_input_embeddings().weight

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.lm(input_ids=batch["input_ids"]).logits

    def state_dict(self, *args, **kwargs):
        sd = super().state_dict(*args, **kwargs)
        if self.tied:
            sd.pop(kwargs.get("prefix", "") + self.HEAD, None)
        return sd

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        if self.tied and self.HEAD not in state_dict and self.EMBED in state_dict:
            state_dict = {**state_dict, self.HEAD: state_dict[self.EMBED]}
        return super().load_state_dict(state_dict, strict=strict, assign=assign)


class NextTokenLoss(nn.Module):
    """Mean next-token cross-entropy over a block (``loss``) and over its answer tokens
    (``answer``, logged only)."""

    def forward(self, logits: torch.Tensor, batch: dict[str, torch.Tensor]
                ) -> tuple[torch.Tensor, dict[str, float]]:
        target = batch["input_ids"][:, 1:]
        ce = nn.functional.cross_entropy(logits[:, :-1].flatten(0, 1).float(),
                                         target.flatten(), reduction="none").view_as(target)
        ans = batch["answer"][:, 1:]
        answer = float(ce.detach()[ans].mean()) if bool(ans.any()) else float("nan")
        return ce.mean(), {"answer": answer}


# ---------------------------------------------------------------------- the stage
def find_base_lm(run: str | Path | None, lm: str | Path | None = None, *,
                 required: bool = True) -> dict[str, str] | None:
    """The one place that resolves the base LM of the later stages: ``lm`` (a local Hugging
    Face causal-LM folder, ``--lm PATH``) or else the run's stage-0 model ``RUN/stage0``.

    Returns:
        ``{"source": "given", "path": <absolute folder>}`` or ``{"source": "stage0", "path":
        "stage0"}`` (relative to the run, as stage files record it; :func:`base_lm_dir` gives
        the folder), or ``None`` when the run has no stage-0 model and ``required`` is false
        (stage 3 then builds a fresh LM).

    Raises:
        FileNotFoundError: ``lm`` holds no model; ``required`` and the run has no stage-0 model.
        ValueError: neither ``run`` nor ``lm`` given.
    """
    if lm is not None:
        path = Path(lm)
        if not (path / "config.json").is_file():
            raise FileNotFoundError(f"--lm {path}: no Hugging Face causal-LM folder "
                                    "(config.json missing)")
        return {"source": "given", "path": str(path.resolve())}
    if run is None:
        raise ValueError("find_base_lm: give a run folder or --lm PATH")
    path = Path(run) / f"stage{STAGE}"
    if (path / "config.json").is_file():
        return {"source": "stage0", "path": f"stage{STAGE}"}
    if not required:
        return None
    raise FileNotFoundError(f"{path} holds no stage-0 language model: train it with "
                            f"`v2xbench aurora train --stage 0 --data DATA --out {run}` or "
                            "pass --lm PATH (a local Hugging Face causal-LM folder)")


def base_lm_dir(run: str | Path | None, choice: dict[str, str]) -> Path:
    """The folder of a :func:`find_base_lm` choice (relative paths are inside ``run``)."""
    p = Path(choice["path"])
    if p.is_absolute():
        return p
    if run is None:
        raise ValueError(f"base_lm_dir: {p} is relative to a run folder; none given")
    return Path(run) / p


def _check_same_run(path: Path, info: dict) -> None:
    if not path.is_file():
        return
    old = json.loads(path.read_text())
    diff = [k for k in ("stage", "scale", "data", "chat", "item_stride", "seed")
            if old.get(k) != info[k]]
    diff += [] if same_config(old.get("config"), info["config"]) else ["config"]
    if diff:
        raise ValueError(f"aurora train: {path.parent} holds a stage-0 run with other settings "
                         f"({', '.join(diff)} differ: {[old.get(k) for k in diff if k != 'config']}"
                         f" vs {[info[k] for k in diff if k != 'config']}); use the same settings "
                         "to resume, or another --out")


def _save_pretrained(lm: nn.Module, tokenizer, out: Path) -> None:
    """``save_lm`` into a temporary folder, then each file moved into ``out`` atomically."""
    tmp = out / ".hf_tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    save_lm(lm, tokenizer, tmp)
    for f in sorted(tmp.iterdir(), key=lambda p: p.name == "config.json"):  # config last
        os.replace(f, out / f.name)
    tmp.rmdir()


def train_stage0(data: str | Path, out: str | Path, *, scale: str = "default",
                 chat: str | Path | None = None, device: str = "cpu",
                 max_steps: int | None = None, stride: int | None = None, seed: int = 0,
                 progress: bool = True) -> dict:
    """Stage 0 (module docstring) into ``out/stage0``; resumes a run of the same settings.

    Args:
        data: data set folder (its manifest gives the splits). out: run folder RUN.
        scale: ``tiny``, ``default`` or ``paper``. chat: ``qa.jsonl`` or its folder (default
            ``DATA/chat``). device: torch device. max_steps: stop after this many optimizer
            steps in total (the schedule still spans the stage; run again to go on).
        stride: keep every k-th QA item (default: the scale's ``stage0.frame_stride``).
        seed: seed of the tokenizer-independent parts: initial weights, document order, epochs.

    Returns:
        :func:`~.trainer.fit`'s summary plus ``stage``, ``scale``, ``documents``, ``blocks``,
        ``tokens``, ``prepare_s`` (reading, tokenizer training and packing) and ``lm_dir``.
    """
    import dataclasses

    t0 = time.perf_counter()
    cfg = AuroraConfig.for_scale(scale)
    hp = cfg.stage_hparams(STAGE)
    if stride is not None:
        hp = dataclasses.replace(hp, frame_stride=stride)
    if not Path(data).is_dir():
        raise FileNotFoundError(f"aurora train: data directory {data} does not exist")
    items, qa_path = split_qa_items(data, "train", chat)
    docs = documents(items, hp.frame_stride)
    stage_dir = Path(out) / f"stage{STAGE}"
    stage_dir.mkdir(parents=True, exist_ok=True)
    with dir_lock(stage_dir, "aurora training"):
        return _train(cfg, hp, data, qa_path, items, docs, stage_dir, scale, device, max_steps,
                      seed, progress, t0)


def _train(cfg, hp, data, qa_path, items, docs, stage_dir, scale, device, max_steps, seed,
           progress, t0) -> dict:
    from .trainer import fit

    info = {"format": RUN_FORMAT, "stage": STAGE, "branch": "language model", "scale": scale,
            "config": cfg.to_dict(), "data": str(Path(data).resolve()),
            "chat": str(qa_path.resolve()), "split": "train", "item_stride": hp.frame_stride,
            "seed": seed}
    _check_same_run(stage_dir / RUN_FILE, info)
    old = json.loads((stage_dir / RUN_FILE).read_text()) if (stage_dir / RUN_FILE).is_file() else {}
    atomic_write_json(stage_dir / RUN_FILE, {**old, **info}, indent=1)  # before the tokenizer
    if (stage_dir / "tokenizer.json").is_file():
        tok = load_tokenizer(stage_dir)
    else:
        tok = train_tokenizer(tokenizer_corpus(documents(items)), cfg.lm_vocab)
        tok.save_pretrained(str(stage_dir))
    ids, answer = pack(tok, docs, cfg.lm_pretrain_block, seed)
    info.update(documents=len(docs), blocks=len(ids), block=cfg.lm_pretrain_block,
                tokens=int(ids.numel()), vocab=len(tok))
    atomic_write_json(stage_dir / RUN_FILE, info, indent=1)
    loader = DataLoader(PackedText(ids, answer), batch_size=hp.batch_size, shuffle=True)
    torch.manual_seed(seed)  # the initial weights are part of the run
    model = CausalLMTrainee(build_lm(cfg, tok))
    prepare_s = time.perf_counter() - t0
    summary = fit(model, NextTokenLoss(), loader, stage_dir, hp, device=device, seed=seed,
                  progress=progress, max_steps=max_steps, lock=False)
    model.lm.to("cpu")
    _save_pretrained(model.lm, tok, stage_dir)
    summary.update(stage=STAGE, branch="language model", scale=scale, documents=len(docs),
                   blocks=len(ids), tokens=int(ids.numel()),
                   prepare_s=prepare_s, lm_dir=str(stage_dir))
    atomic_write_json(stage_dir / "train_summary.json", summary, indent=1)
    return summary


def format_stage0_summary(s: dict) -> str:
    """One line about a stage-0 training call."""
    from .trainer import loss_text, progress_text

    return (f"stage 0 (language model, {s['scale']}): {progress_text(s)}, "
            f"{s['documents']} QA documents, "
            f"{s['tokens']} tokens in {s['blocks']} blocks, loss {loss_text(s)}, "
            f"{s['samples_per_s'] * s['tokens'] / max(s['blocks'], 1):.0f} tokens/s, "
            f"{s['wall_s'] + s['prepare_s']:.0f} s -> {s['lm_dir']} (from_pretrained)")


def load_stage0(run: str | Path | None, lm: str | Path | None = None):
    """``(model, tokenizer, path)`` of :func:`find_base_lm` (``from_pretrained``), in eval
    mode."""
    path = base_lm_dir(run, find_base_lm(run, lm))
    model, tok = load_lm(path)
    return model.eval(), tok, path


__all__ = ["CausalLMTrainee", "NextTokenLoss", "PackedText", "documents", "format_stage0_summary",
           "item_prompt",
           "base_lm_dir", "find_base_lm", "load_stage0", "pack", "split_qa_items",
           "tokenizer_corpus",
           "train_stage0"]
