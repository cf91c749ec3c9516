"""UniMM-V2X's roadside message: UniV2X's sparse agent queries and dense occupancy (the
perception level) plus each sent agent's **motion query** (the prediction level), and its
payload through the V2X channel.

:func:`rsu_message` selects the agents as UniV2X does (:func:`~..univ2x.message.rsu_message`:
the top ``cfg.msg_topk`` by score, their reference points and scores, the occupancy max-pooled
to ``cfg.msg_occ``) and adds the selected agents' motion queries (:mod:`.motion`).

Payload (:func:`serialize_message`; ``F`` = :meth:`~.config.UniMMV2XConfig.message_floats`;
float16-representable values, a raw payload):

======================  ===============================================================
floats                  content
======================  ===============================================================
6                       header: :data:`MAGIC`, :data:`VERSION`, ``K``, ``D``, ``Ox``, ``Oy``
``K * (4 + 2 D)``       per agent: reference ``x, y, z`` (m, the unit's ground frame), score,
                        perception query (``D``), motion query (``D``)
``Ox * Oy``             occupancy probability per cell, row-major over ``x`` then ``y``
======================  ===============================================================

The channel adds its 16-byte header and sends 2 bytes a float: ``16 + 2 F`` bytes on air.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from ..common.message import read_header, to_payload
from ..univ2x import message as univ2x_message
from .config import MESSAGE_HEADER_FLOATS, UniMMV2XConfig

MAGIC = 2026.0  # UniV2X's is 2025, AURORA's 1717
VERSION = 1.0
KEYS = ("queries", "motion", "ref", "scores", "mask", "occ")


def rsu_message(out: Mapping[str, torch.Tensor], cfg: UniMMV2XConfig
                ) -> dict[str, torch.Tensor]:
    """The message tensors (batch ``B``; :data:`KEYS`) of the roadside half's outputs (UniV2X's
    keys plus ``motion_q`` ``(B, Q, D)``). Gradients flow into the selected queries."""
    d = out["queries"].shape[-1]
    both = dict(out, queries=torch.cat([out["queries"], out["motion_q"]], -1))
    msg = univ2x_message.rsu_message(both, cfg)  # the same agents for both levels
    q = msg["queries"]
    msg["queries"], msg["motion"] = q[..., :d], q[..., d:]
    return msg


def empty_message(cfg: UniMMV2XConfig, batch: int, device: torch.device | str = "cpu"
                  ) -> dict[str, torch.Tensor]:
    """The message of "nothing received": no agent (all masked), zero occupancy."""
    msg = univ2x_message.empty_message(cfg, batch, device)
    msg["motion"] = torch.zeros_like(msg["queries"])
    return msg


def check_message(msg: Mapping[str, torch.Tensor], cfg: UniMMV2XConfig) -> None:
    """Raise ``ValueError`` naming the key, its shape and the expected one unless ``msg`` has
    every key of :data:`KEYS` with this config's sizes and one batch size."""
    k, d = cfg.msg_topk, cfg.width
    want = {"queries": (k, d), "motion": (k, d), "ref": (k, 3), "scores": (k,), "mask": (k,),
            "occ": tuple(cfg.msg_occ)}
    batch = None
    for key, shape in want.items():
        if key not in msg:
            raise ValueError(f"UniMM-V2X message: no {key!r} (keys {sorted(msg)}; expected "
                             f"{list(KEYS)})")
        got = tuple(msg[key].shape)
        if got[1:] != shape or (batch is not None and got[0] != batch):
            raise ValueError(f"UniMM-V2X message: {key} has shape {got}; expected "
                             f"({batch if batch is not None else 'B'}, "
                             f"{', '.join(str(v) for v in shape)}) (K=msg_topk={k}, D=width={d}, "
                             f"occupancy msg_occ={tuple(cfg.msg_occ)})")
        batch = got[0]


def serialize_message(msg: Mapping[str, torch.Tensor]) -> np.ndarray:
    """A one-sample message (batch 1) as a raw payload (module docstring)."""
    q, m, ref, sc, occ = msg["queries"], msg["motion"], msg["ref"], msg["scores"], msg["occ"]
    if q.dim() != 3 or q.shape[0] != 1 or m.shape != q.shape:
        raise ValueError(f"UniMM-V2X serialize_message: queries {tuple(q.shape)} and motion "
                         f"{tuple(m.shape)} must both be (1, K, D) (one unit's message)")
    k, d = q.shape[1:]
    ox, oy = occ.shape[1:]
    head = torch.tensor([MAGIC, VERSION, k, d, ox, oy], dtype=torch.float32)
    agents = torch.cat([ref[0], sc[0, :, None], q[0], m[0]], -1).reshape(-1)
    flat = torch.cat([head, agents.detach().float().cpu(),
                      occ[0].reshape(-1).detach().float().cpu()]).numpy()
    return to_payload(flat)


def deserialize_message(payload: np.ndarray, cfg: UniMMV2XConfig) -> dict[str, torch.Tensor]:
    """The message tensors (batch 1, :data:`KEYS`) of a payload of :func:`serialize_message`.

    Raises:
        ValueError: not a UniMM-V2X message (magic, version), sizes other than ``cfg``'s, or a
            length that disagrees with them.
    """
    x, (k, d, ox, oy) = read_header(payload, MAGIC, VERSION, MESSAGE_HEADER_FLOATS,
                                    "UniMM-V2X")
    want = (cfg.msg_topk, cfg.width, *cfg.msg_occ)
    if (k, d, ox, oy) != want:
        raise ValueError(f"UniMM-V2X deserialize_message: the message has K={k}, D={d}, "
                         f"occupancy {ox}x{oy}; this model takes K={want[0]}, D={want[1]}, "
                         f"occupancy {want[2]}x{want[3]}")
    h, per = MESSAGE_HEADER_FLOATS, 4 + 2 * d
    n = h + k * per + ox * oy
    if x.shape[0] != n:
        raise ValueError(f"UniMM-V2X deserialize_message: {x.shape[0]} floats; a message of "
                         f"these sizes has {n}")
    agents = torch.from_numpy(x[h:h + k * per].copy()).view(k, per)
    occ = torch.from_numpy(x[h + k * per:].copy()).view(ox, oy)
    return {"queries": agents[None, :, 4:4 + d], "motion": agents[None, :, 4 + d:],
            "ref": agents[None, :, :3], "scores": agents[None, :, 3],
            "mask": torch.ones(1, k, dtype=torch.bool), "occ": occ[None]}


__all__ = ["KEYS", "MAGIC", "VERSION", "check_message", "deserialize_message",
           "empty_message", "rsu_message", "serialize_message"]
