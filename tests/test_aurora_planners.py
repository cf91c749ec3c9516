"""AURORA planners and planning losses (issue #33): KL, overfitting two samples per planner,
the map-boundary and collision constraints, the criterion's parts and masks."""

from __future__ import annotations

import math

import pytest
import torch
from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.planner_losses import (
    BOUNDARY,
    PlanningCriterion,
    boundary_loss,
    collision_loss,
    constant_velocity_futures,
    kl_divergence,
)
from v2xbench.agents.aurora.planners import build_planner, fit_anchors

from tests.planner_fit import TIMES, T, overfit, turn

torch.set_num_threads(1)


def straight(speed: float, y: float = 0.0) -> torch.Tensor:
    """``(T, 2)`` waypoints at constant speed along x."""
    return torch.stack([speed * TIMES, torch.full((T,), y)], -1)


def road(b: int, p: int = 6, half: float = 5.0) -> dict[str, torch.Tensor]:
    """A straight road: boundaries at y = +-half (x in [-10, 50]), a divider at y = 0, a padded
    boundary row at y = 1 (masked: must be ignored)."""
    xs = torch.linspace(-10, 50, p)
    line = lambda y: torch.stack([xs, torch.full((p,), y)], -1)  # noqa: E731
    pts = torch.stack([line(half), line(-half), line(0.0), line(1.0)])
    return {"map_points": pts.expand(b, -1, -1, -1).clone(),
            "map_labels": torch.tensor([BOUNDARY, BOUNDARY, 0, BOUNDARY]).expand(b, -1).clone(),
            "map_mask": torch.tensor([True, True, True, False]).expand(b, -1).clone(),
            "map_closed": torch.zeros(b, 4, dtype=torch.bool)}


def route_on(radius: float | None, cfg: AuroraConfig, side: float = 1.0) -> torch.Tensor:
    """``(K, 2)`` route points every ``plan_route_spacing`` m: straight on (``radius`` None) or
    on a circle to the left (``side=1``) or right."""
    s = torch.arange(1, cfg.plan_route_points + 1) * cfg.plan_route_spacing
    if radius is None:
        return torch.stack([s, torch.zeros_like(s)], -1)
    a = s / radius
    return torch.stack([radius * torch.sin(a), side * radius * (1 - torch.cos(a))], -1)


def bound(wps: torch.Tensor, margin: float = 1.0) -> torch.Tensor:
    r = road(wps.shape[0])
    return boundary_loss(wps, r["map_points"], r["map_labels"], r["map_mask"], r["map_closed"],
                         margin)


# ---------------------------------------------------------------------- KL
def test_vae_kl_is_zero_for_equal_distributions():
    g = torch.Generator().manual_seed(0)
    mu, lv = torch.randn(4, 8, generator=g), torch.randn(4, 8, generator=g)
    assert torch.allclose(kl_divergence(mu, lv, mu, lv), torch.zeros(4), atol=1e-6)
    assert bool((kl_divergence(mu + 0.1, lv, mu, lv) > 0).all())
    assert bool((kl_divergence(mu, lv + 0.3, mu, lv) > 0).all())
    one = torch.ones(1, 1)
    # KL(N(1, 1) || N(0, 1)) = 1/2
    assert float(kl_divergence(one, 0 * one, 0 * one, 0 * one)) == pytest.approx(0.5)


# ---------------------------------------------------------------------- constraints
def test_boundary_term_zero_when_safe_positive_when_violating():
    safe = torch.stack([straight(4.0), straight(4.0, y=-2.0)])  # stays >= 3 m from the kerbs
    assert torch.equal(bound(safe), torch.zeros(2))
    lane_change = torch.stack([torch.stack([4.0 * TIMES, torch.linspace(0.3, 2.5, T)], -1)])
    assert float(bound(lane_change)) == 0.0  # crossing the divider is not a violation
    leave = torch.stack([torch.stack([4.0 * TIMES, torch.linspace(1.0, 9.0, T)], -1)])
    near = torch.stack([straight(4.0, y=4.5)])  # inside but within the 1 m margin
    assert float(bound(near)) == pytest.approx(0.5, abs=1e-5)
    cost = float(bound(leave))
    # y = 1, 2.6, 4.2 (margin costs 0, 0, 0.2), then outside at 5.8, 7.4, 9 (1.8, 3.4, 5)
    assert cost == pytest.approx((0.2 + 1.8 + 3.4 + 5.0) / T, abs=1e-4)
    # the gradient pushes violating waypoints back towards the road
    leave.requires_grad_(True)
    bound(leave).sum().backward()
    assert float(leave.grad[0, -1, 1]) > 0  # d cost / d y > 0: descending y lowers it
    # no boundary at all: zero
    r = road(1)
    r["map_mask"][:] = False
    assert float(boundary_loss(leave.detach(), *[r[k] for k in r], 1.0)) == 0.0


def test_collision_term_zero_when_safe_positive_when_violating():
    ego = torch.stack([straight(4.0)])
    boxes = torch.zeros(1, 3, 10)
    boxes[0, :, 3:6], boxes[0, :, 7] = 1.0, 1.0
    boxes[0, 0, :2], boxes[0, 0, 8:10] = torch.tensor([10.0, 0.0]), torch.tensor([-2.0, 0.0])
    boxes[0, 1, :2], boxes[0, 1, 8:10] = torch.tensor([0.0, 10.0]), torch.tensor([4.0, 0.0])
    boxes[0, 2, :2] = torch.tensor([6.0, 0.0])  # parked on the ego's path, but padding
    fut, mask = constant_velocity_futures(boxes, torch.tensor([[True, True, False]]), T, 0.5)
    assert torch.allclose(fut[0, 0, 0], torch.tensor([9.0, 0.0]))  # 0.5 s at -2 m/s
    assert tuple(fut.shape) == (1, 3, T, 2) and tuple(mask.shape) == (1, 3, T)
    # the oncoming agent meets the ego around t = 1.5 s: a collision
    assert float(collision_loss(ego, fut, mask, 2.5)) > 0
    # only the parallel agent (10 m to the left) is valid: safe
    only_side = torch.tensor([[False, True, False]])
    assert float(collision_loss(ego, fut, only_side[..., None].expand(1, 3, T), 2.5)) == 0.0
    # the parked agent sits on the ego's path: a collision once it counts (here it is padding)
    assert float(collision_loss(ego, fut, mask & torch.tensor([[False, False, True]])[..., None],
                                2.5)) == 0.0
    parked = torch.tensor([[False, False, True]])
    assert float(collision_loss(ego, fut, parked, 2.5)) > 0


# ---------------------------------------------------------------------- overfitting
def two_samples(cfg: AuroraConfig) -> tuple[torch.Tensor, torch.Tensor, dict]:
    g = torch.Generator().manual_seed(0)
    h = torch.randn(2, cfg.lm_width, generator=g)
    command = torch.tensor([3, 1])  # straight, left
    gt = torch.stack([straight(6.0), turn(5.0, 12.0)])
    batch = {"expert_waypoints": torch.cat([gt, gt[:, -2:] * 1.1], 1),  # 8 rows like the data
             "ego_speed": torch.tensor([6.0, 5.0]),
             "agent_future": torch.zeros(2, 0, T, 2),
             "agent_future_mask": torch.zeros(2, 0, T, dtype=torch.bool),
             "route_points": torch.stack([route_on(None, cfg), route_on(12.0, cfg)]),
             **road(2, half=15.0)}  # a wide junction: both trajectories are drivable
    return h, command, batch


@pytest.mark.parametrize("name", ["vae", "mlp", "diffusion"])
def test_each_planner_overfits_two_samples(name):
    cfg = AuroraConfig.for_scale("tiny", planner=name, plan_frame="ego")
    torch.manual_seed(0)
    planner = build_planner(cfg, cfg.lm_width)
    h, command, batch = two_samples(cfg)
    gt = batch["expert_waypoints"][:, :T]
    if name == "diffusion":  # anchors from a family of trajectories around the two
        fam = [straight(v) for v in (2.0, 4.0, 6.0, 8.0, 10.0)]
        fam += [turn(v, r, s) for v in (3.0, 5.0) for r in (8.0, 12.0) for s in (1.0, -1.0)]
        anchors = fit_anchors(torch.stack(fam), cfg.plan_anchors, seed=0)
        assert tuple(anchors.shape) == (cfg.plan_anchors, T, 2)
        planner.set_anchors(anchors)
    parts = overfit(planner, PlanningCriterion(cfg), batch, h, command, 300,
                    gt if name == "vae" else None, route=batch["route_points"])
    expect = {"vae": {"plan_l1", "plan_col", "plan_bound", "plan_kl"},
              "mlp": {"plan_l1", "plan_col", "plan_bound"},
              "diffusion": {"plan_cls", "plan_reg", "plan_bound"}}[name]
    assert set(parts) == expect
    with torch.no_grad():
        pred = planner(h, command, route=batch["route_points"])["waypoints"]
    assert tuple(pred.shape) == (2, T, 2)
    err = (pred - gt).norm(dim=-1).mean(1)
    assert float(err.max()) < 0.25, (name, err.tolist(), parts)  # m, mean over waypoints
    # the command conditions the output: another command gives another trajectory
    if name != "diffusion":
        with torch.no_grad():
            other = planner(h, torch.tensor([0, 2]), route=batch["route_points"])["waypoints"]
        assert float((other - pred).abs().max()) > 0.1


# ---------------------------------------------------------------------- criterion and errors
def test_plan_mask_and_errors():
    cfg = AuroraConfig.for_scale("tiny", planner="mlp", plan_frame="ego")
    planner = build_planner(cfg, cfg.lm_width)
    h, command, batch = two_samples(cfg)
    route = batch["route_points"]
    out = planner(h, command, route=route)
    loss, _ = PlanningCriterion(cfg)(out, {**batch, "plan_mask": torch.zeros(2, dtype=torch.bool)})
    assert float(loss.detach()) == 0.0  # QA-only samples carry no planning loss
    loss1, _ = PlanningCriterion(cfg)(out, {**batch, "plan_mask": torch.tensor([True, False])})
    assert float(loss1.detach()) > 0
    with pytest.raises(ValueError, match="command codes outside"):
        planner(h, torch.tensor([0, cfg.num_commands]), route=route)
    with pytest.raises(ValueError, match="h_wp has shape"):
        planner(h[:, :-1], command, route=route)
    with pytest.raises(ValueError, match="agent_future"):
        PlanningCriterion(cfg)(out, {k: v for k, v in batch.items() if k != "agent_future"})
    diff_cfg = AuroraConfig.for_scale("tiny", planner="diffusion", plan_frame="ego")
    with pytest.raises(ValueError, match="no anchors"):
        build_planner(diff_cfg, cfg.lm_width)(h, command, route=route)
    with pytest.raises(ValueError, match="cannot give"):
        fit_anchors(torch.zeros(2, T, 2), 4)
    with pytest.raises(ValueError, match="known planners"):
        AuroraConfig.for_scale("tiny", planner="rnn")
    vae_cfg = AuroraConfig.for_scale("tiny", plan_frame="ego")
    vae = build_planner(vae_cfg, vae_cfg.lm_width)
    with pytest.raises(ValueError, match="without the expert trajectory"):
        PlanningCriterion(vae_cfg)(vae(h, command, route=route), batch)
    loss, _ = PlanningCriterion(vae_cfg)(vae(h, command, batch["expert_waypoints"], route=route),
                                         batch)
    assert math.isfinite(float(loss.detach()))


# ---------------------------------------------------------------------- route points (#33)
@pytest.mark.parametrize("name", ["vae", "mlp", "diffusion"])
def test_planner_overfits_two_samples_that_differ_only_in_their_route(name):
    """The same ``h_wp`` and command (straight), a straight and a left-bending route: only the
    route points tell the two expert trajectories apart."""
    cfg = AuroraConfig.for_scale("tiny", planner=name, plan_frame="ego")
    assert cfg.plan_route_points > 0  # on at the tiny scale (as at every scale)
    torch.manual_seed(0)
    planner = build_planner(cfg, cfg.lm_width)
    h, _, batch = two_samples(cfg)
    h = h[:1].expand(2, -1).clone()
    command = torch.tensor([3, 3])
    gt = batch["expert_waypoints"][:, :T]
    route = batch["route_points"]
    if name == "diffusion":
        planner.set_anchors(fit_anchors(torch.stack(
            [straight(v) for v in (3.0, 6.0, 9.0)] + [turn(5.0, r) for r in (8.0, 12.0, 16.0)]
            + [turn(5.0, 12.0, -1.0)]), cfg.plan_anchors, seed=0))
    overfit(planner, PlanningCriterion(cfg), batch, h, command, 500,
            gt if name == "vae" else None, route=route)
    with torch.no_grad():
        pred = planner(h, command, route=route)["waypoints"]
        swapped = planner(h, command, route=route.flip(0))["waypoints"]
    err = (pred - gt).norm(dim=-1).mean(1)
    assert float(err.max()) < 0.25, (name, err.tolist())
    # the route alone decides which trajectory comes out
    assert float((swapped - gt.flip(0)).norm(dim=-1).mean(1).max()) < 0.25
