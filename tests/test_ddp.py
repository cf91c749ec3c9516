"""The shared training loop under ``torchrun``: 2 CPU processes with gloo give the losses and
weights of one process with the same global batch (issue #35, item 4)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
from v2xbench.agents.aurora import distributed as ddp

SCRIPT = textwrap.dedent("""
    import sys
    import torch
    from torch import nn
    from torch.utils.data import DataLoader, Dataset

    from v2xbench.agents.aurora.config import StageHParams
    from v2xbench.agents.aurora.trainer import fit

    torch.set_num_threads(1)

    class Pairs(Dataset):
        def __init__(self):
            g = torch.Generator().manual_seed(0)
            self.x = torch.randn(21, 5, generator=g)
            self.y = self.x @ torch.randn(5, 2, generator=g) + 0.1 * torch.randn(21, 2, generator=g)
        def __len__(self):
            return len(self.x)
        def __getitem__(self, i):
            return {"x": self.x[i], "y": self.y[i]}

    class Net(nn.Module):
        def __init__(self):
            super().__init__()
            torch.manual_seed(1)
            self.body = nn.Sequential(nn.Linear(5, 16), nn.Tanh(), nn.Linear(16, 2))
        def forward(self, batch):
            return self.body(batch["x"])

    class Mse(nn.Module):
        def forward(self, out, batch):
            loss = ((out - batch["y"]) ** 2).mean()
            return loss, {"mse": float(loss.detach())}

    def collate(items):
        return {k: torch.stack([it[k] for it in items]) for k in items[0]}

    hp = StageHParams(batch_size=4, epochs=2, lr=1e-2, warmup_iters=2, grad_clip=1.0)
    loader = DataLoader(Pairs(), batch_size=4, shuffle=True, collate_fn=collate)
    fit(Net(), Mse(), loader, sys.argv[1], hp, seed=3, progress=False, max_steps=int(sys.argv[2]))
""")


def _run(cmd: list[str], cwd: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("RANK", "WORLD_SIZE", "LOCAL_RANK")}
    env.update(OMP_NUM_THREADS="1", MASTER_ADDR="127.0.0.1")
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-4000:]


def _losses(run: Path) -> list[float]:
    return [json.loads(line)["loss"] for line in (run / "log.jsonl").read_text().splitlines()]


def _weights(run: Path) -> dict[str, torch.Tensor]:
    from safetensors.torch import load_file

    return load_file(str(run / "checkpoint.safetensors"))


def test_two_gloo_processes_match_one(tmp_path: Path) -> None:
    script = tmp_path / "train.py"
    script.write_text(SCRIPT)
    _run([sys.executable, str(script), str(tmp_path / "one"), "100"], tmp_path)
    torchrun = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2"]
    # stop after 3 steps, then resume to the end: resuming works under DDP as well
    _run(torchrun + [str(script), str(tmp_path / "two"), "3"], tmp_path)
    assert len(_losses(tmp_path / "two")) == 3
    _run(torchrun + [str(script), str(tmp_path / "two"), "100"], tmp_path)
    one, two = _losses(tmp_path / "one"), _losses(tmp_path / "two")
    # 21 samples in batches of 4, 2 epochs: the last batch of 1 leaves rank 1 a stand-in
    assert len(one) == len(two) == 12
    assert two == pytest.approx(one, rel=1e-5, abs=1e-7)
    w1, w2 = _weights(tmp_path / "one"), _weights(tmp_path / "two")
    assert w1.keys() == w2.keys()
    for k in w1:
        torch.testing.assert_close(w2[k], w1[k], rtol=1e-5, atol=1e-6)
    state = json.loads((tmp_path / "two" / "state.json").read_text())
    assert state["done"] and state["step"] == 12


def test_shard_and_loss_scale() -> None:
    batch = [7, 3, 9, 1, 4]
    assert ddp.shard(batch, 0, 2) == [7, 9, 4] and ddp.shard(batch, 1, 2) == [3, 1]
    # means of 3 and of 2 samples, weighted so that DDP's average is the mean over 5
    # rank losses m0 (3 samples), m1 (2): DDP averages 1.2 m0 and 0.8 m1 -> (3 m0 + 2 m1) / 5
    assert ddp.local_loss_scale(3, 5, 2) == pytest.approx(1.2)
    assert (ddp.local_loss_scale(3, 5, 2) + ddp.local_loss_scale(2, 5, 2)) / 2 == pytest.approx(1.0)


def test_world_size_must_be_a_positive_int(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WORLD_SIZE", "two")
    with pytest.raises(ValueError, match="WORLD_SIZE"):
        ddp.world_size()
    monkeypatch.setenv("WORLD_SIZE", "1")
    assert ddp.world_size() == 1 and ddp.rank() == 0 and ddp.is_main()
