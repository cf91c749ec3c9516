"""AURORA perception evaluation: decoding, metrics from a perfect and an untrained model,
the paper's table, files and pictures."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from torch import nn
from v2xbench.agents.aurora.branch import PerceptionBranch
from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.data import AuroraFrames
from v2xbench.agents.aurora.eval_perception import (
    TABLE_COLUMNS,
    decode_detections,
    evaluate_branch,
    evaluate_run,
    markdown_table,
    predict,
    run_branches,
)
from v2xbench.envs.v2x_intersection.core.classes import NUM_CLASSES
from v2xbench.envs.v2x_intersection.evaluation.metrics_perception import detection_metrics

CFG = AuroraConfig.for_scale("tiny")


class GroundTruthEcho(nn.Module):
    """A stand-in branch whose predictions are the batch's own targets (``shift`` metres off in
    x), one query per target row: a perfect detector when ``shift == 0``."""

    def __init__(self, shift: float = 0.0) -> None:
        super().__init__()
        self.shift = shift

    def forward(self, batch: dict) -> dict:
        mask, labels = batch["det_mask"], batch["det_labels"]
        logits = torch.full((*labels.shape, NUM_CLASSES), -12.0)
        logits.scatter_(2, labels[..., None], torch.where(mask, 12.0, -12.0)[..., None])
        boxes = batch["det_boxes"].clone()
        boxes[..., 0] += self.shift
        mlog = torch.where(batch["map_mask"][..., None], 12.0, -12.0).expand(
            -1, -1, 3).clone()
        return {"det_logits": logits[None], "det_boxes": boxes[None],
                "map_logits": mlog[None], "map_points": batch["map_points"][None]}


@pytest.fixture(scope="module")
def frames(tiny_dataset):
    return {b: AuroraFrames(tiny_dataset, "all", b, CFG, stride=2) for b in ("ego", "rsu")}


def test_decode_keeps_the_top_k_by_sigmoid_max():
    logits = torch.tensor([[[0.0, 3.0], [-2.0, -1.0], [5.0, 1.0]]])  # (1, 3, 2)
    boxes = torch.arange(30, dtype=torch.float32).reshape(1, 3, 10)
    score, cls, kept = decode_detections(logits, boxes, top_k=2)
    np.testing.assert_allclose(score.numpy(), torch.sigmoid(torch.tensor([[5.0, 3.0]])).numpy())
    assert cls.tolist() == [[0, 1]] and torch.equal(kept[0], boxes[0, [2, 0]])
    assert decode_detections(logits, boxes, top_k=10)[0].shape == (1, 3)
    with pytest.raises(ValueError, match="top_k"):
        decode_detections(logits, boxes, top_k=0)


@pytest.mark.parametrize("branch", ["ego", "rsu"])
def test_ground_truth_as_prediction_scores_one(frames, branch):
    ds = frames[branch]
    res = predict(GroundTruthEcho(), ds, top_k=96, batch_size=3, min_score=0.5)
    assert len(res["gts"].frame) > 10 and res["frames"] == len(ds)
    m = detection_metrics(res["preds"], res["gts"])
    assert m["mAP"] == pytest.approx(1.0) and m["NDS"] == pytest.approx(1.0)
    # 3 m off in x: every match fails below 2 m, a few at 4 m
    off = detection_metrics(*(lambda r: (r["preds"], r["gts"]))(
        predict(GroundTruthEcho(3.0), ds, top_k=96, min_score=0.5)))
    assert off["mAP"] < 0.5
    # keeping one query per frame loses recall; low-score queries after full recall cost a
    # little precision at recall 1 (nuScenes interpolation), so min_score drops the padding rows
    assert detection_metrics(*(lambda r: (r["preds"], r["gts"]))(
        predict(GroundTruthEcho(), ds, top_k=96)))["mAP"] < 1.0
    one = predict(GroundTruthEcho(), ds, top_k=1, min_score=0.5)
    assert detection_metrics(one["preds"], one["gts"])["mAP"] < 0.9


def test_untrained_branch_metrics_and_pictures(frames, tmp_path):
    torch.manual_seed(0)
    ds = frames["ego"]
    out = evaluate_branch(PerceptionBranch(CFG, "ego"), ds, top_k=10, pictures=2,
                          picture_dir=tmp_path / "pics")
    t = out["table"]
    assert set(t) == {c for c, _ in TABLE_COLUMNS}
    assert 0.0 <= t["avg_mAP"] <= 1.0 and 0.0 <= t["NDS"] <= 1.0
    assert out["frames"] == len(ds) and out["gt_boxes"] > 0 and 0 <= out["light_accuracy"] <= 1
    assert len(out["pictures"]) == 2
    for p in out["pictures"]:
        with open(p, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    md = markdown_table({"ego": t, "rsu": {c: float("nan") for c, _ in TABLE_COLUMNS}})
    assert "| ego branch (ego frame) |" in md and "n/a" in md and md.count("\n") == 4


def test_evaluate_run_writes_json_markdown_and_pictures(tiny_dataset, tmp_path):
    from v2xbench.agents.aurora.cli import train_stage

    run = tmp_path / "run"
    with pytest.raises(FileNotFoundError, match="does not exist"):
        run_branches(run)
    run.mkdir()
    with pytest.raises(FileNotFoundError, match="no trained stage"):
        run_branches(run)
    train_stage(tiny_dataset, run, 2, scale="tiny", max_steps=1, stride=4, progress=False)
    res = evaluate_run(run, tiny_dataset, "all", stride=3, pictures=1, progress=False)
    out = run / "eval_all"
    saved = json.loads((out / "perception.json").read_text())
    assert set(saved["branches"]) == {"rsu"}  # only the trained stage
    row = saved["branches"]["rsu"]["table"]
    assert set(row) == {c for c, _ in TABLE_COLUMNS}
    assert all(v is None or (isinstance(v, float) and math.isfinite(v)) for v in row.values())
    md = (out / "perception.md").read_text()
    assert "roadside branch" in md and "avg mAP" in md and res["table"] in md
    assert len(list((out / "pictures").glob("rsu_*.png"))) == 1
    with pytest.raises(FileNotFoundError, match="data directory"):
        evaluate_run(run, tmp_path / "missing", "all")
