"""``v2xbench experiments run`` / ``report`` (issue #35, item 1 and the machinery of items 2, 5).

One module-scoped run of the shipped quick config, cut to what CI affords (AURORA, No Fusion,
AURORA without the Chat-V2XBench loss, UniV2X, an unregistered baseline, the V2X oracle and one
500 ms latency point), trained on the session's tiny data set and evaluated on a collected
test50 route, feeds the tests: the tables are written (the VQA ablation's two rows with numbers,
AURORA's perception from its fused heads and No Fusion's from its ego branch), a second run
skips every job, the report refuses incomplete results naming the job and file, the DS
confidence interval is the shared bootstrap over routes x seeds, and the sweep's latency reaches
the channel (message age in the route logs).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from v2xbench.collectors.chat.export import build as build_qa
from v2xbench.collectors.experiments import shipped_config
from v2xbench.collectors.experiments.config import (
    ConfigError,
    channel_overrides,
    load_config,
    parse_config,
)
from v2xbench.collectors.experiments.report import (
    IncompleteResults,
    build_report,
    closed_loop_summary,
)
from v2xbench.collectors.experiments.runner import run_experiments
from v2xbench.envs.v2x_intersection.evaluation.metrics import bootstrap_ci

from v2xbench.cli import main

KEEP = {"aurora", "no_fusion", "aurora_no_vqa", "univ2x", "codriving", "oracle_v2x"}
UNREGISTERED = "no_such_baseline"  # codriving's stand-in: never in BASELINES


def _cut(values: list) -> list:
    return [v for v in values if not isinstance(v, str) or v in KEEP]


def ci_config(data: Path) -> dict:
    """The shipped quick config with the tiny data set as its training data, cut to the
    methods of :data:`KEEP`, the 500 ms latency point and no loss / bandwidth sweeps."""
    raw = json.loads(shipped_config("quick").read_text())
    raw["methods"] = {k: v for k, v in raw["methods"].items() if k in KEEP}
    raw["methods"]["codriving"]["baseline"] = UNREGISTERED
    jobs = []
    for j in raw["jobs"]:
        if j["id"] == "data_train":  # the test split stays a collect job (1 route, 40 ticks)
            j = {"id": j["id"], "kind": "dataset", "path": str(data)}
        m = j.get("matrix", {})
        if "loss_pct" in m or "bandwidth_bytes_per_s" in m:
            continue
        if "method" in m:
            m["method"] = _cut(m["method"])
        elif j.get("method") is not None and j["method"] not in KEEP:
            continue
        jobs.append(j)
    raw["jobs"] = jobs
    raw["report"] = {k: _cut(v) for k, v in raw["report"].items()}
    return raw


@pytest.fixture(scope="module")
def exp(tiny_dataset, tmp_path_factory) -> dict:
    """The cut quick config run once: ``{"dir", "config", "state", "lines"}``."""
    base = tmp_path_factory.mktemp("experiments")
    data = base / "data"
    shutil.copytree(tiny_dataset, data, ignore=shutil.ignore_patterns("chat"))
    build_qa(data)
    cfg_path = base / "ci.json"
    cfg_path.write_text(json.dumps(ci_config(data)))
    lines: list[str] = []
    state = run_experiments(cfg_path, base / "run", say=lines.append)
    return {"dir": base / "run", "config": cfg_path, "state": state, "lines": lines}


def test_quick_pipeline_runs_end_to_end_and_writes_the_tables(exp, tmp_path):
    st = exp["state"]["jobs"]
    assert not [k for k, r in st.items() if r["status"] in ("failed", "blocked")], st
    done = {k for k, r in st.items() if r["status"] == "done"}
    assert {"data_test", "train_aurora", "train_no_fusion", "train_univ2x", "perc_aurora",
            "ol_aurora", "ol_univ2x", "vqa_aurora", "cl_aurora", "cl_univ2x",
            "cl_oracle_v2x_lat500"} <= done
    for k in ("train_codriving", "perc_codriving", "ol_codriving", "cl_codriving"):
        assert st[k]["status"] == "not available" and UNREGISTERED in st[k]["reason"]
    assert any(x.startswith("[experiments 1/") and "done in" in x for x in exp["lines"])
    r = build_report(exp["dir"], tmp_path / "report")
    out = Path(r["out"])
    for name in ("perception", "planning", "fusion_ablation", "planner_ablation",
                 "vqa_ablation", "per_scenario", "robustness"):
        assert (out / f"{name}.md").is_file(), name
    md = (out / "report.md").read_text()
    assert "| AURORA | 2 x 2 |" in md and "| UniV2X | 2 x 2 |" in md
    assert f"| CoDriving | not available (baseline '{UNREGISTERED}'" in md
    assert "| 0 ms | 500 ms |" in md and "V2X-specific scenario types" in md
    for png in ("ds_vs_latency.png", "bps_vs_ds.png"):
        assert (out / png).stat().st_size > 1000
    assert (out / "leaderboard" / "leaderboard.md").is_file()
    data = json.loads((out / "report.json").read_text())["tables"]
    # the VQA ablation: AURORA with and without the QA loss in stages 3-5, every cell a number
    assert st["train_aurora_no_vqa"]["status"] == "done"
    vqa = {r["method"]: r for r in data["vqa_ablation"]}
    assert set(vqa) == {"aurora", "aurora_no_vqa"}
    for r in vqa.values():
        for k in ("driving_score", "route_completion", "l2_avg", "collision_avg", "vqa_closed",
                  "vqa_f1"):
            assert isinstance(r[k], (int, float)), (r["method"], k, r[k])
    no_qa = json.loads((Path(json.loads((exp["dir"] / "train_aurora_no_vqa" / "result.json")
                                        .read_text())["outputs"]["run"]) / "stage5"
                        / "aurora.json").read_text())
    assert no_qa["qa"] is False and no_qa["samples"]["qa"] == 0
    vqa_md = (out / "vqa_ablation.md").read_text()
    assert "| AURORA without the Chat-V2XBench loss | " in vqa_md and "not available" not in vqa_md
    # open-loop L2 in the planning table for AURORA and a baseline (its own evaluator)
    plan = {r["method"]: r for r in data["planning"]}
    for m in ("aurora", "univ2x"):
        assert isinstance(plan[m]["l2_avg"], float) and plan[m]["l2_avg"] > 0, plan[m]
    ol = json.loads((exp["dir"] / "ol_univ2x" / "eval" / "metrics.json").read_text())
    assert ol["title"] == "UniV2X" and ol["frames"] > 0
    # perception: AURORA's fused heads vs gt/fused, No Fusion's ego branch vs gt/ego
    perc = {r["method"]: r for r in data["perception"]}
    assert perc["aurora"]["evaluator"].startswith("fused heads (CQAF")
    assert perc["aurora"]["ground_truth"] == "gt/fused"
    assert perc["no_fusion"]["evaluator"].startswith("ego branch")
    assert perc["no_fusion"]["ground_truth"] == "gt/ego"
    assert "no perception evaluator" not in md and "--fused" in md
    # the fusion ablation scores both on the ground both have: gt/ego
    assert {r["method"]: r["ground_truth"] for r in data["fusion_ablation"]} == {
        "aurora": "gt/ego", "no_fusion": "gt/ego"}
    # and pairs No Fusion's closed-loop runs with AURORA's, run by run
    pv = {r["method"]: r for r in data["fusion_ablation"]}["no_fusion"]["paired_vs_first"]
    assert pv["runs"] == 4 and pv["ds_difference_ci"][0] <= pv["ds_difference"] <= pv["ds_difference_ci"][1]
    assert "AURORA minus " in (out / "fusion_ablation.md").read_text() and "paired on the 4 runs" in md
    lat = {p["x"]: p for p in data["robustness"]["latency_ms"]["oracle_v2x"]}
    assert set(lat) == {0.0, 500.0}
    # UniV2X has no sweep: its main run is a flat reference at every point, labelled so
    ref = data["robustness"]["latency_ms"]["univ2x"]
    assert [p["x"] for p in ref] == [0.0, 500.0] and all(p["reference"] for p in ref)
    assert ref[0]["driving_score"] == ref[1]["driving_score"]
    assert not any(p["reference"] for p in lat.values())
    assert "| UniV2X (no sweep: its main run) |" in (out / "robustness.md").read_text()
    assert main(["experiments", "report", str(exp["dir"]), "--out", str(tmp_path / "cli"),
                 "--no-plots"]) == 0


def test_resume_skips_finished_jobs_and_reruns_a_removed_one(exp):
    d = exp["dir"]
    stamp = {p: p.stat().st_mtime_ns for p in d.glob("*/result.json")}
    (d / "cl_oracle_v2x_lat500" / "result.json").unlink()
    lines: list[str] = []
    state = run_experiments(exp["config"], d, say=lines.append)
    st = state["jobs"]
    assert st["cl_oracle_v2x_lat500"]["status"] == "done"
    assert all(r["status"] in ("skipped", "not available") for k, r in st.items()
               if k != "cl_oracle_v2x_lat500")
    assert sum("skipped, result exists" in x for x in lines) == len(stamp) - 1
    for p, t in stamp.items():
        if p.parent.name != "cl_oracle_v2x_lat500":
            assert p.stat().st_mtime_ns == t, p
    # a job whose spec changed is refused before anything runs, naming the job
    raw = json.loads(exp["config"].read_text())
    for j in raw["jobs"]:
        if j["id"] == "cl_oracle_v2x":
            j["seeds"] = 3
    changed = exp["config"].with_name("changed.json")
    changed.write_text(json.dumps(raw))
    with pytest.raises(ValueError, match="job 'cl_oracle_v2x'.*another spec"):
        run_experiments(changed, d, say=lambda m: None)


def test_report_refuses_incomplete_results_naming_the_job(exp, tmp_path):
    d = tmp_path / "run"
    shutil.copytree(exp["dir"], d, ignore=shutil.ignore_patterns("eval", "run", "data"))
    (d / "cl_no_fusion" / "result.json").unlink()
    with pytest.raises(IncompleteResults) as e:
        build_report(d, tmp_path / "report")
    msg = str(e.value)
    assert "job 'cl_no_fusion'" in msg and str(d / "cl_no_fusion" / "result.json") in msg
    assert "'planning'" in msg and "'fusion_ablation'" in msg
    assert not (tmp_path / "report").exists()  # nothing written
    assert main(["experiments", "report", str(d), "--out", str(tmp_path / "r2")]) == 2
    r = build_report(d, tmp_path / "partial", allow_partial=True)
    assert "cl_no_fusion" in json.dumps(r["missing"])
    planning = (tmp_path / "partial" / "planning.md").read_text()
    assert "| No Fusion | missing | missing |" in planning


def test_ds_ci_is_the_bootstrap_over_routes_x_seeds(exp, tmp_path):
    """A constructed case: the oracle's 2 routes x 2 seeds given chosen driving scores."""
    src = json.loads((exp["dir"] / "cl_oracle_v2x" / "result.json").read_text())
    ev = tmp_path / "eval"
    shutil.copytree(src["outputs"]["eval"], ev)
    files = sorted((ev / "routes").glob("*.json"))
    assert len(files) == 4  # 2 routes x 2 seeds
    ds = [12.0, 81.0, 33.0, 97.0]
    for f, v in zip(files, ds):
        r = json.loads(f.read_text())
        r["metrics"]["driving_score"] = v
        f.write_text(json.dumps(r))
    s = closed_loop_summary(ev)
    lo, hi = bootstrap_ci(np.array(ds))  # the shared function, over the 4 runs
    m = s["metrics"]
    assert m["driving_score"] == pytest.approx(np.mean(ds))
    assert (m["driving_score_ci_low"], m["driving_score_ci_high"]) == pytest.approx((lo, hi))
    assert [f.stem[-3:] for f in files] == ["_s0", "_s1", "_s0", "_s1"]  # route-major names
    by_route = bootstrap_ci(np.array([np.mean(ds[:2]), np.mean(ds[2:])]))
    assert (lo, hi) != pytest.approx(by_route)  # not a bootstrap over route means
    # the planning table shows that interval for the job
    d = tmp_path / "run"
    shutil.copytree(exp["dir"], d, ignore=shutil.ignore_patterns("eval", "run", "data"))
    res = json.loads((d / "cl_oracle_v2x" / "result.json").read_text())
    res["outputs"]["eval"] = str(ev)
    (d / "cl_oracle_v2x" / "result.json").write_text(json.dumps(res))
    build_report(d, tmp_path / "report", plots=False)
    row = f"| V2X oracle | 2 x 2 | {np.mean(ds):.1f} [{lo:.1f}, {hi:.1f}] |"
    assert row in (tmp_path / "report" / "planning.md").read_text()


def test_sweep_latency_reaches_the_channel(exp):
    """500 ms added to the channel's one tick: the ego's message is 6 ticks old."""
    def ages(job: str) -> list[dict]:
        ev = json.loads((exp["dir"] / job / "result.json").read_text())["outputs"]["eval"]
        return [json.loads(p.read_text())["v2x"] for p in sorted(Path(ev, "routes").glob("*"))]

    assert channel_overrides({"latency_ms": 500}) == {"latency_ticks": 6}
    slow, base = ages("cl_oracle_v2x_lat500"), ages("cl_oracle_v2x")
    assert len(slow) == 4 and all(v["latency_ticks"] == 6 for v in slow)
    assert all(v["message_age_ticks"]["min"] == 6 for v in slow if v["ticks_with_message"])
    assert any(v["ticks_with_message"] for v in slow)
    assert all(v["message_age_ticks"]["max"] == 1 for v in base if v["ticks_with_message"])


def test_config_errors_name_the_field_and_job(tmp_path):
    ok = {"name": "t", "methods": {"a": {"agent": "route_follower"}},
          "jobs": [{"id": "cl_a", "kind": "closed_loop", "method": "a", "suite": "test50"}]}
    parse_config(ok)

    def bad(patch: dict, match: str) -> None:
        raw = json.loads(json.dumps(ok))
        raw["jobs"][0].update(patch)
        with pytest.raises(ConfigError, match=match):
            parse_config(raw, "cfg.json")

    bad({"seeds": 0}, r"cfg.json: job 'cl_a': field 'seeds': expected an int >= 1")
    bad({"channel": {"latency_ms": 150}}, r"channel.latency_ms.*multiple of the 100 ms tick")
    bad({"channel": {"jitter": 1}}, r"field 'channel.jitter': unknown")
    bad({"run": "nope"}, r"job 'cl_a': field 'run': no job 'nope'")
    bad({"method": "b"}, r"field 'method': 'b' is not in 'methods'")
    bad({"sed": 1}, r"unknown field\(s\) \['sed'\]")
    bad({"matrix": {"seeds": [1, 2]}}, r"the id repeats")
    p = tmp_path / "c.json"
    p.write_text("{\"name\": ")
    with pytest.raises(ConfigError, match="not valid JSON"):
        load_config(p)
    assert main(["experiments", "run", "--config", str(p), "--out", str(tmp_path / "o")]) == 2


def test_a_failing_job_blocks_only_its_dependents(tiny_dataset, tmp_path):
    raw = {"name": "f", "methods": {"aurora": {"agent": "aurora"}},
           "jobs": [{"id": "bad", "kind": "dataset", "path": str(tmp_path / "nowhere")},
                    {"id": "train", "kind": "aurora_train", "method": "aurora", "data": "bad"},
                    {"id": "good", "kind": "dataset", "path": str(tiny_dataset)}]}
    cfg = tmp_path / "f.toml"
    cfg.write_text("name = 'f'\n[methods.aurora]\nagent = 'aurora'\n" + "".join(
        "[[jobs]]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in j.items())
        for j in raw["jobs"]))
    assert main(["experiments", "run", "--config", str(cfg), "--out", str(tmp_path / "o")]) == 1
    st = json.loads((tmp_path / "o" / "experiments.json").read_text())["jobs"]
    assert st["bad"]["status"] == "failed" and "nowhere" in st["bad"]["reason"]
    assert st["train"]["status"] == "blocked" and "'bad'" in st["train"]["reason"]
    assert st["good"]["status"] == "done"
    fail = json.loads((tmp_path / "o" / "bad" / "failed.json").read_text())
    assert "FileNotFoundError" in fail["error"] and fail["traceback"]


def test_status_shows_each_job_and_closed_loop_progress(exp, tmp_path, capsys):
    from v2xbench.collectors.experiments.status import experiment_status

    rows = {r["id"]: r for r in experiment_status(exp["dir"])}
    st = exp["state"]["jobs"]
    assert {k: r["status"] for k, r in rows.items()} == {k: r["status"] for k, r in st.items()}
    assert "min" in rows["cl_aurora"]["detail"] and "progress" not in rows["cl_aurora"]
    # the same experiment with cl_aurora stopped half-way: no result.json, 2 of its 4 runs
    part = tmp_path / "part"
    shutil.copytree(exp["dir"], part)
    (part / "cl_aurora" / "result.json").unlink()
    runs = sorted((part / "cl_aurora" / "eval" / "routes").glob("*.json"))
    for f in runs[2:]:
        f.unlink()
    row = {r["id"]: r for r in experiment_status(part)}["cl_aurora"]
    assert row["status"] == "unfinished" and row["progress"]["runs"] == 2 and row["progress"]["of"] == 4
    assert row["detail"].startswith("2 of 4 runs, ~")
    assert main(["experiments", "status", str(part)]) == 0
    assert "| cl_aurora | closed_loop | unfinished | 2 of 4 runs" in capsys.readouterr().out
    with pytest.raises(FileNotFoundError, match="config.json"):
        experiment_status(tmp_path)


def test_shipped_weights_jobs(tiny_dataset, tmp_path):
    """A ``shipped`` job names the package's exported weights: open-loop and closed-loop jobs
    run them (the closed loop as ``v2xbench eval --agent NAME``: no agent config, so its results
    are those of the plain command), No Fusion's says it reads no messages, and AURORA's
    perception (which needs a training run's stages) is not available from them."""
    from v2xbench.agents.aurora.export import SHIPPED

    raw = {"name": "t", "methods": {"univ2x": {"agent": "univ2x", "baseline": "univ2x"},
                                    "no_fusion": {"agent": "no_fusion"}},
           "jobs": [{"id": "weights_{method}", "kind": "shipped", "method": "{method}",
                     "matrix": {"method": ["univ2x", "no_fusion"]}},
                    {"id": "data", "kind": "dataset", "path": str(tiny_dataset)},
                    {"id": "perc_no_fusion", "kind": "perception", "method": "no_fusion",
                     "run": "weights_no_fusion", "data": "data"},
                    {"id": "cl_univ2x", "kind": "closed_loop", "method": "univ2x",
                     "run": "weights_univ2x", "suite": "test50", "max_routes": 1,
                     "set": {"max_steps": 5}}]}
    st = run_experiments(parse_config(raw), tmp_path / "run")["jobs"]
    assert {k: r["status"] for k, r in st.items()} == {
        "weights_univ2x": "done", "weights_no_fusion": "done", "data": "done",
        "perc_no_fusion": "not available", "cl_univ2x": "done"}, st
    assert "final model" in st["perc_no_fusion"]["reason"]
    res = {k: json.loads((tmp_path / "run" / k / "result.json").read_text())
           for k in ("weights_univ2x", "weights_no_fusion")}
    assert Path(res["weights_no_fusion"]["outputs"]["run"]) == (SHIPPED / "no_fusion").resolve()
    assert res["weights_no_fusion"]["metrics"]["fusion"] is False
    assert res["weights_univ2x"]["metrics"]["manifest"]["method"] == "univ2x"
    fp = json.loads((tmp_path / "run" / "cl_univ2x" / "eval" / "run.json").read_text())["fingerprint"]
    assert not fp["components"]["agent_config"]  # the shipped weights: the agent's default
    with pytest.raises(ConfigError, match="weights_x"):
        parse_config({**raw, "jobs": raw["jobs"] + [
            {"id": "ol", "kind": "open_loop", "method": "univ2x", "run": "weights_x", "data": "data"}]})


def test_shipped_configs_validate():
    paper = load_config(shipped_config("paper"))
    quick = load_config(shipped_config("quick"))
    shipped = load_config(shipped_config("shipped"))  # the shipped weights, no training
    assert {j.kind for j in shipped.jobs} == {"shipped", "collect", "open_loop", "closed_loop"}
    assert {j.method for j in shipped.jobs if j.kind == "closed_loop" and j.get("seeds") == 3
            and j.get("suite") == "test50" and not j.get("max_routes")} == set(shipped.report["planning"])
    for cfg in (paper, quick):
        assert set(cfg.report) == {"perception", "planning", "fusion_ablation",
                                   "planner_ablation", "vqa_ablation", "per_scenario",
                                   "robustness"}
    methods = set(paper.methods)
    assert {"aurora", "no_fusion", "univ2x", "v2x_vit", "codriving", "unimm_v2x",
            "oracle_v2x"} <= methods
    lat = sorted({j.get("channel", {}).get("latency_ms") for j in paper.jobs
                  if j.kind == "closed_loop" and "latency_ms" in j.get("channel", {})})
    loss = sorted({j.get("channel", {}).get("loss_pct") for j in paper.jobs
                   if j.kind == "closed_loop" and "loss_pct" in j.get("channel", {})})
    assert lat == [100, 200, 500] and loss == [10, 30, 50]
