"""AURORA's language model: a Llama-architecture causal LM, LoRA adapters, fused visual tokens
and the ``<wp>`` hidden state (seed paper, section 4.3).

- :func:`build_lm`: a ``transformers`` ``LlamaForCausalLM`` from a ``LlamaConfig`` sized by the
  scale (``cfg.lm_*``; a few million parameters at ``default``, ~60k at ``tiny``). No pretrained
  model can be downloaded here: the stage-0 training (a later part) pre-trains it on the
  Chat-V2XBench text; :func:`load_lm` reads any local Hugging Face causal-LM folder
  (``from_pretrained(local_dir)``), :func:`save_lm` writes one (model + tokenizer).
- :func:`add_lora`: LoRA through ``peft`` (``cfg.lora_rank``, ``lora_alpha``, ``lora_dropout``,
  ``lora_targets``): the base weights are frozen, only the adapters train; :func:`save_adapter`
  / :func:`load_adapter` use peft's own ``save_pretrained`` / ``PeftModel.from_pretrained``.
- :class:`AuroraLM`: the fused semantic tokens ``T^f_det`` / ``T^f_map`` replace the input
  embeddings of the ``<det>`` / ``<map>`` placeholders (through a linear projection when their
  width differs from the LM's), ``<wp>``'s input embedding is a learned vector of the wrapper
  (the base embedding table stays frozen), and the forward pass returns the final-layer hidden
  state at ``<wp>`` (after the final norm: what the planner reads) with the next-token loss.
  :meth:`AuroraLM.save` / :meth:`AuroraLM.load`: the adapters (peft) and the wrapper's own
  weights (:class:`TokenBridge`, safetensors through :mod:`.trainer`).
- :func:`encode_qa`, :func:`collate_text`: token ids and labels of (prompt, answer) pairs, the
  loss only on the answer and its ``</s>``.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

import torch
from peft import LoraConfig, PeftModel, get_peft_model
from torch import nn
from transformers import AutoModelForCausalLM, LlamaConfig, LlamaForCausalLM
from transformers import PreTrainedTokenizerFast as Tokenizer
from transformers.utils import logging as hf_logging

from .config import AuroraConfig
from .tokenizer import DET, MAP, WP, check_tokenizer, load_tokenizer
from .trainer import load_weights, save_checkpoint

# peft 0.21 still calls transformers 5's deprecated ``is_gradient_checkpointing`` when it wraps a
# model: a warning about the libraries' own versions, not about anything a user can change
warnings.filterwarnings("ignore", message=".*is_gradient_checkpointing.*", category=FutureWarning)

IGNORE = -100  # label of positions without a next-token loss
hf_logging.disable_progress_bar()  # no tqdm bars when saving / loading small local models


# ---------------------------------------------------------------------- the base model
def lm_config(cfg: AuroraConfig, tokenizer: Tokenizer) -> LlamaConfig:
    """The ``LlamaConfig`` of the scale, with the tokenizer's vocabulary and special ids."""
    check_tokenizer(tokenizer)
    return LlamaConfig(
        vocab_size=len(tokenizer), hidden_size=cfg.lm_width, intermediate_size=cfg.lm_ffn,
        num_hidden_layers=cfg.lm_layers, num_attention_heads=cfg.lm_heads,
        num_key_value_heads=cfg.lm_kv_heads, max_position_embeddings=cfg.lm_max_len,
        tie_word_embeddings=cfg.lm_tie_embeddings, pad_token_id=tokenizer.pad_token_id,
        bos_token_id=tokenizer.bos_token_id, eos_token_id=tokenizer.eos_token_id)


def build_lm(cfg: AuroraConfig, tokenizer: Tokenizer) -> LlamaForCausalLM:
    """A randomly initialized Llama causal LM of the scale (seed torch for repeatable weights)."""
    return LlamaForCausalLM(lm_config(cfg, tokenizer))


def save_lm(lm: nn.Module, tokenizer: Tokenizer, out_dir: str | Path) -> Path:
    """``save_pretrained`` of the base model (safetensors) and the tokenizer into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    lm.save_pretrained(str(out))
    tokenizer.save_pretrained(str(out))
    return out


def load_lm(path: str | Path) -> tuple[nn.Module, Tokenizer]:
    """``(model, tokenizer)`` of a local Hugging Face causal-LM folder (``from_pretrained``).

    Raises:
        FileNotFoundError: no ``config.json`` in ``path``. ValueError: the tokenizer lacks
            AURORA's special tokens, or its size differs from the model's vocabulary.
    """
    path = Path(path)
    if not (path / "config.json").is_file():
        raise FileNotFoundError(f"load_lm: {path} holds no Hugging Face model (config.json)")
    tok = load_tokenizer(path)
    lm = AutoModelForCausalLM.from_pretrained(str(path))
    if lm.get_input_embeddings().num_embeddings < len(tok):
        raise ValueError(f"load_lm: {path}: the tokenizer has {len(tok)} tokens but the model's "
                         f"vocabulary only {lm.get_input_embeddings().num_embeddings}")
    return lm, tok


# ---------------------------------------------------------------------- LoRA
def lora_config(cfg: AuroraConfig) -> LoraConfig:
    """peft's ``LoraConfig`` of the scale (causal LM, no bias)."""
    return LoraConfig(r=cfg.lora_rank, lora_alpha=cfg.lora_alpha,
                      target_modules=list(cfg.lora_targets), lora_dropout=cfg.lora_dropout,
                      bias="none", task_type="CAUSAL_LM")


def add_lora(lm: nn.Module, cfg: AuroraConfig) -> PeftModel:
    """Wrap a base LM with fresh LoRA adapters (base weights frozen)."""
    names = {n.rsplit(".", 1)[-1] for n, _ in lm.named_modules()}
    missing = [t for t in cfg.lora_targets if t not in names]
    if missing:
        raise ValueError(f"add_lora: the model has no modules named {missing} (lora_targets)")
    return get_peft_model(lm, lora_config(cfg))


def save_adapter(model: PeftModel, out_dir: str | Path) -> Path:
    """peft's ``save_pretrained``: the adapter weights and ``adapter_config.json`` only."""
    out = Path(out_dir)
    model.save_pretrained(str(out))
    return out


def load_adapter(lm: nn.Module, adapter_dir: str | Path, trainable: bool = True) -> PeftModel:
    """``PeftModel.from_pretrained`` of saved adapters onto a base LM."""
    path = Path(adapter_dir)
    if not (path / "adapter_config.json").is_file():
        raise FileNotFoundError(f"load_adapter: {path} holds no peft adapter "
                                "(adapter_config.json)")
    return PeftModel.from_pretrained(lm, str(path), is_trainable=trainable)


# ---------------------------------------------------------------------- text
def encode_qa(tokenizer: Tokenizer, prompt: str, answer: str | None, max_len: int
              ) -> tuple[list[int], list[int]]:
    """``(input_ids, labels)`` of ``<s> prompt [answer </s>]``; labels only on the answer.

    Raises ``ValueError`` when the sequence exceeds ``max_len`` (never silently cut: the
    visual placeholders must all stay).
    """
    ids = tokenizer(prompt)["input_ids"]
    labels = [IGNORE] * len(ids)
    if answer:
        ans = tokenizer(" " + answer.strip(), add_special_tokens=False)["input_ids"]
        ans.append(tokenizer.eos_token_id)
        ids, labels = ids + ans, labels + ans
    if len(ids) > max_len:
        raise ValueError(f"encode_qa: {len(ids)} tokens exceed lm_max_len={max_len}")
    return ids, labels


def collate_text(rows: Sequence[tuple[list[int], list[int]]], pad_id: int
                 ) -> dict[str, torch.Tensor]:
    """Right-padded ``input_ids``, ``attention_mask`` and ``labels`` ``(B, T)``."""
    if not rows:
        raise ValueError("collate_text: no rows")
    t = max(len(ids) for ids, _ in rows)
    ids = torch.full((len(rows), t), pad_id, dtype=torch.long)
    labels = torch.full((len(rows), t), IGNORE, dtype=torch.long)
    mask = torch.zeros(len(rows), t, dtype=torch.long)
    for i, (x, y) in enumerate(rows):
        ids[i, :len(x)] = torch.tensor(x)
        labels[i, :len(y)] = torch.tensor(y)
        mask[i, :len(x)] = 1
    return {"input_ids": ids, "attention_mask": mask, "labels": labels}


# ---------------------------------------------------------------------- the wrapper
BRIDGE_FILE = "bridge.safetensors"


class TokenBridge(nn.Module):
    """The wrapper's own weights: the projection of the fused tokens to the LM's width
    (identity when equal) and the learned input embedding of ``<wp>``."""

    def __init__(self, token_width: int, hidden: int) -> None:
        super().__init__()
        self.proj = nn.Identity() if token_width == hidden else nn.Linear(token_width, hidden)
        self.wp_embed = nn.Parameter(torch.randn(hidden) * 0.02)


class AuroraLM(nn.Module):
    """The language model with fused visual tokens and the ``<wp>`` hidden state.

    Args:
        lm: a causal LM (usually :func:`add_lora`'s ``PeftModel``).
        tokenizer: its tokenizer (AURORA's special tokens, :mod:`.tokenizer`).
        token_width: width of the fused semantic tokens (``cfg.lm_width``).
    """

    def __init__(self, lm: nn.Module, tokenizer: Tokenizer, token_width: int) -> None:
        super().__init__()
        check_tokenizer(tokenizer)
        self.lm = lm
        self.det_id, self.map_id, self.wp_id = tokenizer.convert_tokens_to_ids([DET, MAP, WP])
        self.hidden = lm.get_input_embeddings().embedding_dim
        self.bridge = TokenBridge(token_width, self.hidden)

    # ------------------------------------------------------------------ files
    def save(self, out_dir: str | Path) -> Path:
        """Adapters (peft's ``save_pretrained``) and :class:`TokenBridge` (safetensors)."""
        if not isinstance(self.lm, PeftModel):
            raise ValueError("AuroraLM.save: the model has no LoRA adapters (use save_lm for a "
                             "base model)")
        out = save_adapter(self.lm, out_dir)
        save_checkpoint(self.bridge, out / BRIDGE_FILE, {"hidden": str(self.hidden)})
        return out

    @classmethod
    def load(cls, lm: nn.Module, tokenizer: Tokenizer, token_width: int, adapter_dir: str | Path,
             trainable: bool = True) -> AuroraLM:
        """:meth:`save`'s folder onto a base LM (``from_pretrained`` of the adapters)."""
        model = cls(load_adapter(lm, adapter_dir, trainable), tokenizer, token_width)
        load_weights(model.bridge, Path(adapter_dir) / BRIDGE_FILE)
        return model

    # ------------------------------------------------------------------ forward
    def _place(self, embeds: torch.Tensor, where: torch.Tensor, tokens: torch.Tensor | None,
               name: str) -> torch.Tensor:
        counts = where.sum(1)
        n = 0 if tokens is None else tokens.shape[1]
        if bool((counts != n).any()):
            raise ValueError(f"AuroraLM: rows hold {counts.tolist()} {name} placeholders but "
                             f"{n} {name} tokens were given")
        if tokens is None or n == 0:
            return embeds
        vis = self.bridge.proj(tokens).to(embeds.dtype)
        return embeds.masked_scatter(where[..., None], vis)

    def embed(self, input_ids: torch.Tensor, det_tokens: torch.Tensor | None = None,
              map_tokens: torch.Tensor | None = None) -> torch.Tensor:
        """Input embeddings ``(B, T, H)`` with the placeholders and ``<wp>`` replaced."""
        emb = self.lm.get_input_embeddings()(input_ids)
        emb = self._place(emb, input_ids == self.det_id, det_tokens, DET)
        emb = self._place(emb, input_ids == self.map_id, map_tokens, MAP)
        wp = (input_ids == self.wp_id)[..., None]
        return torch.where(wp, self.bridge.wp_embed.to(emb.dtype), emb)

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor | None = None,
                det_tokens: torch.Tensor | None = None, map_tokens: torch.Tensor | None = None,
                labels: torch.Tensor | None = None) -> dict[str, torch.Tensor | None]:
        """Run the LM on ``input_ids`` ``(B, T)`` with ``det_tokens`` ``(B, Q, W)`` and
        ``map_tokens`` ``(B, Qm, W)`` in place of their placeholders (each row must hold exactly
        ``Q`` / ``Qm`` of them).

        Returns ``loss`` (next-token cross-entropy over ``labels``; ``None`` without labels),
        ``logits`` ``(B, T, V)``, ``h_wp`` ``(B, H)`` final-layer hidden state at the row's last
        ``<wp>`` (zeros where there is none) and ``has_wp`` ``(B,)``.
        """
        embeds = self.embed(input_ids, det_tokens, map_tokens)
        out = self.lm(inputs_embeds=embeds, attention_mask=attention_mask, labels=labels,
                      output_hidden_states=True)
        h = out.hidden_states[-1]
        wp = input_ids == self.wp_id
        has_wp = wp.any(1)
        pos = torch.arange(input_ids.shape[1], device=input_ids.device)
        last = torch.where(wp, pos, -1).amax(1).clamp_min(0)
        h_wp = h[torch.arange(h.shape[0], device=h.device), last]
        h_wp = torch.where(has_wp[:, None], h_wp, torch.zeros_like(h_wp))
        return {"loss": out.loss, "logits": out.logits, "h_wp": h_wp, "has_wp": has_wp}


__all__ = ["BRIDGE_FILE", "IGNORE", "AuroraLM", "TokenBridge", "add_lora", "build_lm",
           "collate_text", "encode_qa", "load_adapter", "load_lm", "lm_config", "lora_config",
           "save_adapter", "save_lm"]
