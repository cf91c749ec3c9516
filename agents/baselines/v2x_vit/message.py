"""V2X-ViT's roadside message: the unit's intermediate BEV feature map, through a learned 1x1
bottleneck, and its payload through the V2X channel.

The roadside half (:class:`~.model.RoadsideNet`) computes its BEV features over its own range in
its ground frame and compresses them with a 1x1 convolution to ``cfg.sent_channels()``
channels (``compress_channels``; 0 sends all ``width`` channels). The ego decompresses them
with its own 1x1 convolution, warps them into its grid by ``E_{r->e}`` and fuses them
(:mod:`.fusion`). Training rounds the sent map to float16 as the channel does (AURORA's
:func:`~v2xbench.agents.aurora.rsu_agent.to_wire`).

Payload (:func:`serialize_message`; ``F`` = :meth:`~.config.V2XViTConfig.message_floats`; a raw
payload, ``wire.FORMAT_RAW``; every value float16-representable):

=================  ============================================================
floats             content
=================  ============================================================
5                  header: :data:`MAGIC`, :data:`VERSION`, ``C``, ``nx``, ``ny``
``C * nx * ny``    the sent feature map, row-major over channel, ``x``, ``y``
=================  ============================================================

The channel adds its 16-byte header and sends 2 bytes a float, so a message costs ``16 + 2 F``
bytes on air. The message's age (``v2x_info``'s ``age_ticks``) and ``E_{r->e}`` (its
``rsu_x, rsu_y, rsu_yaw``) come with the observation, not in the payload.
"""

from __future__ import annotations

import numpy as np
import torch

from ..common.message import read_header, to_payload
from .config import MESSAGE_HEADER_FLOATS, V2XViTConfig

MAGIC = 2022.0  # an integer float16 holds exactly (UniV2X's messages start with 2025)
VERSION = 1.0


def empty_features(cfg: V2XViTConfig, batch: int, device: torch.device | str = "cpu"
                   ) -> torch.Tensor:
    """The sent map of "nothing received": zeros ``(B, C, nx, ny)``."""
    return torch.zeros(batch, cfg.sent_channels(), *cfg.feature_size("rsu"), device=device)


def serialize_message(features: torch.Tensor) -> np.ndarray:
    """A one-unit sent feature map ``(1, C, nx, ny)`` as a raw payload: a 1-D float32 array of
    float16-representable values (module docstring; values beyond ``+-PAYLOAD_LIMIT`` clipped)."""
    if features.dim() != 4 or features.shape[0] != 1:
        raise ValueError(f"V2X-ViT serialize_message: features have shape "
                         f"{tuple(features.shape)}; expected (1, C, nx, ny)")
    c, nx, ny = features.shape[1:]
    head = np.array([MAGIC, VERSION, c, nx, ny], np.float32)
    flat = np.concatenate([head, features.detach().float().cpu().reshape(-1).numpy()])
    return to_payload(flat)


def deserialize_message(payload: np.ndarray, cfg: V2XViTConfig) -> torch.Tensor:
    """The sent feature map ``(1, C, nx, ny)`` of a payload made by :func:`serialize_message`.

    Raises:
        ValueError: not a V2X-ViT message (magic, version), sizes other than ``cfg``'s, or a
            length that disagrees with them.
    """
    x, (c, nx, ny) = read_header(payload, MAGIC, VERSION, MESSAGE_HEADER_FLOATS, "V2X-ViT")
    want = (cfg.sent_channels(), *cfg.feature_size("rsu"))
    if (c, nx, ny) != want:
        raise ValueError(f"V2X-ViT deserialize_message: the message has C={c} channels on a "
                         f"{nx} x {ny} grid; this model takes C={want[0]} on {want[1]} x "
                         f"{want[2]}")
    n = MESSAGE_HEADER_FLOATS + c * nx * ny
    if x.shape[0] != n:
        raise ValueError(f"V2X-ViT deserialize_message: {x.shape[0]} floats; a message of these "
                         f"sizes has {n}")
    return torch.from_numpy(x[MESSAGE_HEADER_FLOATS:].copy()).view(1, c, nx, ny)


__all__ = ["MAGIC", "VERSION", "deserialize_message", "empty_features", "serialize_message"]
