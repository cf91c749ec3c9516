"""One perception branch of AURORA (seed paper, section 4.1): ego (6 cameras) or roadside (1).

``PerceptionBranch(cfg, "ego" | "rsu")``: the branch's own ViT encoder whose patch tokens carry
the depth-aware 3D position embedding of the branch frame (:mod:`.position`), a detection decoder
(:mod:`.det_decoder`) and a map decoder (:mod:`.map_decoder`). The ego branch also has the traffic-
light head and the semantic tokens ``T_det``, ``T_map``: linear projections of its final detection
and map queries to the language model's width (``cfg.lm_width``). The two branches share no
parameters. Output keys and shapes are listed in :meth:`PerceptionBranch.forward`.
"""

from __future__ import annotations

import torch
from torch import nn

from .config import NUM_CAMERAS, AuroraConfig, check_branch
from .det_decoder import DetectionDecoder, LightHead
from .map_decoder import MapDecoder
from .position import DepthAwarePE
from .vit import ViTEncoder

INPUT_KEYS = ("images", "intrinsics", "cam_to_frame")


class PerceptionBranch(nn.Module):
    """Encoder + 3D position embedding + detection and map decoders of one view.

    Args:
        cfg: the model configuration.
        branch: ``"ego"`` or ``"rsu"``.
    """

    def __init__(self, cfg: AuroraConfig, branch: str = "ego") -> None:
        super().__init__()
        self.cfg, self.branch = cfg, check_branch(branch)
        self.num_cameras = NUM_CAMERAS[branch]
        self.image_size = cfg.image_size(branch)
        rng = cfg.pc_range(branch)
        self.pe = DepthAwarePE(self.image_size, cfg.patch_size, cfg.depth_bins, cfg.depth_near,
                               cfg.depth_far(branch), rng, cfg.vit_width)
        self.encoder = ViTEncoder(self.image_size, cfg.patch_size, cfg.vit_width, cfg.vit_depth,
                                  cfg.vit_heads, cfg.mlp_ratio, self.num_cameras, cfg.dropout,
                                  cfg.patch_stem)
        same = cfg.vit_width == cfg.dec_width
        self.mem_proj = nn.Identity() if same else nn.Linear(cfg.vit_width, cfg.dec_width)
        self.pos_proj = nn.Identity() if same else nn.Linear(cfg.vit_width, cfg.dec_width)
        self.det = DetectionDecoder(cfg.dec_width, cfg.dec_heads, cfg.dec_ffn, cfg.det_layers,
                                    cfg.num_det_queries, cfg.num_classes, rng, cfg.dropout)
        self.map = MapDecoder(cfg.dec_width, cfg.dec_heads, cfg.dec_ffn, cfg.map_layers,
                              cfg.num_map_queries, cfg.map_points, cfg.num_map_classes, rng,
                              cfg.dropout)
        if branch == "ego":
            self.light = LightHead(cfg.dec_width, cfg.dec_heads, cfg.num_light_classes,
                                   cfg.dropout)
            self.t_det = nn.Linear(cfg.dec_width, cfg.lm_width)
            self.t_map = nn.Linear(cfg.dec_width, cfg.lm_width)

    def check_inputs(self, batch: dict) -> None:
        """Raise ``ValueError`` naming the key whose shape does not fit this branch."""
        for key in INPUT_KEYS:
            if key not in batch:
                raise ValueError(f"PerceptionBranch({self.branch}): batch has no {key!r}")
        img = batch["images"]
        w, h = self.image_size
        if img.dim() != 5 or tuple(img.shape[1:]) != (self.num_cameras, 3, h, w):
            raise ValueError(
                f"PerceptionBranch({self.branch}): images has shape {tuple(img.shape)}; "
                f"expected (B, {self.num_cameras}, 3, {h}, {w})")
        bn = tuple(img.shape[:2])
        for key, tail in (("intrinsics", (3, 3)), ("cam_to_frame", (4, 4))):
            if tuple(batch[key].shape) != bn + tail:
                raise ValueError(f"PerceptionBranch({self.branch}): {key} has shape "
                                 f"{tuple(batch[key].shape)}; expected {bn + tail}")

    def forward(self, batch: dict) -> dict[str, torch.Tensor]:
        """Perceive one batch (reads ``images``, ``intrinsics``, ``cam_to_frame``).

        Returns (``L`` decoder layers, ``Q`` / ``Qm`` detection / map queries, ``D`` width):
            ``det_logits`` ``(L, B, Q, C)``, ``det_boxes`` ``(L, B, Q, 10)`` metres in the
            branch frame, ``det_ref`` ``(B, Q, 3)`` normalized, ``q_det`` ``(B, Q, D)``,
            ``map_logits`` ``(L, B, Qm, 3)``, ``map_points`` ``(L, B, Qm, P, 2)`` metres,
            ``q_map`` ``(B, Qm, D)``; ego only: ``light_logits`` ``(B, 5)``, ``t_det``
            ``(B, Q, lm_width)``, ``t_map`` ``(B, Qm, lm_width)``.
        """
        self.check_inputs(batch)
        pe = self.pe(batch["intrinsics"], batch["cam_to_frame"])  # (B, N, T, Dv)
        tokens = self.encoder(batch["images"].float(), pe)  # (B, N, T, Dv)
        memory = self.mem_proj(tokens.flatten(1, 2))  # (B, N*T, D)
        mem_pos = self.pos_proj(pe.flatten(1, 2))
        det = self.det(memory, mem_pos)
        mp = self.map(memory, mem_pos)
        out = {"det_logits": det["logits"], "det_boxes": det["boxes"], "det_ref": det["ref"],
               "q_det": det["queries"], "map_logits": mp["logits"], "map_points": mp["points"],
               "q_map": mp["queries"]}
        if self.branch == "ego":
            out["light_logits"] = self.light(memory, mem_pos)
            out["t_det"] = self.t_det(det["queries"])
            out["t_map"] = self.t_map(mp["queries"])
        return out
