"""AURORA training (issue #32): overfitting, checkpoints, repeatability, resume, schedule.

Synthetic batches in the contract's format (tests/test_aurora_model.py); no data set needed.
"""

from __future__ import annotations

import json
import math

import pytest
import torch
from torch.utils.data import DataLoader, Dataset
from v2xbench.agents.aurora.branch import PerceptionBranch
from v2xbench.agents.aurora.config import AuroraConfig, StageHParams
from v2xbench.agents.aurora.losses import SetCriterion
from v2xbench.agents.aurora.trainer import (
    CHECKPOINT,
    LOG,
    OPTIMIZER,
    PLOT,
    STATE,
    fit,
    load_weights,
    lr_at,
    save_checkpoint,
)

from tests.test_aurora_model import synthetic_batch
from v2xbench.locks import DirectoryLocked, dir_lock

torch.set_num_threads(1)
CFG = AuroraConfig.for_scale("tiny")


class SyntheticFrames(Dataset):
    """``n`` per-sample dicts cut from one synthetic batch (default collate stacks them)."""

    def __init__(self, branch: str, n: int = 6, seed: int = 0) -> None:
        self.batch = synthetic_batch(CFG, branch, b=n, m=5, k=3, seed=seed)
        self.n = n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> dict:
        return {k: v[i] for k, v in self.batch.items()}


def hp(**kw) -> StageHParams:
    base = dict(batch_size=2, epochs=2, lr=2e-3, warmup_iters=2, grad_clip=10.0)
    return StageHParams(**{**base, **kw})


def run(out, branch="ego", seed=0, init_seed=0, max_steps=None, h=None, n=6):
    torch.manual_seed(init_seed)
    model = PerceptionBranch(CFG, branch)
    h = h or hp()
    loader = DataLoader(SyntheticFrames(branch, n), batch_size=h.batch_size, shuffle=True)
    summary = fit(model, SetCriterion(CFG, branch), loader, out, h, device="cpu", seed=seed,
                  progress=False, max_steps=max_steps)
    return model, summary


def losses(out) -> list[tuple[int, float]]:
    return [(r["step"], r["loss"]) for r in map(json.loads, (out / LOG).read_text().splitlines())]


# ---------------------------------------------------------------------- overfitting
@pytest.mark.parametrize("branch", ["ego", "rsu"])
def test_tiny_model_overfits_one_batch(branch):
    torch.manual_seed(1)
    model = PerceptionBranch(CFG, branch)
    crit = SetCriterion(CFG, branch)
    batch = synthetic_batch(CFG, branch, b=2, m=6, k=4, seed=1)
    opt = torch.optim.AdamW(model.parameters(), lr=2e-3)
    first = last = None
    for _ in range(300):
        loss, _ = crit(model(batch), batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        last = float(loss.detach())
        first = last if first is None else first
    assert last * 10 <= first, (first, last)


# ---------------------------------------------------------------------- checkpoints
def test_checkpoint_round_trips_bit_exactly(tmp_path):
    torch.manual_seed(0)
    a = PerceptionBranch(CFG, "ego")
    a(synthetic_batch(CFG, "ego"))  # moves BatchNorm running statistics off their init
    save_checkpoint(a, tmp_path / "w.safetensors", {"note": "x"})
    torch.manual_seed(1)
    b = PerceptionBranch(CFG, "ego")
    meta = load_weights(b, tmp_path / "w.safetensors")
    assert meta["note"] == "x"
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys()
    for k in sa:
        assert sa[k].dtype == sb[k].dtype and torch.equal(sa[k], sb[k]), k
    a.eval()
    b.eval()
    batch = synthetic_batch(CFG, "ego")
    assert torch.equal(a(batch)["det_boxes"], b(batch)["det_boxes"])
    with pytest.raises(ValueError, match="does not fit the model"):
        load_weights(PerceptionBranch(CFG, "rsu"), tmp_path / "w.safetensors")
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        load_weights(b, tmp_path / "missing.safetensors")


# ---------------------------------------------------------------------- the loop
def test_fit_writes_its_files_and_is_repeatable(tmp_path):
    _, s1 = run(tmp_path / "a", seed=0)
    _, s2 = run(tmp_path / "b", seed=0)
    _, s3 = run(tmp_path / "c", seed=5)
    la, lb, lc = losses(tmp_path / "a"), losses(tmp_path / "b"), losses(tmp_path / "c")
    assert [s for s, _ in la] == list(range(1, 7))  # 6 samples / 2 per batch x 2 epochs
    assert la == lb
    assert la != lc  # the seed orders the epochs
    for name in (CHECKPOINT, OPTIMIZER, STATE, PLOT):
        assert (tmp_path / "a" / name).is_file(), name
    rec = json.loads((tmp_path / "a" / LOG).read_text().splitlines()[0])
    assert {"step", "epoch", "loss", "det_cls", "det_box", "map_cls", "map_pts", "light", "lr",
            "grad_norm", "data_s", "compute_s"} <= set(rec)
    state = json.loads((tmp_path / "a" / STATE).read_text())
    assert (state["step"], state["epoch"], state["done"]) == (6, 2, True)
    assert s1["done"] and s1["steps"] == 6 and s1["samples"] == 12
    assert s1["samples_per_s"] > 0 and 0 <= s1["data_share"] < 1
    # a finished run is not trained again
    _, again = run(tmp_path / "a", seed=0)
    assert again["steps"] == 6 and again["samples"] == 0 and losses(tmp_path / "a") == la


def test_interrupted_training_resumes_at_the_same_step(tmp_path):
    h = hp(epochs=3)
    full, _ = run(tmp_path / "full", h=h)
    _, part = run(tmp_path / "cut", h=h, max_steps=4)  # mid-epoch 2 (3 steps per epoch)
    assert part["steps"] == 4 and not part["done"]
    state = json.loads((tmp_path / "cut" / STATE).read_text())
    assert (state["step"], state["epoch"], state["done"]) == (4, 1, False)
    resumed, rest = run(tmp_path / "cut", h=h, init_seed=7)  # other init: weights come from disk
    assert rest["resumed_from"] == 4 and rest["steps"] == 9 and rest["done"]
    assert losses(tmp_path / "cut") == losses(tmp_path / "full")
    for (k, a), b in zip(full.state_dict().items(), resumed.state_dict().values()):
        assert torch.equal(a, b), k
    with pytest.raises(ValueError, match="other settings"):
        run(tmp_path / "cut", h=hp(epochs=4))


def test_resume_drops_a_log_line_cut_off_by_a_crash(tmp_path):
    """A full disk or a kill mid-write leaves half a JSON line at the log's end: resuming drops
    it (it came after the last checkpoint); a corrupt line before the end is an error."""
    h = hp(epochs=3)
    run(tmp_path / "full", h=h)
    run(tmp_path / "cut", h=h, max_steps=4)
    log = tmp_path / "cut" / "log.jsonl"
    log.write_text(log.read_text() + '{"step": 5, "epoch": 1, "lo')
    _, rest = run(tmp_path / "cut", h=h)
    assert rest["resumed_from"] == 4 and rest["done"]
    assert losses(tmp_path / "cut") == losses(tmp_path / "full")
    lines = log.read_text().splitlines()
    log.write_text("\n".join([lines[0], "{broken", *lines[1:]]) + "\n")
    with pytest.raises(ValueError, match="line 2 is not JSON"):
        run(tmp_path / "cut", h=h)


def test_fit_rejects_bad_setups(tmp_path):
    loader = DataLoader(SyntheticFrames("rsu"), batch_size=3)
    model, crit = PerceptionBranch(CFG, "rsu"), SetCriterion(CFG, "rsu")
    with pytest.raises(ValueError, match="batch_size=3 differs from hp.batch_size=2"):
        fit(model, crit, loader, tmp_path / "x", hp(), progress=False)
    with dir_lock(tmp_path / "held", "test"):
        with pytest.raises(DirectoryLocked, match="in use"):
            run(tmp_path / "held", branch="rsu")


def test_learning_rate_schedule():
    h = StageHParams(lr=1e-3, warmup_iters=10, warmup_ratio=1 / 3, min_lr_ratio=1e-3)
    total = 100
    lrs = [lr_at(s, total, h) for s in range(total + 1)]
    cos = [1e-6 + 0.5 * (1e-3 - 1e-6) * (1 + math.cos(math.pi * s / total)) for s in range(101)]
    assert lrs[0] == pytest.approx(cos[0] / 3)
    assert lrs[5] == pytest.approx(cos[5] * (1 - 0.5 * 2 / 3))
    assert lrs[10:] == pytest.approx(cos[10:])
    assert all(a < b for a, b in zip(lrs[:10], lrs[1:11]))  # warm-up rises
    assert lrs[-1] == pytest.approx(1e-6)
