"""Tests of the closed-loop evaluation harness (collectors/evaluate.py, eval_env.py, leaderboard.py).

A tiny suite of three short routes in Town01, small populations and a 40-tick time budget keep
every evaluation to a few seconds; the two-worker run (spawned processes) dominates the time.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import check_env_specs
from v2xbench.collectors import jobs as J
from v2xbench.collectors.eval_env import EvalEnv
from v2xbench.collectors.evaluate import evaluate
from v2xbench.collectors.leaderboard import build_leaderboard
from v2xbench.envs.v2x_intersection.evaluation.metrics import RouteRecord, compute_metrics
from v2xbench.envs.v2x_intersection.suites.route_files import (
    SUITE_FORMAT,
    parse_route,
    save_json_atomic,
)

from v2xbench import cli
from v2xbench.platform_info import run_platform

CFG = {"num_vehicles": 3, "num_parked": 2, "num_pedestrians": 2, "num_bicycles": 0, "max_steps": 40}
CANDIDATES = ("PedestrianCrossing", "ParkedObstacle", "DynamicObjectCrossing", "Accident",
              "HardBreakRoute", "ParkingCrossingPedestrian")
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "my_agent.py"

FLAKY_AGENT = '''
import numpy as np

START_1, START_2 = {start_1}, {start_2}  # first route points of tiny_1 and tiny_2


class FlakyAgent:
    """Drives slowly on route tiny_0, raises in act() on tiny_1, raises in reset() on tiny_2
    (it tells the routes apart by where they start: route_info has no route id)."""
    obs_mode, privileged, rsu_policy = "objects", False, "none"

    def reset(self, route_info):
        start = np.asarray(route_info["route_points"][0])
        self.route, self.ticks = 0, 0
        for k, p in ((1, START_1), (2, START_2)):
            if np.allclose(start, p, atol=1e-6):
                self.route = k
        if self.route == 2:
            raise RuntimeError("reset exploded")

    def act(self, obs):
        self.ticks += 1
        if self.route == 1 and self.ticks > 5:
            raise ValueError("boom in act")
        return np.array([0.3, 0.0, 0.0], np.float32)
'''


def route_starts(suite: str) -> list[tuple[float, float]]:
    """First route point of each route of a suite file."""
    from v2xbench.envs.v2x_intersection.suites.route_files import (
        build_episode_from_spec,
        load_suite_cached,
    )

    return [tuple(float(v) for v in build_episode_from_spec(s)[0].points[0]) for s in load_suite_cached(suite)]


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> str:
    """A suite JSON of three short Town01 routes, one scenario each."""
    from v2xbench.envs.v2x_intersection.suites.suites_build import compose_route
    from v2xbench.envs.v2x_intersection.town import get_town

    town, rng = get_town("Town01"), np.random.default_rng(0)
    routes = []
    for name in CANDIDATES:
        d = compose_route(town, rng, [name], f"tiny_{len(routes)}", seed=10 + len(routes))
        if d is not None:
            parse_route(d)
            routes.append(d)
        if len(routes) == 3:
            break
    assert len(routes) == 3, "could not compose three test routes"
    path = tmp_path_factory.mktemp("suite") / "tiny.json"
    save_json_atomic({"format": SUITE_FORMAT, "name": "tiny", "split": "tiny", "routes": routes}, path)
    return str(path)


@pytest.fixture(scope="module")
def rf_run(suite, tmp_path_factory) -> tuple[Path, dict]:
    """The route follower on the tiny suite, one worker."""
    out = tmp_path_factory.mktemp("rf") / "route_follower"
    return out, evaluate("route_follower", suite, seeds=1, workers=1, out=out, config=CFG, progress=False)


@pytest.fixture(scope="module")
def flaky_run(suite, tmp_path_factory) -> tuple[Path, dict]:
    """An agent that fails on two of the three routes."""
    d = tmp_path_factory.mktemp("flaky")
    starts = route_starts(suite)
    (d / "flaky.py").write_text(FLAKY_AGENT.format(start_1=starts[1], start_2=starts[2]))
    out = d / "out"
    return out, evaluate(f"{d / 'flaky.py'}:FlakyAgent", suite, out=out, config=CFG, progress=False)


def _results(out: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in sorted((out / "routes").glob("*.json"))}


def test_one_result_per_job_and_summary(rf_run):
    out, summary = rf_run
    res = _results(out)
    assert sorted(res) == ["tiny_0_s0", "tiny_1_s0", "tiny_2_s0"]
    for jid, r in res.items():
        assert r["job_id"] == jid and r["agent"] == "route_follower" and r["error"] is None
        assert r["privileged"] is False and r["agent_process"] == "in_process"
        assert r["ended_by"] in ("timeout", "completed") and r["ticks"] <= CFG["max_steps"]
        assert r["town"] == "Town01" and len(r["scenario_types"]) == len(r["scenarios"]) == 1
        assert set(r["scenarios"][0]) >= {"type", "triggered", "passed", "timed_out", "collision", "success"}
        rec = RouteRecord.from_dict(r["record"])  # the stored record round-trips and gives the metrics
        m = compute_metrics(rec)
        assert m["driving_score"] == pytest.approx(r["metrics"]["driving_score"])
        assert len(rec.ego_speed) == r["ticks"] and rec.seed == r["seed"]
        assert r["platform"] == run_platform() and r["platform"]["numpy"] == np.__version__
    assert not list((out / "routes").glob("*.tmp"))
    assert summary["n_results"] == summary["n_jobs"] == 3 and summary["agent_process"] == "in_process"
    ds = np.mean([r["metrics"]["driving_score"] for r in res.values()])
    assert summary["metrics"]["driving_score"] == pytest.approx(ds)
    assert summary["metrics"]["driving_score_ci_low"] <= ds <= summary["metrics"]["driving_score_ci_high"]
    assert set(summary["per_scenario"]) == {r["scenario_types"][0] for r in res.values()}
    assert all(v["instances"] == 1 for v in summary["per_scenario"].values())
    assert json.loads((out / "summary.json").read_text())["n_results"] == 3
    md = (out / "summary.md").read_text()
    assert "Driving score" in md and "scenario type" in md


def test_resume_reruns_only_missing_job(rf_run, tmp_path):
    src, _ = rf_run
    out = tmp_path / "resume"
    shutil.copytree(src, out)
    before = _results(out)
    (out / "routes" / "tiny_1_s0.json").unlink()
    mtimes = {p.name: p.stat().st_mtime_ns for p in (out / "routes").glob("*.json")}
    evaluate("route_follower", str(json.loads((out / "run.json").read_text())["suite"]), out=out,
             config=CFG, progress=False)
    after = _results(out)
    assert sorted(after) == sorted(before)
    for name, t in mtimes.items():
        assert (out / "routes" / name).stat().st_mtime_ns == t  # untouched
    assert after["tiny_1_s0"]["record"] == before["tiny_1_s0"]["record"]  # same seed, same drive
    with pytest.raises(ValueError, match="agent"):  # another agent may not write into this dir
        evaluate("random", after["tiny_1_s0"]["suite"], out=out, config=CFG, progress=False)


def test_agent_exceptions_are_route_failures(flaky_run):
    out, summary = flaky_run
    res = _results(out)
    assert len(res) == 3
    ok, act_err, reset_err = res["tiny_0_s0"], res["tiny_1_s0"], res["tiny_2_s0"]
    assert ok["error"] is None and ok["ticks"] == CFG["max_steps"]
    assert act_err["ended_by"] == "error" and "boom in act" in act_err["error"]
    assert "ValueError" in act_err["traceback"] and act_err["ticks"] == 5
    assert act_err["metrics"]["driving_score"] == 0.0
    assert reset_err["ended_by"] == "error" and "reset exploded" in reset_err["error"]
    assert reset_err["ticks"] == 0 and reset_err["metrics"]["driving_score"] == 0.0
    assert summary["metrics"]["n_crashed"] == 2
    assert summary["metrics"]["driving_score"] == pytest.approx(ok["metrics"]["driving_score"] / 3)
    assert {f["job_id"] for f in summary["failures"]} == {"tiny_1_s0", "tiny_2_s0"}
    assert summary["ended_by"]["error"] == 2


def test_two_workers_match_one_worker(rf_run, suite, tmp_path):
    ref, _ = rf_run
    out = tmp_path / "w2"
    summary = evaluate("route_follower", suite, seeds=1, workers=2, out=out, config=CFG, progress=False)
    one, two = _results(ref), _results(out)
    assert sorted(one) == sorted(two)
    for jid in one:
        for key in ("record", "metrics", "scenarios", "ended_by", "seed"):
            assert one[jid][key] == two[jid][key], (jid, key)
    assert summary["run"]["workers"] == 2 and summary["n_results"] == 3


def test_example_agent_via_cli_with_video(suite, tmp_path, capsys):
    out = tmp_path / "cautious"
    rc = cli.main(["eval", "--agent", f"{EXAMPLE}:CautiousDriver", "--suite", suite, "--out", str(out),
                   "--max-routes", "1", "--video", "--quiet", "--set", "max_steps=30",
                   "--set", "num_vehicles=3", "--set", "num_pedestrians=2"])
    assert rc == 0
    (r,) = _results(out).values()
    assert r["agent_name"] == "CautiousDriver" and r["error"] is None and r["ticks"] == 30
    assert r["config_overrides"] == {"max_steps": 30, "num_vehicles": 3, "num_pedestrians": 2}
    assert Path(r["video"]).is_file() and Path(r["video"]).suffix == ".gif"
    assert "CautiousDriver" in capsys.readouterr().out


def test_plain_torchrl_policy(suite, tmp_path):
    lin = torch.nn.Linear(9, 3)
    with torch.no_grad():
        lin.weight.zero_()
        lin.bias.copy_(torch.tensor([0.6, 0.0, 0.0]))
    policy = TensorDictModule(lin, in_keys=["ego"], out_keys=["action"])
    summary = evaluate(policy, suite, out=tmp_path / "lin", max_routes=1, config=CFG, agent_name="linear",
                       progress=False)
    (r,) = _results(tmp_path / "lin").values()
    assert r["agent_name"] == "linear" and r["error"] is None and r["ticks"] == CFG["max_steps"]
    assert max(r["record"]["ego_speed"]) > 1.0  # the policy's throttle drove the car
    assert summary["n_routes"] == 1


def test_env_specs_and_idle_queue(suite, tmp_path):
    env = EvalEnv(suite, tmp_path / "specs", agent="route_follower", max_routes=1, config=CFG)
    check_env_specs(env)
    env.close()
    assert not list((tmp_path / "specs" / "claims").iterdir())  # close() released the unfinished job
    idle = EvalEnv(suite, tmp_path / "idle", agent="route_follower", jobs=[], config=CFG)
    td = idle.reset()
    assert td["job"].item() == -1 and not td["done"].item()
    td = idle.step(td.set("action", torch.zeros(3)))
    assert td["next", "done"].item() and idle.world.ended  # nothing was simulated


def test_claims_are_exclusive_and_stale_ones_cleared(tmp_path):
    jobs = J.make_jobs(["a", "b"], seeds=2)
    assert [j.job_id for j in jobs] == ["a_s0", "b_s0", "a_s1", "b_s1"]
    assert J.job_seed(7, 2) == 2007
    assert J.try_claim(tmp_path, "a_s0") and not J.try_claim(tmp_path, "a_s0")
    assert J.try_claim(tmp_path, "b_s0")
    J.write_json_atomic({"job_id": "b_s0", "ended_by": "completed", "metrics": {"x": float("nan")},
                         "scenarios": [], "ticks": 0}, J.result_path(tmp_path, "b_s0"))
    assert np.isnan(J.read_result(tmp_path, "b_s0")["metrics"]["x"])  # NaN stored as null
    assert J.clear_stale_claims(tmp_path) == ["a_s0"]
    assert J.count_results(tmp_path, jobs) == 1


def test_leaderboard_from_two_runs(rf_run, flaky_run, tmp_path, capsys):
    (rf, _), (fl, _) = rf_run, flaky_run
    res = build_leaderboard([rf, fl, tmp_path / "missing"], tmp_path / "lb")
    rows = res["rows"]
    assert [r["agent"] for r in rows] == ["route_follower", "FlakyAgent"]  # sorted by DS
    md = Path(res["markdown"]).read_text()
    assert "route_follower" in md and "FlakyAgent" in md and "Per scenario type" in md
    assert rows[0]["driving_score"] >= rows[1]["driving_score"]
    if res["note"] is None:
        assert len(res["plots"]) == 4 and all(Path(p).stat().st_size > 0 for p in res["plots"])
    assert cli.main(["leaderboard", str(rf), str(fl), "--out", str(tmp_path / "lb2"), "--no-plots"]) == 0
    assert "V2X-type DS" in capsys.readouterr().out
    with pytest.raises(ValueError, match="summary"):
        build_leaderboard([tmp_path / "missing"], tmp_path / "lb3")


def test_leaderboard_common_scores_every_folder_on_the_shared_runs(rf_run, flaky_run, tmp_path):
    from v2xbench.collectors.leaderboard import common_runs, world_settings

    (rf, _), (fl, _) = rf_run, flaky_run
    part = tmp_path / "part"  # an evaluation still running: tiny_2 not done yet
    shutil.copytree(rf, part)
    (part / "routes" / "tiny_2_s0.json").unlink()
    assert common_runs([rf, fl, part]) == (json.loads((rf / "run.json").read_text())["suite"],
                                           ["tiny_0", "tiny_1"], 1)
    res = build_leaderboard([rf, fl, part], tmp_path / "lb", plots=False, common=True)
    rows = {r["run"]: r for r in res["rows"]}
    assert len(res["groups"]) == 1 and "runs all 3 folders hold" in res["groups"][0]
    assert all(r["n_routes"] == 2 and r["n_results"] == 2 for r in rows.values())
    by_run = _results(rf)
    mean = np.mean([by_run[j]["metrics"]["driving_score"] for j in ("tiny_0_s0", "tiny_1_s0")])
    assert rows["route_follower"]["driving_score"] == pytest.approx(mean)
    assert rows["part"]["driving_score"] == rows["route_follower"]["driving_score"]
    assert "| 2 x 1 |" in Path(res["markdown"]).read_text()
    only2 = tmp_path / "only2"
    shutil.copytree(rf, only2)
    for j in ("tiny_0_s0", "tiny_1_s0"):
        (only2 / "routes" / f"{j}.json").unlink()
    with pytest.raises(ValueError, match="share no run"):
        common_runs([part, only2])
    with pytest.raises(ValueError, match="two or more"):
        common_runs([rf])
    other = tmp_path / "other_suite"
    shutil.copytree(rf, other)
    m = json.loads((other / "run.json").read_text())
    (other / "run.json").write_text(json.dumps({**m, "suite": "test50"}))
    with pytest.raises(ValueError, match="one suite"):
        common_runs([rf, other])
    # the payload limit a method declares for its messages does not split the table
    assert world_settings({"max_payload_floats": 1494, "num_vehicles": 3}) == {"num_vehicles": 3}


def test_lost_claim_is_recovered_when_all_workers_idle(suite, tmp_path):
    from v2xbench.collectors.eval_env import copy_policy, make_env_factory
    from v2xbench.collectors.eval_workers import run_jobs

    out = tmp_path / "lost"
    jobs = J.make_jobs(["tiny_0", "tiny_1"], seeds=1)
    assert J.try_claim(out, "tiny_0_s0")  # a claim no worker will ever finish
    env_fn = make_env_factory(suite=suite, out=str(out), agent="route_follower", jobs=jobs, config=CFG)
    failures = []
    stats = run_jobs(env_fn, copy_policy(), workers=1, out=out, jobs=jobs, frames_per_batch=32,
                     record_failure=lambda *a: failures.append(a))  # returns once both have results
    assert J.count_results(out, jobs) == 2 and not failures
    assert stats["workers_started"] == 2  # the second took the claim freed when the first was done


def test_tensordict_policy_agent_drives_through_the_interface():
    import gymnasium as gym
    import torch
    from tensordict.nn import TensorDictModule
    from v2xbench.agents.interface import to_control
    from v2xbench.agents.torchrl_policy import TensorDictPolicyAgent

    torch.manual_seed(0)
    env = gym.make("v2xbench:V2XIntersection-v0", num_vehicles=2, num_pedestrians=0)
    obs, _ = env.reset(seed=0)
    net = torch.nn.Linear(obs["ego"].shape[0], 3)
    agent = TensorDictPolicyAgent(TensorDictModule(net, in_keys=["ego"], out_keys=["action"]))
    agent.reset({})
    a = agent.act(obs)
    expect = net(torch.as_tensor(obs["ego"]).float()).detach().numpy()
    assert a.shape == (3,) and np.allclose(a, expect, atol=1e-6)
    env.step(np.clip(to_control(a, obs), [0, -1, 0], [1, 1, 1]))
    wp = TensorDictPolicyAgent(TensorDictModule(torch.nn.Linear(obs["ego"].shape[0], 16), in_keys=["ego"],
                                                out_keys=["action"]), waypoints=True)
    out = wp.act(obs)
    assert out["waypoints"].shape == (8, 2) and to_control(out, obs).shape == (3,)
    bad = TensorDictPolicyAgent(TensorDictModule(torch.nn.Linear(obs["ego"].shape[0], 3), in_keys=["ego"],
                                                 out_keys=["other"]))
    with pytest.raises(KeyError, match="action"):
        bad.act(obs)


def test_leaderboard_ranks_comparable_runs_together(rf_run, flaky_run, suite, tmp_path,
                                                    monkeypatch):
    import os

    from v2xbench.collectors.eval_summary import sensor_settings
    from v2xbench.collectors.leaderboard import world_settings

    import v2xbench.files as files

    (rf, rf_summary), (fl, _) = rf_run, flaky_run
    assert (rf_summary["obs_mode"], rf_summary["rsu_policy"], rf_summary["action_mode"]) == (
        "objects", "share_objects", "carla")
    one = tmp_path / "one_route"
    evaluate("route_follower", suite, out=one, routes="tiny_0", config=CFG, progress=False)
    old = tmp_path / "old"  # a summary written before these fields existed
    shutil.copytree(rf, old)
    s = json.loads((old / "summary.json").read_text())
    for k in ("obs_mode", "rsu_policy", "action_mode", "sensors", "selection", "fingerprint",
              "agent_config"):
        s.pop(k)
    (old / "summary.json").write_text(json.dumps(s))
    synced = []
    real = os.fsync
    monkeypatch.setattr(files.os, "fsync", lambda fd: (synced.append(fd), real(fd)))
    res = build_leaderboard([rf, fl, one, old], tmp_path / "lb")
    assert len(synced) >= 2 + (0 if res["note"] else 4 * len(res["groups"]))  # every file atomic
    rows = {r["run"]: r for r in res["rows"]}
    assert rows["route_follower"]["group"] == rows["out"]["group"]  # flaky's dir is "out"
    assert len({rows[k]["group"] for k in rows}) == 3 and len(res["groups"]) == 3
    assert rows["out"]["rsu_policy"] == "none"
    assert rows["route_follower"]["rsu_policy"] == "share_objects"
    assert rows["one_route"]["rank"] == 1
    assert rows["one_route"]["selection"] == "routes tiny_0"
    assert {rows["route_follower"]["rank"], rows["out"]["rank"]} == {1, 2}
    assert rows["old"]["obs_mode"] == "unknown" and rows["old"]["selection"] == "all 3 routes"
    assert rows["route_follower"]["sensors"] == {} and rows["one_route"]["n_routes"] == 1
    md = Path(res["markdown"]).read_text()
    assert md.count("\n## ") == 3 and "`objects` track on" in md and "`unknown` track on" in md
    assert "| 3 x 1 |" in md and "| 1 x 1 |" in md and "| share_objects | default |" in md
    assert not list((tmp_path / "lb").glob(".*"))  # no temporaries left
    if res["note"] is None:
        assert len(res["plots"]) == 12 and Path(res["plots"][0]).name == "driving_score_g1.png"
    cfg = {"camera_size": [256, 128], "lidar_scale": 0.5, "num_vehicles": 3, "rsu_policy": "none"}
    assert sensor_settings(cfg) == {"camera_size": [256, 128], "lidar_scale": 0.5}
    assert world_settings(cfg) == {"num_vehicles": 3}


def test_each_agent_gets_its_own_default_results_folder(tmp_path, monkeypatch):
    """Without --out, eval writes to results/<agent name>, so a second agent does not meet the
    first one's results (a file:Class agent is named by its class)."""
    from v2xbench.cli import main
    from v2xbench.cli.evaluation import default_out_name

    assert default_out_name("expert") == "expert"
    assert default_out_name("examples/my_agent.py:CautiousDriver") == "CautiousDriver"
    assert default_out_name("../weird name!") == "weird_name"
    monkeypatch.chdir(tmp_path)
    for agent in ("route_follower", "expert"):
        assert main(["eval", "--agent", agent, "--suite", "val", "--max-routes", "1",
                     "--quiet"]) == 0
        assert (tmp_path / "results" / agent / "summary.json").is_file()
