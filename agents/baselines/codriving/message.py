"""CoDriving's roadside message: the features of the cells it chose (:mod:`.request`), sparse,
and its payload through the V2X channel.

Payload (:func:`serialize_message`; a raw payload, ``wire.FORMAT_RAW``; every value
float16-representable; ``K`` cells of ``C`` = :meth:`~.config.CoDrivingConfig.sent_channels`
features each):

=================  ==========================================================================
floats             content
=================  ==========================================================================
6                  header: :data:`MAGIC`, :data:`VERSION`, ``K``, ``C``, ``nx``, ``ny`` (the
                   unit's feature grid)
``K * (2 + C)``    per cell: its indices ``i, j`` on that grid, then its ``C`` features
=================  ==========================================================================

so a message of ``K`` cells has ``F(K) = 6 + K (2 + C)`` floats
(:meth:`~.config.CoDrivingConfig.message_floats`) and costs ``16 + 2 F(K)`` bytes on air (the
channel's 16-byte header, 2 bytes a float). ``K`` is at most the budget ``max_cells``; a larger
message raises ``ValueError`` here (and the channel, whose limit the agent sets to
``F(max_cells)``, refuses one too). No cell chosen: no message (the policy says nothing, 0
bytes). Indices and ``K`` are integers below 2048, exact in float16. The message's age and
``E_{r->e}`` come with the observation (``v2x_info``), not in the payload.
"""

from __future__ import annotations

import numpy as np
import torch

from ..common.message import read_header, to_payload
from .config import MESSAGE_HEADER_FLOATS, CoDrivingConfig

MAGIC = 2024.0  # an integer float16 holds exactly (V2X-ViT's: 2022, UniV2X's: 2025)
VERSION = 1.0


def serialize_message(cells: torch.Tensor, features: torch.Tensor, cfg: CoDrivingConfig
                      ) -> np.ndarray:
    """The chosen cells as a raw payload (module docstring).

    Args:
        cells: ``(K, 2)`` int indices ``i, j`` on the unit's feature grid.
        features: ``(K, C)`` their sent features. cfg: the configuration (budget, grid).

    Raises:
        ValueError: shapes that disagree, an index outside the grid, ``C`` other than
            ``sent_channels()``, or more than ``max_cells`` cells (an oversized message).
    """
    k = int(cells.shape[0]) if cells.dim() == 2 else -1
    c = cfg.sent_channels()
    if cells.dim() != 2 or cells.shape[1] != 2 or features.shape != (k, c):
        raise ValueError(f"CoDriving serialize_message: cells {tuple(cells.shape)} and features "
                         f"{tuple(features.shape)}; expected (K, 2) and (K, {c})")
    if k > cfg.max_cells:
        raise ValueError(f"CoDriving serialize_message: oversized message: {k} cells "
                         f"({cfg.message_floats(k)} floats), more than the budget max_cells="
                         f"{cfg.max_cells} ({cfg.message_floats()} floats)")
    nx, ny = cfg.feature_size("rsu")
    ij = cells.detach().long().cpu()
    if k and (int(ij.min()) < 0 or int(ij[:, 0].max()) >= nx or int(ij[:, 1].max()) >= ny):
        raise ValueError(f"CoDriving serialize_message: a cell index is outside the {nx} x {ny} "
                         "roadside grid")
    body = torch.cat([ij.float(), features.detach().float().cpu()], 1).reshape(-1).numpy()
    head = np.array([MAGIC, VERSION, k, c, nx, ny], np.float32)
    out = to_payload(np.concatenate([head, body]))
    assert out.shape[0] == cfg.message_floats(k)
    return out


def deserialize_message(payload: np.ndarray, cfg: CoDrivingConfig
                        ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(cells (K, 2) int64, features (K, C))`` of a payload made by :func:`serialize_message`.

    Raises:
        ValueError: not a CoDriving message (magic, version), sizes other than ``cfg``'s, more
            cells than the budget, or a length that disagrees with ``K``.
    """
    x, (k, c, nx, ny) = read_header(payload, MAGIC, VERSION, MESSAGE_HEADER_FLOATS, "CoDriving")
    want = (cfg.sent_channels(), *cfg.feature_size("rsu"))
    if (c, nx, ny) != want:
        raise ValueError(f"CoDriving deserialize_message: the message has C={c} channels on a "
                         f"{nx} x {ny} grid; this model takes C={want[0]} on {want[1]} x "
                         f"{want[2]}")
    if not 0 <= k <= cfg.max_cells:
        raise ValueError(f"CoDriving deserialize_message: oversized message: K={k} cells, the "
                         f"budget is max_cells={cfg.max_cells}")
    if x.shape[0] != cfg.message_floats(k):
        raise ValueError(f"CoDriving deserialize_message: {x.shape[0]} floats; a message of "
                         f"K={k} cells has {cfg.message_floats(k)}")
    body = torch.from_numpy(x[MESSAGE_HEADER_FLOATS:].copy()).view(k, 2 + c)
    return body[:, :2].round().long(), body[:, 2:]


def dense_message(cells: torch.Tensor, features: torch.Tensor, cfg: CoDrivingConfig
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(map (1, C, nx, ny), sent (1, nx, ny) bool)``: received cells on the unit's grid (zeros
    and not sent elsewhere), what :func:`~.fusion.scatter_to_ego` takes."""
    nx, ny = cfg.feature_size("rsu")
    out = torch.zeros(1, cfg.sent_channels(), nx, ny)
    sent = torch.zeros(1, nx, ny, dtype=torch.bool)
    if len(cells):
        out[0, :, cells[:, 0], cells[:, 1]] = features.float().T
        sent[0, cells[:, 0], cells[:, 1]] = True
    return out, sent


def sent_cells(features: torch.Tensor, sent: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(cells (K, 2), features (K, C))`` of one unit's map ``(1, C, nx, ny)`` and its chosen
    cells ``(1, nx, ny)`` (row-major order)."""
    ij = sent[0].nonzero()
    return ij, features[0, :, ij[:, 0], ij[:, 1]].T


__all__ = ["MAGIC", "VERSION", "dense_message", "deserialize_message", "sent_cells",
           "serialize_message"]
