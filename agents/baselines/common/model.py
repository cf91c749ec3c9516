"""The baselines' parameter counts (no torch import: any model with ``rsu`` and ``ego``)."""

from __future__ import annotations

from typing import Any


def parameter_counts(model: Any) -> dict[str, int]:
    """Parameters of the roadside half (``model.rsu``), the ego half (``model.ego``) and the
    total."""
    rsu = sum(p.numel() for p in model.rsu.parameters())
    ego = sum(p.numel() for p in model.ego.parameters())
    return {"rsu": rsu, "ego": ego, "total": rsu + ego}


__all__ = ["parameter_counts"]
