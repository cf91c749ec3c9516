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

from dataclasses import dataclass, field
from typing import Any, ClassVar

from v2xbench.agents.aurora.config import StageHParams, check_branch
from v2xbench.envs.v2x_intersection.core.classes import NUM_CLASSES
from v2xbench.envs.v2x_intersection.town.model import COMMAND_NAMES

from ..common import config as checks
from ..common.config import TINY_TRAIN, ScaledConfig, grid_ok

SCALES = ScaledConfig.SCALES
MESSAGE_HEADER_FLOATS = 5
#: Point features the pillar encoder reads: ``x, y, z`` (m, the agent's frame) and intensity (the
#: LiDAR's semantic and instance ids are ground truth and never reach the model).
POINT_FEATURES = 4
TICK_S = 0.1  # s per simulator tick (a message's age is counted in ticks)


@dataclass(frozen=True)
class V2XViTConfig(ScaledConfig):
    """Sizes, ranges, loss weights and training settings of V2X-ViT (module docstring)."""

    TITLE: ClassVar[str] = "V2X-ViT"
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
    #: Planner switches (agents/baselines/common/plan_frame.py): told the ego's speed (default
    #: no); output frame ``"route"`` (the default: AURORA's route-relative output) or ``"ego"``
    #: (the published x, y steps).
    plan_ego_speed: bool = False
    plan_frame: str = "route"
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
    # --- training: a message's age is drawn from msg_latency_ticks..train_max_delay ticks (the
    # unit's LiDAR of that many ticks earlier); frame_stride keeps every k-th frame of each episode
    train_max_delay: int = 3
    #: The channel's latency in training samples (ticks): a message is at least this old, and a
    #: frame before the unit's first message arrives has none (data.py, "Delay"); 0: runs
    #: trained before the third stop of 2026-11-28 (ages from 0, a message at every frame with
    #: a unit).
    msg_latency_ticks: int = 1
    train: StageHParams = field(default_factory=lambda: TINY_TRAIN)

    def __post_init__(self) -> None:
        if self.scale not in SCALES:
            raise ValueError(f"V2XViTConfig: scale={self.scale!r}; known scales: {SCALES}")
        who = "V2XViTConfig"
        checks.check_ints(self, who, ("bev_stride", "pillar_channels", "width", "vit_blocks",
                                      "heads", "num_classes", "num_commands", "plan_waypoints",
                                      "plan_hidden", "max_age"))
        checks.check_ints(self, who, ("compress_channels", "train_max_delay",
                                       "msg_latency_ticks"), lo=0)
        if self.width % self.heads:
            raise ValueError(f"V2XViTConfig: width={self.width} must be divisible by heads="
                             f"{self.heads}")
        checks.check_ranges(self, who)
        for name in ("ego_pillars", "rsu_pillars"):
            g = getattr(self, name)
            if not grid_ok(g):
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
        checks.check_planning(self, who, ("plan_dt", "plan_route_spacing", "min_sigma"),
                              "box_code_weights", "compress_channels or rsu_pillars")

    # ------------------------------------------------------------------ views (and pc_range)
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

V2XViTConfig.SCALE_FIELDS = _SCALE_FIELDS

__all__ = ["MESSAGE_HEADER_FLOATS", "POINT_FEATURES", "SCALES", "TICK_S", "V2XViTConfig"]
