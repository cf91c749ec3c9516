"""UniMM-V2X configuration: UniV2X's fields (:class:`~..univ2x.config.UniV2XConfig`, the same
cameras, BEV, queries, message top-k and occupancy, planner and loss weights) plus the
Mixture-of-Experts, motion and prediction-fusion fields; ``tiny`` / ``default`` / ``paper``
scales are UniV2X's with the additions below.

- ``tiny``: tests. ``default``: the 2-core CPU (docs/baselines.md). ``paper``: the paper's
  sizes where it gives them (UniV2X's 200 x 200 BEV of 256 channels, 900 queries, 6 motion
  modes over 6 s as UniAD's MotionFormer; experts and top-k are this project's choice). Not run.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

from ..common.config import check_ints
from ..univ2x.config import _SCALE_FIELDS as _UNIV2X_SCALES
from ..univ2x.config import MESSAGE_HEADER_FLOATS, UniV2XConfig


@dataclass(frozen=True)
class UniMMV2XConfig(UniV2XConfig):
    """UniV2X's configuration plus MoE, motion and prediction-fusion settings."""

    TITLE: ClassVar[str] = "UniMM-V2X"
    # --- Mixture of Experts (BEV encoder and motion decoder): router + expert FFNs, top-k
    num_experts: int = 4
    moe_topk: int = 2
    moe_hidden: int = 64  # hidden width of each expert FFN
    bev_moe_layers: int = 1  # residual MoE-FFN layers over the BEV tokens
    moe_weight: float = 0.1  # lambda of the balance loss lambda * (Var(p) + Var(l)) * E^2
    # --- motion (prediction) head: MotionMoE decoder over the agent queries
    motion_layers: int = 1
    motion_modes: int = 3
    motion_steps: int = 6  # future positions, motion_dt apart
    motion_dt: float = 0.5  # s (5 frames of the 10 Hz data set)
    motion_weight: float = 1.0
    motion_cls_weight: float = 0.5
    motion_match_radius: float = 4.0  # m: a predicted agent supervised by the gt agent this near

    def __post_init__(self) -> None:
        who = "UniMMV2XConfig"
        check_ints(self, who, ("num_experts", "moe_topk", "moe_hidden", "motion_layers",
                               "motion_modes", "motion_steps"))
        check_ints(self, who, ("bev_moe_layers",), lo=0)
        if self.moe_topk > self.num_experts:
            raise ValueError(f"UniMMV2XConfig: moe_topk={self.moe_topk} exceeds num_experts="
                             f"{self.num_experts}")
        for name in ("moe_weight", "motion_weight", "motion_cls_weight"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"UniMMV2XConfig: {name}={v!r} must be a number >= 0")
        for name in ("motion_dt", "motion_match_radius"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"UniMMV2XConfig: {name}={v!r} must be a positive number")
        super().__post_init__()  # UniV2X's checks, the message bound with message_floats below

    def message_floats(self) -> int:
        """Floats of one roadside message (:mod:`.message`): header, ``msg_topk`` agents of
        ``4 + 2 * width`` floats (reference, score, perception query, motion query), the
        ``msg_occ`` occupancy cells."""
        ox, oy = self.msg_occ
        return MESSAGE_HEADER_FLOATS + self.msg_topk * (4 + 2 * self.width) + ox * oy


_SCALE_FIELDS: dict[str, dict[str, Any]] = {
    "tiny": {**_UNIV2X_SCALES["tiny"]},
    "default": {**_UNIV2X_SCALES["default"], "moe_hidden": 128, "num_experts": 4, "moe_topk": 2,
                "motion_layers": 2,  # every 7th frame, 2 epochs: the hour on the 2-core CPU
                "train": dataclasses.replace(_UNIV2X_SCALES["default"]["train"],
                                             frame_stride=7)},
    "paper": {**_UNIV2X_SCALES["paper"], "moe_hidden": 512, "num_experts": 8, "moe_topk": 2,
              "bev_moe_layers": 3, "motion_layers": 3, "motion_modes": 6, "motion_steps": 12},
}

UniMMV2XConfig.SCALE_FIELDS = _SCALE_FIELDS

__all__ = ["UniMMV2XConfig"]
