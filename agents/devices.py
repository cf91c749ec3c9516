"""Running a trained model on its device from an agent's CPU-side observation tensors.

Agents build their inputs from NumPy observations (CPU tensors) and hand results to NumPy
code (serialization, the waypoint controller). A model loaded with ``device="cuda"`` needs its
inputs there: :func:`run_on_module` moves them to the module's device and the outputs back to
the CPU, so an agent works the same on either.
"""

from __future__ import annotations

from typing import Any

import torch


def module_device(module: torch.nn.Module) -> torch.device:
    """The device of ``module``'s first parameter (or buffer); CPU for a module with neither."""
    for t in module.parameters():
        return t.device
    for t in module.buffers():
        return t.device
    return torch.device("cpu")


def to_device(tree: Any, device: torch.device | str) -> Any:
    """``tree`` (tensors in dicts, lists and tuples, any other leaf as is) on ``device``."""
    if isinstance(tree, torch.Tensor):
        return tree.to(device)
    if isinstance(tree, dict):
        return {k: to_device(v, device) for k, v in tree.items()}
    if isinstance(tree, (list, tuple)):
        return type(tree)(to_device(v, device) for v in tree)
    return tree


def run_on_module(module: torch.nn.Module, *args: Any) -> Any:
    """``module(*args)`` with ``args`` moved to the module's device and the result moved to the
    CPU (:func:`to_device` on both)."""
    dev = module_device(module)
    out = module(*to_device(args, dev))
    return out if dev.type == "cpu" else to_device(out, "cpu")


__all__ = ["module_device", "run_on_module", "to_device"]
