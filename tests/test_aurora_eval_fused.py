"""AURORA's fused perception (`aurora eval-perception --fused`) and the VQA-ablation switch
(`aurora pipeline|train --no-qa`), issue #35: a tiny AURORA run's fused heads give numbers that
differ from its ego branch's, a No Fusion run is refused, the message is the closed loop's
float16 payload; a run trained without the QA loss records it, trains no QA term and is refused
when resumed with it."""

from __future__ import annotations

import json
import math
import shutil

import pytest
import torch
from v2xbench.agents.aurora import eval_fused as EF
from v2xbench.agents.aurora.data import AuroraFrames
from v2xbench.agents.aurora.pairs import AuroraPairs, collate_pairs, planning_items
from v2xbench.agents.aurora.pipeline import run_pipeline
from v2xbench.agents.aurora.stages import train_late_stage
from v2xbench.agents.aurora.system import _prefixed, load_system
from v2xbench.collectors.chat.export import build as build_qa
from v2xbench.envs.v2x_intersection.evaluation.metrics_perception import (
    DetBoxes,
    detection_metrics,
)

from v2xbench.cli import main


@pytest.fixture(scope="module")
def runs(tiny_dataset, tmp_path_factory):
    """A tiny AURORA run, and No Fusion / no-QA runs sharing its stages 0-2."""
    torch.set_num_threads(1)
    base = tmp_path_factory.mktemp("aurora_eval_fused")
    data = base / "data"
    shutil.copytree(tiny_dataset, data, ignore=shutil.ignore_patterns("chat"))
    build_qa(data)
    quiet = dict(scale="tiny", progress=False, say=lambda _: None)
    run_pipeline(data, base / "aurora", **quiet)
    out = {"data": data, "aurora": base / "aurora"}
    for name, kw in (("no_fusion", {"fusion": False}), ("no_qa", {"qa": False})):
        for s in (0, 1, 2):
            shutil.copytree(base / "aurora" / f"stage{s}", base / name / f"stage{s}")
        out[name] = base / name
        out[name + "_summary"] = run_pipeline(data, base / name, **quiet, **kw)
    return out


def test_fused_evaluation_gives_numbers_that_differ_from_the_ego_branch(runs, tmp_path, capsys):
    r = EF.evaluate_fused(runs["aurora"], runs["data"], "all", tmp_path / "f", stride=4,
                          progress=False)
    assert r["stage"] == 5 and r["frames"] > 0 and 0 < r["frames_with_unit"] <= r["frames"]
    assert set(r["tables"]) == {f"{p}@{g}" for p, g in EF.ROWS}
    assert r["table"] == r["tables"]["fused@fused"]
    for row in r["tables"].values():  # NaN: a class group without ground truth
        assert all(math.isnan(v) or 0.0 <= v <= 1.0 for v in row.values()), row
        assert 0.0 <= row["NDS"] <= 1.0
    # the tiny model's metrics are all 0 (AP) / 1 (errors); its fused heads' predictions are
    # other boxes and scores than its ego branch's, and they score 1 against themselves
    p = r["predictions"]
    q = json.loads((runs["aurora"] / "stage5" / "aurora.json").read_text())["config"]
    assert p["ego_branch"]["boxes"] == r["frames"] * q["num_det_queries"]  # < top-50: all
    # the fused set: the ego's queries plus the slots for appended roadside queries
    k = min(q["cqaf_det_topk"], q["num_det_queries"])
    assert p["fused"]["boxes"] == r["frames"] * (q["num_det_queries"] + k)
    assert p["fused"]["mean_score"] != pytest.approx(p["ego_branch"]["mean_score"], rel=1e-3)
    system, tok, _ = load_system(runs["aurora"])
    frames = AuroraFrames(runs["data"], "all", "ego", system.cfg, stride=4, images=False)
    ds = AuroraPairs(runs["data"], "all", system.cfg, tok, planning_items(frames, 4), plan=False)
    res = EF.predict_fused(system, ds, top_k=3)
    gt = res["preds"]["fused"]
    gt = DetBoxes(gt.frame, gt.cls, gt.center, gt.size, gt.yaw, gt.velocity)
    assert detection_metrics(res["preds"]["fused"], gt)["NDS"] == pytest.approx(1.0)
    assert detection_metrics(res["preds"]["ego_branch"], gt)["NDS"] < 0.9
    saved = json.loads((tmp_path / "f" / "perception.json").read_text())
    assert saved["frames"] == r["frames"]
    md = (tmp_path / "f" / "perception.md").read_text()
    assert "| fused heads (CQAF) | gt/fused |" in md and "| ego branch | gt/ego |" in md
    # the same through the command
    assert main(["aurora", "eval-perception", "--fused", "--run", str(runs["aurora"]), "--data",
                 str(runs["data"]), "--split", "all", "--stride", "4", "--out",
                 str(tmp_path / "cli"), "--quiet", "--threads", "1"]) == 0
    assert "fused heads (CQAF)" in capsys.readouterr().out
    again = json.loads((tmp_path / "cli" / "perception.json").read_text())
    assert again["tables"] == saved["tables"]


def test_fused_evaluation_refuses_a_no_fusion_run(runs, tmp_path, capsys):
    with pytest.raises(ValueError, match="No Fusion model.*without --fused"):
        EF.evaluate_fused(runs["no_fusion"], runs["data"], "all", tmp_path, progress=False)
    assert main(["aurora", "eval-perception", "--fused", "--run", str(runs["no_fusion"]),
                 "--data", str(runs["data"]), "--split", "all", "--quiet"]) == 2
    assert "No Fusion model" in capsys.readouterr().err


def test_the_message_goes_through_the_float16_wire(runs):
    """The fused evaluator's message is the serialized payload read back: float16 values."""
    system, tok, _ = load_system(runs["aurora"])
    frames = AuroraFrames(runs["data"], "all", "ego", system.cfg, stride=4, images=False)
    ds = AuroraPairs(runs["data"], "all", system.cfg, tok, planning_items(frames, 4), plan=False)
    rows_with_unit = [i for i in range(len(ds)) if bool(ds[i]["has_rsu"])][:2]
    batch = collate_pairs([ds[i] for i in rows_with_unit + [0]], tok.pad_token_id)
    has = batch["has_rsu"].bool()
    rows = has.nonzero()[:, 0]
    with torch.no_grad():
        msg = EF.fused_message(system, {k: v[rows] for k, v in _prefixed(batch, "rsu/").items()},
                               batch["rsu_to_ego"], rows, len(has))
    q = msg["det_queries"][rows]
    assert torch.equal(q, q.half().float()) and q.abs().sum() > 0
    assert torch.equal(msg["det_mask"], has[:, None].expand_as(msg["det_mask"]))
    assert torch.equal(msg["rsu_to_ego"][rows], batch["rsu_to_ego"][rows])


def test_no_qa_run_records_the_switch_and_trains_no_qa_term(runs):
    s = runs["no_qa_summary"]
    assert s["complete"] and s["qa"] is False
    for stage in (3, 4, 5):
        d = runs["no_qa"] / f"stage{stage}"
        info = json.loads((d / "aurora.json").read_text())
        assert info["qa"] is False and info["samples"]["qa"] == 0, stage
        rows = [json.loads(x) for x in (d / "log.jsonl").read_text().splitlines()]
        assert rows and all("qa" not in r for r in rows), stage
        with_qa = [json.loads(x) for x in (runs["aurora"] / f"stage{stage}" / "log.jsonl"
                                            ).read_text().splitlines()]
        assert all("qa" in r for r in with_qa)
    assert json.loads((runs["aurora"] / "stage3" / "aurora.json").read_text())["qa"] is True
    # stage 3 without QA trains the fused heads on planning frames
    assert "fused" in json.loads((runs["no_qa"] / "stage3" / "log.jsonl").read_text()
                                 .splitlines()[0])


def test_no_qa_run_is_refused_when_resumed_with_qa(runs, tmp_path):
    with pytest.raises(ValueError, match=r"stage3 was trained with qa=False.*--no-qa"):
        run_pipeline(runs["data"], runs["no_qa"], scale="tiny", progress=False,
                     say=lambda _: None)
    with pytest.raises(ValueError, match="other settings .qa: False -> True"):
        train_late_stage(runs["data"], runs["no_qa"], 3, progress=False)
    with pytest.raises(ValueError, match=r"stage 3 of .* qa=False; stage 4 must use the same"):
        shutil.copytree(runs["no_qa"], tmp_path / "r", ignore=shutil.ignore_patterns("stage4",
                                                                                     "stage5"))
        train_late_stage(runs["data"], tmp_path / "r", 4, progress=False)
    # a run file from before the switch reads qa=True: the AURORA run resumes with qa
    path = runs["aurora"] / "stage5" / "aurora.json"
    info = json.loads(path.read_text())
    old = tmp_path / "old"
    shutil.copytree(runs["aurora"], old, ignore=shutil.ignore_patterns("eval*"))
    info.pop("qa")
    (old / "stage5" / "aurora.json").write_text(json.dumps(info))
    assert run_pipeline(runs["data"], old, scale="tiny", progress=False,
                        say=lambda _: None)["complete"]
    with pytest.raises(ValueError, match="qa=True"):
        run_pipeline(runs["data"], old, scale="tiny", progress=False, say=lambda _: None,
                     qa=False)
