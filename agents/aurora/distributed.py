"""Data-parallel training under ``torchrun``: what :func:`.trainer.fit` needs to know of it.

Launched by ``torchrun --nproc_per_node N ...`` (environment ``WORLD_SIZE`` > 1), every process
trains the same model on its share of each global batch and DistributedDataParallel averages the
gradients, so N processes follow the single-process run of the same global batch
(``hp.batch_size``): :func:`shard` splits each batch of the seeded epoch order, and
:func:`local_loss_scale` weights each process's mean loss by its share, which makes the averaged
gradient the gradient of the global batch's mean loss even when the last batch does not split
evenly. The backend is ``gloo`` on CPUs and ``nccl`` on GPUs; process ``LOCAL_RANK`` uses
``cuda:LOCAL_RANK``. Only rank 0 writes the run's files (checkpoint, optimizer, log, plot,
state); every rank reads them to resume.

Exactness: equal to one process for losses that are a mean over the batch's samples and models
without dropout (tested: ``tests/test_ddp.py``); dropout masks are drawn per process, so they
differ from the single-process run's (the same distribution, other draws). Set losses normalized by the batch's number of targets (the detection
heads) are normalized per process instead, so their gradients are close to, not equal to, the
single-process ones.
"""

from __future__ import annotations

import atexit
import os
from collections.abc import Callable
from datetime import timedelta
from typing import TypeVar

import torch
import torch.distributed as dist
from torch import nn

T = TypeVar("T")
TEARDOWN_WAIT_S = 60.0  # s the ranks wait for each other before leaving the group at exit
_device = torch.device("cpu")  # this process's device once :func:`setup` ran (collectives use it)


def world_size() -> int:
    """Processes of this run (``WORLD_SIZE``; 1 without ``torchrun``)."""
    try:
        n = int(os.environ.get("WORLD_SIZE", "1"))
    except ValueError:
        raise ValueError(f"WORLD_SIZE={os.environ['WORLD_SIZE']!r} is not an integer") from None
    if n < 1:
        raise ValueError(f"WORLD_SIZE={n} must be >= 1")
    return n


def rank() -> int:
    """This process's rank (``RANK``; 0 without ``torchrun``)."""
    return int(os.environ.get("RANK", "0")) if world_size() > 1 else 0


def is_main() -> bool:
    """Rank 0: the process that writes files and prints."""
    return rank() == 0


def setup(device: str | torch.device) -> torch.device:
    """Join the process group when launched by ``torchrun`` (idempotent) and return this
    process's device: ``cuda:LOCAL_RANK`` for a CUDA ``device``, else ``device`` itself."""
    global _device
    device = torch.device(device)
    if world_size() == 1:
        return device
    if device.type == "cuda":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.accelerator.set_device_index(device.index)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
        # leave the group before the interpreter exits: a process whose gloo threads are still
        # running at exit aborts ("terminate called without an active exception", seen under
        # load in CI)
        atexit.register(teardown)
    _device = device
    return device


def teardown() -> None:
    """Leave the process group (idempotent; registered by :func:`setup` to run at exit). On gloo
    the ranks first meet at a monitored barrier (at most :data:`TEARDOWN_WAIT_S`): a rank that
    destroys its group while another still talks to it aborts that one (seen under load)."""
    if not (dist.is_available() and dist.is_initialized()):
        return
    if dist.get_backend() == "gloo":
        try:
            dist.monitored_barrier(timeout=timedelta(seconds=TEARDOWN_WAIT_S))
        except RuntimeError:  # a rank is gone or late: leave anyway
            pass
    dist.destroy_process_group()


def wrap(model: nn.Module, device: torch.device) -> nn.Module:
    """``model`` in DistributedDataParallel when there are several processes, else itself.
    Unused parameters are allowed (a stage may train a head that some batches skip)."""
    if world_size() == 1:
        return model
    ids = [device.index] if device.type == "cuda" else None
    return nn.parallel.DistributedDataParallel(model, device_ids=ids, find_unused_parameters=True)


def shard(batch: list[int], r: int | None = None, n: int | None = None) -> list[int]:
    """Rank ``r``'s share of a global batch of sample indices: every ``n``-th one from ``r``."""
    r = rank() if r is None else r
    n = world_size() if n is None else n
    return batch[r::n]


def local_loss_scale(local: int, global_: int, n: int | None = None) -> float:
    """Factor on a process's mean loss over ``local`` samples so that DDP's average of the N
    gradients is the gradient of the mean over the ``global_`` samples of the batch."""
    n = world_size() if n is None else n
    return local * n / global_


def global_mean(value: float, local: int, global_: int) -> float:
    """The batch mean of a per-process mean ``value`` over ``local`` of ``global_`` samples."""
    if world_size() == 1:
        return value
    t = torch.tensor([value * local / global_], dtype=torch.float64, device=_device)
    dist.all_reduce(t)
    return float(t.item())


def main_first(fn: Callable[[], T]) -> T:
    """``fn()`` on rank 0, then (after it wrote what it writes) on the other ranks, which find
    its files there: for idempotent builders of shared files (a feature cache, a base LM)."""
    if world_size() == 1:
        return fn()
    out = fn() if is_main() else None
    barrier()
    return out if is_main() else fn()


def barrier() -> None:
    """Wait for every process (no-op with one)."""
    if world_size() > 1 and dist.is_initialized():
        dist.barrier()
