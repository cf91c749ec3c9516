"""``v2xbench aurora train`` / ``eval-perception`` end to end at the tiny scale."""

from __future__ import annotations

import json

from v2xbench.cli import main


def _train(data, run, *extra: str) -> int:
    return main(["aurora", "train", "--data", str(data), "--out", str(run), "--scale", "tiny",
                 "--quiet", *extra])


def test_train_resume_and_eval_perception(tiny_dataset, tmp_path, capsys):
    run = tmp_path / "run"
    assert _train(tiny_dataset, run, "--stage", "1", "--max-steps", "2", "--stride", "3") == 0
    assert "stage 1 (ego branch, tiny): step 2/" in capsys.readouterr().out
    s1 = run / "stage1"
    for name in ("aurora.json", "checkpoint.safetensors", "state.json", "log.jsonl", "loss.png",
                 "train_summary.json"):
        assert (s1 / name).is_file(), name
    info = json.loads((s1 / "aurora.json").read_text())
    assert info["branch"] == "ego" and info["scale"] == "tiny" and info["frame_stride"] == 3
    # the same command with more steps resumes at step 2
    assert _train(tiny_dataset, run, "--stage", "1", "--max-steps", "3", "--stride", "3") == 0
    log = [json.loads(x) for x in (s1 / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3]
    assert json.loads((s1 / "train_summary.json").read_text())["resumed_from"] == 2
    # other settings on the same run folder are refused, by name
    assert _train(tiny_dataset, run, "--stage", "1", "--max-steps", "4", "--stride", "2") == 2
    assert "frame_stride" in capsys.readouterr().err
    assert _train(tiny_dataset, run, "--stage", "2", "--max-steps", "1", "--stride", "3") == 0
    capsys.readouterr()
    assert main(["aurora", "eval-perception", "--run", str(run), "--data", str(tiny_dataset),
                 "--split", "all", "--stride", "4", "--pictures", "1", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "| ego branch (ego frame) |" in out and "| roadside branch" in out
    saved = json.loads((run / "eval_all" / "perception.json").read_text())
    assert set(saved["branches"]) == {"ego", "rsu"}
    assert len(list((run / "eval_all" / "pictures").glob("*.png"))) == 2


def test_bad_input_is_named(tiny_dataset, tmp_path, capsys):
    run = tmp_path / "run"
    assert _train(tiny_dataset, run, "--stage", "6") == 2
    assert "unknown AURORA stage 6" in capsys.readouterr().err
    assert _train(tiny_dataset, run, "--stage", "3") == 2  # stages 3-5 need stages 1 and 2
    assert "has no trained stage 1" in capsys.readouterr().err
    assert _train(tiny_dataset, run, "--stage", "1", "--scale", "huge") == 2
    assert "unknown AURORA scale 'huge'" in capsys.readouterr().err
    assert _train(tmp_path / "nodata", run, "--stage", "1") == 2
    assert "nodata does not exist" in capsys.readouterr().err
    assert main(["aurora", "eval-perception", "--run", str(tmp_path / "norun"), "--data",
                 str(tiny_dataset)]) == 2
    assert "norun does not exist" in capsys.readouterr().err


def test_bench_model_quick(tiny_dataset, tmp_path, capsys):
    assert main(["bench-model", "--quick", "--out", str(tmp_path), "--data",
                 str(tiny_dataset)]) == 0
    res = json.loads((tmp_path / "model_speed_quick.json").read_text())
    assert [(r["stage"], r["branch"]) for r in res["rows"]] == [(1, "ego"), (2, "rsu")]
    for r in res["rows"]:
        assert r["samples_per_s"] > 0 and r["infer_ms_per_frame"] > 0
        assert r["bound_by"] in ("compute", "data loading") and r["load_ms_per_sample"] > 0
    assert "train samples/s" in capsys.readouterr().out
    assert main(["bench-model", "--quick", "--out", str(tmp_path), "--data",
                 str(tmp_path / "none")]) == 2
