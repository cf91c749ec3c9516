"""The UniMM-V2X network: its roadside half (:class:`RoadsideNet`), its ego half (:class:`EgoNet`)
and both together for training (:class:`UniMMV2X`).

- **MoE-BEV perception** (:class:`MoEPerception`, per agent): UniV2X's Lift-Splat BEV
  (:class:`~..univ2x.bev.LiftSplatEncoder`), then ``cfg.bev_moe_layers`` post-norm residual MoE
  FFNs over the BEV tokens (:class:`~.moe.MoEFFN`; the paper replaces the BEV encoder's FFNs by
  MoE blocks), then AURORA's DETR decoder for the agent queries (as UniV2X).
- **Roadside half** (the ``"rsu"`` agent's policy): MoE-BEV perception on the unit's camera, an
  occupancy head, and the MotionMoE decoder (:class:`~.motion.MotionDecoder`) over its agent
  queries; its message (:func:`~.message.rsu_message`) carries perception and motion queries.
- **Ego half**: MoE-BEV perception on the six cameras; *perception-level fusion*: UniV2X's
  agent association and fusion (:class:`~..univ2x.fusion.AgentFusion`), AURORA's fused
  detection head, UniV2X's occupancy fusion; the MotionMoE decoder over the fused agents;
  *prediction-level fusion* of the roadside motion queries (:class:`~.motion.MotionFusion`);
  the motion heads on the fused motion queries; UniV2X's query planner
  (:class:`~..univ2x.planner.QueryPlanner`) attending to the fused motion queries and the
  fused BEV.
- **Training** (:class:`UniMMV2X`): end to end, the message rounded to float16 as the channel
  delivers it (AURORA's :func:`~v2xbench.agents.aurora.rsu_agent.to_wire`); rows without a unit
  get the empty message.
"""

from __future__ import annotations

import torch
from torch import nn
from v2xbench.agents.aurora.cqaf import query_scores
from v2xbench.agents.aurora.det_decoder import DetectionDecoder
from v2xbench.agents.aurora.fused_heads import FusedDetHead
from v2xbench.agents.aurora.route_input import PATH_KEY

from ..common.model import parameter_counts
from ..univ2x.bev import LiftSplatEncoder
from ..univ2x.fusion import AgentFusion, OccupancyFusion
from ..univ2x.model import BEVTokens, UniV2X
from ..univ2x.model import RoadsideNet as UniV2XRoadsideNet
from ..univ2x.planner import QueryPlanner
from .config import UniMMV2XConfig
from .message import check_message, empty_message, rsu_message
from .moe import MoEFFN
from .motion import MotionDecoder, MotionFusion


class MoEPerception(nn.Module):
    """One agent's cameras -> MoE-enhanced BEV and agent queries (module docstring)."""

    def __init__(self, cfg: UniMMV2XConfig, branch: str) -> None:
        super().__init__()
        self.size = tuple(cfg.bev_size(branch))
        self.encoder = LiftSplatEncoder(cfg, branch)
        self.moe = nn.ModuleList(MoEFFN(cfg.width, cfg.moe_hidden, cfg.num_experts, cfg.moe_topk)
                                 for _ in range(cfg.bev_moe_layers))
        self.norms = nn.ModuleList(nn.LayerNorm(cfg.width) for _ in range(cfg.bev_moe_layers))
        self.tokens = BEVTokens(cfg, branch)
        self.decoder = DetectionDecoder(cfg.width, cfg.heads, cfg.ffn, cfg.det_layers,
                                        cfg.num_queries, cfg.num_classes, cfg.pc_range(branch),
                                        cfg.dropout)

    def forward(self, images: torch.Tensor, intrinsics: torch.Tensor,
                cam_to_frame: torch.Tensor) -> dict[str, torch.Tensor]:
        """``bev`` ``(B, W, nx, ny)``, ``bev_tokens`` / ``bev_pos``, ``det_logits`` ``(L, B,
        Q, C)``, ``det_boxes`` ``(L, B, Q, 10)``, ``queries`` ``(B, Q, W)``, ``balance``."""
        bev = self.encoder(images, intrinsics, cam_to_frame)["bev"]
        tokens, pos = self.tokens(bev)
        bal = tokens.new_zeros(())
        for moe, norm in zip(self.moe, self.norms):
            y, bl = moe(tokens)
            tokens, bal = norm(tokens + y), bal + bl
        b, w = bev.shape[:2]
        bev = tokens.transpose(1, 2).reshape(b, w, *self.size)
        dec = self.decoder(tokens, pos.expand(b, -1, -1))
        return {"bev": bev, "bev_tokens": tokens, "bev_pos": pos, "det_logits": dec["logits"],
                "det_boxes": dec["boxes"], "queries": dec["queries"], "balance": bal}


class RoadsideNet(UniV2XRoadsideNet):
    """The roadside half (module docstring); ``branch = "rsu"``: UniV2X's (occupancy head) on
    MoE-BEV perception, plus the MotionMoE decoder."""

    perception_cls = MoEPerception

    def __init__(self, cfg: UniMMV2XConfig) -> None:
        super().__init__(cfg)
        self.motion = MotionDecoder(cfg, cfg.rsu_range)

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """``images`` ``(B, 1, 3, H, W)``, ``intrinsics``, ``cam_to_frame`` (the unit's ground
        frame) -> the perception outputs, ``occ_logits`` ``(B, nx, ny)``, ``motion_q``,
        ``traj``, ``mode_logits`` and ``balance`` (both MoE parts)."""
        out = super().forward(batch)
        q = out["queries"]
        mask = torch.ones(q.shape[:2], dtype=torch.bool, device=q.device)
        mot = self.motion(q, out["det_boxes"][-1][..., :3], mask, out["bev_tokens"],
                          out["bev_pos"])
        out.update(motion_q=mot["motion_q"], traj=mot["traj"], mode_logits=mot["mode_logits"],
                   balance=out["balance"] + mot["balance"])
        return out


class EgoNet(nn.Module):
    """The ego half (module docstring)."""

    def __init__(self, cfg: UniMMV2XConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.perception = MoEPerception(cfg, "ego")
        self.agent_fusion = AgentFusion(cfg)
        self.det_head = FusedDetHead(cfg.data_config())
        self.occ_fusion = OccupancyFusion(cfg)
        self.motion = MotionDecoder(cfg, cfg.ego_range)
        self.motion_fusion = MotionFusion(cfg)
        self.planner = QueryPlanner(cfg)

    def forward(self, batch: dict[str, torch.Tensor], msg: dict[str, torch.Tensor],
                e_rsu_to_ego: torch.Tensor, has_rsu: torch.Tensor) -> dict[str, torch.Tensor]:
        """Ego inputs (``ego/images``, ``ego/intrinsics``, ``ego/cam_to_frame``, ``command``,
        ``ego_speed``, ``route_points``), the message (:mod:`.message`, batch ``B``),
        ``E_{r->e}`` ``(B, 4, 4)``, ``has_rsu`` ``(B,)`` -> UniV2X's outputs (``ego_det_*``,
        ``det_logits`` / ``det_boxes`` / ``det_mask`` of the fused agents, ``occ_logits``,
        ``waypoints``, ``match``) plus ``traj`` ``(B, Q + K, M, T, 2)`` (m, ego frame),
        ``mode_logits`` and ``balance``."""
        check_message(msg, self.cfg)
        p = self.perception(batch["ego/images"], batch["ego/intrinsics"],
                            batch["ego/cam_to_frame"])
        ref = p["det_boxes"][-1][..., :3].detach()
        scores = query_scores(p["det_logits"][-1]).detach()
        fused = self.agent_fusion(p["queries"], ref, scores, msg, e_rsu_to_ego)
        det = self.det_head(fused["queries"], fused["ref"], fused["mask"])
        bev, occ = self.occ_fusion(p["bev"], msg["occ"], e_rsu_to_ego, has_rsu)
        tokens, pos = self.perception.tokens(bev)
        agent_ref = det["det_boxes"][-1][..., :3]
        mq, bal = self.motion.decode(det["q_det"], agent_ref, fused["mask"], tokens, pos)
        q = ref.shape[1]
        partner = self.motion_fusion.partners(fused["match"], fused["mask"][:, q:])
        mq = self.motion_fusion(mq, msg["motion"], msg["scores"], partner, e_rsu_to_ego)
        traj, modes = self.motion.heads(mq, agent_ref)
        wps = self.planner(mq, det["det_pos"], fused["mask"], tokens,
                           pos.expand(tokens.shape[0], -1, -1), batch["command"],
                           batch["ego_speed"], batch["route_points"], batch.get(PATH_KEY))
        return {"ego_det_logits": p["det_logits"], "ego_det_boxes": p["det_boxes"],
                "det_logits": det["det_logits"], "det_boxes": det["det_boxes"],
                "det_mask": fused["mask"], "occ_logits": occ, "waypoints": wps,
                "match": fused["match"], "traj": traj, "mode_logits": modes,
                "balance": p["balance"] + bal}


class UniMMV2X(UniV2X):
    """Both halves, trained end to end (module docstring): UniV2X's training model
    (:class:`~..univ2x.model.UniV2X`: the message of the rows with a unit, float16 as on air)
    with UniMM-V2X's halves and message."""

    roadside_net, ego_net = RoadsideNet, EgoNet
    empty_message, rsu_message = staticmethod(empty_message), staticmethod(rsu_message)


__all__ = ["EgoNet", "MoEPerception", "RoadsideNet", "UniMMV2X", "parameter_counts"]
