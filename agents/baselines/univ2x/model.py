"""The UniV2X network: its roadside half (:class:`RoadsideNet`), its ego half (:class:`EgoNet`)
and both together for training (:class:`UniV2X`).

- **Roadside half** (runs as the ``"rsu"`` agent's policy): Lift-Splat BEV of the unit's camera
  (:class:`~.bev.LiftSplatEncoder`, its ground frame) -> agent queries: AURORA's DETR decoder
  (:class:`~v2xbench.agents.aurora.det_decoder.DetectionDecoder`) attending to the BEV tokens
  (TrackFormer-style detection; no tracking across frames) -> boxes; an occupancy head (1x1
  conv) on the BEV. Its message: :func:`~.message.rsu_message`.
- **Ego half**: the same encoder and decoder on the six ego cameras (ego frame), then
  :class:`~.fusion.AgentFusion` with the received agents, AURORA's fused detection head
  (:class:`~v2xbench.agents.aurora.fused_heads.FusedDetHead`: self-attention over the fused
  agents, boxes as offsets from their references) for the fused detections,
  :class:`~.fusion.OccupancyFusion` for the fused BEV and occupancy, and the query planner
  (:class:`~.planner.QueryPlanner`) over the fused agents and BEV.
- **Training** (:class:`UniV2X`): end to end; the roadside half runs on the batch's rows with
  an active unit, its message rounded to float16 as the channel delivers it (AURORA's
  :func:`~v2xbench.agents.aurora.rsu_agent.to_wire`; the cast passes gradients); the other rows
  get the empty message.

BEV tokens: the BEV cells as a sequence ``(B, nx * ny, W)`` with a position embedding (MLP of
the sine embedding of the normalized cell centre, :class:`BEVTokens`).
"""

from __future__ import annotations

import torch
from torch import nn
from v2xbench.agents.aurora.cqaf import query_scores
from v2xbench.agents.aurora.det_decoder import DetectionDecoder, focal_bias, mlp, sine_embed
from v2xbench.agents.aurora.fused_heads import FusedDetHead
from v2xbench.agents.aurora.route_input import PATH_KEY
from v2xbench.agents.aurora.rsu_agent import to_wire

from ..common.model import parameter_counts
from .bev import LiftSplatEncoder, cell_centres
from .config import UniV2XConfig
from .fusion import AgentFusion, OccupancyFusion
from .message import empty_message, rsu_message
from .planner import QueryPlanner


class BEVTokens(nn.Module):
    """``(B, W, nx, ny)`` BEV -> ``(tokens (B, nx * ny, W), position (1, nx * ny, W))``."""

    def __init__(self, cfg: UniV2XConfig, branch: str) -> None:
        super().__init__()
        r = cfg.pc_range(branch)
        centres = cell_centres(r, cfg.bev_size(branch)).reshape(-1, 2)
        lo, hi = torch.tensor(r[:2]), torch.tensor(r[3:5])
        self.register_buffer("norm", (centres - lo) / (hi - lo), persistent=False)
        self.feats = cfg.width // 2
        self.pos = mlp([2 * self.feats, cfg.width, cfg.width])

    def forward(self, bev: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return bev.flatten(2).transpose(1, 2), self.pos(sine_embed(self.norm, self.feats))[None]


class AgentPerception(nn.Module):
    """One agent's cameras -> BEV and agent queries (the part both halves share in design)."""

    def __init__(self, cfg: UniV2XConfig, branch: str) -> None:
        super().__init__()
        self.branch = branch
        self.encoder = LiftSplatEncoder(cfg, branch)
        self.tokens = BEVTokens(cfg, branch)
        self.decoder = DetectionDecoder(cfg.width, cfg.heads, cfg.ffn, cfg.det_layers,
                                        cfg.num_queries, cfg.num_classes, cfg.pc_range(branch),
                                        cfg.dropout)

    def forward(self, images: torch.Tensor, intrinsics: torch.Tensor,
                cam_to_frame: torch.Tensor) -> dict[str, torch.Tensor]:
        """``bev`` ``(B, W, nx, ny)``, ``bev_tokens`` / ``bev_pos``, and the decoder's
        ``det_logits`` ``(L, B, Q, C)``, ``det_boxes`` ``(L, B, Q, 10)`` (m), ``queries``
        ``(B, Q, W)``."""
        bev = self.encoder(images, intrinsics, cam_to_frame)["bev"]
        tokens, pos = self.tokens(bev)
        dec = self.decoder(tokens, pos.expand(tokens.shape[0], -1, -1))
        return {"bev": bev, "bev_tokens": tokens, "bev_pos": pos, "det_logits": dec["logits"],
                "det_boxes": dec["boxes"], "queries": dec["queries"]}


class RoadsideNet(nn.Module):
    """The roadside half (module docstring); ``branch = "rsu"``."""

    branch = "rsu"
    #: The per-agent perception (UniMM-V2X's roadside half swaps in its MoE perception).
    perception_cls = AgentPerception

    def __init__(self, cfg: UniV2XConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.perception = self.perception_cls(cfg, "rsu")
        self.occ_head = nn.Conv2d(cfg.width, 1, 1)
        nn.init.constant_(self.occ_head.bias, focal_bias())  # cells start at p = 0.01

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """``images`` ``(B, 1, 3, H, W)``, ``intrinsics``, ``cam_to_frame`` (the unit's ground
        frame) -> the perception outputs plus ``occ_logits`` ``(B, nx, ny)``."""
        out = self.perception(batch["images"], batch["intrinsics"], batch["cam_to_frame"])
        out["occ_logits"] = self.occ_head(out["bev"])[:, 0]
        return out


class EgoNet(nn.Module):
    """The ego half (module docstring)."""

    def __init__(self, cfg: UniV2XConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.perception = AgentPerception(cfg, "ego")
        self.agent_fusion = AgentFusion(cfg)
        self.det_head = FusedDetHead(cfg.data_config())
        self.occ_fusion = OccupancyFusion(cfg)
        self.planner = QueryPlanner(cfg)

    def forward(self, batch: dict[str, torch.Tensor], msg: dict[str, torch.Tensor],
                e_rsu_to_ego: torch.Tensor, has_rsu: torch.Tensor) -> dict[str, torch.Tensor]:
        """Ego inputs (``ego/images``, ``ego/intrinsics``, ``ego/cam_to_frame``, ``command``,
        ``ego_speed``, ``route_points``), the message (batch ``B``; rows without one masked),
        ``E_{r->e}`` ``(B, 4, 4)`` and ``has_rsu`` ``(B,)`` -> ``ego_det_logits`` /
        ``ego_det_boxes`` (the ego's own agents, ``(L, B, Q, .)``), ``det_logits`` /
        ``det_boxes`` (fused, ``(1, B, Q + K, .)``), ``det_mask``, ``occ_logits`` ``(B, nx,
        ny)``, ``waypoints`` ``(B, T, 2)``, ``match``."""
        p = self.perception(batch["ego/images"], batch["ego/intrinsics"],
                            batch["ego/cam_to_frame"])
        ref = p["det_boxes"][-1][..., :3].detach()
        scores = query_scores(p["det_logits"][-1]).detach()
        fused = self.agent_fusion(p["queries"], ref, scores, msg, e_rsu_to_ego)
        det = self.det_head(fused["queries"], fused["ref"], fused["mask"])
        bev, occ = self.occ_fusion(p["bev"], msg["occ"], e_rsu_to_ego, has_rsu)
        tokens, pos = self.perception.tokens(bev)
        wps = self.planner(det["q_det"], det["det_pos"], fused["mask"], tokens,
                           pos.expand(tokens.shape[0], -1, -1), batch["command"],
                           batch["ego_speed"], batch["route_points"], batch.get(PATH_KEY))
        return {"ego_det_logits": p["det_logits"], "ego_det_boxes": p["det_boxes"],
                "det_logits": det["det_logits"], "det_boxes": det["det_boxes"],
                "det_mask": fused["mask"], "occ_logits": occ, "waypoints": wps,
                "match": fused["match"]}


class UniV2X(nn.Module):
    """Both halves, trained end to end (module docstring)."""

    #: The halves and the message's functions (UniMM-V2X's model swaps them).
    roadside_net, ego_net = RoadsideNet, EgoNet
    empty_message, rsu_message = staticmethod(empty_message), staticmethod(rsu_message)

    def __init__(self, cfg: UniV2XConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.rsu = self.roadside_net(cfg)
        self.ego = self.ego_net(cfg)

    def message(self, batch: dict[str, torch.Tensor]
                ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor] | None, torch.Tensor]:
        """The batch's messages (empty for rows without a unit), the roadside outputs of the
        rows with one (``None`` if none) and those rows' indices."""
        has = batch["has_rsu"].bool()
        msg = self.empty_message(self.cfg, has.shape[0], has.device)
        rows = has.nonzero().squeeze(1)
        if not len(rows):
            return msg, None, rows
        out = self.rsu({k: batch[f"rsu/{k}"][rows] for k in
                        ("images", "intrinsics", "cam_to_frame")})
        for k, v in to_wire(self.rsu_message(out, self.cfg)).items():
            msg[k] = msg[k].index_put((rows,), v.to(msg[k].dtype))
        return msg, out, rows

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Training / evaluation pass over a batch of :class:`~.data.UniV2XFrames` (or
        UniMM-V2X's)."""
        msg, rsu_out, rows = self.message(batch)
        out = self.ego(batch, msg, batch["rsu_to_ego"], batch["has_rsu"].bool())
        out.update(rsu=rsu_out, rsu_rows=rows)
        return out


__all__ = ["AgentPerception", "BEVTokens", "EgoNet", "RoadsideNet", "UniV2X", "parameter_counts"]
