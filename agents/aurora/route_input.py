"""The planner's route input: the route points ahead of the ego, in the ego frame.

AURORA's planner (seed paper, section 4.3) reads the ``<wp>`` hidden state and the navigation
command. CARLA hands every agent its route's points, and TransFuser-style agents condition their
planner on a target point from them; so does AURORA here (``cfg.plan_route_points`` = K > 0,
a deviation from the paper's planner inputs; docs/aurora.md, "Route points").

Both the data set (``route``, recorded from the ego observation, :mod:`~v2xbench.collectors.
dataset.record`) and the run-time observation (``obs["route"]``) carry the route ahead as
``(R, 3)`` rows ``(x, y, command)``: ego-frame metres (x forward, y left) of every
``route_step``-th 1-m route point from the ego's current route point on (row 0), clamped to the
route's last point. :func:`planner_route_points` turns such rows into the planner's input, the K
points at arc lengths ``spacing, 2 spacing, ..., K spacing`` along the polyline from row 0
(linear interpolation between rows; past the route's end: its last point). Measuring along the
polyline, not by row index, makes the input independent of ``route_step``. It is the one
function both paths use: :class:`~.pairs.AuroraPairs` (training and open-loop evaluation) and
:class:`~.policy.AuroraPolicyNet` (closed loop), under the batch key :data:`ROUTE_KEY`.
"""

from __future__ import annotations

import numpy as np
import torch

from .config import AuroraConfig

#: Batch key of the planner's route input ``(B, K, 2)`` (m, ego frame).
ROUTE_KEY = "route_points"


def route_points_ahead(route: torch.Tensor | np.ndarray, count: int, spacing: float
                       ) -> torch.Tensor:
    """``(..., count, 2)`` float32 points at arc lengths ``spacing * (1 .. count)`` m along the
    polyline of ``route``'s rows (module docstring).

    Args:
        route: ``(..., R, C)`` with ``R >= 1`` rows and ``C >= 2`` columns, the first two
            ego-frame x, y (m); the rest (the command) is ignored.
        count: points to return (``>= 0``). spacing: metres of arc length between them (> 0).

    Raises:
        ValueError: a route of another shape, non-finite coordinates, or a bad count / spacing.
    """
    r = torch.as_tensor(route)
    if r.dim() < 2 or r.shape[-2] < 1 or r.shape[-1] < 2:
        raise ValueError(f"route_points_ahead: route has shape {tuple(r.shape)}; expected "
                         "(..., R >= 1, >= 2) rows of ego-frame x, y (and command)")
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise ValueError(f"route_points_ahead: count={count!r} must be an int >= 0")
    if isinstance(spacing, bool) or not isinstance(spacing, (int, float)) \
            or not (np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"route_points_ahead: spacing={spacing!r} must be a positive number (m)")
    xy = r[..., :2].to(torch.float32)
    if not bool(torch.isfinite(xy).all()):
        raise ValueError("route_points_ahead: the route has non-finite x, y")
    lead = xy.shape[:-2]
    if count == 0:
        return xy.new_zeros((*lead, 0, 2))
    if xy.shape[-2] == 1:
        return xy.expand(*lead, count, 2).clone()
    step = xy[..., 1:, :] - xy[..., :-1, :]  # (..., R - 1, 2)
    seg = step.norm(dim=-1)
    arc = torch.cat([seg.new_zeros((*lead, 1)), seg.cumsum(-1)], -1)  # (..., R), non-decreasing
    want = spacing * torch.arange(1, count + 1, dtype=torch.float32)
    want = want.expand(*lead, count).contiguous()
    i = (torch.searchsorted(arc.contiguous(), want, right=True) - 1).clamp(0, seg.shape[-1] - 1)
    s0 = arc.gather(-1, i)
    length = seg.gather(-1, i)
    frac = ((want - s0) / length.clamp_min(1e-6)).clamp(0.0, 1.0)
    start = xy.gather(-2, i[..., None].expand(*i.shape, 2))
    delta = step.gather(-2, i[..., None].expand(*i.shape, 2))
    return start + frac[..., None] * delta


def planner_route_points(route: torch.Tensor | np.ndarray, cfg: AuroraConfig) -> torch.Tensor:
    """The planner's route input of ``route`` rows (``(..., R, 3)``: the data set's ``route``
    or the observation's): ``(..., cfg.plan_route_points, 2)`` m, ego frame
    (:func:`route_points_ahead` at ``cfg.plan_route_spacing``; ``(..., 0, 2)`` when off)."""
    return route_points_ahead(route, cfg.plan_route_points, cfg.plan_route_spacing)


__all__ = ["ROUTE_KEY", "planner_route_points", "route_points_ahead"]
