"""AURORA's route-relative planner (issue #33, ``plan_frame = "route"``): the route polyline,
the differentiable ``(s, d)`` -> ego-frame conversion, each planner fitting two samples in the
route frame, and old run files reading as ego-frame planners."""

from __future__ import annotations

import json
import math

import pytest
import torch
from v2xbench.agents.aurora.config import AuroraConfig, same_config
from v2xbench.agents.aurora.planner_losses import PlanningCriterion
from v2xbench.agents.aurora.planners import build_planner, fit_anchors
from v2xbench.agents.aurora.route_input import (
    PATH_POINTS,
    PATH_SPACING,
    ego_to_route,
    planner_route_path,
    polyline_at,
    route_path,
    route_to_ego,
)

from tests.planner_fit import TIMES, T, overfit, turn

torch.set_num_threads(1)

RADIUS = 20.0


def arc_rows(radius: float | None, rows: int = 20, step: float = 2.0, side: float = 1.0,
             start: float = 0.0) -> torch.Tensor:
    """``(rows, 3)`` observed route rows every ``step`` m from arc length ``start``: straight
    along x (``radius`` None) or on a circle of ``radius`` to the left (``side`` 1) / right."""
    s = start + torch.arange(rows) * step
    if radius is None:
        xy = torch.stack([s, torch.zeros_like(s)], -1)
    else:
        a = s / radius
        xy = torch.stack([radius * torch.sin(a), side * radius * (1 - torch.cos(a))], -1)
    return torch.cat([xy, torch.full((rows, 1), 3.0)], -1)


def on_circle(s: torch.Tensor, d: torch.Tensor, radius: float) -> torch.Tensor:
    """Exact point at arc length ``s``, ``d`` to the left, of the left circle from the origin."""
    a = s / radius
    r = radius - d
    return torch.stack([r * torch.sin(a), radius - r * torch.cos(a)], -1)


# ---------------------------------------------------------------------- the polyline
def test_route_path_starts_at_the_egos_foot_point_and_extrapolates():
    # straight route offset 0.3 m to the left, row 0 0.4 m behind the ego
    rows = arc_rows(None, start=-0.4)
    rows[:, 1] += 0.3
    path = route_path(rows, PATH_POINTS, PATH_SPACING)
    assert tuple(path.shape) == (PATH_POINTS, 2)
    expect = torch.stack([torch.arange(PATH_POINTS) * PATH_SPACING,
                          torch.full((PATH_POINTS,), 0.3)], -1)
    assert torch.allclose(path, expect, atol=1e-4)  # past 37.6 m: the last segment, on
    # row 0 1.5 m ahead of the ego: the path starts on the line before it
    ahead = route_path(arc_rows(None, start=1.5), 4, 2.0)
    assert torch.allclose(ahead[:, 0], torch.tensor([0.0, 2.0, 4.0, 6.0]), atol=1e-5)
    # a route of one point (or without length) runs straight ahead from the ego's foot
    one = route_path(torch.tensor([[3.0, -1.0, 3.0]]), 3, 2.0)
    assert torch.allclose(one, torch.tensor([[0.0, -1.0], [2.0, -1.0], [4.0, -1.0]]))
    # batched and leading dims kept; the cfg helper needs a route-frame config
    two = torch.stack([arc_rows(None), arc_rows(RADIUS)])
    assert tuple(planner_route_path(two, AuroraConfig.for_scale("tiny")).shape) \
        == (2, PATH_POINTS, 2)
    with pytest.raises(ValueError, match="plan_frame='ego'"):
        planner_route_path(two, AuroraConfig.for_scale("tiny", plan_frame="ego"))
    with pytest.raises(ValueError, match="route has shape"):
        route_path(torch.zeros(4), 4, 2.0)
    with pytest.raises(ValueError, match="count"):
        route_path(two, 1, 2.0)
    with pytest.raises(ValueError, match="non-finite"):
        route_path(torch.full((3, 3), float("nan")), 4, 2.0)


def test_polyline_at_interpolates_and_goes_on_past_both_ends():
    xy = torch.tensor([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]])
    s = torch.tensor([-1.0, 1.0, 3.0, 5.0])
    got = polyline_at(xy, s)
    assert torch.allclose(got, torch.tensor([[-1.0, 0.0], [1.0, 0.0], [2.0, 1.0], [2.0, 3.0]]))


# ---------------------------------------------------------------------- the conversion
def test_route_to_ego_puts_s_on_the_route_and_d_to_its_left():
    path = route_path(arc_rows(RADIUS), PATH_POINTS, PATH_SPACING)[None]  # left turn, R = 20 m
    s = torch.tensor([0.0, 3.0, 11.0, 17.5, 29.0])  # 11: mid-chord (a vertex is a corner)
    on = route_to_ego(torch.stack([s, torch.zeros_like(s)], -1)[None], path)[0]
    # (s, 0) is on the polyline at arc length s (within the chords' sag, 2 m chords: 2.5 cm)
    assert torch.allclose(on, on_circle(s, torch.zeros_like(s), RADIUS), atol=0.03)
    # ... and on the path polyline (whose 2 m chords are a hair shorter than 2 m of route)
    assert torch.allclose(on, polyline_at(path[0], s), atol=2e-3)
    left = route_to_ego(torch.stack([s, torch.full_like(s, 1.5)], -1)[None], path)[0]
    # d metres to the left: 1.5 m from the route point, towards the circle's centre
    assert torch.allclose((left - on).norm(dim=-1), torch.full_like(s, 1.5), atol=1e-5)
    assert torch.allclose(left, on_circle(s, torch.full_like(s, 1.5), RADIUS), atol=0.1)
    right = route_to_ego(torch.stack([s, torch.full_like(s, -1.5)], -1)[None], path)[0]
    assert torch.allclose(right, on_circle(s, torch.full_like(s, -1.5), RADIUS), atol=0.1)
    # a straight route: s along x, d along y
    straight = route_path(arc_rows(None), PATH_POINTS, PATH_SPACING)[None]
    sd = torch.tensor([[[7.0, 0.5], [100.0, -2.0]]])  # 100 m: past the path's end, straight on
    assert torch.allclose(route_to_ego(sd, straight), sd, atol=1e-4)
    # ego_to_route inverts it off the corners
    back = ego_to_route(left[None], path)[0]
    assert torch.allclose(back[:, 1], torch.full_like(s, 1.5), atol=0.05)
    assert torch.allclose(back[:, 0], s, atol=0.1)
    with pytest.raises(ValueError, match="route path has shape"):
        route_to_ego(sd, straight[:, :, :1])


def test_gradient_flows_to_s_and_d():
    path = route_path(arc_rows(RADIUS), PATH_POINTS, PATH_SPACING)[None]
    sd = torch.tensor([[[9.0, 0.4], [21.0, -0.7]]], requires_grad=True)
    xy = route_to_ego(sd, path)
    xy.sum().backward()
    g = sd.grad[0]
    assert bool(torch.isfinite(g).all())
    assert bool((g.abs() > 1e-3).all())  # both s and d of both waypoints move the output
    # along the left turn: more s moves left (+y), more d moves towards the centre (+y)
    for i, s in enumerate((9.0, 21.0)):
        tangent = torch.tensor([math.cos(s / RADIUS), math.sin(s / RADIUS)])
        ds = torch.autograd.functional.jacobian(
            lambda v: route_to_ego(v, path), sd.detach())[0, i, :, 0, i, 0]
        assert torch.allclose(ds, tangent, atol=0.06)


# ---------------------------------------------------------------------- planners
def two_samples(cfg: AuroraConfig) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """A straight sample 0.5 m left of a straight route and a left turn on a 12 m curve."""
    g = torch.Generator().manual_seed(0)
    h = torch.randn(2, cfg.lm_width, generator=g)
    command = torch.tensor([3, 1])
    straight = torch.stack([6.0 * TIMES, torch.full((T,), 0.5)], -1)
    gt = torch.stack([straight, turn(5.0, 12.0)])
    rows = torch.stack([arc_rows(None), arc_rows(12.0)])
    k = torch.arange(1, cfg.plan_route_points + 1) * cfg.plan_route_spacing
    route_pts = torch.stack([polyline_at(rows[i, :, :2], k) for i in range(2)])
    batch = {"expert_waypoints": torch.cat([gt, gt[:, -2:] * 1.1], 1),
             "ego_speed": torch.tensor([6.0, 5.0]),
             "agent_future": torch.zeros(2, 0, T, 2),
             "agent_future_mask": torch.zeros(2, 0, T, dtype=torch.bool),
             "route_points": route_pts, "route_path": planner_route_path(rows, cfg),
             "map_points": torch.zeros(2, 1, 4, 2), "map_labels": torch.zeros(2, 1).long(),
             "map_mask": torch.zeros(2, 1, dtype=torch.bool),
             "map_closed": torch.zeros(2, 1, dtype=torch.bool)}
    return h, command, batch


@pytest.mark.parametrize("name", ["vae", "mlp", "diffusion"])
def test_each_planner_overfits_two_samples_in_the_route_frame(name):
    cfg = AuroraConfig.for_scale("tiny", planner=name)
    assert cfg.plan_frame == "route"  # the default for new runs
    torch.manual_seed(0)
    planner = build_planner(cfg, cfg.lm_width)
    h, command, batch = two_samples(cfg)
    gt = batch["expert_waypoints"][:, :T]
    path, route = batch["route_path"], batch["route_points"]
    if name == "diffusion":  # route-frame anchors of a family of trajectories
        fam = [torch.stack([v * TIMES, torch.full((T,), y)], -1)
               for v in (2.0, 4.0, 6.0, 8.0) for y in (-0.5, 0.5)]
        planner.set_anchors(fit_anchors(torch.stack(fam), cfg.plan_anchors, seed=0))
    overfit(planner, PlanningCriterion(cfg), batch, h, command, 300,
            gt if name == "vae" else None, route=route, path=path)
    with torch.no_grad():
        out = planner(h, command, route=route, path=path)
    pred = out["waypoints"]
    assert tuple(pred.shape) == (2, T, 2) and tuple(out["route_sd"].shape) == (2, T, 2)
    assert torch.allclose(route_to_ego(out["route_sd"], path), pred, atol=1e-4)
    err = (pred - gt).norm(dim=-1).mean(1)
    assert float(err.max()) < 0.25, (name, err.tolist())
    # the route frame: the left turn's trajectory is close to d = 0, s >= 0 and increasing
    sd = out["route_sd"]
    assert float(sd[1, :, 1].abs().max()) < 0.3
    assert float(sd[..., 0].min()) >= 0.0
    if name != "diffusion":
        assert bool((sd[..., 1:, 0] >= sd[..., :-1, 0]).all())
    with pytest.raises(ValueError, match="no route path"):
        planner(h, command, route=route)


def test_untrained_mlp_follows_a_curved_route():
    """At initialization d ~ 0 and s > 0: a route-frame planner starts out on the route (an
    ego-frame one starts out straight ahead)."""
    cfg = AuroraConfig.for_scale("tiny", planner="mlp", plan_route_step="softplus")
    torch.manual_seed(0)
    planner = build_planner(cfg, cfg.lm_width)
    for p in planner.head[-1].parameters():
        torch.nn.init.zeros_(p)  # all steps 0: softplus(0) along the route, no offset
    h, command, batch = two_samples(cfg)
    wps = planner(h, command, route=batch["route_points"], path=batch["route_path"])["waypoints"]
    s = (torch.arange(1, T + 1) * math.log(2) / 10.0 * cfg.plan_traj_scale[0]).float()
    assert torch.allclose(wps[1].detach(), on_circle(s, torch.zeros(T), 12.0), atol=0.05)


def test_relu_ste_step_stands_exactly_yet_passes_the_gradient():
    """``plan_route_step = "relu_ste"`` (the default for new runs): a negative pre-activation is
    a step of exactly 0 m, a positive one its size; the gradient is 1 on both sides (a
    softplus's would be ~0 far below 0), so a sample can leave the standing region."""
    cfg = AuroraConfig.for_scale("tiny", planner="mlp")
    assert cfg.plan_route_step == "relu_ste"
    planner = build_planner(cfg, cfg.lm_width)
    u = torch.tensor([-2.0, -0.1, 0.05, 0.2]).view(1, 1, 4, 1).repeat(1, 1, 1, 2)
    u.requires_grad_(True)
    s = planner.steps_to_traj(u)[..., 0]
    scale = cfg.plan_traj_scale[0]
    assert torch.allclose(s, torch.tensor([0.0, 0.0, 0.05, 0.25]) * scale)
    s.sum().backward()
    assert torch.allclose(u.grad[..., 0], torch.tensor([4.0, 3.0, 2.0, 1.0]) * scale)
    soft = build_planner(AuroraConfig.for_scale("tiny", planner="mlp",
                                                plan_route_step="softplus"), cfg.lm_width)
    u.grad = None
    soft.steps_to_traj(u)[..., 0].sum().backward()
    assert float(u.grad[0, 0, 0, 0]) < 0.01 * 4 * scale  # the softplus: no gradient at -2


def test_abs_step_moves_forward_for_either_sign():
    """``plan_route_step = "abs"``: a step's pre-activation of either sign moves ``s`` forward
    by its size (a softplus would give ~0 for -0.1)."""
    cfg = AuroraConfig.for_scale("tiny", planner="mlp", plan_route_step="abs")
    torch.manual_seed(0)
    planner = build_planner(cfg, cfg.lm_width)
    last = planner.head[-1]
    torch.nn.init.zeros_(last.weight)
    bias = torch.zeros(cfg.num_commands, T, 2)
    bias[..., 0] = torch.tensor([-0.1, 0.1]).repeat(T // 2)  # alternating signs along the route
    last.bias.data = bias.flatten()
    h, command, batch = two_samples(cfg)
    wps = planner(h, command, route=batch["route_points"], path=batch["route_path"])["waypoints"]
    s = torch.arange(1, T + 1) * 0.1 * cfg.plan_traj_scale[0]
    assert torch.allclose(wps[1].detach(), on_circle(s, torch.zeros(T), 12.0), atol=0.05)


def rest_batch(cfg: AuroraConfig, spread: float) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Six standing samples (the expert stays) and two starting from rest (1.5 m/s^2, 0.75 m
    at 1 s), all with ego speed 0 on a straight route; their ``h_wp`` differ by ``spread``
    times a unit normal around one common state (the real data's standing and starting frames
    look alike to the planner)."""
    g = torch.Generator().manual_seed(0)
    n = 8
    h = torch.randn(1, cfg.lm_width, generator=g) + spread * torch.randn(n, cfg.lm_width,
                                                                          generator=g)
    gt = torch.zeros(n, T, 2)
    gt[6:, :, 0] = 0.75 * TIMES ** 2
    rows = arc_rows(None).expand(n, -1, -1)
    k = torch.arange(1, cfg.plan_route_points + 1) * cfg.plan_route_spacing
    batch = {"expert_waypoints": torch.cat([gt, gt[:, -2:]], 1), "ego_speed": torch.zeros(n),
             "agent_future": torch.zeros(n, 0, T, 2),
             "agent_future_mask": torch.zeros(n, 0, T, dtype=torch.bool),
             "route_points": polyline_at(rows[0, :, :2], k).expand(n, -1, -1),
             "route_path": planner_route_path(rows, cfg),
             "map_points": torch.zeros(n, 1, 4, 2), "map_labels": torch.zeros(n, 1).long(),
             "map_mask": torch.zeros(n, 1, dtype=torch.bool),
             "map_closed": torch.zeros(n, 1, dtype=torch.bool)}
    return h, torch.full((n,), 3), batch


@pytest.mark.parametrize("name, spread", [("mlp", 0.1), ("vae", 1.0)])
def test_planner_starts_from_rest_among_standing_samples(name, spread):
    """The fourth run's failure (docs/aurora.md, "A fifth run"): standing samples push the
    softplus step's pre-activation far below 0, where its gradient vanishes, and the samples
    that start from rest stay at ~0 m; the ``relu_ste`` and ``abs`` steps (gradient 1) fit
    them and keep the standing ones standing."""
    dist = {}
    for step in ("relu_ste", "abs", "softplus"):
        cfg = AuroraConfig.for_scale("tiny", planner=name, plan_route_step=step)
        torch.manual_seed(0)
        planner = build_planner(cfg, cfg.lm_width)
        h, command, batch = rest_batch(cfg, spread)
        gt = batch["expert_waypoints"][:, :T]
        overfit(planner, PlanningCriterion(cfg), batch, h, command, 300,
                gt if name == "vae" else None, route=batch["route_points"],
                path=batch["route_path"])
        with torch.no_grad():
            wps = planner(h, command, route=batch["route_points"],
                          path=batch["route_path"])["waypoints"]
        dist[step] = wps.norm(dim=-1)  # (8, T) m from the ego
    for step in ("relu_ste", "abs"):
        assert float(dist[step][:6].max()) < 0.3, step  # the standing samples stay
        one_s = dist[step][6:, 1]  # expert: 0.75 m at 1 s, 6.75 m at 3 s
        assert bool(((one_s > 0.5) & (one_s < 1.0)).all()), (step, one_s.tolist())
        assert float(dist[step][6:, -1].min()) > 4.5, (step, dist[step][6:, -1].tolist())
    assert float(dist["softplus"][6:, -1].max()) < 0.2  # the old step: stuck at rest


# ---------------------------------------------------------------------- config
def test_old_run_file_loads_as_an_ego_frame_planner(tmp_path):
    new = AuroraConfig.for_scale("default")
    assert new.plan_frame == "route"
    old = new.to_dict()
    old.pop("plan_frame")
    path = tmp_path / "aurora.json"
    path.write_text(json.dumps({"config": old}))
    loaded = AuroraConfig.from_dict(json.loads(path.read_text())["config"])
    assert loaded.plan_frame == "ego"
    # a fourth-run file (route frame, no plan_route_step) reads as the softplus step
    fourth = {k: v for k, v in new.to_dict().items() if k != "plan_route_step"}
    assert AuroraConfig.from_dict(fourth).plan_route_step == "softplus"
    assert new.plan_route_step == "relu_ste"
    assert AuroraConfig.from_dict(new.to_dict()).plan_route_step == "relu_ste"
    with pytest.raises(ValueError, match="plan_route_step='relu'"):
        AuroraConfig.for_scale("tiny", plan_route_step="relu")
    assert AuroraConfig.from_dict(new.to_dict()).plan_frame == "route"
    assert not same_config(AuroraConfig.for_scale("default", plan_frame="ego").to_dict(),
                           new.to_dict())
    with pytest.raises(ValueError, match="plan_frame='polar'"):
        AuroraConfig.for_scale("tiny", plan_frame="polar")


def test_stage_5_keeps_the_frame_of_stage_4(tmp_path):
    """Stage 5 continues stage 4's planner: an old stage 4 (no ``plan_frame``) stays ego-frame
    under the new default; a resume in another frame is refused."""
    from v2xbench.agents.aurora.stages import _check_same_run, _route_config

    new = AuroraConfig.for_scale("tiny")
    old = new.to_dict()
    old.pop("plan_frame")
    (tmp_path / "stage4").mkdir()
    (tmp_path / "stage4" / "aurora.json").write_text(json.dumps({"config": old}))
    assert _route_config(tmp_path, 5, new, None).plan_frame == "ego"
    assert _route_config(tmp_path, 4, new, None).plan_frame == "route"
    info = {"config": new.to_dict(), "qa": True, **{k: None for k in (
        "stage", "scale", "data", "frame_stride", "seed", "fusion", "lm", "cache")}}
    (tmp_path / "stage4" / "aurora.json").write_text(json.dumps({**info, "config": old}))
    with pytest.raises(ValueError, match="config"):
        _check_same_run(tmp_path / "stage4" / "aurora.json", info)
    _check_same_run(tmp_path / "stage4" / "aurora.json", {**info, "config": {
        **new.to_dict(), "plan_frame": "ego"}})


def test_stage_5_keeps_the_route_step_of_stage_4(tmp_path):
    """A fourth-run stage 4 (route frame, no ``plan_route_step``) is a softplus planner: stage 5
    continues it as one under the new default ``"relu_ste"``; resuming it with the default is
    refused; a new stage 4 gets the default."""
    from v2xbench.agents.aurora.stages import _check_same_run, _route_config

    new = AuroraConfig.for_scale("tiny")
    old = new.to_dict()
    old.pop("plan_route_step")
    (tmp_path / "stage4").mkdir()
    info = {"config": new.to_dict(), "qa": True, **{k: None for k in (
        "stage", "scale", "data", "frame_stride", "seed", "fusion", "lm", "cache")}}
    (tmp_path / "stage4" / "aurora.json").write_text(json.dumps({**info, "config": old}))
    kept = _route_config(tmp_path, 5, new, None)
    assert (kept.plan_frame, kept.plan_route_step) == ("route", "softplus")
    assert _route_config(tmp_path, 4, new, None).plan_route_step == "relu_ste"
    with pytest.raises(ValueError, match="config"):
        _check_same_run(tmp_path / "stage4" / "aurora.json", info)
    _check_same_run(tmp_path / "stage4" / "aurora.json", {**info, "config": {
        **new.to_dict(), "plan_route_step": "softplus"}})
    # the planner's step does not touch the branches: the feature cache's digest ignores it
    from types import SimpleNamespace

    from v2xbench.agents.aurora.feature_cache import weights_digest

    branches = {"ego": torch.nn.Linear(2, 2), "rsu": torch.nn.Linear(2, 2)}  # what it reads
    digest = {step: weights_digest(SimpleNamespace(cfg=AuroraConfig.for_scale(
        "tiny", plan_route_step=step), **branches)) for step in ("relu_ste", "softplus")}
    assert digest["relu_ste"] == digest["softplus"]
    assert digest["relu_ste"] == weights_digest(SimpleNamespace(cfg=AuroraConfig.for_scale(
        "tiny", plan_speed_dropout=1.0), **branches))  # nor the speed dropout of stage 4
    assert digest["relu_ste"] != weights_digest(SimpleNamespace(cfg=AuroraConfig.for_scale(
        "tiny", vit_depth=2), **branches))
