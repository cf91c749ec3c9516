"""Planning losses of AURORA (seed paper, appendix stage 4).

VAE / MLP: ``L = w_l1 L_reg + w_bound L_bound + w_col L_col (+ w_kl L_KL for the VAE)``;
diffusion: ``L = w_cls L_cls + w_l1 L_reg + w_bound L_bound``. Per sample, then averaged over
the samples that carry a planning target (``plan_mask``; stage 5 mixes QA-only samples),
each weighted by :func:`start_weights`: a start-from-rest sample (the ego slower than
``cfg.plan_start_speed``, the expert's last planned waypoint farther than
``cfg.plan_start_dist``) counts ``cfg.plan_start_weight`` times, every other sample once. Of
the default training frames 45 % stand (< 0.5 m/s) and 2.4 % start from rest: unweighted, the
L1 median of a standing frame is "stay standing" (the planner learned "stopped stays stopped").

- ``plan_l1``: command-conditioned L1: mean absolute error (m) of the given command's trajectory
  (the planners select it) against the first ``T`` expert waypoints.
- ``plan_bound``: map-boundary constraint on the drivable area from the map ground truth's
  ``boundary`` polylines (ego frame): a waypoint's signed distance ``s`` to the nearest boundary
  is positive inside the drivable area and negative outside; a waypoint is outside once the path
  from the ego (the origin, on the road) through the waypoints has crossed boundary segments an
  odd number of times. The cost is ``relu(margin - s)`` (``cfg.plan_bound_margin``, about half
  the car's width), averaged over the waypoints: zero for a trajectory that keeps the margin,
  growing with the depth of a violation.
- ``plan_col``: collision constraint against the agents' future positions (``agent_future``
  ``(B, A, T, 2)``, ego frame, at the waypoints' times; :func:`constant_velocity_futures` of the
  ``gt/fused`` boxes in training): ``relu(radius - distance)`` summed over agents, averaged
  over the waypoints (``cfg.plan_col_radius``, centre to centre).
- ``plan_kl`` (VAE): ``KL(N_future || N_present)`` summed over latent dimensions.
- ``plan_cls`` / ``plan_reg`` (diffusion): cross-entropy of the mode logits against the anchor
  nearest to the expert trajectory, and L1 of that mode's denoised trajectory.

All terms read ego-frame x, y, also for a route-frame planner (``cfg.plan_frame = "route"``,
:mod:`.planners`, whose outputs are converted differentiably): the L1 stays the error the
controller sees and comparable with the ego-frame runs', the boundary and collision costs need
x, y anyway, and no expert waypoint has to be projected onto the route (ambiguous at corners
and where the expert leaves it).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .config import MAP_CLASS_NAMES, AuroraConfig

BOUNDARY = MAP_CLASS_NAMES.index("boundary")
MAP_KEYS = ("map_points", "map_labels", "map_mask", "map_closed")


def kl_divergence(mu_q: torch.Tensor, logvar_q: torch.Tensor, mu_p: torch.Tensor,
                  logvar_p: torch.Tensor) -> torch.Tensor:
    """``KL(N(mu_q, e^logvar_q) || N(mu_p, e^logvar_p))`` of diagonal Gaussians ``(B, Z)`` ->
    ``(B,)`` (summed over dimensions; zero iff equal)."""
    var_q, var_p = logvar_q.exp(), logvar_p.exp()
    kl = 0.5 * (logvar_p - logvar_q + (var_q + (mu_q - mu_p).square()) / var_p - 1.0)
    return kl.sum(-1)


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def point_segment_distance(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Distances ``(B, T, S)`` of points ``(B, T, 2)`` to segments ``a -> b`` ``(B, S, 2)``."""
    ab = (b - a)[:, None]  # (B, 1, S, 2)
    ap = p[:, :, None] - a[:, None]  # (B, T, S, 2)
    u = ((ap * ab).sum(-1) / ab.square().sum(-1).clamp_min(1e-9)).clamp(0.0, 1.0)
    return (ap - u[..., None] * ab).norm(dim=-1)


def boundary_segments(map_points: torch.Tensor, map_labels: torch.Tensor,
                      map_mask: torch.Tensor, map_closed: torch.Tensor
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Segments of the boundary polylines: starts, ends ``(B, K*P, 2)`` and validity
    ``(B, K*P)`` (the closing segment counts only for closed polylines)."""
    b, k, p, _ = map_points.shape
    a = map_points
    e = torch.roll(map_points, -1, dims=2)
    is_bound = map_mask.bool() & (map_labels == BOUNDARY)
    seg_ok = torch.ones(b, k, p, dtype=torch.bool, device=a.device)
    seg_ok[:, :, -1] = map_closed.bool()
    valid = is_bound[..., None] & seg_ok
    return a.reshape(b, k * p, 2), e.reshape(b, k * p, 2), valid.reshape(b, k * p)


def outside_drivable(waypoints: torch.Tensor, starts: torch.Tensor, ends: torch.Tensor,
                     valid: torch.Tensor) -> torch.Tensor:
    """``(B, T)`` bool: the path origin -> waypoints has crossed valid boundary segments an odd
    number of times by each waypoint."""
    prev = torch.cat([torch.zeros_like(waypoints[:, :1]), waypoints[:, :-1]], 1)
    p, q = prev[:, :, None], waypoints[:, :, None]  # (B, T, 1, 2)
    c, d = starts[:, None], ends[:, None]  # (B, 1, S, 2)
    o1, o2 = _cross(q - p, c - p), _cross(q - p, d - p)
    o3, o4 = _cross(d - c, p - c), _cross(d - c, q - c)
    hits = (o1 * o2 < 0) & (o3 * o4 < 0) & valid[:, None]
    return hits.sum(-1).cumsum(1) % 2 == 1


def boundary_loss(waypoints: torch.Tensor, map_points: torch.Tensor, map_labels: torch.Tensor,
                  map_mask: torch.Tensor, map_closed: torch.Tensor, margin: float
                  ) -> torch.Tensor:
    """``(B,)`` map-boundary cost (module docstring); zero for frames without boundaries."""
    starts, ends, valid = boundary_segments(map_points, map_labels, map_mask, map_closed)
    if starts.shape[1] == 0:
        return waypoints.sum((1, 2)) * 0.0
    dist = point_segment_distance(waypoints, starts, ends)
    dist = dist.masked_fill(~valid[:, None], float("inf")).amin(-1)  # (B, T)
    with torch.no_grad():
        outside = outside_drivable(waypoints, starts, ends, valid)
    has = valid.any(1)[:, None]
    signed = torch.where(outside, -dist, dist)
    cost = torch.where(has & torch.isfinite(signed), F.relu(margin - signed),
                       torch.zeros_like(dist))
    return cost.mean(1)


def collision_loss(waypoints: torch.Tensor, agent_future: torch.Tensor,
                   agent_mask: torch.Tensor, radius: float) -> torch.Tensor:
    """``(B,)``: ``relu(radius - |w_t - a_t|)`` summed over agents, mean over waypoints.

    Args:
        waypoints: ``(B, T, 2)`` m; agent_future ``(B, A, T, 2)`` m at the same times;
        agent_mask: ``(B, A, T)`` or ``(B, A)`` valid.
    """
    if agent_mask.dim() == 2:
        agent_mask = agent_mask[..., None].expand(agent_future.shape[:3])
    d = (waypoints[:, None] - agent_future).norm(dim=-1)  # (B, A, T)
    return (F.relu(radius - d) * agent_mask.float()).sum(1).mean(1)


def constant_velocity_futures(boxes: torch.Tensor, mask: torch.Tensor, steps: int, dt: float
                              ) -> tuple[torch.Tensor, torch.Tensor]:
    """Agents' future centres ``(B, M, steps, 2)`` at ``dt, 2 dt, ...`` from boxes
    ``(B, M, 10)`` (part 1's layout: x, y, z, l, w, h, sin, cos, vx, vy) moving at constant
    velocity, and their mask ``(B, M, steps)``."""
    t = torch.arange(1, steps + 1, device=boxes.device, dtype=boxes.dtype) * dt
    fut = boxes[:, :, None, :2] + boxes[:, :, None, 8:10] * t[:, None]
    return fut, mask.bool()[..., None].expand(*mask.shape, steps)


def start_from_rest(ego_speed: torch.Tensor, expert: torch.Tensor, cfg: AuroraConfig
                    ) -> torch.Tensor:
    """``(B,)`` bool: the ego is slower than ``cfg.plan_start_speed`` (m/s) and the expert's
    waypoint ``cfg.plan_waypoints`` (the last one planned) is farther than
    ``cfg.plan_start_dist`` (m): the expert drives off from rest."""
    far = expert[:, cfg.plan_waypoints - 1].float().norm(dim=-1) > cfg.plan_start_dist
    return (ego_speed.float() < cfg.plan_start_speed) & far


def start_weights(batch: dict, cfg: AuroraConfig) -> torch.Tensor:
    """``(B,)`` per-sample planning-loss weights: ``cfg.plan_start_weight`` where
    :func:`start_from_rest`, 1 elsewhere (``batch``: ``ego_speed``, ``expert_waypoints``)."""
    start = start_from_rest(batch["ego_speed"], batch["expert_waypoints"], cfg)
    one = torch.ones(start.shape, device=start.device)
    return torch.where(start, one * cfg.plan_start_weight, one)


def _masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of ``x`` over the samples weighted by ``mask`` (bool or per-sample weights)."""
    m = mask.float()
    return (x * m).sum() / m.sum().clamp_min(1e-9)  # 0 when no sample carries weight


class PlanningCriterion(nn.Module):
    """``PlanningCriterion(cfg)(out, batch) -> (loss, parts)`` for ``cfg.planner`` (module
    docstring). ``batch``: ``expert_waypoints`` ``(B, >= T, 2)``, the ego-frame map targets
    (``map_points``, ``map_labels``, ``map_mask``, ``map_closed``), for VAE / MLP
    ``agent_future`` ``(B, A, T, 2)`` and ``agent_future_mask``, optional ``plan_mask``
    ``(B,)``, and ``ego_speed`` ``(B,)`` (m/s) unless ``cfg.plan_start_weight`` is 1."""

    def __init__(self, cfg: AuroraConfig) -> None:
        super().__init__()
        self.cfg = cfg

    def check_batch(self, batch: dict) -> None:
        """Raise ``ValueError`` naming a missing or misshapen planning target."""
        need = ("expert_waypoints",) + MAP_KEYS
        if self.cfg.planner != "diffusion":
            need += ("agent_future", "agent_future_mask")
        if self.cfg.plan_start_weight != 1.0:
            need += ("ego_speed",)
        missing = [k for k in need if k not in batch]
        if missing:
            raise ValueError(f"PlanningCriterion({self.cfg.planner}): batch has no {missing}")
        wp, t = batch["expert_waypoints"], self.cfg.plan_waypoints
        if wp.dim() != 3 or wp.shape[1] < t or wp.shape[2] != 2:
            raise ValueError(f"PlanningCriterion: expert_waypoints has shape {tuple(wp.shape)}; "
                             f"expected (B, >= {t}, 2)")
        if "agent_future" in batch and tuple(batch["agent_future"].shape[2:]) != (t, 2):
            raise ValueError(f"PlanningCriterion: agent_future has shape "
                             f"{tuple(batch['agent_future'].shape)}; expected (B, A, {t}, 2)")

    def forward(self, out: dict, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        """Total planning loss (scalar) and its weighted parts."""
        cfg = self.cfg
        self.check_batch(batch)
        gt = batch["expert_waypoints"][:, :cfg.plan_waypoints].float()
        b = gt.shape[0]
        mask = batch.get("plan_mask", torch.ones(b, dtype=torch.bool, device=gt.device)).bool()
        if cfg.plan_start_weight != 1.0:
            mask = mask.float() * start_weights(batch, cfg).to(gt.device)
        maps = [batch[k] for k in MAP_KEYS]
        terms: dict[str, torch.Tensor] = {}
        if cfg.planner == "diffusion":
            trajs = out["mode_trajs"]
            anchors = out["anchors"]  # (K, T, 2), or each sample's (B, K, T, 2) (route frame)
            anchors = anchors[None] if anchors.dim() == 3 else anchors
            target = (anchors - gt[:, None]).norm(dim=-1).mean(-1).argmin(1)  # (B,)
            chosen = trajs[torch.arange(b), target]
            terms["plan_cls"] = cfg.plan_cls_weight * _masked_mean(
                F.cross_entropy(out["mode_logits"], target, reduction="none"), mask)
            terms["plan_reg"] = cfg.plan_l1_weight * _masked_mean(
                (chosen - gt).abs().mean((1, 2)), mask)
            wps = chosen
        else:
            wps = out["waypoints"]
            terms["plan_l1"] = cfg.plan_l1_weight * _masked_mean(
                (wps - gt).abs().mean((1, 2)), mask)
            terms["plan_col"] = cfg.plan_col_weight * _masked_mean(
                collision_loss(wps, batch["agent_future"], batch["agent_future_mask"],
                               cfg.plan_col_radius), mask)
        terms["plan_bound"] = cfg.plan_bound_weight * _masked_mean(
            boundary_loss(wps, *maps, cfg.plan_bound_margin), mask)
        if cfg.planner == "vae":
            if "mu_f" not in out:
                raise ValueError("PlanningCriterion(vae): the planner ran without the expert "
                                 "trajectory (no future distribution)")
            terms["plan_kl"] = cfg.plan_kl_weight * _masked_mean(
                kl_divergence(out["mu_f"], out["logvar_f"], out["mu_p"], out["logvar_p"]), mask)
        total = sum(terms.values())
        return total, {k: float(v.detach()) for k, v in terms.items()}


__all__ = ["BOUNDARY", "PlanningCriterion", "boundary_loss", "boundary_segments",
           "collision_loss", "constant_velocity_futures", "kl_divergence",
           "outside_drivable", "point_segment_distance", "start_from_rest", "start_weights"]
