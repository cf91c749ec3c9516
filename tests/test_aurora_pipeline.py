"""A tiny AURORA pipeline end to end (issue #33 items 5-7): `v2xbench aurora pipeline` trains
stages 0-5 on the tiny data set (stopped early and resumed, then every stage skipped), then
`v2xbench eval --agent aurora` / `--agent no_fusion` drive a route."""

from __future__ import annotations

import json
import math
import shutil

from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.rsu_agent import message_floats
from v2xbench.collectors.chat.export import build as build_qa

from v2xbench.cli import main

TINY_FLOATS = message_floats(AuroraConfig.for_scale("tiny"))
PIPELINE_NAMES = ("language model", "ego branch", "roadside branch", "fusion + QA", "planning",
                  "joint QA + planning")


def _train(data, run, stage: int, *extra: str) -> int:
    scale = ("--scale", "tiny") if stage <= 2 else ()
    return main(["aurora", "train", "--stage", str(stage), "--data", str(data), "--out",
                 str(run), "--quiet", "--threads", "1", *scale, *extra])


def _log(run, stage: int) -> list[dict]:
    return [json.loads(x) for x in (run / f"stage{stage}" / "log.jsonl").read_text().splitlines()]


def _eval(agent: str, run, out, tmp_path) -> dict:
    conf = tmp_path / f"{agent}.json"
    conf.write_text(json.dumps({"run": str(run)}))
    code = main(["eval", "--agent", agent, "--agent-config", str(conf), "--suite", "test50",
                 "--max-routes", "1", "--set", "max_steps=15", "--out", str(out), "--quiet"])
    assert code == 0
    res = json.loads(next((out / "routes").glob("*.json")).read_text())
    assert res["error"] is None and res["ticks"] == 15
    return json.loads((out / "summary.json").read_text())


def _pipeline(data, run, *extra: str) -> int:
    return main(["aurora", "pipeline", "--data", str(data), "--out", str(run), "--scale", "tiny",
                 "--quiet", "--threads", "1", *extra])


def test_tiny_pipeline_trains_stages_0_to_5_and_drives(tiny_dataset, tmp_path, capsys):
    data, run = tmp_path / "data", tmp_path / "run"
    # without QA items whatever other tests built into the shared data set
    shutil.copytree(tiny_dataset, data, ignore=shutil.ignore_patterns("chat"))
    assert _pipeline(data, run) == 2  # no QA items yet: refused before any training
    assert "qa build" in capsys.readouterr().err and not (run / "stage0").exists()
    build_qa(data)  # the Chat-V2XBench items stages 0, 3 and 5 train on
    assert _pipeline(data, run, "--max-steps", "2") == 0  # stage 0 stops early: so does the rest
    out = capsys.readouterr().out
    assert "stopped after stage 0 at step 2/" in out and not (run / "stage1").exists()
    assert _pipeline(data, run) == 0  # resumes stage 0, then stages 1-5 in order
    out = capsys.readouterr().out
    lines = [x for x in out.splitlines() if x.startswith("[pipeline] stage")]
    assert [x.split(":")[0] for x in lines] == [f"[pipeline] stage {s}/5 ({n})" for s, n in
                                               enumerate(PIPELINE_NAMES)]
    assert all("training" in x for x in lines)
    log0 = _log(run, 0)
    assert [r["step"] for r in log0] == list(range(1, len(log0) + 1))  # resumed at step 2
    summ = json.loads((run / "pipeline_summary.json").read_text())
    assert summ["complete"] and [r["status"] for r in summ["stages"]] == ["trained"] * 6
    for r in summ["stages"]:
        assert r["done"] and r["steps"] == r["total_steps"] > 0 and r["wall_s"] > 0
        assert math.isfinite(r["final"]["loss"])
    assert "| 4 | planning | trained |" in (run / "pipeline_summary.md").read_text()
    s3 = run / "stage3"
    info3 = json.loads((s3 / "aurora.json").read_text())
    assert info3["lm"] == {"source": "stage0", "path": "stage0"}  # stage 0's LM is the base
    assert (s3 / "adapter" / "adapter_config.json").is_file()  # peft's adapter files
    assert {"fused", "ego", "rsu", "qa"} <= set(_log(run, 3)[0])  # tiny: live branches (L3)
    info = json.loads((run / "stage4" / "aurora.json").read_text())
    assert info["cache"] and info["freeze_backbone"] and info["samples"]["qa"] == 0
    assert {"plan_l1", "plan_kl", "plan"} <= set(_log(run, 4)[0])
    info5 = json.loads((run / "stage5" / "aurora.json").read_text())
    assert info5["samples"]["qa"] > 0 and info5["samples"]["plan"] > 0

    stamps = {s: (run / f"stage{s}" / "state.json").stat().st_mtime_ns for s in range(6)}
    assert _pipeline(data, run) == 0  # again: every stage is complete and skipped
    out = capsys.readouterr().out
    assert out.count("), skipped") == 6 and "training" not in out
    assert json.loads((run / "pipeline_summary.json").read_text())["stages"][5]["status"] == \
        "skipped"
    assert stamps == {s: (run / f"stage{s}" / "state.json").stat().st_mtime_ns for s in range(6)}
    assert _pipeline(data, run, "--no-fusion") == 2  # a complete stage of other settings
    assert "fusion" in capsys.readouterr().err
    assert _train(data, run, 4, "--max-steps", "3", "--no-fusion") == 2
    assert "fusion" in capsys.readouterr().err

    # the feature cache changes nothing but the time: the same losses without it
    nc = tmp_path / "run_nc"
    for s in (0, 1, 2, 3):
        shutil.copytree(run / f"stage{s}", nc / f"stage{s}")
    assert _train(data, nc, 4, "--max-steps", "2", "--no-cache") == 0  # same schedule
    cached, live = _log(run, 4)[:2], _log(nc, 4)
    for a, b in zip(cached, live):
        assert abs(a["loss"] - b["loss"]) <= 1e-4 * abs(b["loss"])

    # closed loop: the learned roadside unit speaks over the channel; No Fusion stays silent
    summ = _eval("aurora", run, tmp_path / "ev", tmp_path)
    assert summ["rsu_policy"] == "custom:AuroraRoadside"
    assert summ["config_overrides"]["max_payload_floats"] == TINY_FLOATS  # declared channel
    assert summ["sensors"] == {"camera_images": ["rgb"], "camera_size": [32, 16]}  # the data's
    assert 0 < summ["metrics"]["bps"] <= 10 * (16 + 2 * TINY_FLOATS)  # <= one message a tick
    nf = _eval("no_fusion", run, tmp_path / "ev_nf", tmp_path)
    assert nf["rsu_policy"] == "none" and nf["metrics"]["bps"] == 0
    assert "max_payload_floats" not in nf["config_overrides"]  # it sends nothing
