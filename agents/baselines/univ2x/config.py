"""UniV2X configuration: one frozen dataclass with the ``tiny`` / ``default`` / ``paper`` scales.

- ``tiny``: tests; a training step takes milliseconds.
- ``default``: sized for the 2-core CPU (a training run on the default data set within the
  issue's hour, measured in ``docs/baselines.md``).
- ``paper``: UniV2X's sizes where its paper and UniAD / BEVFormer give them (200 x 200 BEV of
  256 channels over the ego range, 900 agent queries, 6 decoder layers); the image backbone is
  our ViT (the paper's is a ResNet-101), and the message's top-k and occupancy resolution are
  this project's choices (the paper does not fix them). For a GPU; not run here.

Frames are AURORA's (:mod:`v2xbench.agents.aurora.calib`): the ego frame, and the roadside
unit's ground frame for the roadside half. A BEV grid spans the ``(xmin, ymin)`` - ``(xmax,
ymax)`` of its range with ``(nx, ny)`` cells; tensors are laid out ``(..., nx, ny)``: cell
``(i, j)`` has its centre at ``x = xmin + (i + 0.5) dx``, ``y = ymin + (j + 0.5) dy``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

from v2xbench.agents.aurora.config import AuroraConfig, StageHParams, check_branch
from v2xbench.envs.v2x_intersection.core.classes import GROUPS, NUM_CLASSES
from v2xbench.envs.v2x_intersection.town.model import COMMAND_NAMES

from ..common import config as checks
from ..common.config import TINY_TRAIN, ScaledConfig, grid_ok

SCALES = ScaledConfig.SCALES
#: Classes an occupancy cell is occupied by: the dynamic agents (vehicles and VRUs).
OCC_CLASSES = tuple(sorted(GROUPS["vehicle"] + GROUPS["vru"]))
MESSAGE_HEADER_FLOATS = 6


@dataclass(frozen=True)
class UniV2XConfig(ScaledConfig):
    """Sizes, ranges, loss weights and training settings of UniV2X (module docstring)."""

    TITLE: ClassVar[str] = "UniV2X"
    scale: str = "tiny"
    # --- cameras and image backbone (AURORA's ViT, conv stem; one token per stride^2 pixels)
    image_size: tuple[int, int] = (64, 32)  # (width, height), both agents
    stride: int = 8  # image feature stride = the ViT's patch (a power of two)
    vit_width: int = 24
    vit_depth: int = 1
    vit_heads: int = 2
    mlp_ratio: float = 2.0
    # --- lift-splat: depth bins per feature pixel, BEV channels
    depth_bins: int = 6
    depth_near: float = 2.0  # m
    ego_depth_far: float = 60.0  # m
    rsu_depth_far: float = 90.0  # m
    bev_channels: int = 16  # lifted context channels (C of Lift-Splat)
    ego_range: tuple[float, ...] = (-51.2, -51.2, -3.0, 51.2, 51.2, 5.0)
    rsu_range: tuple[float, ...] = (0.0, -40.0, -3.0, 80.0, 40.0, 5.0)
    ego_bev: tuple[int, int] = (16, 16)  # cells (nx, ny) of the ego BEV
    rsu_bev: tuple[int, int] = (16, 16)  # cells of the roadside BEV
    # --- agent queries (TrackFormer-like DETR decoder over BEV tokens)
    width: int = 32
    heads: int = 2
    ffn: int = 64
    det_layers: int = 1
    num_queries: int = 16
    num_classes: int = NUM_CLASSES
    dropout: float = 0.0
    # --- the roadside message: sparse agent queries + dense occupancy
    msg_topk: int = 6  # agent queries sent (highest scores)
    msg_occ: tuple[int, int] = (8, 8)  # cells of the occupancy map sent (roadside range)
    # --- cross-view association and fusion
    match_radius: float = 4.0  # m: an ego and a roadside agent farther apart never associate
    ego_score: float = 0.3  # ego agents scoring below this are not association candidates
    # --- planner (query-based, UniAD-style)
    num_commands: int = len(COMMAND_NAMES)
    plan_waypoints: int = 6  # 0.5 s apart (the data's expert_waypoints)
    plan_dt: float = 0.5  # s
    plan_layers: int = 1
    plan_route_points: int = 4  # route points ahead (as AURORA's planner input)
    plan_route_spacing: float = 5.0  # m between them
    #: The planner reads the ego's speed. False (the default, as every method of the planning
    #: table): it is told 0 m/s in training and in closed loop (UniAD's planner reads no ego
    #: status; with it, behaviour cloning plans from the speed: ``v2xbench baselines
    #: eval-planning --ego-speed 0``, docs/baselines.md).
    plan_ego_speed: bool = False
    #: The planner's output frame: ``"route"`` (the default: AURORA's route-relative planner, per
    #: waypoint an arc length along the observed route, never decreasing, and a lateral offset
    #: from it, turned into x, y by ``route_input.route_to_ego``; batch key ``route_path``) or
    #: ``"ego"`` (the published x, y steps; planners trained so ignore the route here:
    #: docs/baselines.md, "What makes a planner drive here").
    plan_frame: str = "route"
    #: Ticks between the roadside unit's sensing and the ego reading its message in training
    #: samples (``UniV2XFrames``): the channel's default ``latency_ticks`` = 1, so that a sample
    #: pairs the ego's tick t with the message closed loop delivers at t (the unit's of t - 1;
    #: none at an episode's first tick). 0: the same tick (runs before 2026-11-28).
    msg_latency_ticks: int = 1
    # --- losses (AURORA's detection weights; UniAD-style planning L1 + collision)
    focal_alpha: float = 0.25
    focal_gamma: float = 2.0
    det_cls_weight: float = 2.0
    det_box_weight: float = 0.25
    det_code_weights: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.2, 0.2)
    occ_weight: float = 1.0
    ego_aux_weight: float = 0.5  # the ego's own detection before fusion (gt/ego)
    rsu_weight: float = 1.0  # the roadside half's detection and occupancy (gt/rsu)
    plan_l1_weight: float = 1.0
    plan_col_weight: float = 1.0
    plan_col_radius: float = 2.5  # m
    plan_start_weight: float = 5.0  # AURORA's start-from-rest weighting
    plan_start_speed: float = 0.5  # m/s
    plan_start_dist: float = 1.0  # m
    # --- training (AURORA's loop; frame_stride keeps every k-th frame of each episode)
    train: StageHParams = field(default_factory=lambda: TINY_TRAIN)

    def __post_init__(self) -> None:
        if self.scale not in SCALES:
            raise ValueError(f"UniV2XConfig: scale={self.scale!r}; known scales: {SCALES}")
        who = "UniV2XConfig"
        checks.check_ints(self, who, ("stride", "vit_width", "vit_depth", "vit_heads",
                                      "depth_bins", "bev_channels", "width", "heads", "ffn",
                                      "det_layers", "num_queries", "num_classes", "msg_topk",
                                      "num_commands", "plan_waypoints", "plan_layers"))
        checks.check_ints(self, who, ("msg_latency_ticks",), lo=0)
        if self.stride & (self.stride - 1):
            raise ValueError(f"UniV2XConfig: stride={self.stride} must be a power of two")
        w, h = self.image_size
        if w % self.stride or h % self.stride:
            raise ValueError(f"UniV2XConfig: image_size={self.image_size} must be multiples of "
                             f"stride={self.stride}")
        if self.vit_width % self.vit_heads or self.width % self.heads:
            raise ValueError("UniV2XConfig: vit_width / width must be divisible by their heads")
        for name in ("ego_bev", "rsu_bev", "msg_occ"):
            if not grid_ok(getattr(self, name)):
                raise ValueError(f"UniV2XConfig: {name}={getattr(self, name)!r} must be two "
                                 "ints >= 1 (cells along x, y)")
        checks.check_ranges(self, who)
        if not 0 < self.depth_near < min(self.ego_depth_far, self.rsu_depth_far):
            raise ValueError("UniV2XConfig: need 0 < depth_near < ego_depth_far, rsu_depth_far")
        if self.msg_topk > self.num_queries:
            raise ValueError(f"UniV2XConfig: msg_topk={self.msg_topk} exceeds num_queries="
                             f"{self.num_queries}")
        if not 0 <= self.ego_score <= 1 or not 0 <= self.dropout < 1:
            raise ValueError("UniV2XConfig: ego_score must be in [0, 1], dropout in [0, 1)")
        checks.check_planning(self, who, ("match_radius", "plan_dt", "plan_route_spacing"),
                              "det_code_weights", "msg_topk, width or msg_occ")

    # ------------------------------------------------------------------ views (and pc_range)
    def bev_size(self, branch: str) -> tuple[int, int]:
        """``(nx, ny)`` cells of the agent's BEV grid."""
        return self.ego_bev if check_branch(branch) == "ego" else self.rsu_bev

    def depth_far(self, branch: str) -> float:
        """Far end (m) of the agent's depth bins."""
        return self.ego_depth_far if check_branch(branch) == "ego" else self.rsu_depth_far

    def image_size_of(self, branch: str) -> tuple[int, int]:
        """``(width, height)`` of the agent's images (both agents: ``image_size``)."""
        check_branch(branch)
        return tuple(self.image_size)

    def message_floats(self) -> int:
        """Floats of one roadside message (:mod:`.message`): header, ``msg_topk`` agents of
        ``4 + width`` floats, the ``msg_occ`` occupancy cells."""
        ox, oy = self.msg_occ
        return MESSAGE_HEADER_FLOATS + self.msg_topk * (4 + self.width) + ox * oy

    def data_config(self) -> AuroraConfig:
        """An :class:`AuroraConfig` with this config's cameras, ranges and detection-loss
        weights: what AURORA's data set (:class:`~v2xbench.agents.aurora.data.AuroraFrames`),
        set criterion and fused detection head read (one map element, not used here)."""
        return AuroraConfig.for_scale(
            "tiny", ego_image_size=tuple(self.image_size), rsu_image_size=tuple(self.image_size),
            patch_size=self.stride, ego_range=tuple(self.ego_range),
            rsu_range=tuple(self.rsu_range), num_classes=self.num_classes, num_map_queries=1,
            map_points=2, dec_width=self.width, dec_heads=self.heads, dec_ffn=self.ffn,
            dropout=self.dropout, focal_alpha=self.focal_alpha, focal_gamma=self.focal_gamma,
            det_cls_weight=self.det_cls_weight, det_box_weight=self.det_box_weight,
            det_code_weights=tuple(self.det_code_weights), lm_width=2 * self.heads)


_SCALE_FIELDS: dict[str, dict[str, Any]] = {
    "tiny": {},
    "default": dict(
        image_size=(128, 64), stride=8, vit_width=64, vit_depth=2, vit_heads=4,
        depth_bins=12, bev_channels=48, ego_bev=(32, 32), rsu_bev=(32, 32), width=64, heads=4,
        ffn=128, det_layers=2, num_queries=48, msg_topk=16, msg_occ=(20, 20), plan_layers=2,
        train=StageHParams(batch_size=8, epochs=2, lr=3e-4, warmup_iters=200, frame_stride=5,
                           num_workers=1)),
    "paper": dict(
        image_size=(1024, 512), stride=16, vit_width=256, vit_depth=6, vit_heads=8,
        mlp_ratio=4.0, depth_bins=48, bev_channels=256, ego_bev=(200, 200),
        rsu_bev=(160, 160), width=256, heads=8, ffn=512, det_layers=6, num_queries=900,
        msg_topk=100, msg_occ=(50, 50), plan_layers=3, dropout=0.1,
        train=StageHParams(batch_size=1, epochs=20, lr=2e-4, warmup_iters=500)),
}

UniV2XConfig.SCALE_FIELDS = _SCALE_FIELDS

__all__ = ["MESSAGE_HEADER_FLOATS", "OCC_CLASSES", "SCALES", "UniV2XConfig"]
