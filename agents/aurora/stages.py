"""Stages 3, 4 and 5 of AURORA (seed paper, appendix "Stage-wise training") on part 1's trainer.

================  ===========================================================================
stage             trains (losses)
================  ===========================================================================
3 fusion + QA     CQAF, fused heads (``gt/fused``: part 1's set losses), LoRA + bridge (the
                  QA next-token loss), and the branches where the scale does not freeze them
                  (their ego / roadside set losses: the paper's L3); planner off
4 planning        the planner (L1 to the expert's first 6 waypoints, map boundary, collision
                  with the fused agents' constant-velocity futures, VAE KL), CQAF, LoRA;
                  branches frozen; planning prompts ending with ``<wp>``
5 joint           as 4 on a mix of QA and planning samples; the waypoint loss only on samples
                  with ``<wp>``, the QA loss only on samples with an answer
================  ===========================================================================

Each stage starts from the previous one (stage 3: the ego branch of ``RUN/stage1``, the roadside
branch of ``RUN/stage2``, the base LM, new LoRA adapters; stages 4 and 5: the whole previous
checkpoint) and trains in ``RUN/stage<N>`` with :func:`~.trainer.fit` (resume, logs, plots).
The base LM is ``--lm PATH`` (a local Hugging Face causal LM), else ``RUN/stage0`` (stage 0's
pre-trained LM) when present, else a freshly built one: a BPE tokenizer trained on the train
split's QA text and a randomly initialized Llama of the scale, saved in ``RUN/stage3/base_lm``
(the summary says which). While the branches are frozen their outputs come from a feature
cache (:mod:`.feature_cache`, ``RUN/cache``), computed once.

Samples (:mod:`.pairs`, train split): stage 3 every ``frame_stride``-th QA item, stage 4 every
``frame_stride``-th frame as a planning sample, stage 5 both. ``fusion=False`` trains the No
Fusion model: every roadside message dropped, the prompt saying none arrived.

``qa=False`` (``aurora train|pipeline --no-qa``, the VQA ablation) drops the Chat-V2XBench
next-token loss from all three stages: stage 3 trains on every ``frame_stride``-th frame with
the planning prompt instead of the QA items, its loss only the fused heads' (and, with live
branches, the ego / roadside set losses), the planner not run (``plan_mask`` off), so LoRA, the
bridge and semantic fusion get no gradient there; stage 4 is unchanged (its samples carry no
answer); stage 5 trains on its planning samples only (stage 4's losses, stage 5's schedule).
The setting is recorded as ``qa`` in each stage's ``aurora.json`` (a file without it: ``True``)
and must agree along the run.

The planner's route input (``plan_route_points``, :mod:`.route_input`) is chosen per late stage:
``route_points`` (``aurora train --plan-route-points K``) if given, else the value of stages
1-2's run file, else (a run file from before the field) the scale's default. Stage 5 continues
stage 4's planner and keeps its value (a different one is refused). Stage 3 does not train the
planner, so stage 4 may add (or drop) the route encoder on top of a stage 3 without it: that is
how stages 4-5 of an existing run are retrained with route points, stages 1-3 kept.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import shutil
from pathlib import Path

import torch
from torch import nn

from v2xbench.files import atomic_write_json

from .config import ABSENT_MEANS_OFF, SCALES, STAGE_TABLE, AuroraConfig
from .fused_heads import FusedCriterion
from .losses import SetCriterion
from .planner_losses import PlanningCriterion
from .system import (
    ADAPTER_DIR,
    CHECKPOINT,
    RUN_CONFIG,
    AuroraSystem,
    build_system,
    read_stage_info,
    resolve_lm_path,
    stage_dir,
)

LATE_STAGES = (3, 4, 5)
ROUTE_ENCODER = "planner.route."  # the planner's route encoder's weights (planners.Planner)
STAGE_NAMES = {3: "fusion + QA", 4: "planning", 5: "joint QA + planning"}
BASE_LM_DIR = "base_lm"
FUSED_PARTS = ("det_cls", "det_box", "map_cls", "map_pts")
PLAN_PARTS = {"vae": ("plan_l1", "plan_col", "plan_bound", "plan_kl"),
              "mlp": ("plan_l1", "plan_col", "plan_bound"),
              "diffusion": ("plan_cls", "plan_reg", "plan_bound")}


# ---------------------------------------------------------------------- the losses
class StageCriterion(nn.Module):
    """The loss of stage 3, 4 or 5 (module docstring): ``(total, parts)``. Parts: ``fused``
    (stage 3), ``ego`` / ``rsu`` (stage 3 with live branches), ``qa`` and, in stages 4-5, the
    planning terms (:class:`~.planner_losses.PlanningCriterion`); every part of the stage is
    reported at every step (0 where the batch has none). ``qa=False``: no ``qa`` part."""

    def __init__(self, cfg: AuroraConfig, stage: int, live_branches: bool = False,
                 qa: bool = True) -> None:
        super().__init__()
        self.cfg, self.stage, self.live = cfg, int(stage), bool(live_branches)
        self.qa = bool(qa)
        self.fused = FusedCriterion(cfg)
        self.plan = PlanningCriterion(cfg)
        self.ego = SetCriterion(cfg, "ego")
        self.rsu = SetCriterion(cfg, "rsu")

    def forward(self, out: dict, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        """Total loss (scalar tensor) and its weighted parts."""
        zero = (out["h_wp"].sum() * 0.0).abs()  # 0 in the graph (never a logged -0.0)
        terms: dict[str, torch.Tensor] = {}
        report: dict[str, float] = {}
        if self.stage == 3:
            terms["fused"] = self.fused(out["fused"], batch)[0]
            per = out["perception"]
            if self.live:
                terms["ego"] = terms["rsu"] = zero
                if per["ego_out"] is not None:
                    sub = {k[4:]: v for k, v in batch.items() if k.startswith("ego/")}
                    terms["ego"] = self.ego(per["ego_out"], sub)[0]
                if per["rsu_out"] is not None:
                    rows = per["rsu_rows"]
                    sub = {k[4:]: v[rows] for k, v in batch.items() if k.startswith("rsu/")}
                    terms["rsu"] = self.rsu(per["rsu_out"], sub)[0]
        if self.qa:
            terms["qa"] = out["lm_loss"] if out["lm_loss"] is not None else zero
        if self.stage >= 4:
            names = PLAN_PARTS[self.cfg.planner]
            if out["plan"] is None:
                terms["plan"] = zero
                report.update({k: 0.0 for k in names})
            else:
                terms["plan"], parts = self.plan(out["plan"], batch)
                report.update({k: parts.get(k, 0.0) for k in names})
        total = sum(terms.values())
        report.update({k: float(v.detach()) for k, v in terms.items()})
        return total, report


# ---------------------------------------------------------------------- the base LM
def base_lm(run: Path, data: Path, cfg: AuroraConfig, lm: str | Path | None, seed: int
            ) -> dict[str, str]:
    """Stage 3's base LM: ``{"source", "path"}``: :func:`~.stage0.find_base_lm`'s choice (``--lm
    PATH``, else ``RUN/stage0``), else a fresh one built and saved in ``RUN/stage3/base_lm``
    (once: a resumed stage reuses it)."""
    from .language import build_lm, save_lm
    from .prompt import template_texts
    from .stage0 import find_base_lm
    from .tokenizer import qa_texts, train_tokenizer

    chosen = find_base_lm(run, lm, required=False)
    if chosen is not None:
        return chosen
    out = stage_dir(run, 3) / BASE_LM_DIR
    if not (out / "config.json").is_file():
        texts = itertools.chain(qa_texts(data, "train"), template_texts())
        tok = train_tokenizer(texts, cfg.lm_vocab)
        torch.manual_seed(seed)
        tmp = out.with_name(BASE_LM_DIR + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        save_lm(build_lm(cfg, tok), tok, tmp)
        shutil.rmtree(out, ignore_errors=True)
        tmp.rename(out)
    return {"source": "fresh", "path": f"stage3/{BASE_LM_DIR}"}


# ---------------------------------------------------------------------- one stage
def _run_config(run: Path, scale: str | None) -> AuroraConfig:
    """The configuration stages 1 and 2 of ``run`` were trained with (they must agree); a
    planner field their files predate takes the scale's default (they trained no planner)."""
    cfgs = []
    for s in (1, 2):
        path = stage_dir(run, s) / RUN_CONFIG
        if not path.is_file() or not (stage_dir(run, s) / CHECKPOINT).is_file():
            raise FileNotFoundError(f"aurora train: {stage_dir(run, s)} has no trained stage {s} "
                                    f"(train stages 1 and 2 first: `v2xbench aurora train "
                                    f"--stage {s} --out {run}`)")
        raw = json.loads(path.read_text())["config"]
        defaults = AuroraConfig.for_scale(raw["scale"]).to_dict() \
            if raw.get("scale") in SCALES else {}
        cfgs.append(AuroraConfig.from_dict({k: defaults[k] for k in ABSENT_MEANS_OFF
                                            if k in defaults} | raw))
    if cfgs[0] != cfgs[1]:
        raise ValueError(f"aurora train: stages 1 and 2 of {run} were trained with different "
                         "configurations")
    if scale is not None and cfgs[0].scale != scale:
        raise ValueError(f"aurora train: {run} was trained at scale {cfgs[0].scale!r} (stages 1-2)"
                         f", not {scale!r}; drop --scale or use another run")
    return cfgs[0]


def _route_config(run: Path, stage: int, cfg: AuroraConfig, requested: int | None,
                  speed_dropout: float | None = None) -> AuroraConfig:
    """``cfg`` with the stage's planner inputs (module docstring): stage 5 keeps stage 4's
    ``plan_route_points`` / ``plan_route_spacing`` / ``plan_frame`` / ``plan_route_step`` /
    ``plan_speed_dropout``; stages 3-4 take ``requested`` (route points) and stage 4
    ``speed_dropout`` if given."""
    if stage == 5:
        prev = AuroraConfig.from_dict(read_stage_info(run, 4)["config"])
        for flag, want, had in (("--plan-route-points", requested, prev.plan_route_points),
                                ("--speed-dropout", speed_dropout, prev.plan_speed_dropout)):
            if want is not None and want != had:
                raise ValueError(f"aurora train: stage 4 of {run} trained its planner with "
                                 f"{flag} {had}; stage 5 continues it (drop {flag} {want}, or "
                                 "retrain stage 4 with it in another run folder)")
        return dataclasses.replace(cfg, plan_route_points=prev.plan_route_points,
                                   plan_route_spacing=prev.plan_route_spacing,
                                   plan_frame=prev.plan_frame,
                                   plan_route_step=prev.plan_route_step,
                                   plan_speed_dropout=prev.plan_speed_dropout)
    if speed_dropout is not None:
        if stage != 4:
            raise ValueError("aurora train: --speed-dropout applies to stage 4 (stage 5 keeps "
                             "stage 4's)")
        cfg = dataclasses.replace(cfg, plan_speed_dropout=float(speed_dropout))
    if requested is None:
        return cfg
    return dataclasses.replace(cfg, plan_route_points=requested)


def _load_previous(system: AuroraSystem, run: Path, stage: int) -> None:
    """The whole checkpoint of stage ``stage - 1`` into ``system``. Stage 4 on a stage 3 of
    another route input (stage 3 does not train the planner): the route encoder keeps its fresh
    weights (or is not loaded); every other weight must fit."""
    from safetensors.torch import load_file

    from .trainer import load_weights

    ckpt = stage_dir(run, stage - 1) / CHECKPOINT
    prev = AuroraConfig.from_dict(read_stage_info(run, stage - 1)["config"])
    if stage != 4 or prev.plan_route_points == system.cfg.plan_route_points:
        load_weights(system, ckpt)
        return
    state = {k: v for k, v in load_file(str(ckpt)).items() if not k.startswith(ROUTE_ENCODER)}
    missing, unexpected = system.load_state_dict(state, strict=False)
    bad = [k for k in missing if not k.startswith(ROUTE_ENCODER)] + list(unexpected)
    if bad:
        raise ValueError(f"load_weights: {ckpt} does not fit the model: {bad[:5]}")


def _items(data: Path, stage: int, frames, stride: int, qa: bool = True) -> list:
    """The stage's samples (module docstring; ``qa=False``: planning frames only)."""
    from .pairs import planning_items, qa_items

    if stage == 3 and qa:
        return qa_items(data, frames, stride)
    if stage == 4 or not qa:
        return planning_items(frames, stride)
    return planning_items(frames, stride) + qa_items(data, frames, stride)


def _check_same_run(path: Path, info: dict) -> None:
    from .cli import _same_config
    from .config import config_changes

    if not path.is_file():
        return
    old = json.loads(path.read_text())
    keys = ("stage", "scale", "data", "frame_stride", "seed", "fusion", "qa", "lm", "cache")
    old = {"qa": True, **old}  # a run file from before the switch trained with the QA loss
    shown = [f"{k}: {old.get(k)!r} -> {info[k]!r}" for k in keys
             if old.get(k) != json.loads(json.dumps(info[k]))]
    if not _same_config(old.get("config"), info["config"]):
        shown.append(f"config ({config_changes(old.get('config'), info['config'])})")
    else:  # a run file without the key trained a planner without route input
        was = AuroraConfig.from_dict(old["config"])
        route = ("plan_route_points", "plan_frame", "plan_route_step")  # absent: off
        changed = [f"{k}: {getattr(was, k)!r} -> {info['config'][k]!r}" for k in route
                   if getattr(was, k) != info["config"][k]]
        if changed:
            shown.append(f"config ({', '.join(changed)})")
    if shown:
        raise ValueError(f"aurora train: {path.parent} holds a run with other settings "
                         f"({'; '.join(shown)}); use the same settings to resume, or another "
                         "--out")


def _save_adapter(system: AuroraSystem, out: Path) -> None:
    """The LoRA adapters and bridge via peft's own API (:meth:`~.language.AuroraLM.save`)."""
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    system.lm.save(tmp)
    shutil.rmtree(out, ignore_errors=True)
    tmp.rename(out)


def train_late_stage(data: str | Path, out: str | Path, stage: int, *,
                     scale: str | None = None, device: str = "cpu",
                     max_steps: int | None = None, stride: int | None = None, seed: int = 0,
                     progress: bool = True, num_workers: int | None = None,
                     lm: str | Path | None = None, fusion: bool = True,
                     cache: bool = True, route_points: int | None = None,
                     qa: bool = True, speed_dropout: float | None = None) -> dict:
    """Train stage 3, 4 or 5 of ``out`` on the train split of ``data`` (module docstring).

    Args:
        data: data set folder with Chat-V2XBench items (``v2xbench qa build``).
        out: the run folder (stages 1 and 2 trained there; stage 3 before 4, 4 before 5).
        stage: 3, 4 or 5. scale: must match the run's (default: the run's).
        device, max_steps, seed, progress, num_workers: as part 1's ``train_stage``.
        stride: every k-th QA item / planning frame (default: the stage's ``frame_stride``).
        lm: stage 3 only: a local Hugging Face causal-LM folder for the base LM.
        fusion: ``False`` trains the No Fusion model (stage 3 decides; later stages follow).
        cache: use the feature cache while the branches are frozen.
        route_points: the planner's ``plan_route_points`` (stages 3-4; default: the run's,
            module docstring; stage 5 keeps stage 4's).
        qa: ``False`` drops the Chat-V2XBench loss (module docstring; the VQA ablation); every
            stage of a run must use the same.
        speed_dropout: stage 4 only: the share of planning prompts whose speed reads
            "unknown" (``plan_speed_dropout``; 1: the planner never reads the ego's speed, and
            the agent then never says it; docs/aurora.md, "A sixth run"); stage 5 keeps stage
            4's.

    Returns:
        :func:`~.trainer.fit`'s summary plus ``stage``, ``branch`` (the stage's name),
        ``frames``, ``samples`` (QA / planning), ``lm`` (source, path), ``cache`` (statistics or
        ``None``), ``fusion`` and ``qa``.

    Raises:
        FileNotFoundError: no data, no earlier stage, no QA items. ValueError: a run folder of
            other settings, ``lm`` for a later stage, a fusion or qa setting other than the
            previous stage's.
    """
    from . import distributed as ddp
    from .data import AuroraFrames
    from .feature_cache import ensure_cache
    from .pairs import AuroraPairs, make_pair_loader
    from .planners import fit_anchors
    from .trainer import fit, load_weights

    if stage not in LATE_STAGES:
        raise ValueError(f"train_late_stage: stage {stage!r} is not 3, 4 or 5")
    data, run = Path(data), Path(out)
    if not data.is_dir():
        raise FileNotFoundError(f"aurora train: data directory {data} does not exist")
    cfg = _route_config(run, stage, _run_config(run, scale), route_points, speed_dropout)
    device = ddp.setup(device)  # under torchrun: join the group; rank 0 builds shared files
    hp = cfg.stage_hparams(stage)
    if stride is not None:
        hp = dataclasses.replace(hp, frame_stride=stride)
    if num_workers is not None:
        hp = dataclasses.replace(hp, num_workers=num_workers)
    frozen = cfg.freeze_backbone(stage)
    sdir = stage_dir(run, stage)
    sdir.mkdir(parents=True, exist_ok=True)
    if stage == 3:
        lm_info = ddp.main_first(lambda: base_lm(run, data, cfg, lm, seed))
    else:
        if lm is not None:
            raise ValueError("aurora train: --lm chooses stage 3's base LM; later stages use "
                             "stage 3's")
        prev = read_stage_info(run, stage - 1)
        if not (stage_dir(run, stage - 1) / CHECKPOINT).is_file():
            raise FileNotFoundError(f"aurora train: {stage_dir(run, stage - 1)} has no "
                                    "checkpoint")
        if bool(prev.get("fusion", True)) != fusion:
            raise ValueError(f"aurora train: stage {stage - 1} of {run} was trained with "
                             f"fusion={prev.get('fusion')}; stage {stage} must use the same "
                             "(--no-fusion)")
        if bool(prev.get("qa", True)) != bool(qa):
            raise ValueError(f"aurora train: stage {stage - 1} of {run} was trained with "
                             f"qa={bool(prev.get('qa', True))}; stage {stage} must use the same "
                             "(--no-qa drops the Chat-V2XBench loss in stages 3-5)")
        lm_info = dict(prev["lm"])
    torch.manual_seed(seed)  # the new weights (LoRA, CQAF, planner) are part of the run
    system, tok = build_system(cfg, resolve_lm_path(run, {"lm": lm_info}), fusion)
    if stage == 3:
        load_weights(system.ego, stage_dir(run, 1) / CHECKPOINT)
        load_weights(system.rsu, stage_dir(run, 2) / CHECKPOINT)
    else:
        _load_previous(system, run, stage)
    system.set_trainable(branches=not frozen, planner=stage >= 4)
    frames = AuroraFrames(data, "train", "ego", cfg, images=False)
    items = _items(data, stage, frames, hp.frame_stride, qa)
    use_cache = frozen and cache
    cstats = None
    feature_cache = None
    if use_cache:
        fids = sorted({fid for fid, _, _ in items})
        feature_cache, cstats = ddp.main_first(lambda: ensure_cache(
            system, data, "train", fids, run / "cache", batch_size=hp.batch_size,
            num_workers=hp.num_workers, device=device, progress=progress and ddp.is_main()))
    ds = AuroraPairs(data, "train", cfg, tok, items, fusion=fusion, images=not use_cache,
                     cache=feature_cache, speed_dropout=cfg.plan_speed_dropout, seed=seed,
                     plan=stage >= 4)
    if stage == 4 and cfg.planner == "diffusion" and not bool(system.planner.anchors_set):
        wps = torch.stack([ds.extra[fid]["expert_waypoints"] for fid, _, _ in items])
        wps = wps[:, :cfg.plan_waypoints].float()
        if cfg.plan_frame == "route":  # anchors of the route-frame (s, d) trajectories
            from .route_input import ego_to_route, planner_route_path

            paths = torch.stack([planner_route_path(ds.extra[fid]["route"], cfg)
                                 for fid, _, _ in items])
            wps = ego_to_route(wps, paths)
        system.planner.set_anchors(fit_anchors(wps, cfg.plan_anchors, seed=seed))
    n_qa = sum(q is not None for _, q, _ in items)
    info = {"format": "v2xbench-aurora-run/1", "stage": stage, "branch": STAGE_NAMES[stage],
            "scale": cfg.scale, "config": cfg.to_dict(), "data": str(data.resolve()),
            "split": "train", "frame_stride": hp.frame_stride, "seed": seed,
            "fusion": bool(fusion), "qa": bool(qa), "lm": lm_info, "cache": bool(use_cache),
            "freeze_backbone": frozen, "samples": {"qa": n_qa, "plan": len(items) - n_qa},
            "from": "stages 1-2" if stage == 3 else f"stage{stage - 1}",
            "trains": STAGE_TABLE[stage], "camera_size": list(frames.recorded_size)}
    _check_same_run(sdir / RUN_CONFIG, info)
    if ddp.is_main():
        atomic_write_json(sdir / RUN_CONFIG, info, indent=1)
    loader = make_pair_loader(ds, hp.batch_size, shuffle=True, seed=seed,
                              num_workers=hp.num_workers)
    criterion = StageCriterion(cfg, stage, live_branches=not frozen, qa=qa)
    summary = fit(system, criterion, loader, sdir, hp, device=device, seed=seed,
                  progress=progress, max_steps=max_steps)
    if ddp.is_main():
        _save_adapter(system, sdir / ADAPTER_DIR)
    if cstats is not None:  # what the cache saves: the branches' forward pass per sample
        cstats["branch_s_per_epoch_without_cache"] = cstats["ms_per_frame"] * len(ds) / 1e3
    summary.update(stage=stage, branch=STAGE_NAMES[stage], frames=len(set(ds.frame_ids())),
                   scale=cfg.scale, samples=info["samples"], lm=lm_info, cache=cstats,
                   fusion=bool(fusion), qa=bool(qa))
    if ddp.is_main():
        atomic_write_json(sdir / "train_summary.json", summary, indent=1)
    return summary


def format_late_summary(s: dict) -> str:
    """Lines about a stage 3-5 training call (base LM, cache, progress)."""
    from .trainer import loss_text, progress_text, speed_text

    lines = []
    if s["stage"] == 3:
        src = s["lm"]["source"]
        lines.append({"fresh": "base LM: none given and no RUN/stage0 (stage 0): a freshly "
                      f"built LM (random weights, tokenizer trained on the train split's QA "
                      f"text), saved in {s['lm']['path']}",
                      "stage0": "base LM: RUN/stage0 (stage 0's pre-trained LM)",
                      "given": f"base LM: {s['lm']['path']}"}[src])
    c = s.get("cache")
    if c:
        lines.append(f"feature cache: {c['frames']} frames ({c['built']} computed now in "
                     f"{c['build_s']:.0f} s, {c['ms_per_frame']:.1f} ms/frame); without it the "
                     f"frozen branches would cost {c['branch_s_per_epoch_without_cache']:.0f} s "
                     "per epoch")
    fusion = ("" if s.get("fusion", True) else ", no fusion") \
        + ("" if s.get("qa", True) else ", no QA loss")
    lines.append(f"stage {s['stage']} ({s['branch']}, {s['scale']}{fusion}): {progress_text(s)}, "
                 f"{s['samples']['qa']} QA + {s['samples']['plan']} planning samples on "
                 f"{s['frames']} frames, loss {loss_text(s)}, {speed_text(s)}")
    return "\n".join(lines)


__all__ = ["LATE_STAGES", "STAGE_NAMES", "StageCriterion", "base_lm", "format_late_summary",
           "train_late_stage"]
