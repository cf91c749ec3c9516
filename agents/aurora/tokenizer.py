"""AURORA's BPE tokenizer: trained with ``tokenizers`` on Chat-V2XBench text, used through
``transformers``' ``PreTrainedTokenizerFast``.

Byte-level BPE (GPT-2 style: every string is encodable, no unknown token) with the special
tokens :data:`SPECIAL_TOKENS`: padding, begin / end of sequence, the visual placeholders
``<det>`` and ``<map>`` (one per fused detection / map token, replaced by those tokens' input
embeddings in :mod:`.language`) and the waypoint token ``<wp>`` (its final hidden state drives the
planner). Encoding a text prepends ``<s>`` (like Llama's tokenizers); ``add_special_tokens=False``
leaves it out.

Training text (:func:`qa_texts`): the questions and answers of ``<data>/chat/qa.jsonl``
(``v2xbench qa build``) of one split's episodes (the split comes from the data set's manifest),
never the items' ``context`` (in files written before the hint-free export it carries the
ground-truth object hints that are now the separate ``hints`` field), plus the fixed phrases of
the run-time prompt (:func:`.prompt.template_texts`). Stage 0 (:mod:`.stage0`) trains its
tokenizer on whole hint-free documents (run-time prompt and answer) instead.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from pathlib import Path

from tokenizers import Tokenizer, decoders, models, pre_tokenizers, processors, trainers
from transformers import PreTrainedTokenizerFast
from v2xbench.collectors.dataset.shards import load_manifest

PAD, BOS, EOS = "<pad>", "<s>", "</s>"
DET, MAP, WP = "<det>", "<map>", "<wp>"
#: Special tokens, in id order (``<pad>`` = 0).
SPECIAL_TOKENS = (PAD, BOS, EOS, DET, MAP, WP)
EXTRA_TOKENS = (DET, MAP, WP)


def train_tokenizer(texts: Iterable[str], vocab_size: int) -> PreTrainedTokenizerFast:
    """A byte-level BPE tokenizer of ``vocab_size`` entries (special tokens included) trained
    on ``texts``; ``ValueError`` if the size cannot hold the byte alphabet and specials."""
    alphabet = pre_tokenizers.ByteLevel.alphabet()
    if vocab_size < len(alphabet) + len(SPECIAL_TOKENS):
        raise ValueError(f"train_tokenizer: vocab_size={vocab_size} must be at least "
                         f"{len(alphabet) + len(SPECIAL_TOKENS)} (256 bytes + special tokens)")
    tok = Tokenizer(models.BPE())
    tok.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(vocab_size=vocab_size, special_tokens=list(SPECIAL_TOKENS),
                                  initial_alphabet=alphabet, show_progress=False)
    tok.train_from_iterator(texts, trainer)
    bos = tok.token_to_id(BOS)
    tok.post_processor = processors.TemplateProcessing(
        single=f"{BOS} $A", pair=f"{BOS} $A $B", special_tokens=[(BOS, bos)])
    return PreTrainedTokenizerFast(tokenizer_object=tok, bos_token=BOS, eos_token=EOS,
                                   pad_token=PAD, extra_special_tokens=list(EXTRA_TOKENS))


def check_tokenizer(tokenizer: PreTrainedTokenizerFast, where: str = "tokenizer") -> None:
    """Raise ``ValueError`` if a special token is not a single known token of ``tokenizer``."""
    vocab = tokenizer.get_vocab()
    missing = [t for t in SPECIAL_TOKENS if t not in vocab]
    if missing:
        raise ValueError(f"{where}: the tokenizer lacks the special tokens {missing} "
                         "(train it with agents.aurora.tokenizer.train_tokenizer)")


def load_tokenizer(path: str | Path) -> PreTrainedTokenizerFast:
    """``PreTrainedTokenizerFast.from_pretrained(path)`` of a local folder, checked."""
    path = Path(path)
    if not (path / "tokenizer.json").is_file():
        raise FileNotFoundError(f"load_tokenizer: {path / 'tokenizer.json'} does not exist")
    tok = PreTrainedTokenizerFast.from_pretrained(str(path))
    check_tokenizer(tok, str(path))
    return tok


def qa_texts(root: str | Path, split: str = "train") -> Iterator[str]:
    """``"question\\nanswer"`` of every Chat-V2XBench item of ``root`` whose episode is in
    ``split`` (``"all"``: every episode); never the ground-truth ``context``.

    Raises:
        FileNotFoundError: no manifest or no ``chat/qa.jsonl`` (run ``v2xbench qa build``).
        ValueError: a line that is not a QA item, or an episode the manifest does not list
            (file and line named).
    """
    root = Path(root)
    shards = load_manifest(root).get("shards", {})
    path = root / "chat" / "qa.jsonl"
    if not path.is_file():
        raise FileNotFoundError(f"qa_texts: {path} does not exist (run `v2xbench qa build`)")
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                item = json.loads(line)
                ep, q, a = item["episode"], item["question"], item["answer"]
            except (ValueError, KeyError, TypeError) as e:
                raise ValueError(f"{path}:{n}: not a QA item ({type(e).__name__}: {e})") from None
            if ep not in shards:
                raise ValueError(f"{path}:{n}: episode {ep!r} is not in the manifest of {root}")
            if split == "all" or shards[ep].get("split") == split:
                yield f"{q}\n{a}"


__all__ = ["BOS", "DET", "EOS", "EXTRA_TOKENS", "MAP", "PAD", "SPECIAL_TOKENS", "WP",
           "check_tokenizer", "load_tokenizer", "qa_texts", "train_tokenizer"]
