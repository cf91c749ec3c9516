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

Route-relative planning (``cfg.plan_frame = "route"``): the planner predicts per waypoint an
arc length ``s >= 0`` along the route and a lateral offset ``d`` (m, positive to the left) and
:func:`route_to_ego` turns them into ego-frame x, y (differentiable in ``s`` and ``d``), so
following the route is what a planner does by default and it learns deviations and speed. The
polyline it reads is :func:`planner_route_path` (batch key :data:`PATH_KEY`, the one function
the pairs and the policy use): :data:`PATH_POINTS` points :data:`PATH_SPACING` m of arc length
apart from the ego's foot point on the route (``s = 0``: the point of the route nearest to the
ego, which may lie behind row 0), reaching 78 m ahead, past a 3 s waypoint at highway speed.
The observed route holds 38 m (20 rows, 2 m apart); before row 0 and past the route's last
point the path goes on along its first / last segment (straight extrapolation; a route without
length runs straight ahead). :func:`ego_to_route` projects ego-frame points back (the
diffusion planner's anchors, the VAE's expert encoding).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from .config import AuroraConfig

#: Batch key of the planner's route input ``(B, K, 2)`` (m, ego frame).
ROUTE_KEY = "route_points"
#: Batch key of the route-relative planner's polyline ``(B, PATH_POINTS, 2)`` (m, ego frame).
PATH_KEY = "route_path"
PATH_POINTS = 40  # points of the planner's route polyline
PATH_SPACING = 2.0  # m of arc length between them (the observed route's row spacing)
FOOT_SEARCH = 10.0  # m: the ego's foot point is sought on the route's first 10 m
_EPS = 1e-6


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


def _route_xy(route: torch.Tensor | np.ndarray, who: str) -> torch.Tensor:
    r = torch.as_tensor(route)
    if r.dim() < 2 or r.shape[-2] < 1 or r.shape[-1] < 2:
        raise ValueError(f"{who}: route has shape {tuple(r.shape)}; expected "
                         "(..., R >= 1, >= 2) rows of ego-frame x, y (and command)")
    xy = r[..., :2].to(torch.float32)
    if not bool(torch.isfinite(xy).all()):
        raise ValueError(f"{who}: the route has non-finite x, y")
    return xy


def _end_direction(unit: torch.Tensor, valid: torch.Tensor, last: bool) -> torch.Tensor:
    """``(..., 2)`` unit direction of the first (``last``: last) segment with length; ``(1, 0)``
    (straight ahead) for a route without any."""
    n = valid.shape[-1]
    order = torch.arange(n, device=valid.device).expand_as(valid)
    key = torch.where(valid, order if last else n - 1 - order, torch.full_like(order, -1))
    i = key.argmax(-1, keepdim=True)
    d = unit.gather(-2, i[..., None].expand(*i.shape, 2))[..., 0, :]
    ahead = torch.tensor([1.0, 0.0], dtype=d.dtype, device=d.device).expand_as(d)
    return torch.where(valid.any(-1, keepdim=True), d, ahead)


def polyline_at(xy: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Points ``(..., M, 2)`` at arc lengths ``s`` ``(..., M)`` (m, any sign) along the polyline
    ``xy`` ``(..., R >= 1, 2)`` from its row 0: linear between rows; before row 0 and past the
    last row straight on along the first / last segment with length (module docstring)."""
    lead = xy.shape[:-2]
    if xy.shape[-2] == 1:
        xy = torch.cat([xy, xy], -2)
    step = xy[..., 1:, :] - xy[..., :-1, :]
    seg = step.norm(dim=-1)
    valid = seg > _EPS
    unit = step / seg.clamp_min(_EPS)[..., None]
    arc = torch.cat([seg.new_zeros((*lead, 1)), seg.cumsum(-1)], -1)
    total = arc[..., -1:]
    i = (torch.searchsorted(arc.contiguous(), s.contiguous(), right=True) - 1)
    i = i.clamp(0, seg.shape[-1] - 1)
    frac = ((s - arc.gather(-1, i)) / seg.gather(-1, i).clamp_min(_EPS)).clamp(0.0, 1.0)
    start = xy.gather(-2, i[..., None].expand(*i.shape, 2))
    inner = start + frac[..., None] * step.gather(-2, i[..., None].expand(*i.shape, 2))
    first = xy[..., :1, :] + s[..., None].clamp_max(0.0) \
        * _end_direction(unit, valid, last=False)[..., None, :]
    beyond = (s - total).clamp_min(0.0)
    last = _end_direction(unit, valid, last=True)[..., None, :]
    after = xy[..., -1:, :] + beyond[..., None] * last
    out = torch.where((s < 0)[..., None], first, inner)
    return torch.where((s > total)[..., None], after, out)


def route_path(route: torch.Tensor | np.ndarray, count: int, spacing: float) -> torch.Tensor:
    """``(..., count, 2)`` float32 points at arc lengths ``s0 + spacing * (0 .. count - 1)``
    along ``route``'s polyline, where ``s0`` is the arc length of the ego's foot point (the
    point of the route's first :data:`FOOT_SEARCH` m, or of the line before row 0, nearest to
    the ego frame's origin); extrapolated as :func:`polyline_at`.

    Raises:
        ValueError: a route of another shape, non-finite coordinates, or a bad count / spacing.
    """
    xy = _route_xy(route, "route_path")
    if isinstance(count, bool) or not isinstance(count, int) or count < 2:
        raise ValueError(f"route_path: count={count!r} must be an int >= 2")
    if isinstance(spacing, bool) or not isinstance(spacing, (int, float)) \
            or not (np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"route_path: spacing={spacing!r} must be a positive number (m)")
    lead = xy.shape[:-2]
    pts = torch.cat([xy, xy[..., -1:, :]], -2) if xy.shape[-2] == 1 else xy
    step = pts[..., 1:, :] - pts[..., :-1, :]
    seg = step.norm(dim=-1)
    arc = torch.cat([seg.new_zeros((*lead, 1)), seg.cumsum(-1)], -1)
    a = pts[..., :-1, :]
    t = (-(a * step).sum(-1) / seg.square().clamp_min(_EPS)).clamp(0.0, 1.0)
    dist = (a + t[..., None] * step).norm(dim=-1)
    dist = dist.masked_fill(arc[..., :-1] > FOOT_SEARCH, float("inf"))
    # the line before row 0 (the ego may not have reached its current route point yet)
    d0 = _end_direction(step / seg.clamp_min(_EPS)[..., None], seg > _EPS, last=False)
    back = (-(pts[..., 0, :] * d0).sum(-1)).clamp_max(0.0)  # (...,) m, <= 0
    back_dist = (pts[..., 0, :] + back[..., None] * d0).norm(dim=-1)
    j = dist.argmin(-1, keepdim=True)
    s_seg = (arc[..., :-1].gather(-1, j) + t.gather(-1, j) * seg.gather(-1, j))[..., 0]
    s0 = torch.where(back_dist < dist.gather(-1, j)[..., 0], back, s_seg)
    want = s0[..., None] + spacing * torch.arange(count, dtype=torch.float32)
    return polyline_at(xy, want)


def planner_route_path(route: torch.Tensor | np.ndarray, cfg: Any) -> torch.Tensor:
    """The route-relative planner's polyline of ``route`` rows: ``(..., PATH_POINTS, 2)`` m,
    ego frame (:func:`route_path`); ``cfg`` (AURORA's or a baseline's configuration: its
    ``plan_frame``) is checked to plan in the route frame."""
    if cfg.plan_frame != "route":
        raise ValueError(f"planner_route_path: cfg.plan_frame={cfg.plan_frame!r}; the route "
                         "polyline is the input of a route-frame planner only")
    return route_path(route, PATH_POINTS, PATH_SPACING)


def _check_path(path: torch.Tensor, lead: tuple[int, ...], who: str) -> None:
    if path.dim() != 3 or path.shape[1] < 2 or path.shape[2] != 2 or path.shape[0] != lead[0]:
        raise ValueError(f"{who}: route path has shape {tuple(path.shape)}; expected "
                         f"({lead[0]}, >= 2, 2) (batch key {PATH_KEY!r})")


def route_to_ego(sd: torch.Tensor, path: torch.Tensor, spacing: float = PATH_SPACING
                 ) -> torch.Tensor:
    """Route-frame waypoints ``sd`` ``(B, ..., 2)`` (arc length ``s`` from the path's point 0,
    lateral offset ``d``, m, positive to the left) -> ego-frame ``(B, ..., 2)``: the path point
    at ``s`` (linear between the ``(B, N, 2)`` ``path``'s points ``spacing`` m apart, straight
    on past either end) plus ``d`` times the left normal of that path segment. Differentiable
    in ``sd`` (and ``path``)."""
    _check_path(path, tuple(sd.shape), "route_to_ego")
    if sd.shape[-1] != 2:
        raise ValueError(f"route_to_ego: sd has shape {tuple(sd.shape)}; expected (B, ..., 2)")
    b, n = path.shape[0], path.shape[1]
    flat = sd.reshape(b, -1, 2)
    path = path.to(flat.dtype)
    f = flat[..., 0] / spacing
    i = f.detach().floor().long().clamp(0, n - 2)  # (B, M)
    frac = f - i.to(f.dtype)
    p0 = path.gather(1, i[..., None].expand(*i.shape, 2))
    p1 = path.gather(1, (i + 1)[..., None].expand(*i.shape, 2))
    chord = p1 - p0
    tangent = chord / chord.norm(dim=-1, keepdim=True).clamp_min(_EPS)
    normal = torch.stack([-tangent[..., 1], tangent[..., 0]], -1)
    xy = p0 + frac[..., None] * chord + flat[..., 1:2] * normal
    return xy.view(sd.shape)


def ego_to_route(xy: torch.Tensor, path: torch.Tensor, spacing: float = PATH_SPACING
                 ) -> torch.Tensor:
    """Ego-frame points ``xy`` ``(B, ..., 2)`` -> route frame ``(B, ..., 2)`` ``(s, d)`` on the
    ``(B, N, 2)`` ``path`` (the nearest point of its segments, the first and last going on past
    the ends; :func:`route_to_ego` inverts it off the corners). Not differentiable."""
    _check_path(path, tuple(xy.shape), "ego_to_route")
    with torch.no_grad():
        b, n = path.shape[0], path.shape[1]
        p = xy.reshape(b, -1, 2).to(torch.float32)[:, :, None]  # (B, M, 1, 2)
        a = path[:, :-1].to(torch.float32)[:, None]  # (B, 1, N - 1, 2)
        ab = (path[:, 1:] - path[:, :-1]).to(torch.float32)[:, None]
        t = ((p - a) * ab).sum(-1) / ab.square().sum(-1).clamp_min(_EPS)  # (B, M, N - 1)
        lo = torch.zeros(n - 1, device=t.device)
        hi = torch.ones(n - 1, device=t.device)
        lo[0], hi[-1] = -float("inf"), float("inf")
        t = torch.maximum(torch.minimum(t, hi), lo)
        foot = a + t[..., None] * ab
        j = (p - foot).norm(dim=-1).argmin(-1, keepdim=True)  # (B, M, 1)
        tj = t.gather(-1, j)[..., 0]
        fj = foot.gather(2, j[..., None].expand(*j.shape, 2))[:, :, 0]
        abj = ab[:, 0].gather(1, j[..., 0, None].expand(-1, -1, 2))
        tan = abj / abj.norm(dim=-1, keepdim=True).clamp_min(_EPS)
        rel = p[:, :, 0] - fj
        d = tan[..., 0] * rel[..., 1] - tan[..., 1] * rel[..., 0]
        s = (j[..., 0].to(torch.float32) + tj) * spacing
        return torch.stack([s, d], -1).view(xy.shape)


__all__ = ["FOOT_SEARCH", "PATH_KEY", "PATH_POINTS", "PATH_SPACING", "ROUTE_KEY",
           "ego_to_route", "planner_route_path", "planner_route_points", "polyline_at",
           "route_path", "route_points_ahead", "route_to_ego"]
