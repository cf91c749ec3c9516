"""AURORA perception model (issue #32): config, 3D position embedding, shapes, matching, losses.

Synthetic batches follow the batch format of the AURORA contract (images, intrinsics,
cam_to_frame, det_*, map_*, light, frame_id); nothing here reads a data set.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest
import torch
from v2xbench.agents.aurora.branch import PerceptionBranch
from v2xbench.agents.aurora.config import AuroraConfig, StageHParams
from v2xbench.agents.aurora.losses import SetCriterion
from v2xbench.agents.aurora.matching import (
    detection_cost,
    hungarian,
    map_cost,
    polyline_orders,
)
from v2xbench.agents.aurora.position import DepthAwarePE, lid_depths

torch.set_num_threads(1)

EGO_YAWS = (0.0, 60.0, -60.0, 120.0, -120.0, 180.0)  # EGO_CAMERA_NAMES order (deg)


def cam_matrix(yaw_deg: float, pitch_deg: float, pos: tuple[float, float, float]) -> torch.Tensor:
    """``(4, 4)`` camera optical frame (x right, y down, z forward) -> frame (x fwd, z up)."""
    base = torch.tensor([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    y, p = math.radians(yaw_deg), math.radians(pitch_deg)
    rz = torch.tensor([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    ry = torch.tensor([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    m = torch.eye(4)
    m[:3, :3] = rz @ ry @ base
    m[:3, 3] = torch.tensor(pos)
    return m


def calibration(cfg: AuroraConfig, branch: str) -> tuple[torch.Tensor, torch.Tensor]:
    """``(N, 3, 3)`` intrinsics and ``(N, 4, 4)`` cam_to_frame like the simulator's rigs."""
    w, h = cfg.image_size(branch)
    fov = 110.0 if branch == "ego" else 90.0
    f = (w / 2) / math.tan(math.radians(fov / 2))
    k = torch.tensor([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]])
    if branch == "ego":
        t = torch.stack([cam_matrix(y, 0.0, (0.0, 0.0, 1.8)) for y in EGO_YAWS])
    else:
        t = cam_matrix(15.0, 12.0, (0.0, 0.0, 5.0))[None]
    return k.expand(t.shape[0], 3, 3).clone(), t


def synthetic_batch(cfg: AuroraConfig, branch: str, b: int = 2, m: int = 6, k: int = 4,
                    seed: int = 0) -> dict[str, torch.Tensor]:
    """A random batch in the contract's format (some padded rows, some closed polylines)."""
    g = torch.Generator().manual_seed(seed)
    kk, tt = calibration(cfg, branch)
    n = kk.shape[0]
    w, h = cfg.image_size(branch)
    rng = cfg.pc_range(branch)
    lo, hi = torch.tensor(rng[:3]), torch.tensor(rng[3:])
    centre = lo + (hi - lo) * (0.1 + 0.8 * torch.rand(b, m, 3, generator=g))
    yaw = torch.rand(b, m, 1, generator=g) * 2 * math.pi
    size = 0.5 + 4 * torch.rand(b, m, 3, generator=g)
    boxes = torch.cat([centre, size, yaw.sin(), yaw.cos(), torch.randn(b, m, 2, generator=g)], -1)
    start = lo[:2] + (hi - lo)[:2] * (0.2 + 0.6 * torch.rand(b, k, 1, 2, generator=g))
    steps = torch.randn(b, k, cfg.map_points, 2, generator=g).cumsum(2) * 2.0
    det_mask = torch.ones(b, m, dtype=torch.bool)
    det_mask[:, -1] = False
    map_mask = torch.ones(b, k, dtype=torch.bool)
    map_mask[0, -1] = False
    return {
        "images": torch.rand(b, n, 3, h, w, generator=g),
        "intrinsics": kk.expand(b, -1, -1, -1).clone(),
        "cam_to_frame": tt.expand(b, -1, -1, -1).clone(),
        "det_boxes": boxes,
        "det_labels": torch.randint(0, cfg.num_classes, (b, m), generator=g),
        "det_mask": det_mask,
        "map_points": start + steps,
        "map_labels": torch.randint(0, cfg.num_map_classes, (b, k), generator=g),
        "map_mask": map_mask,
        "map_closed": torch.arange(k).expand(b, k) % 2 == 1,
        "light": torch.randint(0, cfg.num_light_classes, (b,), generator=g),
        "frame_id": torch.arange(b),
    }


@pytest.fixture(scope="module")
def tiny() -> AuroraConfig:
    return AuroraConfig.for_scale("tiny")


# ---------------------------------------------------------------------- config
def test_scales_and_errors():
    paper = AuroraConfig.for_scale("paper")
    for s in (paper.stage1, paper.stage2):  # seed paper appendix: stages 1 and 2
        assert (s.batch_size, s.epochs, s.lr, s.weight_decay) == (12, 4, 5e-5, 1e-5)
        assert (s.betas, s.warmup_iters, s.warmup_ratio) == ((0.9, 0.999), 500, 1 / 3)
    assert paper.ego_image_size == paper.rsu_image_size == (1024, 512)
    default = AuroraConfig.for_scale("default")
    assert default.scale == "default" and default.stage1.frame_stride > 1
    with pytest.raises(ValueError, match="unknown AURORA scale 'huge'.*tiny, default, paper"):
        AuroraConfig.for_scale("huge")
    with pytest.raises(ValueError, match="unknown fields"):
        AuroraConfig.for_scale("tiny", vit_dpeth=3)
    with pytest.raises(ValueError, match="unknown stage 6"):
        default.stage_hparams(6)
    assert (paper.stage3.lr, paper.stage4.epochs, paper.stage5.batch_size) == (4e-5, 6, 6)
    assert not paper.freeze_backbone(3) and paper.freeze_backbone(4) and paper.freeze_backbone(5)
    with pytest.raises(ValueError, match="branch 'car'"):
        PerceptionBranch(default, "car")
    with pytest.raises(ValueError, match="patch_size"):
        AuroraConfig.for_scale("tiny", ego_image_size=(100, 64))
    with pytest.raises(ValueError, match="lr"):
        StageHParams(lr=0.0)
    assert AuroraConfig.from_dict(default.to_dict()) == default
    with pytest.raises(ValueError, match="unknown keys"):
        AuroraConfig.from_dict({**default.to_dict(), "wings": 2})


# ---------------------------------------------------------------------- 3D position embedding
@pytest.mark.parametrize("branch", ["ego", "rsu"])
def test_position_points_project_back_into_their_patch(tiny, branch):
    kk, tt = calibration(tiny, branch)
    pe = DepthAwarePE(tiny.image_size(branch), tiny.patch_size, 6, tiny.depth_near,
                      tiny.depth_far(branch), tiny.pc_range(branch), 16)
    pts = pe.points(kk[None], tt[None])[0]  # (N, T, D, 3) in the branch frame
    n, t, d, _ = pts.shape
    w, h = tiny.image_size(branch)
    p = tiny.patch_size
    assert t == (w // p) * (h // p) and d == 6
    homog = torch.cat([pts, torch.ones(n, t, d, 1)], -1)
    cam = torch.einsum("nij,ntdj->ntdi", torch.linalg.inv(tt), homog)[..., :3]
    assert torch.allclose(cam[..., 2], lid_depths(6, tiny.depth_near, tiny.depth_far(branch))
                          .expand(n, t, d), atol=1e-3)  # depth along the optical axis
    uv = torch.einsum("nij,ntdj->ntdi", kk, cam)
    uv = uv[..., :2] / uv[..., 2:]
    patch = (uv[..., 1] // p) * (w // p) + uv[..., 0] // p
    assert torch.equal(patch.long(), torch.arange(t).view(1, t, 1).expand(n, t, d))
    # far bins widen (LID), and the embedding depends on the calibration
    dep = lid_depths(6, 1.0, 60.0)
    assert dep[0] == 1.0 and abs(float(dep[-1]) - 60.0) < 1e-4
    assert torch.all(dep.diff().diff() > 0)
    moved = tt.clone()
    moved[:, 0, 3] += 5.0
    assert not torch.allclose(pe(kk[None], tt[None]), pe(kk[None], moved[None]))


# ---------------------------------------------------------------------- shapes
@pytest.mark.parametrize("branch", ["ego", "rsu"])
def test_output_shapes(tiny, branch):
    cfg = tiny
    model = PerceptionBranch(cfg, branch)
    batch = synthetic_batch(cfg, branch, b=3)
    out = model(batch)
    L, B, Q, Qm, P, D = cfg.det_layers, 3, cfg.num_det_queries, cfg.num_map_queries, \
        cfg.map_points, cfg.dec_width
    want = {"det_logits": (L, B, Q, 9), "det_boxes": (L, B, Q, 10), "det_ref": (B, Q, 3),
            "q_det": (B, Q, D), "map_logits": (cfg.map_layers, B, Qm, 3),
            "map_points": (cfg.map_layers, B, Qm, P, 2), "q_map": (B, Qm, D)}
    if branch == "ego":
        want.update(light_logits=(B, 5), t_det=(B, Q, cfg.lm_width), t_map=(B, Qm, cfg.lm_width))
    assert {k: tuple(v.shape) for k, v in out.items()} == want
    rng = torch.tensor(cfg.pc_range(branch))
    centres = out["det_boxes"][..., :3]
    assert torch.all(centres >= rng[:3]) and torch.all(centres <= rng[3:])
    assert torch.all(out["det_boxes"][..., 3:6] > 0)
    xy = out["map_points"]
    assert torch.all(xy >= rng[:2]) and torch.all(xy <= rng[3:5])
    assert ((out["det_ref"] >= 0) & (out["det_ref"] <= 1)).all()
    loss, parts = SetCriterion(cfg, branch)(out, batch)
    assert loss.dim() == 0 and torch.isfinite(loss)
    want_parts = {"det_cls", "det_box", "map_cls", "map_pts"} | ({"light"} if branch == "ego"
                                                                  else set())
    assert set(parts) == want_parts


def test_bad_inputs_raise(tiny):
    model = PerceptionBranch(tiny, "ego")
    batch = synthetic_batch(tiny, "ego")
    with pytest.raises(ValueError, match="images has shape"):
        model({**batch, "images": batch["images"][:, :5]})
    with pytest.raises(ValueError, match="no 'cam_to_frame'"):
        model({k: v for k, v in batch.items() if k != "cam_to_frame"})
    with pytest.raises(ValueError, match="intrinsics has shape"):
        model({**batch, "intrinsics": batch["intrinsics"][:, :, :2]})
    crit = SetCriterion(tiny, "ego")
    out = model(batch)
    with pytest.raises(ValueError, match="no 'light'"):
        crit(out, {k: v for k, v in batch.items() if k != "light"})
    with pytest.raises(ValueError, match="map_points has shape"):
        crit(out, {**batch, "map_points": batch["map_points"][:, :, :3]})
    with pytest.raises(ValueError, match="det_labels outside"):
        crit(out, {**batch, "det_labels": batch["det_labels"] + 9})


def test_branches_share_no_parameters(tiny):
    ego, rsu = PerceptionBranch(tiny, "ego"), PerceptionBranch(tiny, "rsu")
    ptrs = {p.data_ptr() for p in ego.parameters()}
    assert not ptrs & {p.data_ptr() for p in rsu.parameters()}
    assert not hasattr(rsu, "light") and not hasattr(rsu, "t_det")


def test_no_cuda_only_code():
    src = Path(__file__).resolve().parents[1] / "agents" / "aurora"
    for f in src.glob("*.py"):
        text = f.read_text()
        assert ".cuda(" not in text and "torch.cuda." not in text, f.name


# ---------------------------------------------------------------------- matching
def brute_force(cost: torch.Tensor) -> float:
    """Minimum total cost assigning every column to a distinct row (rows >= columns)."""
    q, m = cost.shape
    return min(sum(float(cost[r, c]) for c, r in enumerate(rows))
               for rows in itertools.permutations(range(q), m))


def test_hungarian_equals_brute_force():
    g = torch.Generator().manual_seed(0)
    for trial in range(40):
        q = 2 + trial % 5
        m = 1 + trial % q
        cost = torch.rand(q, m, generator=g, dtype=torch.float64) * 10
        rows, cols = hungarian(cost)
        assert len(set(rows.tolist())) == len(rows) == m
        assert sorted(cols.tolist()) == list(range(m))
        assert abs(float(cost[rows, cols].sum()) - brute_force(cost)) < 1e-9
    cfg = AuroraConfig.for_scale("tiny")
    for trial in range(10):  # the criterion's own cost builders
        q, m = 6, 1 + trial % 5
        logits = torch.randn(q, 9, generator=g)
        boxes = torch.randn(q, 10, generator=g).abs() + 0.1
        labels = torch.randint(0, 9, (m,), generator=g)
        gt = torch.randn(m, 10, generator=g).abs() + 0.1
        cost = detection_cost(logits, boxes, labels, gt, 2.0, 0.25)
        rows, cols = hungarian(cost)
        assert abs(float(cost[rows, cols].sum()) - brute_force(cost)) < 1e-6
        pts, gpts = torch.rand(q, cfg.map_points, 2, generator=g), torch.rand(
            m, cfg.map_points, 2, generator=g)
        closed = torch.rand(m, generator=g) < 0.5
        mcost, _ = map_cost(logits[:, :3], pts, labels % 3, gpts, closed, 2.0, 5.0)
        rows, cols = hungarian(mcost)
        assert abs(float(mcost[rows, cols].sum()) - brute_force(mcost)) < 1e-6
    with pytest.raises(ValueError, match="NaN or inf"):
        hungarian(torch.tensor([[float("nan")]]))


def test_polyline_orders():
    assert polyline_orders(4, False).tolist() == [[0, 1, 2, 3], [3, 2, 1, 0]]
    closed = polyline_orders(4, True)
    assert closed.shape == (8, 4)
    assert [0, 1, 2, 3] in closed.tolist() and [2, 3, 0, 1] in closed.tolist()
    assert [1, 0, 3, 2] in closed.tolist()  # reversed, starting at point 1
    assert len({tuple(r) for r in closed.tolist()}) == 8


# ---------------------------------------------------------------------- losses
def perfect_outputs(cfg: AuroraConfig, branch: str, batch: dict, perm_seed: int = 1) -> dict:
    """Outputs that predict ``batch`` exactly, in a shuffled query order."""
    b, m = batch["det_labels"].shape
    q, qm = cfg.num_det_queries, cfg.num_map_queries
    g = torch.Generator().manual_seed(perm_seed)
    logits = torch.full((b, q, cfg.num_classes), -30.0)
    boxes = torch.tensor([10.0, 10.0, 0.0, 1, 1, 1, 0, 1, 0, 0]).repeat(b, q, 1)
    mlog = torch.full((b, qm, cfg.num_map_classes), -30.0)
    pts = torch.zeros(b, qm, cfg.map_points, 2)
    for i in range(b):
        perm = torch.randperm(q, generator=g)
        for j in batch["det_mask"][i].nonzero().flatten().tolist():
            logits[i, perm[j], batch["det_labels"][i, j]] = 30.0
            boxes[i, perm[j]] = batch["det_boxes"][i, j]
        perm = torch.randperm(qm, generator=g)
        for j in batch["map_mask"][i].nonzero().flatten().tolist():
            mlog[i, perm[j], batch["map_labels"][i, j]] = 30.0
            pts[i, perm[j]] = batch["map_points"][i, j]
    out = {"det_logits": logits.expand(cfg.det_layers, -1, -1, -1),
           "det_boxes": boxes.expand(cfg.det_layers, -1, -1, -1),
           "map_logits": mlog.expand(cfg.map_layers, -1, -1, -1),
           "map_points": pts.expand(cfg.map_layers, -1, -1, -1, -1)}
    if branch == "ego":
        out["light_logits"] = torch.nn.functional.one_hot(batch["light"], 5).float() * 60 - 30
    return out


@pytest.mark.parametrize("branch", ["ego", "rsu"])
def test_losses_minimal_at_perfect_prediction(tiny, branch):
    batch = synthetic_batch(tiny, branch, b=2, m=5, k=4)
    crit = SetCriterion(tiny, branch)
    out = perfect_outputs(tiny, branch, batch)
    _, parts = crit(out, batch)
    assert parts["det_box"] == 0.0 and parts["map_pts"] == 0.0
    assert parts["det_cls"] < 1e-6 and parts["map_cls"] < 1e-6
    if branch == "ego":
        assert parts["light"] < 1e-6

    def worse(key: str, fn) -> dict:
        o = {k: v.clone() for k, v in out.items()}
        o[key] = fn(o[key])
        return crit(o, batch)[1]

    shift = torch.zeros(10)
    shift[0] = 1.0
    assert worse("det_boxes", lambda t: t + shift)["det_box"] > 0.1
    yaw = torch.zeros(10)
    yaw[6] = 0.5
    assert worse("det_boxes", lambda t: t + yaw)["det_box"] > 0.05
    vel = torch.zeros(10)
    vel[8] = 1.0
    assert worse("det_boxes", lambda t: t + vel)["det_box"] > 0.01
    assert worse("det_logits", lambda t: t.roll(1, -1))["det_cls"] > 0.1
    assert worse("map_points", lambda t: t + 0.5)["map_pts"] > 0.01
    assert worse("map_logits", lambda t: t.roll(1, -1))["map_cls"] > 0.1
    if branch == "ego":
        assert worse("light_logits", lambda t: t.roll(1, -1))["light"] > 1.0


def test_map_loss_is_point_order_invariant(tiny):
    batch = synthetic_batch(tiny, "rsu", b=1, m=3, k=4)
    batch["map_mask"][:] = True
    batch["map_closed"][:] = torch.tensor([[False, True, False, True]])
    crit = SetCriterion(tiny, "rsu")
    out = perfect_outputs(tiny, "rsu", batch)
    gt = batch["map_points"]
    same = []
    for i in range(4):  # reverse the open lines; shift + reverse the closed ones
        alt = {k: v.clone() for k, v in batch.items()}
        alt["map_points"] = gt.clone()
        alt["map_points"][0, 0] = gt[0, 0].flip(0)
        alt["map_points"][0, 1] = gt[0, 1].roll(i + 1, 0)
        alt["map_points"][0, 3] = gt[0, 3].roll(i + 2, 0).flip(0)
        same.append(crit(out, alt)[1]["map_pts"])
    assert same == [0.0] * 4
    alt = {k: v.clone() for k, v in batch.items()}
    alt["map_points"][0, 0] = gt[0, 0].roll(1, 0)  # not the same open line
    assert crit(out, alt)[1]["map_pts"] > 1e-3
