"""CQAF: Cross-View Query Alignment and Fusion (seed paper, section 4.2).

The roadside unit sends only spatial queries (:func:`rsu_message`: the top-k detection queries
with their reference points and scores, the top map queries with their polylines and scores, all
in the roadside unit's ground frame, plus ``E_{r->e}``); the ego fuses them with its own:

- **DET-CQAF** (:class:`DetCQAF`): roadside reference points are moved into the ego frame by
  ``E_{r->e}`` (:func:`transform_points`); the flattened rotation of ``E_{r->e}`` is concatenated
  to every roadside query before a re-projection MLP. Each ego query ``i`` aggregates the
  re-projected roadside queries with a distance-based, temperature-controlled soft assignment
  ``w_ij = exp(-d_ij / T) / (exp(-R / T) + sum_k exp(-d_ik / T))`` (``d`` = bird's-eye distance
  between reference points, ``T`` = ``cfg.cqaf_temperature``; the constant "no match" term at
  the match radius ``R`` = ``cfg.cqaf_match_radius`` lets an ego query with no roadside query
  nearby aggregate ~nothing), then the gated residual ``q_f = q_e + g * MLP([q_e; q_agg])`` with
  the channel-wise gate ``g = sigmoid(Linear([q_e; q_agg]))``. Roadside queries farther than
  ``R`` from every ego query scoring at least ``cfg.cqaf_ego_score`` (distant, unmatched) are
  appended to the fused set.
- **MAP-CQAF** (:class:`MapCQAF`): roadside map queries scoring below ``cfg.cqaf_map_score`` are
  dropped; the survivors' polylines are moved by ``E_{r->e}`` and the queries are aligned by the
  encoding ``Phi(q, E, polyline) = q + MLP([q; vec(R); t; polyline])`` (rotation, translation
  and the transformed polyline normalized to the ego range), then appended to the ego's.
- **Semantic fusion** (:class:`SemanticFusion`): per stream, the ego's semantic tokens
  (``t_det``, ``t_map``, language-model width) cross-attend to the fused spatial queries (keyed
  by query + position embedding of its reference, padding excluded): ``T^f_det``, ``T^f_map``.
- Fused detection / map heads (:mod:`.fused_heads`) predict from the fused sets.

Variable counts are fixed-size tensors with masks: the fused sets have ``Q + K`` / ``Qm + Km``
slots, the appended slots valid only where a roadside query was appended. ``E_{r->e}`` is
``T_ego_rsuground`` (calib's roadside ground frame -> ego frame, built by the geometry module:
:func:`rsu_to_ego`); a missing message is the empty message (``K = Km = 0``).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from torch import nn
from v2xbench.envs.v2x_intersection.core.geometry import relative_transform

from .calib import rsu_ground_pose
from .config import AuroraConfig
from .det_decoder import mlp
from .fused_heads import FusedDetHead, FusedMapHead

MESSAGE_KEYS = ("det_queries", "det_ref", "det_scores", "det_mask", "map_queries", "map_points",
                "map_scores", "map_mask", "rsu_to_ego")
EGO_KEYS = ("q_det", "det_ref", "det_logits", "q_map", "map_points", "t_det", "t_map")


# ---------------------------------------------------------------------- frames
def rsu_to_ego(t_world_ego: np.ndarray, t_world_rsu: np.ndarray) -> torch.Tensor:
    """``E_{r->e}`` ``(4, 4)`` float32: the roadside unit's ground frame (:mod:`.calib`) -> ego
    frame, from both world poses (:func:`~v2xbench.envs.v2x_intersection.core.geometry.
    relative_transform`)."""
    e = relative_transform(np.asarray(t_world_ego, np.float64),
                           rsu_ground_pose(np.asarray(t_world_rsu, np.float64)))
    return torch.from_numpy(e.astype(np.float32))


def transform_points(t: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Batched :func:`~v2xbench.envs.v2x_intersection.core.geometry.transform_points`: transforms
    ``t`` ``(B, 4, 4)`` applied to points ``(B, ..., 3)``."""
    b = t.shape[0]
    flat = points.reshape(b, -1, 3)
    out = flat @ t[:, :3, :3].transpose(1, 2) + t[:, None, :3, 3]
    return out.reshape(points.shape)


def transform_xy(t: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """:func:`transform_points` of ground points ``(B, ..., 2)`` (``z = 0``), keeping ``x, y``."""
    z = torch.zeros_like(points[..., :1])
    return transform_points(t, torch.cat([points, z], -1))[..., :2]


# ---------------------------------------------------------------------- the message
def query_scores(logits: torch.Tensor) -> torch.Tensor:
    """``(B, N)`` score of each query: the highest class probability (sigmoid logits)."""
    return logits.sigmoid().amax(-1)


def rsu_message(rsu_out: Mapping[str, torch.Tensor], cfg: AuroraConfig,
                e_rsu_to_ego: torch.Tensor) -> dict[str, torch.Tensor]:
    """The roadside unit's message from its branch's outputs (before serialization).

    Top ``cfg.cqaf_det_topk`` detection queries and ``cfg.cqaf_map_topk`` map queries by score,
    their reference points / polylines in metres in the roadside ground frame, and ``E_{r->e}``
    ``(B, 4, 4)`` (keys :data:`MESSAGE_KEYS`). Gradients flow into the selected queries.
    """
    lo = torch.tensor(cfg.rsu_range[:3], device=rsu_out["det_ref"].device)
    span = torch.tensor(cfg.rsu_range[3:], device=lo.device) - lo
    det_scores = query_scores(rsu_out["det_logits"][-1])
    map_scores = query_scores(rsu_out["map_logits"][-1])
    k = min(cfg.cqaf_det_topk, det_scores.shape[1])
    km = min(cfg.cqaf_map_topk, map_scores.shape[1])
    ds, di = det_scores.topk(k, dim=1)
    ms, mi = map_scores.topk(km, dim=1)

    def take(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        shape = idx.shape + x.shape[2:]
        return x.gather(1, idx.reshape(*idx.shape, *([1] * (x.dim() - 2))).expand(shape))

    return {
        "det_queries": take(rsu_out["q_det"], di),
        "det_ref": lo + take(rsu_out["det_ref"], di) * span,
        "det_scores": ds, "det_mask": torch.ones_like(ds, dtype=torch.bool),
        "map_queries": take(rsu_out["q_map"], mi),
        "map_points": take(rsu_out["map_points"][-1], mi),
        "map_scores": ms, "map_mask": torch.ones_like(ms, dtype=torch.bool),
        "rsu_to_ego": e_rsu_to_ego.to(ds.dtype),
    }


def empty_message(cfg: AuroraConfig, batch: int, device: torch.device | str = "cpu"
                  ) -> dict[str, torch.Tensor]:
    """The message of "nothing received": no roadside query (``K = Km = 0``), identity pose."""
    d, p = cfg.dec_width, cfg.map_points
    z = {"device": device}
    return {"det_queries": torch.zeros(batch, 0, d, **z), "det_ref": torch.zeros(batch, 0, 3, **z),
            "det_scores": torch.zeros(batch, 0, **z),
            "det_mask": torch.zeros(batch, 0, dtype=torch.bool, **z),
            "map_queries": torch.zeros(batch, 0, d, **z),
            "map_points": torch.zeros(batch, 0, p, 2, **z),
            "map_scores": torch.zeros(batch, 0, **z),
            "map_mask": torch.zeros(batch, 0, dtype=torch.bool, **z),
            "rsu_to_ego": torch.eye(4, **z).expand(batch, 4, 4).clone()}


def check_message(msg: Mapping[str, torch.Tensor], cfg: AuroraConfig, batch: int) -> None:
    """Raise ``ValueError`` naming a missing or misshapen key of a roadside message."""
    missing = [k for k in MESSAGE_KEYS if k not in msg]
    if missing:
        raise ValueError(f"CQAF: the roadside message has no {missing}")
    k, km = msg["det_mask"].shape[-1], msg["map_mask"].shape[-1]
    d, p = cfg.dec_width, cfg.map_points
    want = {"det_queries": (batch, k, d), "det_ref": (batch, k, 3), "det_scores": (batch, k),
            "det_mask": (batch, k), "map_queries": (batch, km, d),
            "map_points": (batch, km, p, 2), "map_scores": (batch, km), "map_mask": (batch, km),
            "rsu_to_ego": (batch, 4, 4)}
    for key, shape in want.items():
        if tuple(msg[key].shape) != shape:
            raise ValueError(f"CQAF: message {key} has shape {tuple(msg[key].shape)}; "
                             f"expected {shape}")


# ---------------------------------------------------------------------- modules
class DetCQAF(nn.Module):
    """DET-CQAF (module docstring)."""

    def __init__(self, cfg: AuroraConfig) -> None:
        super().__init__()
        d = cfg.dec_width
        self.temperature, self.radius = cfg.cqaf_temperature, cfg.cqaf_match_radius
        self.ego_score = cfg.cqaf_ego_score
        self.reproject = mlp([d + 9, d, d])
        self.fuse = mlp([2 * d, d, d])
        self.gate = nn.Linear(2 * d, d)
        self.rsu_tag = nn.Parameter(torch.zeros(d))  # marks appended roadside queries

    def forward(self, q_e: torch.Tensor, ref_e: torch.Tensor, q_r: torch.Tensor,
                ref_r: torch.Tensor, mask_r: torch.Tensor, e: torch.Tensor,
                ego_scores: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Fuse roadside detection queries into the ego's.

        Args:
            q_e: ``(B, Q, D)`` ego queries; ``ref_e`` ``(B, Q, 3)`` their references (m, ego).
            q_r: ``(B, K, D)`` roadside queries; ``ref_r`` ``(B, K, 3)`` references (m, roadside
                ground frame); ``mask_r`` ``(B, K)`` valid.
            e: ``(B, 4, 4)`` ``E_{r->e}``.
            ego_scores: ``(B, Q)`` ego query scores (``None``: every ego query can match).

        Returns:
            ``queries`` ``(B, Q + K, D)`` fused set (``Q`` fused ego queries, then the roadside
            slots), ``ref`` ``(B, Q + K, 3)`` ego-frame references (m), ``mask`` ``(B, Q + K)``,
            ``weights`` ``(B, Q, K)`` soft assignment, ``appended`` ``(B, K)``,
            ``rsu_ref`` ``(B, K, 3)`` roadside references in the ego frame.
        """
        b, q = q_e.shape[:2]
        mask_r = mask_r.bool()
        ref_re = transform_points(e, ref_r)
        rot = e[:, :3, :3].flatten(1)  # (B, 9)
        q_rr = self.reproject(torch.cat([q_r, rot[:, None].expand(-1, q_r.shape[1], -1)], -1))
        dist = torch.cdist(ref_e[..., :2], ref_re[..., :2])  # (B, Q, K) bird's-eye metres
        logits = (-dist / self.temperature).masked_fill(~mask_r[:, None], float("-inf"))
        null = torch.full((b, q, 1), -self.radius / self.temperature, device=q_e.device,
                          dtype=logits.dtype)
        weights = torch.softmax(torch.cat([null, logits], -1), -1)[..., 1:]
        q_agg = weights @ q_rr
        h = torch.cat([q_e, q_agg], -1)
        q_f = q_e + torch.sigmoid(self.gate(h)) * self.fuse(h)
        can_match = torch.ones(b, q, dtype=torch.bool, device=q_e.device)
        if ego_scores is not None:
            can_match = ego_scores >= self.ego_score
        nearest = dist.masked_fill(~can_match[..., None], float("inf")).amin(1)  # (B, K)
        appended = mask_r & (nearest > self.radius)
        return {"queries": torch.cat([q_f, q_rr + self.rsu_tag], 1),
                "ref": torch.cat([ref_e, ref_re], 1),
                "mask": torch.cat([torch.ones_like(can_match), appended], 1),
                "weights": weights, "appended": appended, "rsu_ref": ref_re}


class MapCQAF(nn.Module):
    """MAP-CQAF (module docstring): confidence filter, alignment ``Phi``, concatenation."""

    def __init__(self, cfg: AuroraConfig) -> None:
        super().__init__()
        d, p = cfg.dec_width, cfg.map_points
        r = cfg.ego_range
        lo = torch.tensor([r[0], r[1]])
        self.register_buffer("lo", lo, persistent=False)
        self.register_buffer("span", torch.tensor([r[3], r[4]]) - lo, persistent=False)
        self.register_buffer("t_scale", torch.tensor([r[3] - r[0], r[4] - r[1], r[5] - r[2]]),
                             persistent=False)
        self.threshold = cfg.cqaf_map_score
        self.phi = mlp([d + 9 + 3 + 2 * p, d, d])

    def forward(self, q_e: torch.Tensor, pts_e: torch.Tensor, q_r: torch.Tensor,
                pts_r: torch.Tensor, scores_r: torch.Tensor, mask_r: torch.Tensor,
                e: torch.Tensor) -> dict[str, torch.Tensor]:
        """Append the confident roadside map queries to the ego's.

        Args:
            q_e: ``(B, Qm, D)`` ego map queries; ``pts_e`` ``(B, Qm, P, 2)`` their polylines
                (m, ego frame).
            q_r: ``(B, Km, D)`` roadside map queries; ``pts_r`` ``(B, Km, P, 2)`` polylines (m,
                roadside ground frame); ``scores_r``, ``mask_r`` ``(B, Km)``.
            e: ``(B, 4, 4)`` ``E_{r->e}``.

        Returns:
            ``queries`` ``(B, Qm + Km, D)``, ``points`` ``(B, Qm + Km, P, 2)`` reference
            polylines (m, ego frame), ``mask`` ``(B, Qm + Km)``, ``appended`` ``(B, Km)``.
        """
        b, km = q_r.shape[:2]
        keep = mask_r.bool() & (scores_r >= self.threshold)
        pts_re = transform_xy(e, pts_r)
        norm = ((pts_re - self.lo) / self.span).flatten(2)  # (B, Km, 2P)
        pose = torch.cat([e[:, :3, :3].flatten(1), e[:, :3, 3] / self.t_scale], -1)
        x = torch.cat([q_r, pose[:, None].expand(-1, km, -1), norm], -1)
        aligned = q_r + self.phi(x)
        ones = torch.ones(b, q_e.shape[1], dtype=torch.bool, device=q_e.device)
        return {"queries": torch.cat([q_e, aligned], 1), "points": torch.cat([pts_e, pts_re], 1),
                "mask": torch.cat([ones, keep], 1), "appended": keep}


class SemanticFusion(nn.Module):
    """One stream's semantic fusion: ego semantic tokens ``(B, N, lm_width)`` cross-attend to the
    fused spatial queries ``(B, Nf, dec_width)`` (keys: query + position embedding)."""

    def __init__(self, cfg: AuroraConfig) -> None:
        super().__init__()
        w, d = cfg.lm_width, cfg.dec_width
        self.attn = nn.MultiheadAttention(w, cfg.dec_heads, dropout=cfg.dropout, kdim=d, vdim=d,
                                          batch_first=True)
        self.ffn = nn.Sequential(nn.Linear(w, 2 * w), nn.ReLU(), nn.Linear(2 * w, w))
        self.norm1, self.norm2 = nn.LayerNorm(w), nn.LayerNorm(w)

    def forward(self, tokens: torch.Tensor, queries: torch.Tensor, pos: torch.Tensor,
                mask: torch.Tensor) -> torch.Tensor:
        """``T^f`` ``(B, N, lm_width)`` from ego tokens, fused queries, their position, mask."""
        y = self.attn(tokens, queries + pos, queries, key_padding_mask=~mask,
                      need_weights=False)[0]
        t = self.norm1(tokens + y)
        return self.norm2(t + self.ffn(t))


class CQAF(nn.Module):
    """DET-CQAF + MAP-CQAF + fused heads + semantic fusion (module docstring)."""

    def __init__(self, cfg: AuroraConfig) -> None:
        super().__init__()
        self.cfg = cfg
        r = cfg.ego_range
        lo = torch.tensor(r[:3])
        self.register_buffer("lo", lo, persistent=False)
        self.register_buffer("span", torch.tensor(r[3:]) - lo, persistent=False)
        self.det = DetCQAF(cfg)
        self.map = MapCQAF(cfg)
        self.det_head = FusedDetHead(cfg)
        self.map_head = FusedMapHead(cfg)
        self.sem_det = SemanticFusion(cfg)
        self.sem_map = SemanticFusion(cfg)

    def forward(self, ego_out: Mapping[str, torch.Tensor],
                msg: Mapping[str, torch.Tensor] | None) -> dict[str, torch.Tensor]:
        """Fuse the ego branch's outputs (:class:`~.branch.PerceptionBranch`, keys
        :data:`EGO_KEYS`) with a roadside message (:func:`rsu_message`; ``None``: none).

        Returns (``Qf = Q + K``, ``Qmf = Qm + Km``): ``det_logits`` ``(1, B, Qf, C)``,
        ``det_boxes`` ``(1, B, Qf, 10)`` m, ``det_mask`` ``(B, Qf)``, ``map_logits``
        ``(1, B, Qmf, 3)``, ``map_points`` ``(1, B, Qmf, P, 2)`` m, ``map_mask`` ``(B, Qmf)``
        (ego frame, part 1's layout: :class:`~.fused_heads.FusedCriterion` scores them against
        ``gt/fused``), ``t_det`` ``(B, Q, lm_width)`` = ``T^f_det``, ``t_map``
        ``(B, Qm, lm_width)`` = ``T^f_map``, ``det_weights`` ``(B, Q, K)``, ``det_appended``
        ``(B, K)``, ``map_appended`` ``(B, Km)``.
        """
        missing = [k for k in EGO_KEYS if k not in ego_out]
        if missing:
            raise ValueError(f"CQAF: the ego branch's outputs have no {missing}")
        b = ego_out["q_det"].shape[0]
        if msg is None:
            msg = empty_message(self.cfg, b, ego_out["q_det"].device)
        check_message(msg, self.cfg, b)
        e = msg["rsu_to_ego"].to(ego_out["q_det"].dtype)
        ref_e = self.lo + ego_out["det_ref"] * self.span
        det = self.det(ego_out["q_det"], ref_e, msg["det_queries"], msg["det_ref"],
                       msg["det_mask"], e, query_scores(ego_out["det_logits"][-1]).detach())
        mp = self.map(ego_out["q_map"], ego_out["map_points"][-1].detach(), msg["map_queries"],
                      msg["map_points"], msg["map_scores"], msg["map_mask"], e)
        dh = self.det_head(det["queries"], det["ref"], det["mask"])
        mh = self.map_head(mp["queries"], mp["points"], mp["mask"])
        return {
            "det_logits": dh["det_logits"], "det_boxes": dh["det_boxes"], "det_mask": det["mask"],
            "map_logits": mh["map_logits"], "map_points": mh["map_points"],
            "map_mask": mp["mask"], "q_det": dh["q_det"], "q_map": mh["q_map"],
            "t_det": self.sem_det(ego_out["t_det"], dh["q_det"], dh["det_pos"], det["mask"]),
            "t_map": self.sem_map(ego_out["t_map"], mh["q_map"], mh["map_pos"], mp["mask"]),
            "det_weights": det["weights"], "det_appended": det["appended"],
            "map_appended": mp["appended"],
        }


__all__ = ["CQAF", "EGO_KEYS", "MESSAGE_KEYS", "DetCQAF", "MapCQAF", "SemanticFusion",
           "check_message", "empty_message", "query_scores", "rsu_message", "rsu_to_ego",
           "transform_points", "transform_xy"]
