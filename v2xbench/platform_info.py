"""What machine and libraries computed a result: recorded so that results say where they came from.

Closed-loop runs repeat to the last digit on one machine but not across machines: NumPy and
PyTorch choose their CPU kernels by the CPU's instruction set (and by their versions), and a
closed loop grows last-bit differences into other trajectories (docs/baselines.md, "Same code,
another machine"). Every ``v2xbench eval`` route result carries :func:`run_platform`;
``v2xbench fingerprint`` files carry :func:`numpy_platform`.
"""

from __future__ import annotations

import platform

import numpy as np


def numpy_platform() -> dict:
    """What decides the last bits of NumPy's transcendental functions here: NumPy's version and
    the SIMD extensions it dispatches to on this CPU."""
    simd = np.show_config(mode="dicts").get("SIMD Extensions", {})
    return {"numpy": np.__version__, "simd": sorted(simd.get("found", []))}


def run_platform() -> dict:
    """:func:`numpy_platform` plus the Python and PyTorch versions, PyTorch's CPU kernel level and
    the machine's architecture and processor name."""
    import torch

    cpu = ""
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), "")
    except OSError:
        cpu = platform.processor()
    return {**numpy_platform(), "python": platform.python_version(), "torch": torch.__version__,
            "torch_cpu": torch.backends.cpu.get_cpu_capability(), "machine": platform.machine(), "cpu": cpu}


__all__ = ["numpy_platform", "run_platform"]
