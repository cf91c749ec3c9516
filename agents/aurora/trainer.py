"""The training loop every AURORA stage and every baseline reuses (nanoGPT-style: one page).

``fit(model, criterion, train_loader, out_dir, hp)`` runs data -> forward -> loss -> backward ->
clip -> AdamW step -> log, for ``hp.epochs`` epochs, with the seed paper's schedule: the learning
rate follows a cosine from ``hp.lr`` down to ``hp.lr * hp.min_lr_ratio`` over all steps, and
during the first ``hp.warmup_iters`` steps it is scaled linearly up from ``hp.warmup_ratio``
(mmcv's linear warm-up). Files in ``out_dir``:

- ``log.jsonl``: one JSON line per logged step: ``step`` (1-based count of optimizer steps),
  ``epoch``, ``loss``, each part of the criterion, ``lr``, ``grad_norm``, ``data_s`` (waiting for
  the batch and moving it to the device) and ``compute_s`` (forward, backward, step);
- ``loss.png``: the loss curve (total and parts);
- ``checkpoint.safetensors`` (model weights and buffers), ``optimizer.pt`` (AdamW state,
  readable with ``torch.load(weights_only=True)``) and ``state.json`` (step, epoch, settings),
  all written atomically at the end of every epoch and when training stops early (``max_steps``
  or Ctrl-C).

Repeatability: the order of epoch ``e`` is a permutation seeded by ``(seed, e)`` and the global
torch RNG is re-seeded from ``(seed, step)`` before every step, so a run is a function of its
seed and an interrupted run that resumes from ``out_dir`` continues at the same step with the
same batches and gives the same losses as an uninterrupted one. ``fit`` holds
``v2xbench.locks.dir_lock(out_dir)`` while it runs (pass ``lock=False`` if the caller holds it).

Under ``torchrun --nproc_per_node N`` the same call trains data-parallel (:mod:`.distributed`:
DistributedDataParallel, gloo on CPUs, NCCL on GPUs): each process takes its share of every
global batch of ``hp.batch_size`` samples, the logged losses are the global batch's, and only
rank 0 writes files; the result equals the single-process run for batch-mean losses.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import time
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.utils.data import DataLoader, RandomSampler
from tqdm import tqdm

from v2xbench.files import atomic_write, atomic_write_bytes, atomic_write_json, remove_stale_tmp
from v2xbench.locks import dir_lock

from . import distributed as ddp
from .config import StageHParams

CHECKPOINT = "checkpoint.safetensors"
OPTIMIZER = "optimizer.pt"
STATE = "state.json"
LOG = "log.jsonl"
PLOT = "loss.png"
FORMAT = "v2xbench-aurora-train/1"


# ---------------------------------------------------------------------- schedule and seeds
def lr_at(step: int, total_steps: int, hp: StageHParams) -> float:
    """Learning rate of (0-based) ``step`` of ``total_steps``: warm-up x cosine (module doc)."""
    progress = min(step / max(total_steps, 1), 1.0)
    min_lr = hp.lr * hp.min_lr_ratio
    lr = min_lr + 0.5 * (hp.lr - min_lr) * (1 + math.cos(math.pi * progress))
    if step < hp.warmup_iters:
        lr *= 1 - (1 - step / hp.warmup_iters) * (1 - hp.warmup_ratio)
    return lr


def _mix(seed: int, n: int, salt: int) -> int:
    """A 63-bit seed derived from ``(seed, n, salt)``."""
    return (seed * 1_000_003 + n * 7919 + salt * 104_729) % (2**63 - 1)


def epoch_batches(n: int, batch_size: int, seed: int, epoch: int, shuffle: bool,
                  drop_last: bool) -> list[list[int]]:
    """Index batches of one epoch over ``n`` samples (a permutation seeded by seed, epoch)."""
    if shuffle:
        g = torch.Generator().manual_seed(_mix(seed, epoch, 1))
        order = torch.randperm(n, generator=g).tolist()
    else:
        order = list(range(n))
    batches = [order[i:i + batch_size] for i in range(0, n, batch_size)]
    if drop_last and batches and len(batches[-1]) < batch_size:
        batches.pop()
    return batches


# ---------------------------------------------------------------------- weights
def save_checkpoint(model: nn.Module, path: str | Path,
                    metadata: dict[str, str] | None = None) -> Path:
    """Write the model's state dict (weights and buffers) to a safetensors file atomically."""
    from safetensors.torch import save

    tensors, seen = {}, set()
    for k, v in model.state_dict().items():
        t = v.detach().cpu().contiguous()
        ptr = t.untyped_storage().data_ptr() if t.numel() else None
        if ptr is not None and ptr in seen:  # tied weights (e.g. an LM's embeddings and head):
            t = t.clone()  # safetensors refuses shared storage; each key gets its own copy
        seen.add(ptr)
        tensors[k] = t
    meta = {"format": FORMAT, **(metadata or {})}
    return atomic_write_bytes(path, save(tensors, metadata=meta))


def load_weights(model: nn.Module, path: str | Path, device: str | torch.device = "cpu"
                 ) -> dict[str, str]:
    """Load a safetensors checkpoint into ``model`` (strict); returns the file's metadata.

    Raises:
        FileNotFoundError: no file at ``path``. ValueError: keys or shapes do not fit the model.
    """
    from safetensors import safe_open
    from safetensors.torch import load_file

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"load_weights: no checkpoint at {path}")
    state = load_file(str(path), device=str(device))
    with safe_open(str(path), framework="pt") as f:
        meta = dict(f.metadata() or {})
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise ValueError(f"load_weights: {path} does not fit the model: {e}") from None
    return meta


# ---------------------------------------------------------------------- files of a run
def _read_log(path: Path, upto: int) -> list[dict]:
    """Log records with ``step <= upto`` (later lines came after the last checkpoint)."""
    if not path.is_file():
        return []
    lines = [line for line in path.read_text().splitlines() if line.strip()]
    recs = []
    for i, line in enumerate(lines):
        try:
            recs.append(json.loads(line))
        except json.JSONDecodeError:
            if i == len(lines) - 1:  # cut off by a crash or a full disk: logged after the
                break  # last checkpoint anyway, so dropped like every later line
            raise ValueError(f"fit: {path} line {i + 1} is not JSON; the run's log is "
                             "corrupt") from None
    return [r for r in recs if r["step"] <= upto]


def _plot(records: list[dict], path: Path) -> None:
    """Loss curve (total and parts, log scale) as a PNG, written atomically."""
    if not records:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    steps = [r["step"] for r in records]
    skip = {"step", "epoch", "lr", "grad_norm", "data_s", "compute_s"}
    for key in [k for k in records[-1] if k not in skip]:
        vals = [r.get(key, float("nan")) for r in records]
        ax.plot(steps, vals, lw=1.6 if key == "loss" else 0.8, label=key)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def _save(out: Path, model: nn.Module, opt: torch.optim.Optimizer, state: dict,
          records: list[dict]) -> None:
    """Checkpoint, optimizer, plot, then ``state.json`` last (it names the step of the rest)."""
    save_checkpoint(model, out / CHECKPOINT, {"step": str(state["step"])})
    with atomic_write(out / OPTIMIZER, "wb") as f:
        torch.save({"step": state["step"], "optimizer": opt.state_dict()}, f)
    _plot(records, out / PLOT)
    atomic_write_json(out / STATE, state, indent=1)


def _resume(out: Path, model: nn.Module, opt: torch.optim.Optimizer, hp: StageHParams,
            seed: int, steps_per_epoch: int, device: str | torch.device) -> dict | None:
    """Load a run's state from ``out``; ``None`` if it has none. Checks it is the same run."""
    if not (out / STATE).is_file():
        return None
    state = json.loads((out / STATE).read_text())
    mine = {"hp": _hp_dict(hp), "seed": seed, "steps_per_epoch": steps_per_epoch}
    theirs = {k: state.get(k) for k in mine}
    if theirs != mine:
        raise ValueError(f"fit: {out} holds a run with other settings ({theirs}) than this one "
                         f"({mine}); resume with the same settings or choose a new output folder")
    meta = load_weights(model, out / CHECKPOINT, device)
    saved = torch.load(out / OPTIMIZER, map_location=device, weights_only=True)
    if int(meta.get("step", -1)) != state["step"] or saved["step"] != state["step"]:
        raise ValueError(f"fit: {out}: checkpoint, optimizer and state.json disagree on the step")
    opt.load_state_dict(saved["optimizer"])
    return state


def _hp_dict(hp: StageHParams) -> dict:
    d = dataclasses.asdict(hp)
    d.pop("num_workers")  # does not change the result
    d["betas"] = list(d["betas"])
    return d


def _to(batch: Any, device: str | torch.device) -> Any:
    if isinstance(batch, torch.Tensor):
        return batch.to(device, non_blocking=True)
    if isinstance(batch, dict):
        return {k: _to(v, device) for k, v in batch.items()}
    return batch


def _epoch_loader(loader: DataLoader, batches: list[list[int]], seed: int, epoch: int
                  ) -> DataLoader:
    """A loader over ``batches`` with the caller loader's dataset, collate and workers."""
    kw: dict[str, Any] = {}
    if loader.num_workers > 0:
        kw = {"prefetch_factor": loader.prefetch_factor,
              "multiprocessing_context": loader.multiprocessing_context}
    return DataLoader(loader.dataset, batch_sampler=batches, num_workers=loader.num_workers,
                      collate_fn=loader.collate_fn, pin_memory=loader.pin_memory,
                      worker_init_fn=loader.worker_init_fn, timeout=loader.timeout,
                      generator=torch.Generator().manual_seed(_mix(seed, epoch, 2)), **kw)


# ---------------------------------------------------------------------- the loop
def fit(model: nn.Module, criterion: nn.Module, train_loader: DataLoader, out_dir: str | Path,
        hp: StageHParams, *, device: str | torch.device = "cpu", seed: int = 0,
        progress: bool = True, max_steps: int | None = None, log_every: int = 1,
        lock: bool = True) -> dict:
    """Train ``model`` with ``criterion(model(batch), batch) -> (loss, parts)``; resume if a run
    of the same settings is in ``out_dir`` (module docstring).

    Args:
        model: the module to train (moved to ``device``).
        criterion: returns ``(scalar loss, {part: float})``.
        train_loader: a map-style ``DataLoader`` built with ``batch_size=hp.batch_size``; ``fit``
            uses its dataset, collate function, workers and ``shuffle`` / ``drop_last``, and
            orders each epoch itself (seeded).
        out_dir: run folder (created).
        hp: the stage's hyper-parameters (epochs, lr, schedule, clipping).
        device: ``"cpu"``, ``"cuda"``, ...
        seed: seed of the epoch orders and per-step RNG.
        progress: show a tqdm bar with the running loss.
        max_steps: stop (with a checkpoint) once this many optimizer steps are done in total;
            the schedule still spans all ``hp.epochs``, so a later call resumes exactly.
        log_every: write every ``log_every``-th step to ``log.jsonl``.
        lock: hold the output folder's lock while training.

    Returns:
        ``steps`` (done in total), ``epochs`` (completed), ``total_steps``, ``done``,
        ``resumed_from`` (step), ``final_loss`` (mean of the last up to 20 steps of this call),
        ``wall_s``, ``samples``, ``samples_per_s``, ``data_share`` (time share waiting for data).
    """
    if not isinstance(train_loader, DataLoader) or train_loader.batch_size is None:
        raise ValueError("fit: train_loader must be a DataLoader built with batch_size")
    if train_loader.batch_size != hp.batch_size:
        raise ValueError(f"fit: train_loader.batch_size={train_loader.batch_size} differs from "
                         f"hp.batch_size={hp.batch_size}")
    if log_every < 1:
        raise ValueError(f"fit: log_every={log_every} must be >= 1")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    device = ddp.setup(device)
    main = ddp.is_main()
    ctx = dir_lock(out, "aurora training") if lock and main else _nullcontext(out)
    with ctx:
        if main:
            remove_stale_tmp(out)
        return _fit(model, criterion, train_loader, out, hp, device, seed, progress,
                    max_steps, log_every)


class _nullcontext:
    def __init__(self, value: Any) -> None:
        self.value = value

    def __enter__(self) -> Any:
        return self.value

    def __exit__(self, *exc: Any) -> None:
        return None


def _fit(model, criterion, loader, out, hp, device, seed, progress, max_steps, log_every):
    n = len(loader.dataset)
    shuffle = isinstance(loader.sampler, RandomSampler)
    spe = len(epoch_batches(n, hp.batch_size, seed, 0, False, loader.drop_last))
    if spe == 0:
        raise ValueError(f"fit: {n} training samples give no batch of {hp.batch_size}")
    total = hp.epochs * spe
    stop = total if max_steps is None else min(max_steps, total)
    main = ddp.is_main()
    model.to(device).train()
    criterion.to(device)
    net = ddp.wrap(model, device)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=hp.lr, betas=tuple(hp.betas),
                            weight_decay=hp.weight_decay)
    state = _resume(out, model, opt, hp, seed, spe, device) or {
        "format": FORMAT, "step": 0, "epoch": 0, "done": False, "hp": _hp_dict(hp),
        "seed": seed, "steps_per_epoch": spe, "total_steps": total, "samples": n}
    start = step = state["step"]
    records = _read_log(out / LOG, start)  # drop lines logged after the last checkpoint
    ddp.barrier()  # every rank has read the run's files before rank 0 rewrites any
    if main:
        atomic_write_bytes(out / LOG, "".join(json.dumps(r) + "\n" for r in records).encode())

    def save() -> None:
        state.update(step=step, epoch=step // spe, done=step >= total)
        if main:
            _save(out, model, opt, state, records)

    bar = tqdm(total=total, initial=start, disable=not (progress and main), dynamic_ncols=True,
               desc=f"train {out.name}")
    t_data = t_comp = 0.0
    done_samples, recent, running = 0, [], None
    t_start = time.perf_counter()
    try:
        with open(out / LOG, "a") if main else _nullcontext(None) as logf:
            while step < stop:
                epoch, skip = divmod(step, spe)
                batches = epoch_batches(n, hp.batch_size, seed, epoch, shuffle, loader.drop_last)
                sizes = [len(b) for b in batches[skip:]]
                shares = [ddp.shard(b) for b in batches[skip:]]
                counts = [len(x) for x in shares]
                # a rank whose share of a short batch is empty runs one sample with weight 0
                mine = [x or b[:1] for x, b in zip(shares, batches[skip:])]
                it = iter(_epoch_loader(loader, mine, seed, epoch))
                while step < stop and step < (epoch + 1) * spe:
                    t0 = time.perf_counter()
                    batch = _to(next(it), device)
                    t1 = time.perf_counter()
                    lr = lr_at(step, total, hp)
                    k = step - epoch * spe - skip
                    size = sizes[k]
                    loss, parts, grad_norm = _step(net, criterion, opt, params, batch, hp, lr,
                                                   _mix(seed, step, 3), step, size, counts[k])
                    t2 = time.perf_counter()
                    step += 1
                    done_samples += size
                    t_data, t_comp = t_data + t1 - t0, t_comp + t2 - t1
                    rec = {"step": step, "epoch": epoch, "loss": loss, **parts, "lr": lr,
                           "grad_norm": grad_norm, "data_s": t1 - t0, "compute_s": t2 - t1}
                    recent = (recent + [loss])[-20:]
                    running = loss if running is None else 0.95 * running + 0.05 * loss
                    if step % log_every == 0 or step == total:
                        records.append(rec)
                        if main:
                            logf.write(json.dumps(rec) + "\n")
                            logf.flush()
                    bar.update(1)
                    bar.set_postfix(loss=f"{running:.4g}", lr=f"{lr:.2e}")
                del it
                if step % spe == 0 or step == stop:  # end of an epoch, or stopped early
                    save()
    except KeyboardInterrupt:
        save()
        raise
    finally:
        bar.close()
    if step == start and not (out / CHECKPOINT).is_file():
        save()
    ddp.barrier()  # rank 0's files are complete when any rank returns
    busy = t_data + t_comp
    return {"steps": step, "epochs": step // spe, "total_steps": total, "done": step >= total,
            "resumed_from": start, "final_loss": sum(recent) / len(recent) if recent else None,
            "wall_s": time.perf_counter() - t_start, "samples": done_samples,
            "samples_per_s": done_samples / busy if busy > 0 else 0.0,
            "data_share": t_data / busy if busy > 0 else 0.0, "out_dir": str(out)}


def progress_text(summary: dict) -> str:
    """``"step N/M (done|stopped)"`` of a :func:`fit` summary (the training commands' lines)."""
    state = "done" if summary["done"] else "stopped"
    return f"step {summary['steps']}/{summary['total_steps']} ({state})"


def loss_text(summary: dict) -> str:
    """The summary's final loss (4 significant digits), ``"n/a"`` when no step ran."""
    loss = summary.get("final_loss")
    return "n/a" if loss is None else f"{loss:.4g}"


def speed_text(summary: dict) -> str:
    """Samples/s, the share of step time spent waiting for data, wall seconds and the folder."""
    return (f"{summary['samples_per_s']:.2f} samples/s, data loading "
            f"{100 * summary['data_share']:.0f}% of step time, {summary['wall_s']:.0f} s -> "
            f"{summary['out_dir']}")


def _step(model: nn.Module, criterion: nn.Module, opt: torch.optim.Optimizer, params: list,
          batch: Any, hp: StageHParams, lr: float, rng_seed: int, step: int, size: int,
          local: int) -> tuple[float, dict[str, float], float]:
    """One optimizer step at learning rate ``lr`` on this process's share (``local`` samples;
    0: a stand-in sample of weight 0) of a global batch of ``size`` samples; returns the global
    batch's (loss, parts) and the gradient norm."""
    for g in opt.param_groups:
        g["lr"] = lr
    torch.manual_seed(rng_seed)  # dropout etc.: a function of (seed, step), so resume is exact
    loss, parts = criterion(model(batch), batch)
    if not torch.isfinite(loss):
        raise FloatingPointError(f"fit: loss is {float(loss)} at step {step + 1}")
    opt.zero_grad(set_to_none=True)
    (loss * ddp.local_loss_scale(local, size) if ddp.world_size() > 1 else loss).backward()
    clip = hp.grad_clip if hp.grad_clip > 0 else float("inf")
    grad_norm = float(nn.utils.clip_grad_norm_(params, clip))
    opt.step()
    if ddp.world_size() > 1:
        parts = {k: ddp.global_mean(float(v), local, size) for k, v in parts.items()}
    return ddp.global_mean(float(loss.detach()), local, size), parts, grad_norm


def _batch_size(batch: Any) -> int:
    if isinstance(batch, dict):
        for v in batch.values():
            if isinstance(v, torch.Tensor) and v.dim() > 0:
                return int(v.shape[0])
    if isinstance(batch, torch.Tensor):
        return int(batch.shape[0])
    return 1
