"""A tiny AURORA pipeline end to end (issue #33 items 5 and 7): stages 1-5 a few steps each on
the tiny data set, then `v2xbench eval --agent aurora` / `--agent no_fusion` drive a route."""

from __future__ import annotations

import json
import shutil

from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.rsu_agent import message_floats
from v2xbench.collectors.chat.export import build as build_qa

from v2xbench.cli import main

TINY_FLOATS = message_floats(AuroraConfig.for_scale("tiny"))


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
                 "--max-routes", "1", "--set", f"max_payload_floats={TINY_FLOATS}",
                 "--set", "max_steps=15", "--out", str(out), "--quiet"])
    assert code == 0
    res = json.loads(next((out / "routes").glob("*.json")).read_text())
    assert res["error"] is None and res["ticks"] == 15
    return json.loads((out / "summary.json").read_text())


def test_tiny_pipeline_trains_stages_1_to_5_and_drives(tiny_dataset, tmp_path, capsys):
    data, run = tmp_path / "data", tmp_path / "run"
    shutil.copytree(tiny_dataset, data)
    build_qa(data)  # the Chat-V2XBench items stages 3 and 5 train on
    for stage in (1, 2):
        assert _train(data, run, stage, "--max-steps", "2", "--stride", "3") == 0
    assert _train(data, run, 3, "--max-steps", "2") == 0
    out = capsys.readouterr().out
    assert "freshly built LM" in out and "stage 3 (fusion + QA, tiny): step 2/" in out
    s3 = run / "stage3"
    assert (s3 / "base_lm" / "config.json").is_file()  # save_pretrained of the fresh base LM
    assert (s3 / "adapter" / "adapter_config.json").is_file()  # peft's adapter files
    assert {"fused", "ego", "rsu", "qa"} <= set(_log(run, 3)[0])  # tiny: live branches (L3)

    assert _train(data, run, 4, "--max-steps", "2") == 0
    out = capsys.readouterr().out
    assert "feature cache:" in out and "stage 4 (planning, tiny): step 2/" in out
    info = json.loads((run / "stage4" / "aurora.json").read_text())
    assert info["cache"] and info["freeze_backbone"] and info["samples"]["qa"] == 0
    assert {"plan_l1", "plan_kl", "plan"} <= set(_log(run, 4)[0])
    assert _train(data, run, 4, "--max-steps", "3") == 0  # resumes at step 2
    assert [r["step"] for r in _log(run, 4)] == [1, 2, 3]
    assert _train(data, run, 4, "--max-steps", "3", "--no-fusion") == 2
    assert "fusion" in capsys.readouterr().err

    # the feature cache changes nothing but the time: the same losses without it
    nc = tmp_path / "run_nc"
    for s in (1, 2, 3):
        shutil.copytree(run / f"stage{s}", nc / f"stage{s}")
    assert _train(data, nc, 4, "--max-steps", "2", "--no-cache") == 0
    cached, live = _log(run, 4)[:2], _log(nc, 4)
    for a, b in zip(cached, live):
        assert abs(a["loss"] - b["loss"]) <= 1e-4 * abs(b["loss"])

    assert _train(data, run, 5, "--max-steps", "2") == 0
    out = capsys.readouterr().out
    assert "stage 5 (joint QA + planning, tiny): step 2/" in out
    log5 = _log(run, 5)
    info5 = json.loads((run / "stage5" / "aurora.json").read_text())
    assert info5["samples"]["qa"] > 0 and info5["samples"]["plan"] > 0

    # closed loop: the learned roadside unit speaks over the channel; No Fusion stays silent
    summ = _eval("aurora", run, tmp_path / "ev", tmp_path)
    assert summ["rsu_policy"] == "custom:AuroraRoadside"
    assert summ["sensors"] == {"camera_images": ["rgb"], "camera_size": [32, 16]}  # the data's
    assert 0 < summ["metrics"]["bps"] <= 10 * (16 + 2 * TINY_FLOATS)  # <= one message a tick
    nf = _eval("no_fusion", run, tmp_path / "ev_nf", tmp_path)
    assert nf["rsu_policy"] == "none" and nf["metrics"]["bps"] == 0
    assert len(log5) == 2
