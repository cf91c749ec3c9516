"""AURORA's whole model (seed paper, sections 4.1-4.3) and the files of a trained run.

:class:`AuroraSystem` holds the two perception branches, CQAF with its fused heads and semantic
fusion (:mod:`.cqaf`), the language model with LoRA (:class:`~.language.AuroraLM`) and the
planner (:mod:`.planners`). One forward pass on a batch (:mod:`.pairs`) runs:

1. perception: the ego branch on the ego cameras (or its cached outputs, ``feat/*``, while it is
   frozen: :mod:`.feature_cache`); the roadside message (:func:`~.cqaf.rsu_message` of the
   roadside branch on the unit's camera, rounded to the wire's float16: :func:`~.rsu_agent.
   to_wire`; or the cached message, ``msg/*``); rows without a roadside unit, and every row of a
   model without fusion (``fusion=False``: the paper's No Fusion), get the empty message;
2. CQAF: DET-CQAF, MAP-CQAF, fused heads, semantic fusion -> ``T^f_det``, ``T^f_map``;
3. the language model on the prompt with the fused tokens in place of ``<det>`` / ``<map>``
   (next-token loss where the batch has ``labels``), giving the ``<wp>`` hidden state;
4. the planner on ``h_wp``, the navigation command and (``cfg.plan_route_points`` > 0) the
   route points ahead, ``route_points`` (:mod:`.route_input`) (rows with ``plan_mask``).

Run files (``RUN/stage<N>/``, written by :mod:`.stages`): ``aurora.json`` (config, the LM's
base folder, fusion, data), the trainer's ``checkpoint.safetensors`` (every weight of the
system: branches, CQAF, base LM, LoRA, planner) and ``adapter/`` (peft's adapter files plus
the bridge, :meth:`~.language.AuroraLM.save`). :func:`load_system` rebuilds the model of a run.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import torch
from torch import nn

from .branch import PerceptionBranch
from .config import AuroraConfig
from .cqaf import CQAF, empty_message, rsu_message
from .language import AuroraLM, add_lora, load_lm
from .planners import build_planner
from .route_input import PATH_KEY, ROUTE_KEY
from .rsu_agent import to_wire

#: Ego-branch outputs CQAF and the LM read (the last decoder layer), per sample.
EGO_FEATURES = ("q_det", "det_ref", "det_logits", "q_map", "map_points", "t_det", "t_map")
#: Message tensors per sample (:func:`~.cqaf.rsu_message` without the pose and masks).
MSG_FEATURES = ("det_queries", "det_ref", "det_scores", "map_queries", "map_points",
                "map_scores")
RUN_CONFIG = "aurora.json"
CHECKPOINT = "checkpoint.safetensors"
ADAPTER_DIR = "adapter"
LATE_STAGES = (3, 4, 5)


def ego_features(out: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The :data:`EGO_FEATURES` of an ego branch's outputs (last decoder layer, ``(B, ...)``)."""
    return {"q_det": out["q_det"], "det_ref": out["det_ref"], "det_logits": out["det_logits"][-1],
            "q_map": out["q_map"], "map_points": out["map_points"][-1], "t_det": out["t_det"],
            "t_map": out["t_map"]}


def ego_outputs(feat: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """:data:`EGO_FEATURES` -> the layout :class:`~.cqaf.CQAF` reads (``L = 1`` layer)."""
    out = dict(feat)
    out["det_logits"] = feat["det_logits"][None]
    out["map_points"] = feat["map_points"][None]
    return out


def message_features(msg: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The :data:`MSG_FEATURES` of a message (what a feature cache stores)."""
    return {k: msg[k] for k in MSG_FEATURES}


def _prefixed(batch: Mapping, prefix: str) -> dict:
    n = len(prefix)
    return {k[n:]: v for k, v in batch.items() if k.startswith(prefix)}


class AuroraSystem(nn.Module):
    """The whole model (module docstring).

    Args:
        cfg: the configuration (its ``planner`` picks the planning decoder).
        lm: the language model wrapper (:class:`~.language.AuroraLM`, with LoRA).
        fusion: use the roadside message (``False``: No Fusion, every message dropped).
    """

    def __init__(self, cfg: AuroraConfig, lm: AuroraLM, fusion: bool = True) -> None:
        super().__init__()
        self.cfg, self.fusion = cfg, bool(fusion)
        self.ego = PerceptionBranch(cfg, "ego")
        self.rsu = PerceptionBranch(cfg, "rsu")
        self.cqaf = CQAF(cfg)
        self.lm = lm
        self.planner = build_planner(cfg, lm.hidden)
        self.frozen_branches = False

    # ------------------------------------------------------------------ training set-up
    def set_trainable(self, *, branches: bool, planner: bool) -> None:
        """Freeze or unfreeze the perception branches and the planner (the base LM stays frozen
        and the LoRA adapters, bridge and CQAF trainable). Frozen branches stay in eval mode
        (their batch norms keep their statistics)."""
        for p in (*self.ego.parameters(), *self.rsu.parameters()):
            p.requires_grad_(branches)
        for p in self.planner.parameters():
            p.requires_grad_(planner)
        self.frozen_branches = not branches
        self.train(self.training)

    def train(self, mode: bool = True) -> AuroraSystem:
        """``nn.Module.train``, keeping frozen branches in eval mode."""
        super().train(mode)
        if self.frozen_branches:
            self.ego.eval()
            self.rsu.eval()
        return self

    # ------------------------------------------------------------------ perception
    def perceive(self, batch: Mapping[str, torch.Tensor]) -> dict:
        """Ego features, the (wire-rounded) message, and the live branch outputs.

        Reads ``feat/*`` and ``msg/*`` (cached) or ``ego/*`` / ``rsu/*`` camera inputs, plus
        ``has_rsu`` ``(B,)`` and ``rsu_to_ego`` ``(B, 4, 4)``. Returns ``ego`` (features),
        ``msg`` (:data:`~.cqaf.MESSAGE_KEYS`), ``ego_out`` / ``rsu_out`` (live outputs, else
        ``None``) and ``rsu_rows`` (indices of the rows the roadside branch ran on)."""
        live_ego = "feat/q_det" not in batch
        ego_out = self.ego(_prefixed(batch, "ego/")) if live_ego else None
        feat = ego_features(ego_out) if live_ego else _prefixed(batch, "feat/")
        b = feat["q_det"].shape[0]
        dev = feat["q_det"].device
        has = batch.get("has_rsu", torch.zeros(b, dtype=torch.bool, device=dev)).bool()
        out = {"ego": feat, "ego_out": ego_out, "rsu_out": None, "rsu_rows": None}
        if not self.fusion or not bool(has.any()):
            out["msg"] = empty_message(self.cfg, b, dev)
            return out
        e = batch["rsu_to_ego"].float()
        if "msg/det_queries" in batch:
            msg = dict(_prefixed(batch, "msg/"))
            msg = {k: msg[k] for k in MSG_FEATURES}
            msg.update(det_mask=has[:, None].expand(msg["det_scores"].shape).clone(),
                       map_mask=has[:, None].expand(msg["map_scores"].shape).clone())
        else:
            rows = has.nonzero()[:, 0]
            rsu_in = {k: v[rows] for k, v in _prefixed(batch, "rsu/").items()}
            rsu_out = self.rsu(rsu_in)
            sub = to_wire(rsu_message(rsu_out, self.cfg, e[rows]))
            msg = {}
            for k in MSG_FEATURES:
                full = sub[k].new_zeros((b, *sub[k].shape[1:]))
                msg[k] = full.index_copy(0, rows, sub[k])
            msg["det_mask"] = has[:, None].expand(msg["det_scores"].shape).clone()
            msg["map_mask"] = has[:, None].expand(msg["map_scores"].shape).clone()
            out.update(rsu_out=rsu_out, rsu_rows=rows)
        eye = torch.eye(4, device=dev).expand(b, 4, 4)
        msg["rsu_to_ego"] = torch.where(has[:, None, None], e, eye)
        out["msg"] = msg
        return out

    def wp_hidden(self, input_ids: torch.Tensor, attention_mask: torch.Tensor | None,
                  det_tokens: torch.Tensor, map_tokens: torch.Tensor) -> dict:
        """:meth:`~.language.AuroraLM.forward`'s ``h_wp`` / ``has_wp`` without the vocabulary
        logits and the per-layer states (the decoder stack only: what inference needs)."""
        embeds = self.lm.embed(input_ids, det_tokens, map_tokens)
        body = self.lm.lm.get_base_model().model  # LoRA layers are injected in place
        h = body(inputs_embeds=embeds, attention_mask=attention_mask,
                 use_cache=False).last_hidden_state
        wp = input_ids == self.lm.wp_id
        has_wp = wp.any(1)
        pos = torch.arange(input_ids.shape[1], device=input_ids.device)
        last = torch.where(wp, pos, -1).amax(1).clamp_min(0)
        h_wp = h[torch.arange(h.shape[0], device=h.device), last]
        return {"loss": None, "h_wp": torch.where(has_wp[:, None], h_wp, torch.zeros_like(h_wp)),
                "has_wp": has_wp}

    # ------------------------------------------------------------------ the whole pass
    def forward(self, batch: Mapping[str, torch.Tensor], *, plan: bool | None = None,
                sample: bool = False) -> dict:
        """Perception -> CQAF -> LM -> planner on a batch (module docstring).

        Args:
            batch: see :mod:`.pairs` (``input_ids``, ``attention_mask``, optional ``labels``,
                ``command``, ``route_points``, ``plan_mask``, ``expert_waypoints``, ...).
            plan: run the planner (default: when the batch has ``plan_mask`` and any row is
                set). In training mode the planner sees the expert trajectory (VAE's future
                distribution).
            sample: VAE planner at inference: sample the latent instead of its mean.

        Returns:
            ``fused`` (CQAF outputs), ``perception`` (:meth:`perceive`), ``lm_loss`` (``None``
            without labelled tokens), ``h_wp`` ``(B, H)``, ``has_wp`` ``(B,)`` and ``plan``
            (the planner's outputs, ``None`` when it did not run).
        """
        per = self.perceive(batch)
        fused = self.cqaf(ego_outputs(per["ego"]), per["msg"])
        labels = batch.get("labels")
        if labels is not None and not bool((labels != -100).any()):
            labels = None
        if labels is None and not torch.is_grad_enabled():  # inference: no logits needed
            lm = self.wp_hidden(batch["input_ids"], batch.get("attention_mask"), fused["t_det"],
                                fused["t_map"])
        else:
            lm = self.lm(batch["input_ids"], batch.get("attention_mask"), fused["t_det"],
                         fused["t_map"], labels)
        out = {"fused": fused, "perception": per, "lm_loss": lm["loss"], "h_wp": lm["h_wp"],
               "has_wp": lm["has_wp"], "plan": None}
        mask = batch.get("plan_mask")
        if plan is None:
            plan = mask is not None and bool(mask.any())
        if plan:
            target = batch.get("expert_waypoints") if self.training else None
            kw = {"sample": sample} if self.cfg.planner == "vae" and target is None else {}
            out["plan"] = self.planner(lm["h_wp"], batch["command"], target,
                                       route=batch.get(ROUTE_KEY), path=batch.get(PATH_KEY),
                                       **kw)
        return out


# ---------------------------------------------------------------------- run files
def stage_dir(run: str | Path, stage: int) -> Path:
    """``RUN/stage<N>``."""
    return Path(run) / f"stage{int(stage)}"


def read_stage_info(run: str | Path, stage: int) -> dict:
    """``RUN/stage<N>/aurora.json`` (``FileNotFoundError`` naming it when absent)."""
    path = stage_dir(run, stage) / RUN_CONFIG
    if not path.is_file():
        raise FileNotFoundError(f"AURORA run {run}: {path} is missing (train stage {stage} "
                                f"with `v2xbench aurora train --stage {stage} --out {run}`)")
    return json.loads(path.read_text())


def latest_stage(run: str | Path) -> int | None:
    """The highest of stages 5, 4, 3 with a checkpoint in ``run`` (``None``: none)."""
    for s in sorted(LATE_STAGES, reverse=True):
        d = stage_dir(run, s)
        if (d / CHECKPOINT).is_file() and (d / RUN_CONFIG).is_file():
            return s
    return None


def resolve_lm_path(run: str | Path, info: Mapping) -> Path:
    """The base LM folder a stage's ``aurora.json`` names (relative paths: to the run)."""
    from .stage0 import base_lm_dir

    return base_lm_dir(run, info["lm"])


def build_system(cfg: AuroraConfig, lm_dir: str | Path, fusion: bool = True
                 ) -> tuple[AuroraSystem, object]:
    """A fresh :class:`AuroraSystem` on the base LM of ``lm_dir`` (``load_lm``) with new LoRA
    adapters; returns ``(system, tokenizer)``. Seed torch first for repeatable weights."""
    base, tok = load_lm(lm_dir)
    lm = AuroraLM(add_lora(base, cfg), tok, cfg.lm_width)
    return AuroraSystem(cfg, lm, fusion), tok


def load_system(run: str | Path, stage: int | None = None, device: str = "cpu"
                ) -> tuple[AuroraSystem, object, dict]:
    """The trained system of ``run`` (``stage``: default :func:`latest_stage`), in eval mode.

    Returns ``(system, tokenizer, info)``; ``info`` is the stage's ``aurora.json`` plus
    ``checkpoint`` and ``lm_dir`` (the files the weights come from).

    Raises:
        FileNotFoundError: no stage 3-5 in ``run`` or a file of it missing.
        ValueError: the checkpoint does not fit the model the stage's config builds.
    """
    from .trainer import load_weights

    run = Path(run)
    if not run.is_dir():
        raise FileNotFoundError(f"AURORA run {run} does not exist (train it with `v2xbench "
                                "aurora train --stage 3|4|5 --out RUN`, or name another run)")
    if stage is None:
        stage = latest_stage(run)
        if stage is None:
            raise FileNotFoundError(f"AURORA run {run} has no trained stage 3, 4 or 5 "
                                    "(checkpoint.safetensors + aurora.json)")
    info = read_stage_info(run, stage)
    cfg = AuroraConfig.from_dict(info["config"])
    lm_dir = resolve_lm_path(run, info)
    system, tok = build_system(cfg, lm_dir, bool(info.get("fusion", True)))
    ckpt = stage_dir(run, stage) / CHECKPOINT
    load_weights(system, ckpt, device)
    info = dict(info, checkpoint=str(ckpt), lm_dir=str(lm_dir), stage=stage)
    return system.to(device).eval(), tok, info


def load_branch_of_run(run: str | Path, branch: str) -> tuple[PerceptionBranch, AuroraConfig,
                                                              Path]:
    """One trained perception branch of ``run``: from the latest stage 3-5 checkpoint (the
    branch's weights in it), else from stage 1 (ego) / 2 (roadside). Returns ``(branch, cfg,
    checkpoint file)``."""
    from safetensors.torch import load_file

    from .eval_perception import BRANCH_STAGE, load_branch

    stage = latest_stage(run)
    if stage is None:
        d = stage_dir(run, BRANCH_STAGE[branch])
        model, cfg = load_branch(d)
        return model, cfg, d / CHECKPOINT
    info = read_stage_info(run, stage)
    cfg = AuroraConfig.from_dict(info["config"])
    ckpt = stage_dir(run, stage) / CHECKPOINT
    state = {k[len(branch) + 1:]: v for k, v in load_file(str(ckpt)).items()
             if k.startswith(branch + ".")}
    model = PerceptionBranch(cfg, branch)
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise ValueError(f"load_branch_of_run: {ckpt} does not fit the {branch} branch: {e}"
                         ) from None
    return model.eval(), cfg, ckpt


__all__ = ["ADAPTER_DIR", "CHECKPOINT", "EGO_FEATURES", "LATE_STAGES", "MSG_FEATURES",
           "RUN_CONFIG", "AuroraSystem", "build_system", "ego_features", "ego_outputs",
           "latest_stage", "load_branch_of_run", "load_system", "message_features",
           "read_stage_info", "resolve_lm_path", "stage_dir"]
