"""AURORA CQAF (issue #33): frames of DET-CQAF, soft assignment and appending, MAP-CQAF's
confidence filter, semantic fusion, fused heads and their loss, gradients and shapes."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch
from v2xbench.agents.aurora.branch import PerceptionBranch
from v2xbench.agents.aurora.calib import ego_frame_pose
from v2xbench.agents.aurora.cli import _check_same_run
from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.cqaf import (
    CQAF,
    DetCQAF,
    MapCQAF,
    empty_message,
    rsu_message,
    rsu_to_ego,
    transform_points,
)
from v2xbench.agents.aurora.fused_heads import MASKED_LOGIT, FusedCriterion
from v2xbench.envs.v2x_intersection.core.geometry import (
    pose_matrix,
    relative_transform,
)
from v2xbench.envs.v2x_intersection.core.geometry import (
    transform_points as np_transform_points,
)

from tests.test_aurora_model import synthetic_batch

torch.set_num_threads(1)

# Ego at world (100, 50) heading +y; the roadside unit's pole foot at (100, 80), heading -x,
# its camera body 5 m up, pitched 12 deg down and rolled 1 deg (the ground frame drops both).
T_WORLD_EGO = pose_matrix(100.0, 50.0, 0.0, math.pi / 2)
T_WORLD_RSU = pose_matrix(100.0, 80.0, 5.0, math.pi, math.radians(12.0), math.radians(1.0))
# A point 10 m ahead of the unit and 2 m to its left lies at world (90, 78), i.e. 28 m ahead of
# the ego and 10 m to its left.
RSU_POINT, EGO_POINT = (10.0, 2.0, 0.0), (28.0, 10.0, 0.0)


@pytest.fixture(scope="module")
def tiny() -> AuroraConfig:
    return AuroraConfig.for_scale("tiny")


def e_batch(b: int = 1) -> torch.Tensor:
    return rsu_to_ego(T_WORLD_EGO, T_WORLD_RSU).expand(b, 4, 4).clone()


def ego_to_rsu(points: list[tuple[float, float]]) -> torch.Tensor:
    """Ego-frame ground points -> the roadside frame (to place roadside queries)."""
    inv = np.linalg.inv(rsu_to_ego(T_WORLD_EGO, T_WORLD_RSU).double().numpy())
    p = np.c_[np.asarray(points, np.float64), np.zeros(len(points))]
    return torch.from_numpy(np_transform_points(inv, p)).float()


# ---------------------------------------------------------------------- frames
@torch.no_grad()
def test_roadside_point_lands_at_its_ego_point(tiny):
    e = rsu_to_ego(T_WORLD_EGO, T_WORLD_RSU)
    # one home for frames: the same matrix as calib's ground frame composed with T_ego_rsu
    calib = {"T_world_rsu": T_WORLD_RSU, "T_ego_rsu": relative_transform(T_WORLD_EGO, T_WORLD_RSU)}
    assert np.allclose(e.numpy(), ego_frame_pose(calib, "rsu"), atol=1e-5)
    g = torch.Generator().manual_seed(0)
    pts = torch.randn(1, 5, 3, generator=g) * 20
    assert torch.allclose(transform_points(e[None], pts),
                          torch.from_numpy(np_transform_points(e.double().numpy(),
                                                               pts[0].double().numpy())).float(),
                          atol=1e-4)
    det = DetCQAF(tiny)
    d = tiny.dec_width
    out = det(torch.randn(1, 3, d), torch.zeros(1, 3, 3), torch.randn(1, 1, d),
              torch.tensor([[RSU_POINT]]), torch.ones(1, 1, dtype=torch.bool), e[None])
    assert torch.allclose(out["rsu_ref"][0, 0], torch.tensor(EGO_POINT), atol=1e-4)
    assert torch.allclose(out["ref"][0, 3], torch.tensor(EGO_POINT), atol=1e-4)  # appended slot


@torch.no_grad()
def test_rotation_enters_the_reprojection(tiny):
    det = DetCQAF(tiny)
    q_r = torch.randn(1, 1, tiny.dec_width)
    args = (torch.randn(1, 2, tiny.dec_width), torch.zeros(1, 2, 3), q_r,
            torch.tensor([[[60.0, 60.0, 0.0]]]), torch.ones(1, 1, dtype=torch.bool))
    e1 = torch.eye(4)[None]
    e2 = torch.from_numpy(pose_matrix(0.0, 0.0, 0.0, 0.7).astype(np.float32))[None]
    a = det(*args, e1)["queries"][0, 2]
    b = det(*args, e2)["queries"][0, 2]
    assert (a - b).abs().max() > 1e-4  # the same roadside query re-projected differently


# ---------------------------------------------------------------------- DET-CQAF
@torch.no_grad()
def test_soft_assignment_picks_near_and_appends_far(tiny):
    det = DetCQAF(tiny)
    d = tiny.dec_width
    g = torch.Generator().manual_seed(1)
    q_e = torch.randn(1, 3, d, generator=g)
    ref_e = torch.tensor([[[0.0, 0.0, 0.0], [20.0, 0.0, 0.0], [0.0, 20.0, 0.0]]])
    # roadside queries: A 0.6 m from ego query 1, B 28 m from every ego query, C padding placed
    # exactly on ego query 0
    ref_r = ego_to_rsu([(20.5, 0.3), (40.0, 40.0), (0.0, 0.0)])[None]
    mask_r = torch.tensor([[True, True, False]])
    q_r = torch.randn(1, 3, d, generator=g)
    e = e_batch()
    out = det(q_e, ref_e, q_r, ref_r, mask_r, e)
    w = out["weights"][0]  # (Q, K)
    assert int(w[1].argmax()) == 0 and float(w[1, 0]) > 0.8  # ego query 1 takes A
    assert float(w[0].sum()) < 1e-3 and float(w[2].sum()) < 1e-3  # nothing near 0 and 2
    assert float(w[:, 2].abs().max()) == 0.0  # padding never assigned
    assert out["appended"][0].tolist() == [False, True, False]  # B appended, A fused, C pad
    assert out["mask"][0].tolist() == [True] * 3 + [False, True, False]
    assert out["queries"].shape == (1, 6, d) and out["ref"].shape == (1, 6, 3)
    # aggregation: changing A changes ego query 1 and (almost) nothing else
    q_r2 = q_r.clone()
    q_r2[0, 0] += 3.0
    out2 = det(q_e, ref_e, q_r2, ref_r, mask_r, e)
    delta = (out2["queries"] - out["queries"])[0].abs().amax(-1)
    assert float(delta[1]) > 1e-3 and float(delta[0]) < 2e-3 * float(delta[1])
    # with the ego query 1 unconfident, A has no ego match left and is appended too
    out3 = det(q_e, ref_e, q_r, ref_r, mask_r, e, ego_scores=torch.tensor([[0.9, 0.1, 0.9]]))
    assert out3["appended"][0].tolist() == [True, True, False]
    # temperature: a colder assignment is sharper
    hot = DetCQAF(AuroraConfig.for_scale("tiny", cqaf_temperature=20.0))
    hot.load_state_dict(det.state_dict())
    assert float(hot(q_e, ref_e, q_r, ref_r, mask_r, e)["weights"][0, 1, 0]) < float(w[1, 0])


# ---------------------------------------------------------------------- MAP-CQAF
@torch.no_grad()
def test_map_queries_below_threshold_are_not_appended(tiny):
    mp = MapCQAF(tiny)
    d, p = tiny.dec_width, tiny.map_points
    q_e, pts_e = torch.randn(1, 2, d), torch.zeros(1, 2, p, 2)
    line = torch.stack([torch.linspace(0, 10, p), torch.full((p,), 2.0)], -1)
    pts_r = line.expand(1, 4, p, 2).clone()
    scores = torch.tensor([[0.9, 0.1, 0.5, 0.95]])
    mask = torch.tensor([[True, True, True, False]])
    out = mp(q_e, pts_e, torch.randn(1, 4, d), pts_r, scores, mask, e_batch())
    assert tiny.cqaf_map_score == 0.3
    assert out["appended"][0].tolist() == [True, False, True, False]
    assert out["mask"][0].tolist() == [True, True, True, False, True, False]
    assert out["queries"].shape == (1, 6, d) and out["points"].shape == (1, 6, p, 2)
    # the appended polylines are in the ego frame: the point (10, 2) of the unit is (28, 10)
    assert torch.allclose(out["points"][0, 2, -1], torch.tensor(EGO_POINT[:2]), atol=1e-4)
    strict = MapCQAF(AuroraConfig.for_scale("tiny", cqaf_map_score=0.92))
    out = strict(q_e, pts_e, torch.randn(1, 4, d), pts_r, scores, mask, e_batch())
    assert out["appended"][0].tolist() == [False, False, False, False]


# ---------------------------------------------------------------------- whole module
def test_cqaf_end_to_end_shapes_loss_and_gradients():
    # untrained roadside map scores are ~0.01 (the focal prior): keep every map query here
    tiny = AuroraConfig.for_scale("tiny", cqaf_map_score=0.0)
    torch.manual_seed(0)
    ego, rsu, cqaf = PerceptionBranch(tiny, "ego"), PerceptionBranch(tiny, "rsu"), CQAF(tiny)
    b = 2
    ego_out = ego(synthetic_batch(tiny, "ego", b=b))
    msg = rsu_message(rsu(synthetic_batch(tiny, "rsu", b=b, seed=1)), tiny, e_batch(b))
    k, km = tiny.cqaf_det_topk, tiny.cqaf_map_topk
    assert msg["det_queries"].shape == (b, k, tiny.dec_width)
    assert msg["map_points"].shape == (b, km, tiny.map_points, 2)
    assert bool((msg["det_scores"][:, :-1] >= msg["det_scores"][:, 1:]).all())  # top-k order
    out = cqaf(ego_out, msg)
    q, qm = tiny.num_det_queries, tiny.num_map_queries
    assert out["det_logits"].shape == (1, b, q + k, tiny.num_classes)
    assert out["det_boxes"].shape == (1, b, q + k, 10)
    assert out["map_points"].shape == (1, b, qm + km, tiny.map_points, 2)
    assert out["t_det"].shape == (b, q, tiny.lm_width)
    assert out["t_map"].shape == (b, qm, tiny.lm_width)
    pad = ~out["det_mask"]
    assert bool((out["det_logits"][0][pad] == MASKED_LOGIT).all())
    # the fused heads are scored by part 1's set criterion against (here synthetic) gt/fused
    target = synthetic_batch(tiny, "ego", b=b, seed=2)
    loss, parts = FusedCriterion(tiny)(out, target)
    assert set(parts) == {"det_cls", "det_box", "map_cls", "map_pts"}
    (loss + out["t_det"].square().mean() + out["t_map"].square().mean()).backward()
    for name, mod in (("ego", ego.encoder), ("rsu", rsu.det), ("cqaf.det", cqaf.det),
                      ("cqaf.map", cqaf.map), ("sem", cqaf.sem_det)):
        grads = [p.grad for p in mod.parameters() if p.grad is not None]
        assert grads and any(float(g.abs().sum()) > 0 for g in grads), name
    # no message: the ego's sets alone
    alone = cqaf(ego_out, None)
    assert alone["det_logits"].shape == (1, b, q, tiny.num_classes)
    assert alone["t_det"].shape == (b, q, tiny.lm_width)
    assert empty_message(tiny, b)["det_queries"].shape == (b, 0, tiny.dec_width)


def test_bad_message_is_named(tiny):
    cqaf = CQAF(tiny)
    ego_out = PerceptionBranch(tiny, "ego")(synthetic_batch(tiny, "ego", b=1))
    msg = empty_message(tiny, 1)
    del msg["rsu_to_ego"]
    with pytest.raises(ValueError, match="rsu_to_ego"):
        cqaf(ego_out, msg)
    msg = empty_message(tiny, 1)
    msg["map_points"] = torch.zeros(1, 0, tiny.map_points + 1, 2)
    with pytest.raises(ValueError, match="map_points has shape"):
        cqaf(ego_out, msg)


# ---------------------------------------------------------------------- part 2's config fields
PART2_PREFIXES = ("lm_layers", "lm_heads", "lm_kv_heads", "lm_ffn", "lm_vocab", "lm_max_len",
                  "lm_tie", "lora_", "cqaf_", "plan", "num_commands")


def test_part2_config_fields_and_part1_run_files(tmp_path):
    paper = AuroraConfig.for_scale("paper")
    assert (paper.lm_width, paper.lm_layers, paper.lm_heads, paper.lm_ffn) == (4096, 32, 32, 11008)
    assert AuroraConfig.for_scale("tiny").planner == "vae"  # the paper's default planner
    for bad, match in ((dict(planner="gru"), "known planners"), (dict(lm_heads=5), "lm_width"),
                       (dict(lora_targets=()), "lora_targets"),
                       (dict(cqaf_temperature=0.0), "cqaf_temperature"),
                       (dict(cqaf_map_score=1.5), "cqaf_map_score")):
        with pytest.raises(ValueError, match=match):
            AuroraConfig.for_scale("tiny", **bad)
    # a run file written by part 1 (no part-2 fields) reads back as its scale, and resuming it
    # is not refused as "other settings"
    for scale in ("tiny", "default"):
        cfg = AuroraConfig.for_scale(scale)
        old = {k: v for k, v in json.loads(json.dumps(cfg.to_dict())).items()
               if not k.startswith(PART2_PREFIXES)}
        assert "lm_layers" not in old  # ... except the planner's route input: such a file's
        # model has none (plan_route_points absent reads as 0: tests/test_aurora_route_input.py)
        assert AuroraConfig.from_dict(old) == dataclasses.replace(
            cfg, plan_route_points=0, plan_frame="ego", plan_route_step="softplus")
        info = {"stage": 1, "branch": "ego", "scale": scale, "config": cfg.to_dict(),
                "data": "/d", "frame_stride": 5, "seed": 0}
        (tmp_path / "aurora.json").write_text(json.dumps({**info, "config": old}))
        _check_same_run(tmp_path / "aurora.json", info)
        other = {**old, "num_det_queries": cfg.num_det_queries + 1}
        (tmp_path / "aurora.json").write_text(json.dumps({**info, "config": other}))
        with pytest.raises(ValueError, match="other settings"):
            _check_same_run(tmp_path / "aurora.json", info)
