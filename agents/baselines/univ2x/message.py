"""UniV2X's roadside message: sparse agent queries + a dense occupancy map (the paper's
"sparse-dense hybrid transmission"), and its payload through the V2X channel.

:func:`rsu_message` builds it from the roadside half's outputs: the top ``cfg.msg_topk`` agent
queries by score (highest class probability of the last decoder layer,
:func:`~v2xbench.agents.aurora.cqaf.query_scores`) with their reference points (the decoded box
centres, metres, the unit's ground frame) and scores, and the occupancy probabilities max-pooled
to ``cfg.msg_occ`` cells over the roadside range. Training rounds it to float16 as the channel
does (AURORA's :func:`~v2xbench.agents.aurora.rsu_agent.to_wire`).

Payload (:func:`serialize_message`; ``F`` = :meth:`~.config.UniV2XConfig.message_floats`; every
value float16-representable; a raw payload, ``wire.FORMAT_RAW``):

======================  ===============================================================
floats                  content
======================  ===============================================================
6                       header: :data:`MAGIC`, :data:`VERSION`, ``K``, ``D``, ``Ox``, ``Oy``
``K * (4 + D)``         per agent: reference ``x, y, z`` (m), score, query (``D``)
``Ox * Oy``             occupancy probability per cell, row-major over ``x`` then ``y``
======================  ===============================================================

The channel adds its 16-byte header and sends 2 bytes a float (float16), so a message costs
``16 + 2 F`` bytes on air. The ego reads the payload and ``E_{r->e}`` with AURORA's helpers
(:func:`~v2xbench.agents.aurora.rsu_agent.received_payload`,
:func:`~v2xbench.agents.aurora.rsu_agent.received_pose`). A payload larger than the env's
``max_payload_floats`` is refused by the channel (``oversized message``), never cut; the agent
declares ``channel = {"max_payload_floats": F}`` so that ``eval`` sets the limit.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
import torch.nn.functional as F
from v2xbench.agents.aurora.cqaf import query_scores

from ..common.message import read_header, to_payload
from .config import MESSAGE_HEADER_FLOATS, UniV2XConfig

MAGIC = 2025.0  # an integer float16 holds exactly (AURORA's messages start with 1717)
VERSION = 1.0
KEYS = ("queries", "ref", "scores", "mask", "occ")


def rsu_message(out: Mapping[str, torch.Tensor], cfg: UniV2XConfig) -> dict[str, torch.Tensor]:
    """The message tensors (batch ``B``; :data:`KEYS`) of the roadside half's outputs
    (``det_logits`` ``(L, B, Q, C)``, ``det_boxes`` ``(L, B, Q, 10)``, ``queries`` ``(B, Q, D)``,
    ``occ_logits`` ``(B, nx, ny)``). Gradients flow into the selected queries and the map."""
    scores = query_scores(out["det_logits"][-1])  # (B, Q)
    k = min(cfg.msg_topk, scores.shape[1])
    top, idx = scores.topk(k, dim=1)
    q = out["queries"].gather(1, idx[..., None].expand(-1, -1, out["queries"].shape[-1]))
    ref = out["det_boxes"][-1].gather(1, idx[..., None].expand(-1, -1, 10))[..., :3]
    occ = F.adaptive_max_pool2d(out["occ_logits"].sigmoid()[:, None], tuple(cfg.msg_occ))[:, 0]
    return {"queries": q, "ref": ref, "scores": top, "mask": torch.ones_like(top, dtype=torch.bool),
            "occ": occ}


def empty_message(cfg: UniV2XConfig, batch: int, device: torch.device | str = "cpu"
                  ) -> dict[str, torch.Tensor]:
    """The message of "nothing received": no agent (all masked), zero occupancy."""
    k, d = cfg.msg_topk, cfg.width
    return {"queries": torch.zeros(batch, k, d, device=device),
            "ref": torch.zeros(batch, k, 3, device=device),
            "scores": torch.zeros(batch, k, device=device),
            "mask": torch.zeros(batch, k, dtype=torch.bool, device=device),
            "occ": torch.zeros(batch, *cfg.msg_occ, device=device)}


def serialize_message(msg: Mapping[str, torch.Tensor]) -> np.ndarray:
    """A one-sample message (batch 1) as a raw payload: a 1-D float32 array of
    float16-representable values (module docstring; values beyond ``+-PAYLOAD_LIMIT`` clipped)."""
    q, ref, sc, occ = msg["queries"], msg["ref"], msg["scores"], msg["occ"]
    if q.dim() != 3 or q.shape[0] != 1:
        raise ValueError(f"serialize_message: queries has shape {tuple(q.shape)}; expected "
                         "(1, K, D) (one roadside unit's message)")
    k, d = q.shape[1:]
    ox, oy = occ.shape[1:]
    head = torch.tensor([MAGIC, VERSION, k, d, ox, oy], dtype=torch.float32)
    agents = torch.cat([ref[0], sc[0, :, None], q[0]], -1).reshape(-1)
    flat = torch.cat([head, agents.detach().float().cpu(), occ[0].reshape(-1).detach().float()
                      .cpu()]).numpy()
    return to_payload(flat)


def deserialize_message(payload: np.ndarray, cfg: UniV2XConfig) -> dict[str, torch.Tensor]:
    """The message tensors (batch 1, :data:`KEYS`) of a payload made by
    :func:`serialize_message`.

    Raises:
        ValueError: not a UniV2X message (magic, version), sizes other than ``cfg``'s (``K``,
            ``D``, ``Ox``, ``Oy``), or a length that disagrees with them.
    """
    x, (k, d, ox, oy) = read_header(payload, MAGIC, VERSION, MESSAGE_HEADER_FLOATS, "UniV2X")
    want = (cfg.msg_topk, cfg.width, *cfg.msg_occ)
    if (k, d, ox, oy) != want:
        raise ValueError(f"UniV2X deserialize_message: the message has K={k}, D={d}, occupancy "
                         f"{ox}x{oy}; this model takes K={want[0]}, D={want[1]}, occupancy "
                         f"{want[2]}x{want[3]}")
    n = MESSAGE_HEADER_FLOATS + k * (4 + d) + ox * oy
    if x.shape[0] != n:
        raise ValueError(f"UniV2X deserialize_message: {x.shape[0]} floats; a message of these "
                         f"sizes has {n}")
    agents = torch.from_numpy(x[MESSAGE_HEADER_FLOATS:MESSAGE_HEADER_FLOATS + k * (4 + d)]
                              .copy()).view(k, 4 + d)
    occ = torch.from_numpy(x[MESSAGE_HEADER_FLOATS + k * (4 + d):].copy()).view(ox, oy)
    return {"queries": agents[None, :, 4:], "ref": agents[None, :, :3],
            "scores": agents[None, :, 3], "mask": torch.ones(1, k, dtype=torch.bool),
            "occ": occ[None]}


__all__ = ["KEYS", "MAGIC", "VERSION", "deserialize_message", "empty_message", "rsu_message",
           "serialize_message"]
