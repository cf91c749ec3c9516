"""CoDriving's driving-oriented communication: the ego's request map and the unit's choice of
cells.

- **Request** (:func:`request_map`): the ego asks for the BEV cells that matter for its drive: a
  Gaussian corridor around its route ahead, ``r(c) = max_s exp(-d(c, s)^2 / (2 sigma^2))`` over
  the route's segments ``s`` (``sigma`` = ``request_sigma`` m), on the unit's feature grid (the
  route moved into the unit's ground frame by ``E_{r->e}^-1``). The route ahead is the ego
  observation's ``route`` rows (``request_route_points`` points, ``request_route_step`` m apart
  from the ego's place on the route); in closed loop the unit rebuilds the same rows
  (:func:`route_ahead`) from the route the ego announced at the start (``route_info``) and the
  ego's pose in its observation (``calibration[1]``), so the request costs no bytes per tick.
- **Selection** (:func:`select_cells`): the unit's score per cell is its own confidence (the
  largest class probability of its confidence head: where it sees objects) times the request;
  it sends the cells with a score of at least ``select_threshold``, the ``max_cells`` best (the
  budget). A zero request sends nothing.
"""

from __future__ import annotations

import numpy as np
import torch

from ..univ2x.bev import cell_centres
from .config import CoDrivingConfig


def request_map(route_xy: torch.Tensor, e_rsu_to_ego: torch.Tensor, cfg: CoDrivingConfig
                ) -> torch.Tensor:
    """``(B, nx, ny)`` in ``[0, 1]``: the request on the unit's feature grid (module docstring).

    Args:
        route_xy: ``(B, R, 2)`` the route ahead in the ego frame (m; ``R >= 1``).
        e_rsu_to_ego: ``(B, 4, 4)`` ``E_{r->e}``.
        cfg: the configuration (``request_sigma``, the unit's range and grid).

    Raises:
        ValueError: ``route_xy`` not ``(B, R >= 1, >= 2)``.
    """
    if route_xy.dim() != 3 or route_xy.shape[1] < 1 or route_xy.shape[2] < 2:
        raise ValueError(f"CoDriving request_map: route_xy has shape {tuple(route_xy.shape)}; "
                         "expected (B, R >= 1, 2) ego-frame x, y")
    e = e_rsu_to_ego.double()
    inv_r = e[:, :2, :2].transpose(1, 2)  # E^-1 on the plane: R^T (p - t)
    pts = ((route_xy[..., :2].double() - e[:, None, :2, 3]) @ inv_r.transpose(1, 2)).float()
    a, b = pts[:, :-1], pts[:, 1:]
    if pts.shape[1] == 1:
        a = b = pts
    nx, ny = cfg.feature_size("rsu")
    c = cell_centres(cfg.rsu_range, (nx, ny)).to(pts.device).view(1, -1, 1, 2)  # (1, P, 1, 2)
    ab = (b - a)[:, None]  # (B, 1, S, 2)
    t = (((c - a[:, None]) * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-9)).clamp(0.0, 1.0)
    d2 = ((a[:, None] + t[..., None] * ab - c) ** 2).sum(-1)  # (B, P, S)
    r = torch.exp(-d2.amin(-1) / (2.0 * cfg.request_sigma ** 2))
    return r.view(-1, nx, ny)


def select_cells(score: torch.Tensor, cfg: CoDrivingConfig) -> torch.Tensor:
    """``(B, nx, ny)`` bool: the cells sent for the scores ``(B, nx, ny)`` (confidence x
    request): at least ``select_threshold``, the ``max_cells`` highest per row."""
    b = score.shape[0]
    flat = score.detach().reshape(b, -1)
    keep = flat >= cfg.select_threshold
    k = min(cfg.max_cells, flat.shape[1])
    top = flat.masked_fill(~keep, -1.0).topk(k, dim=1).indices
    chosen = torch.zeros_like(keep).scatter_(1, top, True) & keep
    return chosen.view_as(score)


#: The env's route-progress rule (``evaluation/infractions.py``, the ``route`` observation's
#: first row): the furthest route point within :data:`PROGRESS_REACH_M` m of the ego among the
#: :data:`PROGRESS_WINDOW` points from the last progress; no such point: progress stays.
PROGRESS_WINDOW = 40
PROGRESS_REACH_M = 3.0


def route_ahead(route_world: np.ndarray, ego_xy: np.ndarray, progress: int,
                cfg: CoDrivingConfig, advance: bool = True) -> tuple[np.ndarray, int]:
    """``(rows (R, 2) world frame, progress)``: the route ahead as the ego observes it.

    ``progress`` advances by the env's rule (:data:`PROGRESS_WINDOW`, :data:`PROGRESS_REACH_M`),
    so the rows are the env's ``route`` observation (the points ``progress + k *
    request_route_step``, ``k < R``, clipped to the route's end), which is what the request is
    built from in training (``model.CoDriving``, the recorded ``route`` rows). With
    ``advance=False`` (the env's first observation of a route, before its first step, has
    progress 0) it does not move. A roadside unit sees the ego only on the ticks it serves it:
    when the window holds no point in reach but a later point is (the ego drove on while no
    unit served it), progress first jumps to the nearest route point, as the env's tick by
    tick would have; an ego off the route (no point in reach) keeps the last progress, as the
    env does.

    Raises:
        ValueError: an empty route or not ``(P, 2)``.
    """
    r = np.asarray(route_world, np.float64)
    if r.ndim != 2 or r.shape[0] < 1 or r.shape[1] < 2:
        raise ValueError(f"CoDriving route_ahead: route has shape {r.shape}; expected (P >= 1, "
                         "2) world x, y (route_info['route_points'])")
    k = min(max(int(progress), 0), len(r) - 1)
    d = np.hypot(*(r[k:, :2] - np.asarray(ego_xy, np.float64)[:2]).T)
    close = np.flatnonzero(d[:PROGRESS_WINDOW] < PROGRESS_REACH_M)
    if not len(close):
        j = int(np.argmin(d))
        if j >= PROGRESS_WINDOW and d[j] < PROGRESS_REACH_M:  # caught up after a gap
            k, advance = k + j, True
            close = np.flatnonzero(d[j:j + PROGRESS_WINDOW] < PROGRESS_REACH_M)
    if advance and len(close):
        k += int(close[-1])
    ks = np.minimum(k + np.arange(cfg.request_route_points) * cfg.request_route_step, len(r) - 1)
    return r[ks, :2], k


__all__ = ["PROGRESS_REACH_M", "PROGRESS_WINDOW", "request_map", "route_ahead", "select_cells"]
