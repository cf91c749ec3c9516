"""CoDriving configuration: one frozen dataclass with the ``tiny`` / ``default`` / ``paper``
scales.

- ``tiny``: tests; a training step takes milliseconds.
- ``default``: sized for the 2-core CPU (training time measured in ``docs/baselines.md``).
- ``paper``: V2X-ViT's paper-scale perception sizes (PointPillars at 0.4 m, 256-channel BEV
  features at half the pillar resolution) with this benchmark's ranges; the budget keeps the
  message within the channel's 65,535 floats. For a GPU; not run here.

Grids, frames and the cell layout are V2X-ViT's (:mod:`..v2x_vit.config`): the ego frame for the
ego, the unit's ground frame for the unit; BEV features on the grid ``bev_stride`` times coarser
than the pillars (:meth:`CoDrivingConfig.feature_size`). The pillar encoder, the detection head
and the waypoint head are V2X-ViT's modules and read this configuration's fields of the same
names.

**Driving-oriented communication** (:mod:`.request`): the request is a Gaussian corridor of
``request_sigma`` m around the ego's route ahead (``request_route_points`` points of the route,
``request_route_step`` m apart: the observation's ``route`` rows); the unit sends the cells whose
confidence times request is at least ``select_threshold``, at most ``max_cells`` of them (the
budget), each with its ``sent_channels()`` features (:mod:`.message`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar

from v2xbench.agents.aurora.config import StageHParams, check_branch
from v2xbench.envs.v2x_intersection.core.classes import NUM_CLASSES
from v2xbench.envs.v2x_intersection.town.model import COMMAND_NAMES

from ..common import config as checks
from ..common.config import TINY_TRAIN, ScaledConfig, grid_ok

SCALES = ScaledConfig.SCALES
#: Header floats of a message: magic, version, K (cells sent), C, nx, ny (:mod:`.message`).
MESSAGE_HEADER_FLOATS = 6
#: Floats per sent cell besides its features: its indices ``i, j`` on the unit's feature grid.
CELL_INDEX_FLOATS = 2
#: The largest integer every float16 value up to it holds exactly (cell counts and indices).
FLOAT16_EXACT_INT = 2048


@dataclass(frozen=True)
class CoDrivingConfig(ScaledConfig):
    """Sizes, ranges, the communication budget, loss weights and training settings of CoDriving
    (module docstring)."""

    TITLE: ClassVar[str] = "CoDriving"
    scale: str = "tiny"
    # --- LiDAR pillars and the BEV backbone (V2X-ViT's modules)
    ego_range: tuple[float, ...] = (-51.2, -51.2, -3.0, 51.2, 51.2, 5.0)
    rsu_range: tuple[float, ...] = (0.0, -40.0, -3.0, 80.0, 40.0, 5.0)
    ego_pillars: tuple[int, int] = (32, 32)
    rsu_pillars: tuple[int, int] = (32, 32)
    bev_stride: int = 2
    pillar_channels: int = 8
    width: int = 16
    # --- driving-oriented communication
    compress_channels: int = 4  # channels of a sent cell (1x1 bottleneck; 0: all ``width``)
    max_cells: int = 32  # the budget: cells a message carries at most
    select_threshold: float = 0.02  # a cell is sent when confidence x request >= this
    request_sigma: float = 6.0  # m: the corridor's Gaussian around the route ahead
    request_route_points: int = 20  # route rows the request uses (the observation's route)
    request_route_step: int = 2  # m between them (the env's route_step)
    num_classes: int = NUM_CLASSES
    # --- the waypoint planner (V2X-ViT's waypoint head) and the native controller (ours)
    num_commands: int = len(COMMAND_NAMES)
    plan_waypoints: int = 6
    plan_dt: float = 0.5
    plan_route_points: int = 4
    plan_route_spacing: float = 5.0
    plan_hidden: int = 64
    #: Planner switches (agents/baselines/common/plan_frame.py): told the ego's speed (default
    #: no); output frame ``"route"`` (the default: AURORA's route-relative output) or ``"ego"``
    #: (the published x, y steps).
    plan_ego_speed: bool = False
    plan_frame: str = "route"
    # --- losses: fused detection (CenterNet focal + L1), the unit's confidence map (focal),
    # planning L1 + collision
    heat_alpha: float = 2.0
    heat_beta: float = 4.0
    heat_weight: float = 1.0
    box_weight: float = 1.0
    conf_weight: float = 1.0
    box_code_weights: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.2, 0.2)
    min_sigma: float = 0.5
    plan_l1_weight: float = 1.0
    plan_col_weight: float = 1.0
    plan_col_radius: float = 2.5
    plan_start_weight: float = 5.0
    plan_start_speed: float = 0.5
    plan_start_dist: float = 1.0
    # --- training: a message's age drawn from msg_latency_ticks..train_max_delay ticks
    train_max_delay: int = 1
    #: The channel's latency in training samples (ticks): a message is at least this old, and a
    #: frame before the unit's first message arrives has none (data.py, "Delay"); 0: runs
    #: trained before the third stop of 2026-11-28 (ages from 0, a message at every frame with
    #: a unit).
    msg_latency_ticks: int = 1
    train: StageHParams = field(default_factory=lambda: TINY_TRAIN)

    def __post_init__(self) -> None:
        who = "CoDrivingConfig"
        if self.scale not in SCALES:
            raise ValueError(f"{who}: scale={self.scale!r}; known scales: {SCALES}")
        checks.check_ints(self, who, ("bev_stride", "pillar_channels", "width", "num_classes",
                                      "num_commands", "plan_waypoints", "plan_hidden",
                                      "max_cells", "request_route_points",
                                      "request_route_step"))
        checks.check_ints(self, who, ("compress_channels", "train_max_delay",
                                       "msg_latency_ticks"), lo=0)
        checks.check_ranges(self, who)
        for name in ("ego_pillars", "rsu_pillars"):
            g = getattr(self, name)
            if not grid_ok(g):
                raise ValueError(f"{who}: {name}={g!r} must be two ints >= 1")
            if any(v % self.bev_stride for v in g):
                raise ValueError(f"{who}: {name}={g!r} must be multiples of bev_stride="
                                 f"{self.bev_stride}")
        nx, ny = self.feature_size("rsu")
        if max(nx, ny, self.max_cells) > FLOAT16_EXACT_INT:
            raise ValueError(f"{who}: max_cells={self.max_cells} and the roadside feature grid "
                             f"{nx} x {ny} must each be <= {FLOAT16_EXACT_INT} (float16 holds "
                             "cell counts and indices exactly only up to there)")
        if not 0.0 < self.select_threshold <= 1.0:
            raise ValueError(f"{who}: select_threshold={self.select_threshold!r} must be in "
                             "(0, 1] (confidence x request is in [0, 1])")
        checks.check_positive(self, who, ("request_sigma", "conf_weight"))
        checks.check_planning(self, who, ("plan_dt", "plan_route_spacing", "min_sigma"),
                              "box_code_weights", "max_cells or compress_channels")

    # ------------------------------------------------------------------ views (and pc_range)
    def pillar_size(self, branch: str) -> tuple[int, int]:
        """``(nx, ny)`` pillars of the agent's grid."""
        return self.ego_pillars if check_branch(branch) == "ego" else self.rsu_pillars

    def feature_size(self, branch: str) -> tuple[int, int]:
        """``(nx, ny)`` cells of the agent's BEV feature map (pillars / ``bev_stride``)."""
        nx, ny = self.pillar_size(branch)
        return nx // self.bev_stride, ny // self.bev_stride

    def rsu_grid(self) -> CoDrivingConfig:
        """This configuration with the unit's range and grid in the ego's fields: V2X-ViT's
        heatmap targets (which read the ego grid) on the unit's feature grid."""
        return dataclasses.replace(self, ego_range=self.rsu_range, ego_pillars=self.rsu_pillars)

    def sent_channels(self) -> int:
        """Feature channels of a sent cell (the bottleneck's, or ``width``)."""
        return self.compress_channels or self.width

    def cell_floats(self) -> int:
        """Floats per sent cell: its indices ``i, j`` and its features."""
        return CELL_INDEX_FLOATS + self.sent_channels()

    def message_floats(self, cells: int | None = None) -> int:
        """Floats of a message of ``cells`` cells (default: the budget ``max_cells``, the
        largest message): ``6 + cells * (2 + sent_channels)``."""
        k = self.max_cells if cells is None else int(cells)
        return MESSAGE_HEADER_FLOATS + k * self.cell_floats()


_SCALE_FIELDS: dict[str, dict[str, Any]] = {
    "tiny": {},
    "default": dict(
        ego_pillars=(96, 96), rsu_pillars=(80, 80), pillar_channels=32, width=48,
        compress_channels=16, max_cells=256, plan_hidden=128,
        # rest_stride / start_stride: fewer frames where the standing ego stays, every frame
        # where it sets off (agents/aurora/frame_balance.py; DS 17.4 -> 34.2 on the first 10
        # test50 routes x 3 seeds, docs/baselines.md)
        train=StageHParams(batch_size=4, epochs=2, lr=5e-4, warmup_iters=100, frame_stride=8,
                           num_workers=1, rest_stride=16, start_stride=1)),
    "paper": dict(
        ego_pillars=(256, 256), rsu_pillars=(200, 200), pillar_channels=64, width=256,
        compress_channels=64, max_cells=960, request_sigma=4.0, plan_hidden=256,
        train=StageHParams(batch_size=2, epochs=20, lr=2e-4, warmup_iters=500)),
}

CoDrivingConfig.SCALE_FIELDS = _SCALE_FIELDS

__all__ = ["CELL_INDEX_FLOATS", "FLOAT16_EXACT_INT", "MESSAGE_HEADER_FLOATS", "SCALES",
           "CoDrivingConfig"]
