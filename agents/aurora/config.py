"""AURORA configuration: one frozen dataclass with named scales, and per-stage training settings.

Scales (:meth:`AuroraConfig.for_scale`):

- ``tiny``: tests and CI; a forward + backward pass takes milliseconds.
- ``default``: sized for a 2-core CPU (stages 1 + 2 on the default data set in under an hour
  with one torch thread; measured numbers in ``docs/aurora.md``).
- ``paper``: the seed paper's values where it gives them (1024x512 cameras, the stage batch
  sizes, epochs and learning rates of its appendix table); the rest follows the methods it
  builds on (ORION's ViT-L/16 backbone and 4096-wide language model, PETR's 900 detection
  queries and 64 depth bins, MapTR's 50 x 20 map queries, 6 decoder layers). For a GPU.
  Part 2's language model there has the shape of ORION's Vicuna-7B (32 layers, 32 heads, FFN
  11008, 32k vocabulary); the paper gives no LoRA rank, roadside top-k or planner widths, so
  those (LoRA 16 / 32 on every linear layer, 100 + 50 roadside queries, DiffusionDrive's 20
  anchors and 2 denoising steps) are this project's choices.

Frames: ``ego_range`` is in the ego frame, ``rsu_range`` in the roadside unit's ground frame
(origin at the pole's foot, x along the unit's yaw, y left, z up); both
``(xmin, ymin, zmin, xmax, ymax, zmax)`` in metres.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from typing import Any

from v2xbench.envs.v2x_intersection.core.classes import NUM_CLASSES
from v2xbench.envs.v2x_intersection.town.model import COMMAND_NAMES

SCALES = ("tiny", "default", "paper")
BRANCHES = ("ego", "rsu")
MAP_CLASS_NAMES = ("divider", "boundary", "crosswalk")
#: Traffic-light classes of the ego branch: the data set's ``light_state`` + 1.
LIGHT_CLASS_NAMES = ("none", "green", "yellow", "red", "stop_sign")
#: Cameras per branch (ego: ``EGO_CAMERA_NAMES`` order; rsu: the active unit's camera).
NUM_CAMERAS = {"ego": 6, "rsu": 1}
#: Planning decoders of part 2 (:mod:`.planners`); ``vae`` is the paper's default.
PLANNERS = ("vae", "mlp", "diffusion")


@dataclass(frozen=True)
class StageHParams:
    """Training hyper-parameters of one stage (seed paper appendix, "Stage-wise training").

    Attributes:
        batch_size: samples per optimizer step.
        epochs: passes over the (strided) training frames.
        lr: base learning rate of AdamW.
        weight_decay: AdamW weight decay.
        betas: AdamW betas.
        warmup_iters: linear warm-up length in optimizer steps.
        warmup_ratio: learning-rate factor at step 0 of the warm-up.
        min_lr_ratio: the cosine schedule ends at ``lr * min_lr_ratio``.
        grad_clip: max global gradient norm (``<= 0``: no clipping).
        frame_stride: keep every ``frame_stride``-th frame of the training split.
        num_workers: data-loader worker processes.
        rest_stride: keep every k-th frame where the ego stands and the expert stays (0: the
            ``frame_stride``; :mod:`~v2xbench.agents.aurora.frame_balance`; the baselines).
        start_stride: keep every k-th frame where the standing ego sets off (0: the
            ``frame_stride``).
    """

    batch_size: int = 12
    epochs: int = 4
    lr: float = 5e-5
    weight_decay: float = 1e-5
    betas: tuple[float, float] = (0.9, 0.999)
    warmup_iters: int = 500
    warmup_ratio: float = 1.0 / 3.0
    min_lr_ratio: float = 1e-3
    grad_clip: float = 35.0
    frame_stride: int = 1
    num_workers: int = 0
    rest_stride: int = 0
    start_stride: int = 0

    def __post_init__(self) -> None:
        for name in ("batch_size", "epochs", "frame_stride"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"StageHParams: {name}={v!r} must be an int >= 1")
        for name in ("warmup_iters", "num_workers", "rest_stride", "start_stride"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ValueError(f"StageHParams: {name}={v!r} must be an int >= 0")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"StageHParams: lr={self.lr!r} must be a positive number")
        if self.weight_decay < 0:
            raise ValueError(f"StageHParams: weight_decay={self.weight_decay!r} must be >= 0")
        if len(self.betas) != 2 or not all(0 <= b < 1 for b in self.betas):
            raise ValueError(f"StageHParams: betas={self.betas!r} must be two numbers in [0, 1)")
        for name in ("warmup_ratio", "min_lr_ratio"):
            v = getattr(self, name)
            if not 0 <= v <= 1:
                raise ValueError(f"StageHParams: {name}={v!r} must be in [0, 1]")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StageHParams:
        """Build from a dict (e.g. ``state.json``); unknown keys raise ``ValueError``."""
        return _from_dict(cls, d)


@dataclass(frozen=True)
class AuroraConfig:
    """Sizes, ranges, loss weights and stage settings of AURORA's perception (module docstring).

    Image sizes are ``(width, height)`` in pixels and must be multiples of ``patch_size``.
    """

    scale: str = "tiny"
    # --- cameras and encoder
    ego_image_size: tuple[int, int] = (128, 64)
    rsu_image_size: tuple[int, int] = (128, 64)
    patch_size: int = 16
    patch_stem: str = "conv"  # "linear" (ViT patchify) or "conv" (vit.PatchEmbed)
    vit_depth: int = 1
    vit_width: int = 32
    vit_heads: int = 2
    mlp_ratio: float = 2.0
    # --- depth-aware 3D position embedding (PETR)
    depth_bins: int = 8
    depth_near: float = 1.0  # m
    ego_depth_far: float = 65.0  # m, far end of the ego rays
    rsu_depth_far: float = 90.0  # m, far end of the roadside rays
    # --- perception ranges (xmin, ymin, zmin, xmax, ymax, zmax), metres, branch frame
    ego_range: tuple[float, ...] = (-51.2, -51.2, -3.0, 51.2, 51.2, 5.0)
    rsu_range: tuple[float, ...] = (0.0, -40.0, -3.0, 80.0, 40.0, 5.0)
    # --- decoders
    dec_width: int = 32
    dec_heads: int = 2
    dec_ffn: int = 64
    det_layers: int = 2
    map_layers: int = 2
    num_det_queries: int = 16
    num_map_queries: int = 6
    map_points: int = 6
    dropout: float = 0.0
    # --- classes
    num_classes: int = NUM_CLASSES
    num_map_classes: int = len(MAP_CLASS_NAMES)
    num_light_classes: int = len(LIGHT_CLASS_NAMES)
    # --- semantic tokens (ego branch): the language model's width
    lm_width: int = 48
    # --- language model (part 2, :mod:`.language`): Llama architecture of width lm_width
    lm_layers: int = 2
    lm_heads: int = 2
    lm_kv_heads: int = 2
    lm_ffn: int = 96
    lm_vocab: int = 384  # BPE vocabulary size, special tokens included
    lm_max_len: int = 256  # positions: visual placeholders + prompt + answer
    lm_tie_embeddings: bool = True
    lm_pretrain_block: int = 64  # stage 0: tokens per packed pre-training block (<= lm_max_len)
    lora_rank: int = 4
    lora_alpha: float = 8.0
    lora_dropout: float = 0.0
    lora_targets: tuple[str, ...] = ("q_proj", "v_proj")
    # --- CQAF (part 2, :mod:`.cqaf`)
    cqaf_det_topk: int = 8  # roadside detection queries per message (highest scores)
    cqaf_map_topk: int = 4  # roadside map queries per message (highest scores)
    cqaf_temperature: float = 2.0  # m, soft assignment: weight ~ exp(-distance / T)
    cqaf_match_radius: float = 4.0  # m, a roadside query farther from every ego query is appended
    cqaf_ego_score: float = 0.3  # ego queries scoring below this do not match roadside ones
    cqaf_map_score: float = 0.3  # roadside map queries scoring below this are not appended
    # --- planner (part 2, :mod:`.planners`, :mod:`.planner_losses`)
    planner: str = "vae"
    num_commands: int = len(COMMAND_NAMES)
    plan_waypoints: int = 6  # ego-frame waypoints, plan_dt apart (the data's expert_waypoints)
    plan_dt: float = 0.5  # s
    plan_hidden: int = 32
    plan_latent: int = 8  # VAE latent size
    plan_anchors: int = 4  # diffusion: trajectory anchors (k-means of training trajectories)
    plan_diffusion_steps: int = 2  # diffusion: denoising steps at inference
    plan_traj_scale: tuple[float, float] = (20.0, 10.0)  # m, x / y normalization of trajectories
    plan_l1_weight: float = 1.0
    plan_bound_weight: float = 1.0
    plan_col_weight: float = 1.0
    plan_kl_weight: float = 1.0
    plan_cls_weight: float = 1.0  # diffusion: trajectory-mode classification
    plan_bound_margin: float = 1.0  # m, waypoints closer than this to a road boundary cost
    plan_col_radius: float = 2.5  # m, waypoints closer than this to an agent's centre cost
    #: start-from-rest samples (ego slower than ``plan_start_speed`` m/s, the expert's last
    #: planned waypoint farther than ``plan_start_dist`` m): their planning loss counts
    #: ``plan_start_weight`` times (2.4 % of the default training frames; 43 % stand and stay;
    #: 5 overshot: 4.85 m/s predicted from rest where the expert starts at 1.77, docs/aurora.md)
    plan_start_weight: float = 2.0
    plan_start_speed: float = 0.5  # m/s
    plan_start_dist: float = 1.0  # m
    #: training only: share of planning prompts whose speed reads "unknown" (speed dropout)
    plan_speed_dropout: float = 0.15
    #: the planner's route input (:mod:`.route_input`): the ``plan_route_points`` points
    #: ``plan_route_spacing``, 2 x ..., m ahead along the observed route, ego frame (0: none,
    #: the paper's inputs; a run file without the key is such a model: :meth:`from_dict`)
    plan_route_points: int = 4
    plan_route_spacing: float = 5.0  # m of arc length between them
    #: the planner's output frame (:mod:`.route_input`, "Route-relative planning"): ``"route"``
    #: predicts per waypoint an arc length along the observed route and a lateral offset from
    #: it, turned into ego-frame x, y; ``"ego"`` predicts ego-frame x, y (a run file without the
    #: key is such a model: :meth:`from_dict`)
    plan_frame: str = "route"
    #: route frame, MLP and VAE: how a predicted step ``u`` along the route is made
    #: non-negative: ``"relu_ste"`` ``relu(u)`` with gradient 1 also below 0 (straight-through);
    #: ``"abs"`` ``|u|``; ``"softplus"`` (the fourth run; a run file without the key) a softplus
    #: of sharpness ``planners.SOFT_BETA``, which saturates on the standing frames so that the
    #: few start-from-rest frames barely move it (docs/aurora.md, "A fifth run")
    plan_route_step: str = "relu_ste"
    # --- losses and matching costs (PETR / MapTR weights)
    focal_alpha: float = 0.25
    focal_gamma: float = 2.0
    det_cls_weight: float = 2.0
    det_box_weight: float = 0.25
    #: per-dimension L1 weights of (x, y, z, log l, log w, log h, sin, cos, vx, vy)
    det_code_weights: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.2, 0.2)
    map_cls_weight: float = 2.0
    map_pts_weight: float = 5.0  # L1 on points normalized to the range
    light_weight: float = 1.0
    # --- stage 0 (part 2, :mod:`.stage0`): LM pre-training on the Chat-V2XBench text of the
    #     train split; its ``frame_stride`` keeps every k-th QA item
    stage0: StageHParams = field(default_factory=StageHParams)
    # --- stages: 1 = ego branch, 2 = roadside branch
    stage1: StageHParams = field(default_factory=StageHParams)
    stage2: StageHParams = field(default_factory=StageHParams)
    # --- stages 3-5 (part 2, :mod:`.stages`; :data:`STAGE_TABLE`): 3 = CQAF + fused heads +
    #     LoRA on the QA loss, 4 = planner (backbones frozen), 5 = mixed QA and planning (frozen).
    #     Their ``frame_stride`` keeps every k-th planning frame and every k-th QA item.
    stage3: StageHParams = field(default_factory=StageHParams)
    stage4: StageHParams = field(default_factory=StageHParams)
    stage5: StageHParams = field(default_factory=StageHParams)
    stage3_freeze_backbone: bool = False  # the paper fine-tunes the branches in stage 3

    def __post_init__(self) -> None:
        if self.scale not in SCALES:
            raise ValueError(f"AuroraConfig: scale={self.scale!r}; known scales: {SCALES}")
        for name in ("patch_size", "vit_depth", "vit_width", "vit_heads", "depth_bins",
                     "dec_width", "dec_heads", "dec_ffn", "det_layers", "map_layers",
                     "num_det_queries", "num_map_queries", "lm_width", "lm_layers", "lm_heads",
                     "lm_kv_heads", "lm_ffn", "lm_vocab", "lm_max_len", "lora_rank",
                     "cqaf_det_topk", "cqaf_map_topk", "num_commands", "plan_waypoints",
                     "plan_hidden", "plan_latent", "plan_anchors", "plan_diffusion_steps"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"AuroraConfig: {name}={v!r} must be an int >= 1")
        if self.patch_stem not in ("linear", "conv"):
            raise ValueError(f"AuroraConfig: patch_stem={self.patch_stem!r} must be 'linear' or "
                             "'conv'")
        if self.patch_stem == "conv" and self.patch_size & (self.patch_size - 1):
            raise ValueError(f"AuroraConfig: patch_stem='conv' needs a power-of-two patch_size, "
                             f"got {self.patch_size}")
        if self.map_points < 2:
            raise ValueError(f"AuroraConfig: map_points={self.map_points!r} must be >= 2")
        if self.vit_width % self.vit_heads or self.dec_width % self.dec_heads:
            raise ValueError("AuroraConfig: vit_width / dec_width must be divisible by their heads")
        for name in ("ego_image_size", "rsu_image_size"):
            w, h = getattr(self, name)
            if w % self.patch_size or h % self.patch_size or min(w, h) < self.patch_size:
                raise ValueError(f"AuroraConfig: {name}={(w, h)} must be multiples of "
                                 f"patch_size={self.patch_size}")
        for name in ("ego_range", "rsu_range"):
            r = getattr(self, name)
            if len(r) != 6 or not all(r[i] < r[i + 3] for i in range(3)):
                raise ValueError(f"AuroraConfig: {name}={r!r} must be (xmin, ymin, zmin, xmax, "
                                 "ymax, zmax) with min < max")
        if not 0 < self.depth_near < min(self.ego_depth_far, self.rsu_depth_far):
            raise ValueError("AuroraConfig: need 0 < depth_near < ego_depth_far, rsu_depth_far")
        if len(self.det_code_weights) != 10:
            raise ValueError("AuroraConfig: det_code_weights needs 10 values")
        if not 0 <= self.dropout < 1:
            raise ValueError(f"AuroraConfig: dropout={self.dropout!r} must be in [0, 1)")
        self._check_part2()

    def _check_part2(self) -> None:
        """Checks of the language model, CQAF and planner fields (``ValueError`` naming one)."""
        if self.lm_width % self.lm_heads or self.lm_heads % self.lm_kv_heads:
            raise ValueError(f"AuroraConfig: lm_width={self.lm_width} must be divisible by "
                             f"lm_heads={self.lm_heads}, and lm_heads by lm_kv_heads="
                             f"{self.lm_kv_heads}")
        if (self.lm_width // self.lm_heads) % 2:
            raise ValueError("AuroraConfig: lm_width / lm_heads must be even (rotary embedding)")
        if self.lm_width % self.dec_heads:
            raise ValueError(f"AuroraConfig: lm_width={self.lm_width} must be divisible by "
                             f"dec_heads={self.dec_heads} (semantic fusion attention)")
        if not self.lora_targets or not all(isinstance(t, str) and t for t in self.lora_targets):
            raise ValueError(f"AuroraConfig: lora_targets={self.lora_targets!r} must be module "
                             "names such as 'q_proj'")
        if not 0 <= self.lora_dropout < 1:
            raise ValueError(f"AuroraConfig: lora_dropout={self.lora_dropout!r} must be in [0, 1)")
        if (isinstance(self.lm_pretrain_block, bool) or not isinstance(self.lm_pretrain_block, int)
                or not 2 <= self.lm_pretrain_block <= self.lm_max_len):
            raise ValueError(f"AuroraConfig: lm_pretrain_block={self.lm_pretrain_block!r} must be "
                             f"an int in [2, lm_max_len={self.lm_max_len}]")
        if self.planner not in PLANNERS:
            raise ValueError(f"AuroraConfig: planner={self.planner!r}; known planners: {PLANNERS}")
        for name in ("lora_alpha", "cqaf_temperature", "cqaf_match_radius", "plan_dt"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"AuroraConfig: {name}={v!r} must be a positive number")
        for name in ("cqaf_ego_score", "cqaf_map_score"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"AuroraConfig: {name}={getattr(self, name)!r} must be in [0, 1]")
        for name in ("plan_l1_weight", "plan_bound_weight", "plan_col_weight", "plan_kl_weight",
                     "plan_cls_weight", "plan_bound_margin", "plan_col_radius",
                     "plan_start_weight", "plan_start_speed", "plan_start_dist"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"AuroraConfig: {name}={v!r} must be a number >= 0")
        if (isinstance(self.plan_route_points, bool) or not isinstance(self.plan_route_points, int)
                or not 0 <= self.plan_route_points <= MAX_ROUTE_POINTS):
            raise ValueError(f"AuroraConfig: plan_route_points={self.plan_route_points!r} must be "
                             f"an int in [0, {MAX_ROUTE_POINTS}] (0: no route input)")
        if not (isinstance(self.plan_route_spacing, (int, float))
                and math.isfinite(self.plan_route_spacing) and self.plan_route_spacing > 0):
            raise ValueError(f"AuroraConfig: plan_route_spacing={self.plan_route_spacing!r} must "
                             "be a positive number (m)")
        if self.plan_frame not in PLAN_FRAMES:
            raise ValueError(f"AuroraConfig: plan_frame={self.plan_frame!r} must be one of "
                             f"{PLAN_FRAMES}")
        if self.plan_route_step not in ROUTE_STEPS:
            raise ValueError(f"AuroraConfig: plan_route_step={self.plan_route_step!r} must be "
                             f"one of {ROUTE_STEPS}")
        if not (isinstance(self.plan_speed_dropout, (int, float))
                and 0 <= self.plan_speed_dropout <= 1):
            raise ValueError(f"AuroraConfig: plan_speed_dropout={self.plan_speed_dropout!r} must "
                             "be in [0, 1]")
        if not isinstance(self.stage3_freeze_backbone, bool):
            raise ValueError(f"AuroraConfig: stage3_freeze_backbone={self.stage3_freeze_backbone!r}"
                             " must be true or false")
        if len(self.plan_traj_scale) != 2 or min(self.plan_traj_scale) <= 0:
            raise ValueError(f"AuroraConfig: plan_traj_scale={self.plan_traj_scale!r} must be two "
                             "positive numbers (m)")

    # ------------------------------------------------------------------ per-branch views
    def image_size(self, branch: str) -> tuple[int, int]:
        """``(width, height)`` of the branch's camera images."""
        return self.ego_image_size if check_branch(branch) == "ego" else self.rsu_image_size

    def pc_range(self, branch: str) -> tuple[float, ...]:
        """The branch's perception range ``(xmin, ymin, zmin, xmax, ymax, zmax)``."""
        return self.ego_range if check_branch(branch) == "ego" else self.rsu_range

    def depth_far(self, branch: str) -> float:
        """Far end (m) of the branch's camera rays in the position embedding."""
        return self.ego_depth_far if check_branch(branch) == "ego" else self.rsu_depth_far

    def stage_hparams(self, stage: int) -> StageHParams:
        """Training settings of stage 0 (LM pre-training), 1 (ego branch), 2 (roadside branch),
        3-5."""
        if stage == 0:
            return self.stage0
        if stage == 1:
            return self.stage1
        if stage == 2:
            return self.stage2
        if stage in (3, 4, 5):
            return getattr(self, f"stage{stage}")
        raise ValueError(f"AuroraConfig: unknown stage {stage!r}; known: 0-5")

    def freeze_backbone(self, stage: int) -> bool:
        """Whether stage 3, 4 or 5 keeps the perception branches frozen (:data:`STAGE_TABLE`)."""
        if stage == 3:
            return self.stage3_freeze_backbone
        if stage in (4, 5):
            return True
        raise ValueError(f"AuroraConfig: freeze_backbone: stage {stage!r} is not 3, 4 or 5")

    # ------------------------------------------------------------------ construction
    @classmethod
    def for_scale(cls, name: str, **overrides: Any) -> AuroraConfig:
        """The named scale (``tiny``, ``default``, ``paper``), with field ``overrides``."""
        if name not in _SCALE_FIELDS:
            raise ValueError(f"unknown AURORA scale {name!r}; known scales: {', '.join(SCALES)}")
        fields = dict(_SCALE_FIELDS[name], scale=name)
        unknown = set(overrides) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"AuroraConfig: unknown fields {sorted(unknown)}")
        fields.update(overrides)
        return cls(**fields)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (tuples become lists); :meth:`from_dict` reads it back."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AuroraConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``. Keys missing from
        ``d`` (a file written before a field existed, e.g. part 1's runs) take the values of
        ``d["scale"]``, except the fields of :data:`ABSENT_MEANS_OFF`: a file without them
        describes a model without that input (its weights have none), so they read as off."""
        d = dict(d)
        for k, v in ABSENT_MEANS_OFF.items():
            d.setdefault(k, v)
        for k in ("stage0", "stage1", "stage2", "stage3", "stage4", "stage5"):
            if isinstance(d.get(k), dict):
                d[k] = StageHParams.from_dict(d[k])
        for k, v in _SCALE_FIELDS.get(d.get("scale"), {}).items():
            d.setdefault(k, v)
        return _from_dict(cls, d)


#: Fields whose absence in a run file means "off" (not the scale's default): a model trained
#: before the field existed has no weights for it (:meth:`AuroraConfig.from_dict`).
ABSENT_MEANS_OFF: dict[str, Any] = {"plan_route_points": 0, "plan_frame": "ego",
                                     "plan_route_step": "softplus"}
PLAN_FRAMES = ("ego", "route")  # the planner's output frames (``plan_frame``)
ROUTE_STEPS = ("relu_ste", "abs", "softplus")  # non-negative steps (``plan_route_step``)
MAX_ROUTE_POINTS = 16  # the planner's route input: at most this many points


def same_config(old: dict[str, Any] | None, new: dict[str, Any]) -> bool:
    """Whether a run file's ``old`` config equals ``new`` (both :meth:`AuroraConfig.to_dict`
    forms), where ``old`` may predate fields added since: a field it lacks takes ``new``'s value
    (the file never chose it). Resume checks use it; whether a late stage's route input differs
    is checked apart (:mod:`.stages`), since there a missing key means "none"."""
    if not isinstance(old, dict):
        return False
    try:
        return AuroraConfig.from_dict({**new, **old}) == AuroraConfig.from_dict(new)
    except (TypeError, ValueError):
        return False


def config_changes(old: dict[str, Any] | None, new: dict[str, Any]) -> str:
    """``"key: old -> new, ..."`` of the fields where a run file's ``old`` config differs from
    ``new`` (both :meth:`AuroraConfig.to_dict` forms; a field ``old`` lacks counts as ``new``'s,
    as :func:`same_config`), for error messages."""
    if not isinstance(old, dict):
        return f"no config in the run file ({old!r})"
    norm = json.loads(json.dumps(new))
    out = [f"{k}: {old[k]!r} -> {norm[k]!r}" for k in norm if k in old and old[k] != norm[k]]
    out += [f"{k}: (unknown field) {old[k]!r}" for k in old if k not in norm]
    return ", ".join(out) or "none"


def check_branch(branch: str) -> str:
    """Return ``branch`` if it is ``"ego"`` or ``"rsu"``; raise ``ValueError`` otherwise."""
    if branch not in BRANCHES:
        raise ValueError(f"unknown AURORA branch {branch!r}; known: {BRANCHES}")
    return branch


def _from_dict(cls, d: dict[str, Any]):
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(d) - set(names)
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown keys {sorted(unknown)}")
    kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
    return cls(**kw)


#: LoRA on every linear layer of the Llama blocks (attention and MLP).
_LORA_ALL = ("q_proj", "k_proj", "v_proj", "o_proj", "gate_proj", "up_proj", "down_proj")

_TINY_STAGE = StageHParams(batch_size=2, epochs=1, lr=1e-3, warmup_iters=0, num_workers=0)

#: Default scale, sized by measurement on the 2-core CPU with one torch thread (forward +
#: backward + AdamW on a batch of 8): ego branch ~34 samples/s, roadside ~62 samples/s. The
#: 48.5k training frames at stride 5 give 9.7k frames per epoch: 4 epochs take ~19 min (stage 1)
#: + ~10 min (stage 2) of compute; data loading (one worker) is ~3-8 % of a step.
_DEFAULT_STAGE1 = StageHParams(batch_size=8, epochs=4, lr=3e-4, warmup_iters=500,
                               frame_stride=5, num_workers=1)
_DEFAULT_STAGE2 = StageHParams(batch_size=8, epochs=4, lr=3e-4, warmup_iters=500,
                               frame_stride=5, num_workers=1)

#: Stages 3-5 at the default scale: sized by measurement (docs/aurora.md, "Closed loop").
_DEFAULT_STAGE3 = StageHParams(batch_size=8, epochs=1, lr=3e-4, warmup_iters=200,
                               frame_stride=5, num_workers=1)
_DEFAULT_STAGE4 = StageHParams(batch_size=8, epochs=2, lr=3e-4, warmup_iters=200,
                               frame_stride=5, num_workers=1)
_DEFAULT_STAGE5 = StageHParams(batch_size=8, epochs=1, lr=1e-4, warmup_iters=100,
                               frame_stride=10, num_workers=1)

#: The seed paper's stage table (appendix, "Training Configuration"): what each of stages 3-5
#: trains and supervises, and whether the perception backbones are frozen.
STAGE_TABLE = {
    3: "CQAF + fused heads (gt/fused) + LoRA on the QA next-token loss; planner off",
    4: "planner on (waypoint losses) + LoRA; perception branches frozen",
    5: "mixed QA and planning samples (waypoint loss only with <wp>); branches frozen",
}

_SCALE_FIELDS: dict[str, dict[str, Any]] = {
    "tiny": dict(lm_max_len=512,  # a long QA item is ~350 tokens with the tiny vocabulary
                 stage1=_TINY_STAGE, stage2=_TINY_STAGE, stage3=_TINY_STAGE,
                 stage4=_TINY_STAGE, stage5=_TINY_STAGE),
    "default": dict(
        patch_size=16, vit_depth=4, vit_width=128, vit_heads=4, mlp_ratio=2.0,
        depth_bins=16, dec_width=128, dec_heads=4, dec_ffn=256, det_layers=3, map_layers=2,
        num_det_queries=64, num_map_queries=20, map_points=8, lm_width=256,
        lm_layers=4, lm_heads=4, lm_kv_heads=4, lm_ffn=688, lm_vocab=4096, lm_max_len=512,
        lora_rank=8, lora_alpha=16.0, lora_targets=_LORA_ALL,
        cqaf_det_topk=32, cqaf_map_topk=10, plan_hidden=128, plan_latent=32, plan_anchors=20,
        stage1=_DEFAULT_STAGE1, stage2=_DEFAULT_STAGE2, stage3=_DEFAULT_STAGE3,
        stage4=_DEFAULT_STAGE4, stage5=_DEFAULT_STAGE5, stage3_freeze_backbone=True,
    ),
    "paper": dict(
        ego_image_size=(1024, 512), rsu_image_size=(1024, 512), patch_size=16,
        patch_stem="linear",
        vit_depth=24, vit_width=1024, vit_heads=16, mlp_ratio=4.0, depth_bins=64,
        ego_depth_far=61.2, dec_width=256, dec_heads=8, dec_ffn=2048, det_layers=6,
        map_layers=6, num_det_queries=900, num_map_queries=50, map_points=20, dropout=0.1,
        lm_width=4096,
        lm_layers=32, lm_heads=32, lm_kv_heads=32, lm_ffn=11008, lm_vocab=32000,
        lm_max_len=4096, lm_tie_embeddings=False, lora_rank=16, lora_alpha=32.0,
        lora_dropout=0.05, lora_targets=_LORA_ALL, cqaf_det_topk=100, cqaf_map_topk=50,
        plan_hidden=256, plan_latent=32, plan_anchors=20,
        stage1=StageHParams(batch_size=12, epochs=4, lr=5e-5),
        stage2=StageHParams(batch_size=12, epochs=4, lr=5e-5),
        stage3=StageHParams(batch_size=8, epochs=4, lr=4e-5),
        stage4=StageHParams(batch_size=8, epochs=6, lr=8e-5),
        stage5=StageHParams(batch_size=6, epochs=4, lr=8e-5),
    ),
}

#: Stage 0 (LM pre-training, :mod:`.stage0`) per scale. Default: sized by measurement on the
#: 2-core CPU (docs/aurora.md, "Stage 0"): the 4.2 M-parameter LM trains ~3.5k tokens/s with
#: one torch thread; every 3rd QA item of the train split (~15.8k documents, ~1.5 M tokens) in
#: one epoch of 8 x 256-token blocks (~730 steps, ~8 min).
_STAGE0_FIELDS: dict[str, dict[str, Any]] = {
    "tiny": dict(stage0=StageHParams(batch_size=4, epochs=1, lr=3e-3, warmup_iters=0),
                 lm_pretrain_block=64),
    "default": dict(stage0=StageHParams(batch_size=8, epochs=1, lr=1e-3, warmup_iters=50,
                                        frame_stride=3, grad_clip=1.0),
                    lm_pretrain_block=256),
    "paper": dict(stage0=StageHParams(batch_size=32, epochs=1, lr=3e-4, warmup_iters=500,
                                      grad_clip=1.0),
                  lm_pretrain_block=2048),
}
for _name, _fields in _STAGE0_FIELDS.items():
    _SCALE_FIELDS[_name].update(_fields)
