"""V2X-ViT configuration: one frozen dataclass with the ``tiny`` / ``default`` / ``paper`` scales.

- ``tiny``: tests; a training step takes milliseconds.
- ``default``: sized for the 2-core CPU (training time measured in ``docs/baselines.md``).
- ``paper``: V2X-ViT's sizes where the paper gives them (0.4 m pillars, 256-channel features at
  half the pillar resolution, 3 V2X-ViT blocks of 8 heads, windows 4 / 8 / 16); the ranges are
  this benchmark's, and the bottleneck keeps 4 channels because the channel carries at most
  65,535 floats a message. For a GPU; not run here.

Frames are AURORA's (:mod:`v2xbench.agents.aurora.calib`): the ego frame for the ego, the
roadside unit's ground frame for the unit. A grid over a range ``(xmin, ymin, zmin, xmax, ymax,
zmax)`` with ``(nx, ny)`` cells is laid out ``(..., nx, ny)``: cell ``(i, j)`` spans ``x`` in
``[xmin + i dx, xmin + (i + 1) dx)`` and ``y`` in ``[ymin + j dy, ymin + (j + 1) dy)``. Pillars
are the cells of the ``*_pillars`` grid; BEV features live on the grid ``bev_stride`` times
coarser (:meth:`V2XViTConfig.feature_size`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from v2xbench.agents.aurora.config import StageHParams, check_branch
from v2xbench.envs.v2x_intersection.core.classes import NUM_CLASSES
from v2xbench.envs.v2x_intersection.sim.config import FIELD_RULES
from v2xbench.envs.v2x_intersection.town.model import COMMAND_NAMES

SCALES = ("tiny", "default", "paper")
MESSAGE_HEADER_FLOATS = 5
#: Point features the pillar encoder reads: ``x, y, z`` (m, the agent's frame) and intensity (the
#: LiDAR's semantic and instance ids are ground truth and never reach the model).
POINT_FEATURES = 4
TICK_S = 0.1  # s per simulator tick (a message's age is counted in ticks)


def _grid_ok(g: tuple[int, int]) -> bool:
    return len(g) == 2 and all(isinstance(v, int) and not isinstance(v, bool) and v >= 1
                               for v in g)


@dataclass(frozen=True)
class V2XViTConfig:
    """Sizes, ranges, loss weights and training settings of V2X-ViT (module docstring)."""

    scale: str = "tiny"
    # --- LiDAR pillars (PointPillars) and the BEV backbone
    ego_range: tuple[float, ...] = (-51.2, -51.2, -3.0, 51.2, 51.2, 5.0)
    rsu_range: tuple[float, ...] = (0.0, -40.0, -3.0, 80.0, 40.0, 5.0)
    ego_pillars: tuple[int, int] = (32, 32)  # pillar cells (nx, ny) over the ego range
    rsu_pillars: tuple[int, int] = (32, 32)  # pillar cells over the roadside range
    bev_stride: int = 2  # BEV features: one cell per bev_stride x bev_stride pillars
    pillar_channels: int = 8  # PointNet output per pillar
    width: int = 16  # BEV feature channels (and the transformer's width)
    # --- the roadside message: its BEV features through a learned 1x1 bottleneck
    compress_channels: int = 4  # channels sent (0: no bottleneck, all ``width`` channels)
    # --- V2X-ViT encoder
    vit_blocks: int = 1
    heads: int = 2
    windows: tuple[int, ...] = (2, 4)  # window sizes (feature cells) of the MSwin branches
    window_heads: tuple[int, ...] = (2, 1)  # heads of each branch (fewer for larger windows)
    mlp_ratio: float = 2.0
    dropout: float = 0.0
    max_age: int = 20  # ticks; older messages are encoded as this age
    num_classes: int = NUM_CLASSES
    # --- the waypoint head (V2X-ViT has no planner; a simple head behind AURORA's controller)
    num_commands: int = len(COMMAND_NAMES)
    plan_waypoints: int = 6  # 0.5 s apart (the data's expert_waypoints)
    plan_dt: float = 0.5  # s
    plan_route_points: int = 4  # route points ahead (as AURORA's planner input)
    plan_route_spacing: float = 5.0  # m between them
    plan_hidden: int = 64
    # --- losses: CenterNet focal heatmap loss + L1 box regression, planning L1 + collision
    heat_alpha: float = 2.0
    heat_beta: float = 4.0
    heat_weight: float = 1.0
    box_weight: float = 1.0
    box_code_weights: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.2, 0.2)
    min_sigma: float = 0.5  # cells: the narrowest heatmap Gaussian
    plan_l1_weight: float = 1.0
    plan_col_weight: float = 1.0
    plan_col_radius: float = 2.5  # m
    plan_start_weight: float = 5.0  # AURORA's start-from-rest weighting
    plan_start_speed: float = 0.5  # m/s
    plan_start_dist: float = 1.0  # m
    # --- training: a message's age is drawn from 0..train_max_delay ticks (the unit's LiDAR of
    # that many ticks earlier); frame_stride keeps every k-th frame of each episode
    train_max_delay: int = 3
    train: StageHParams = field(default_factory=lambda: _TINY_TRAIN)

    def __post_init__(self) -> None:
        if self.scale not in SCALES:
            raise ValueError(f"V2XViTConfig: scale={self.scale!r}; known scales: {SCALES}")
        for name in ("bev_stride", "pillar_channels", "width", "vit_blocks", "heads",
                     "num_classes", "num_commands", "plan_waypoints", "plan_hidden", "max_age"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"V2XViTConfig: {name}={v!r} must be an int >= 1")
        for name in ("compress_channels", "train_max_delay"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ValueError(f"V2XViTConfig: {name}={v!r} must be an int >= 0")
        if self.width % self.heads:
            raise ValueError(f"V2XViTConfig: width={self.width} must be divisible by heads="
                             f"{self.heads}")
        for name in ("ego_range", "rsu_range"):
            r = getattr(self, name)
            if len(r) != 6 or not all(r[i] < r[i + 3] for i in range(3)):
                raise ValueError(f"V2XViTConfig: {name}={r!r} must be (xmin, ymin, zmin, xmax, "
                                 "ymax, zmax) with min < max")
        for name in ("ego_pillars", "rsu_pillars"):
            g = getattr(self, name)
            if not _grid_ok(g):
                raise ValueError(f"V2XViTConfig: {name}={g!r} must be two ints >= 1")
            if any(v % self.bev_stride for v in g):
                raise ValueError(f"V2XViTConfig: {name}={g!r} must be multiples of bev_stride="
                                 f"{self.bev_stride}")
        if not self.windows or any(not isinstance(w, int) or w < 1 for w in self.windows):
            raise ValueError(f"V2XViTConfig: windows={self.windows!r} must be ints >= 1")
        if len(self.window_heads) != len(self.windows) or any(
                not isinstance(h, int) or h < 1 or self.width % h for h in self.window_heads):
            raise ValueError(f"V2XViTConfig: window_heads={self.window_heads!r} needs one int >= 1 "
                             f"per window, each dividing width={self.width}")
        nx, ny = self.feature_size("ego")
        bad = [w for w in self.windows if nx % w or ny % w]
        if bad:
            raise ValueError(f"V2XViTConfig: windows {bad} do not divide the ego feature grid "
                             f"{nx} x {ny} (ego_pillars / bev_stride)")
        if not 0 <= self.dropout < 1 or not self.mlp_ratio > 0:
            raise ValueError("V2XViTConfig: dropout must be in [0, 1), mlp_ratio > 0")
        for name in ("plan_dt", "plan_route_spacing", "min_sigma"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"V2XViTConfig: {name}={v!r} must be a positive number")
        if isinstance(self.plan_route_points, bool) or not 0 <= self.plan_route_points <= 16:
            raise ValueError(f"V2XViTConfig: plan_route_points={self.plan_route_points!r} must "
                             "be an int in [0, 16]")
        if len(self.box_code_weights) != 10:
            raise ValueError("V2XViTConfig: box_code_weights needs 10 values")
        limit = FIELD_RULES["max_payload_floats"].hi
        if self.message_floats() > limit:
            raise ValueError(f"V2XViTConfig: the roadside message has {self.message_floats()} "
                             f"floats, more than a channel carries (max_payload_floats <= "
                             f"{limit}); lower compress_channels or rsu_pillars")

    # ------------------------------------------------------------------ views
    def pc_range(self, branch: str) -> tuple[float, ...]:
        """The agent's range ``(xmin, ymin, zmin, xmax, ymax, zmax)``."""
        return self.ego_range if check_branch(branch) == "ego" else self.rsu_range

    def pillar_size(self, branch: str) -> tuple[int, int]:
        """``(nx, ny)`` pillars of the agent's grid."""
        return self.ego_pillars if check_branch(branch) == "ego" else self.rsu_pillars

    def feature_size(self, branch: str) -> tuple[int, int]:
        """``(nx, ny)`` cells of the agent's BEV feature map (pillars / ``bev_stride``)."""
        nx, ny = self.pillar_size(branch)
        return nx // self.bev_stride, ny // self.bev_stride

    def sent_channels(self) -> int:
        """Channels of the roadside feature map on air (the bottleneck's, or ``width``)."""
        return self.compress_channels or self.width

    def message_floats(self) -> int:
        """Floats of one roadside message (:mod:`.message`): header + the sent feature map."""
        nx, ny = self.feature_size("rsu")
        return MESSAGE_HEADER_FLOATS + self.sent_channels() * nx * ny

    # ------------------------------------------------------------------ construction
    @classmethod
    def for_scale(cls, name: str, **overrides: Any) -> V2XViTConfig:
        """The named scale with field ``overrides`` (unknown scale or field: ``ValueError``)."""
        if name not in _SCALE_FIELDS:
            raise ValueError(f"unknown V2X-ViT scale {name!r}; known scales: {', '.join(SCALES)}")
        unknown = set(overrides) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"V2XViTConfig: unknown fields {sorted(unknown)}")
        return cls(**{**_SCALE_FIELDS[name], "scale": name, **overrides})

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form; :meth:`from_dict` reads it back."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> V2XViTConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError`` naming them."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"V2XViTConfig: unknown keys {sorted(unknown)}")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        if isinstance(kw.get("train"), dict):
            kw["train"] = StageHParams.from_dict(kw["train"])
        return cls(**kw)


_TINY_TRAIN = StageHParams(batch_size=2, epochs=1, lr=1e-3, warmup_iters=0, num_workers=0)

_SCALE_FIELDS: dict[str, dict[str, Any]] = {
    "tiny": {},
    "default": dict(
        ego_pillars=(96, 96), rsu_pillars=(80, 80), pillar_channels=32, width=48,
        compress_channels=8, vit_blocks=2, heads=4, windows=(4, 8, 16), window_heads=(4, 2, 1),
        plan_hidden=128,
        train=StageHParams(batch_size=4, epochs=2, lr=5e-4, warmup_iters=100, frame_stride=8,
                           num_workers=1)),
    "paper": dict(
        ego_pillars=(256, 256), rsu_pillars=(200, 200), pillar_channels=64, width=256,
        compress_channels=4, vit_blocks=3, heads=8, windows=(4, 8, 16),
        window_heads=(16, 8, 4), mlp_ratio=4.0,
        dropout=0.1, plan_hidden=256,
        train=StageHParams(batch_size=2, epochs=20, lr=2e-4, warmup_iters=500)),
}

__all__ = ["MESSAGE_HEADER_FLOATS", "POINT_FEATURES", "SCALES", "TICK_S", "V2XViTConfig"]
