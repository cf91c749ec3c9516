"""``v2xbench aurora train`` and ``v2xbench aurora eval-perception``: what the commands do.

Run folder layout (``--out RUN``)::

    RUN/stage1/   ego branch (stage 1)        RUN/stage2/   roadside branch (stage 2)
        aurora.json              scale, model config, branch, stage, data, seed (this module)
        checkpoint.safetensors, optimizer.pt, state.json, log.jsonl, loss.png   (trainer.fit)
        train_summary.json       the last call's summary (steps, samples/s, data share, ...)
    RUN/eval_<split>/perception.json, perception.md, pictures/   (eval_perception)

A second ``train`` on the same ``RUN`` resumes the stage where it stopped; it must use the same
scale, data settings and seed (a different run is refused, naming the difference).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from v2xbench.files import atomic_write_json

from .config import AuroraConfig, same_config
from .eval_perception import RUN_CONFIG, STAGE_BRANCH

STAGES = (0, *STAGE_BRANCH, 3, 4, 5)  # 0: agents/aurora/stage0.py; 3-5: stages.py


def check_stage(stage) -> int:
    """``stage`` as an int if it is 0 (LM pre-training), 1 (ego branch), 2 (roadside branch),
    3 (fusion + QA),
    4 (planning) or 5 (joint QA + planning); else ``ValueError``."""
    if isinstance(stage, bool) or stage not in STAGES:
        raise ValueError(f"unknown AURORA stage {stage!r}; known: 0 (language-model "
                         "pre-training), 1 (ego branch), "
                         "2 (roadside branch), 3 (fusion + QA), 4 (planning), "
                         "5 (joint QA + planning)")
    return int(stage)


def train_stage(data: str | Path, out: str | Path, stage: int, *, scale: str = "default",
                device: str = "cpu", max_steps: int | None = None, stride: int | None = None,
                seed: int = 0, progress: bool = True, num_workers: int | None = None) -> dict:
    """Train stage 1 (ego branch) or 2 (roadside branch) on the ``train`` split of ``data``.

    Args:
        data: data set folder (``v2xbench collect --out``).
        out: run folder; the stage trains in ``out/stage<N>`` (resumed when present).
        stage: 1 or 2. scale: ``tiny``, ``default`` or ``paper`` (:class:`AuroraConfig`).
        device: torch device. max_steps: stop after this many optimizer steps in total (the
            schedule still spans the stage's epochs; run again to go on).
        stride: frame stride (default: the scale's ``frame_stride`` of the stage).
        seed: seed of the run. num_workers: data-loader workers (default: the stage's).

    Returns:
        :func:`~.trainer.fit`'s summary plus ``stage``, ``branch``, ``frames``.

    Raises:
        ValueError: unknown stage or scale, a bad stride, or a run folder of other settings.
        FileNotFoundError: the data folder does not exist.
    """
    import torch

    from .branch import PerceptionBranch
    from .data import AuroraFrames, make_loader
    from .losses import SetCriterion
    from .trainer import fit

    stage = check_stage(stage)
    if stage not in STAGE_BRANCH:
        raise ValueError(f"train_stage trains stages 1 and 2; stage {stage} is "
                         "agents.aurora.stages.train_late_stage")
    cfg = AuroraConfig.for_scale(scale)
    if not Path(data).is_dir():
        raise FileNotFoundError(f"aurora train: data directory {data} does not exist (collect "
                                "one with `v2xbench collect --suite train --out DIR`)")
    hp = cfg.stage_hparams(stage)
    if stride is not None:
        hp = dataclasses.replace(hp, frame_stride=stride)
    if num_workers is not None:
        hp = dataclasses.replace(hp, num_workers=num_workers)
    branch = STAGE_BRANCH[stage]
    ds = AuroraFrames(data, "train", branch, cfg, stride=hp.frame_stride)
    stage_dir = Path(out) / f"stage{stage}"
    info = {"format": "v2xbench-aurora-run/1", "stage": stage, "branch": branch,
            "scale": scale, "config": cfg.to_dict(), "data": str(Path(data).resolve()),
            "split": "train", "frame_stride": hp.frame_stride, "frames": len(ds), "seed": seed}
    _check_same_run(stage_dir / RUN_CONFIG, info)
    atomic_write_json(stage_dir / RUN_CONFIG, info, indent=1)
    loader = make_loader(ds, hp.batch_size, shuffle=True, seed=seed, num_workers=hp.num_workers)
    torch.manual_seed(seed)  # the initial weights are part of the run
    model = PerceptionBranch(cfg, branch)
    criterion = SetCriterion(cfg, branch)
    summary = fit(model, criterion, loader, stage_dir, hp, device=device, seed=seed,
                  progress=progress, max_steps=max_steps)
    summary.update(stage=stage, branch=branch, frames=len(ds), scale=scale)
    atomic_write_json(stage_dir / "train_summary.json", summary, indent=1)
    return summary


def _check_same_run(path: Path, info: dict) -> None:
    if not path.is_file():
        return
    old = json.loads(path.read_text())
    keys = ("stage", "branch", "scale", "config", "data", "frame_stride", "seed")
    diff = [k for k in keys if old.get(k) != json.loads(json.dumps(info[k]))
            and not (k == "config" and _same_config(old.get(k), info[k]))]
    if diff:
        raise ValueError(f"aurora train: {path.parent} holds a run with other settings "
                         f"({', '.join(diff)} differ: {[old.get(k) for k in diff]} vs "
                         f"{[info[k] for k in diff if k != 'config']}); use the same settings "
                         "to resume, or another --out")


def _same_config(old, new: dict) -> bool:
    """Equal configs, where the old file may predate fields added since (issue #33;
    :func:`~.config.same_config`)."""
    return same_config(old, new)


def format_summary(s: dict) -> str:
    """One line about a training call."""
    from .trainer import loss_text, progress_text, speed_text

    return (f"stage {s['stage']} ({s['branch']} branch, {s['scale']}): {progress_text(s)}, "
            f"{s['frames']} frames, loss {loss_text(s)}, {speed_text(s)}")


__all__ = ["STAGES", "check_stage", "format_summary", "train_stage"]
