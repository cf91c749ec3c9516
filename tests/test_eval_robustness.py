"""An evaluation survives its agent and its files (issue 31, items 3, 4, 5, 8).

- a job that hangs ends as ``failure = "timeout"`` within ``--route-timeout`` and the other routes
  finish; an isolated agent stuck in ``act`` is killed with its worker;
- ``os._exit`` in the agent fails its job, a new worker runs the later ones; ``SystemExit`` and
  ``KeyboardInterrupt`` fail one job each, and ``eval`` exits 1 saying how many failed;
- an empty or truncated result file is run again with a warning naming it; stale temporary files
  are removed; results are fsynced;
- a second ``eval`` on the same ``--out`` is refused while the first runs (two processes), and
  the first one's worker exits when that run is killed;
- ``drive`` and ``eval`` refuse bad arguments before driving.

The misbehaving agent is a file written to ``tmp_path``; it picks what to do on a route from the
world seed in ``route_info`` (the tiny suite's routes ``tiny_k`` have seed ``10 + k``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from v2xbench.collectors import jobs as J
from v2xbench.collectors.evaluate import evaluate

from tests.test_evaluate import CFG, suite  # noqa: F401  (fixture)
from v2xbench import cli
from v2xbench.locks import DirectoryLocked, dir_lock

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 15.0  # --route-timeout of the hang tests; a 40-tick route takes ~1 s on an idle machine,
# up to ~10 s (isolated agent: its process starts and imports) while evaluations share the cores
SEED = {"tiny_0": 10, "tiny_1": 11, "tiny_2": 12}  # world seed of each route with seed index 0

MISBEHAVING = '''
import os
import sys
import time

import numpy as np

PLAN = {plan!r}  # world seed -> what to do at the third act()
PIDS = {pids!r}  # a file that collects the pid of every process the agent acts in


class Misbehaving:
    obs_mode, rsu_policy = "objects", "none"

    def reset(self, route_info):
        self.todo, self.ticks = PLAN.get(int(route_info["seed"])), 0
        if PIDS:
            with open(PIDS, "a") as f:
                f.write(f"{{os.getpid()}}\\n")

    def act(self, obs):
        self.ticks += 1
        if self.ticks == 3 and self.todo == "hang":
            while True:
                time.sleep(0.05)
        if self.ticks == 3 and self.todo == "os_exit":
            os._exit(7)
        if self.ticks == 3 and self.todo == "system_exit":
            sys.exit(3)
        if self.ticks == 3 and self.todo == "keyboard_interrupt":
            raise KeyboardInterrupt
        return np.array([0.3, 0.0, 0.0], np.float32)
'''


def _agent(tmp_path: Path, plan: dict[str, str], pids: Path | None = None) -> str:
    """Spec of a :data:`MISBEHAVING` agent doing ``plan[route_id]`` on those routes."""
    path = tmp_path / "misbehaving.py"
    path.write_text(MISBEHAVING.format(plan={SEED[r]: what for r, what in plan.items()},
                                       pids=str(pids) if pids else None))
    return f"{path}:Misbehaving"


def _results(out: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in sorted((out / "routes").glob("*.json"))}


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie nobody reaped counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        return state not in ("Z", "X")
    except FileNotFoundError:
        return False
    except (OSError, IndexError):  # pragma: no cover - no procfs
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True


def _assert_ok(result: dict) -> None:
    assert result["error"] is None and result["failure"] is None, result["error"]
    assert result["ticks"] == CFG["max_steps"]


# ------------------------------------------------------------------------------- item 3


@pytest.fixture(scope="module")
def warm(suite, tmp_path_factory):  # noqa: F811
    """One untimed route first: on a cold numba cache its worker compiles the kernels (a minute
    or more), which the timed routes below must not wait for."""
    evaluate("route_follower", suite, out=tmp_path_factory.mktemp("warm") / "out", config=CFG,
             max_routes=1, progress=False)


def test_hanging_agent_times_out_while_the_other_routes_finish(suite, warm, tmp_path):  # noqa: F811
    out = tmp_path / "out"
    t0 = time.monotonic()
    summary = evaluate(_agent(tmp_path, {"tiny_1": "hang"}), suite, out=out, config=CFG,
                       progress=False, route_timeout=TIMEOUT_S)
    wall = time.monotonic() - t0
    res = _results(out)
    assert sorted(res) == ["tiny_0_s0", "tiny_1_s0", "tiny_2_s0"]
    _assert_ok(res["tiny_0_s0"])
    _assert_ok(res["tiny_2_s0"])  # ran by the worker that replaced the killed one
    hung = res["tiny_1_s0"]
    assert hung["failure"] == "timeout" and hung["ended_by"] == "error"
    assert hung["error"].startswith("RouteTimeout:") and f"{TIMEOUT_S:g} s" in hung["error"]
    assert TIMEOUT_S <= hung["wall_seconds"] < TIMEOUT_S + 5.0  # killed within the limit + a poll
    assert hung["metrics"]["driving_score"] == 0.0
    assert wall < TIMEOUT_S + 60.0
    assert summary["failed"] == {"error": 0, "timeout": 1} and summary["metrics"]["n_crashed"] == 1
    assert summary["failures"] == [{"job_id": "tiny_1_s0", "failure": "timeout", "error": hung["error"]}]
    assert summary["run"]["timeouts"] == 1 and summary["run"]["workers_started"] == 2
    assert "(timeout): RouteTimeout" in (out / "summary.md").read_text()
    assert all(J.has_result(out, p.name) for p in (out / "claims").iterdir())  # none left open


def test_isolated_agent_stuck_in_act_is_killed_with_its_worker(suite, warm, tmp_path):  # noqa: F811
    pids = tmp_path / "pids.txt"
    out = tmp_path / "iso"
    summary = evaluate(_agent(tmp_path, {"tiny_0": "hang"}, pids), suite, out=out, config=CFG,
                       max_routes=2, progress=False, route_timeout=TIMEOUT_S, isolate_agent=True)
    res = _results(out)
    assert res["tiny_0_s0"]["failure"] == "timeout" and res["tiny_0_s0"]["agent_process"] == "isolated"
    _assert_ok(res["tiny_1_s0"])
    assert summary["failed"]["timeout"] == 1
    agent_pids = {int(x) for x in pids.read_text().split()}
    assert len(agent_pids) == 2 and os.getpid() not in agent_pids  # one per worker, not ours
    deadline = time.monotonic() + 5.0
    while any(_alive(p) for p in agent_pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in agent_pids)  # the hung agent process did not survive


def test_os_exit_in_agent_fails_one_job_and_later_jobs_run(suite, tmp_path):  # noqa: F811
    out = tmp_path / "out"
    summary = evaluate(_agent(tmp_path, {"tiny_0": "os_exit"}), suite, out=out, config=CFG,
                       progress=False)
    res = _results(out)
    dead = res["tiny_0_s0"]
    assert dead["failure"] == "error" and dead["ended_by"] == "error"
    assert dead["error"].startswith("WorkerDied:") and "exited with code 7" in dead["error"]
    _assert_ok(res["tiny_1_s0"])
    _assert_ok(res["tiny_2_s0"])
    assert summary["failed"] == {"error": 1, "timeout": 0} and summary["n_results"] == 3
    assert summary["run"]["workers_died"] == 1 and summary["run"]["workers_started"] == 2


def test_system_exit_and_keyboard_interrupt_fail_one_job_each(suite, tmp_path, capsys):  # noqa: F811
    out = tmp_path / "out"
    spec = _agent(tmp_path, {"tiny_0": "system_exit", "tiny_1": "keyboard_interrupt"})
    rc = cli.main(["eval", "--agent", spec, "--suite", suite, "--out", str(out), "--quiet",
                   *[f"--set={k}={v}" for k, v in CFG.items()]])
    err = capsys.readouterr().err
    assert rc == 1 and "2 of 3 route runs failed (2 error)" in err
    res = _results(out)
    assert res["tiny_0_s0"]["error"] == "AgentAborted: the agent raised SystemExit: 3"
    assert res["tiny_1_s0"]["error"] == "AgentAborted: the agent raised KeyboardInterrupt"
    assert "SystemExit" in res["tiny_0_s0"]["traceback"] and res["tiny_0_s0"]["ticks"] == 2
    assert res["tiny_1_s0"]["failure"] == "error"
    _assert_ok(res["tiny_2_s0"])
    run = json.loads((out / "summary.json").read_text())["run"]
    assert run["workers_started"] == 1 and run["workers_died"] == 0  # the worker went on
    iso = tmp_path / "iso"  # in an isolated agent's process as well
    summary = evaluate(spec, suite, out=iso, config=CFG, max_routes=2, progress=False,
                       isolate_agent=True)
    res = _results(iso)
    assert "SystemExit: 3" in res["tiny_0_s0"]["error"] and res["tiny_0_s0"]["ticks"] == 2
    assert "KeyboardInterrupt" in res["tiny_1_s0"]["error"]
    assert summary["failed"]["error"] == 2


class ExplodingPolicy(torch.nn.Module):
    """A TorchRL policy that raises while driving the first job of the queue (``job == 0``)."""

    def forward(self, ego: torch.Tensor, job: torch.Tensor) -> torch.Tensor:
        if bool((job == 0).all()) and float(ego.abs().sum()) > 0:
            raise RuntimeError("policy exploded")
        return torch.tensor([0.4, 0.0, 0.0]).expand(*ego.shape[:-1], 3).clone()


def test_policy_exception_fails_its_job_once_and_the_others_run(suite, tmp_path):  # noqa: F811
    from tensordict.nn import TensorDictModule

    policy = TensorDictModule(ExplodingPolicy(), in_keys=["ego", "job"], out_keys=["action"])
    summary = evaluate(policy, suite, out=tmp_path / "p", config=CFG, agent_name="exploding",
                       progress=False)
    res = _results(tmp_path / "p")
    assert res["tiny_0_s0"]["failure"] == "error" and "policy exploded" in res["tiny_0_s0"]["error"]
    _assert_ok(res["tiny_1_s0"])
    _assert_ok(res["tiny_2_s0"])
    assert summary["failed"] == {"error": 1, "timeout": 0} and summary["run"]["workers_died"] == 0


def test_workers_that_cannot_start_stop_the_run_instead_of_looping(suite, tmp_path):  # noqa: F811
    from v2xbench.collectors.eval_env import copy_policy, make_env_factory
    from v2xbench.collectors.eval_workers import MAX_FUTILE_STARTS, run_jobs

    jobs = J.make_jobs(["tiny_0"], seeds=1)  # EvalEnv refuses this config in every worker
    env_fn = make_env_factory(suite=suite, out=str(tmp_path), agent="route_follower", jobs=jobs,
                              config={"route_index": 0})
    with pytest.raises(RuntimeError, match=f"{MAX_FUTILE_STARTS} evaluation workers in a row"):
        run_jobs(env_fn, copy_policy(), workers=1, out=tmp_path, jobs=jobs,
                 record_failure=lambda *a: pytest.fail(f"no job ran, yet {a} failed"))
    assert not J.has_result(tmp_path, "tiny_0_s0")


# ------------------------------------------------------------------------------- item 4


@pytest.fixture(scope="module")
def damaged_resume(suite, tmp_path_factory):  # noqa: F811
    """Two routes evaluated, then result files emptied / truncated and temporary files of killed
    writers left behind; returns (out, results before, the warnings of the resume)."""
    out = tmp_path_factory.mktemp("damaged") / "out"
    evaluate("route_follower", suite, out=out, config=CFG, max_routes=2, progress=False)
    before = _results(out)
    r0, r1 = J.result_path(out, "tiny_0_s0"), J.result_path(out, "tiny_1_s0")
    r0.write_text("")
    r1.write_text(r1.read_text()[: r1.stat().st_size // 2])
    stale = [out / "routes" / ".tiny_0_s0.json.999999.tmp", out / ".summary.json.999999.tmp",
             out / "videos" / ".tiny_1_s0.gif.999999.tmp"]
    for p in stale:
        p.parent.mkdir(exist_ok=True)
        p.write_text("half")
    with pytest.warns(J.UnreadableResultWarning) as caught:
        summary = evaluate("route_follower", suite, out=out, config=CFG, max_routes=2, progress=False)
    return out, before, [str(w.message) for w in caught], stale, summary


def test_unreadable_result_is_named_and_run_again(damaged_resume):
    out, before, warned, _, summary = damaged_resume
    r0, r1 = J.result_path(out, "tiny_0_s0"), J.result_path(out, "tiny_1_s0")
    assert any(str(r0) in w and "is empty" in w for w in warned)
    assert any(str(r1) in w and "not valid JSON" in w for w in warned)
    after = _results(out)
    assert summary["run"]["jobs_run"] == 2 and summary["n_results"] == 2
    for jid in before:  # run again from the same seed: the same drive
        assert after[jid]["record"] == before[jid]["record"]
    with pytest.raises(ValueError, match=r"tiny_0_s0\.json.*not valid JSON"):
        r0.write_text('{"job_id": "tiny_0_s0", "metr')
        J.read_result(out, "tiny_0_s0")


def test_stale_tmp_files_are_removed(damaged_resume):
    out, _, _, stale, _ = damaged_resume
    assert not any(p.exists() for p in stale)
    assert not list(out.rglob("*.tmp"))


def test_results_videos_and_summaries_are_fsynced(tmp_path, monkeypatch):
    import numpy as np
    from v2xbench.envs.v2x_intersection.render.video import save_video

    import v2xbench.files as files

    synced = []
    real = os.fsync
    monkeypatch.setattr(files.os, "fsync", lambda fd: (synced.append(fd), real(fd)))
    J.write_json_atomic({"x": float("nan")}, tmp_path / "r.json")
    assert len(synced) >= 1 and json.loads((tmp_path / "r.json").read_text()) == {"x": None}
    n = len(synced)
    save_video([np.zeros((8, 8, 3), np.uint8)] * 2, tmp_path / "v.gif")
    assert len(synced) > n and (tmp_path / "v.gif").read_bytes()[:3] == b"GIF"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json", "v.gif"]  # no temporaries


# ------------------------------------------------------------------------------- item 5


def test_second_concurrent_eval_is_refused_and_workers_die_with_their_run(suite, tmp_path,  # noqa: F811
                                                                          capsys):
    out = tmp_path / "shared_out"
    spec = _agent(tmp_path, {"tiny_0": "hang"})
    code = "import sys; from v2xbench import cli; sys.exit(cli.main(sys.argv[1:]))"
    log = (tmp_path / "first.log").open("wb")
    first = subprocess.Popen(
        [sys.executable, "-c", code, "eval", "--agent", spec, "--suite", suite, "--out", str(out),
         "--max-routes", "1", "--quiet", "--route-timeout", "300",
         *[f"--set={k}={v}" for k, v in CFG.items()]],
        cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        claim = J.claims_dir(out) / "tiny_0_s0"
        deadline = time.monotonic() + 180.0
        while not (claim.is_file() and claim.read_text().strip()):
            assert first.poll() is None, (tmp_path / "first.log").read_text()[-2000:]
            assert time.monotonic() < deadline, "the first eval never started its route"
            time.sleep(0.2)
        worker = int(claim.read_text())
        rc = cli.main(["eval", "--agent", "route_follower", "--suite", suite, "--out", str(out),
                       "--max-routes", "1", "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2 and f"in use by pid {first.pid}" in err and "evaluation" in err
        with pytest.raises(DirectoryLocked, match=f"pid {first.pid}"):
            evaluate("route_follower", suite, out=out, max_routes=1, progress=False)
        assert not J.has_result(out, "tiny_0_s0")  # the refused runs touched nothing
        assert claim.read_text().strip() == str(worker)
        first.kill()  # SIGKILL: no clean-up in the first run; its worker must notice by itself
        first.wait(timeout=30)
        deadline = time.monotonic() + 10.0
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(worker), "the worker outlived its killed evaluation"
        with dir_lock(out, "evaluation"):  # the kernel released the dead run's lock
            pass
    finally:
        if first.poll() is None:
            os.killpg(first.pid, signal.SIGKILL)
            first.wait(timeout=30)
        log.close()


# ------------------------------------------------------------------------------- item 8


@pytest.mark.parametrize("args, message", [
    (["--frame-every", "0"], "--frame-every 0 must be >= 1"),
    (["--seed", "-1"], "--seed -1 must be in"),
    (["--sensors-every", "-2"], "--sensors-every -2 must be >= 0"),
    (["--size", "0"], "--size 0 must be a positive"),
])
def test_drive_refuses_bad_arguments_before_driving(tmp_path, capsys, args, message):
    out = tmp_path / "drive"
    t0 = time.perf_counter()
    assert cli.main(["drive", "--out", str(out), "--quiet", *args]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() and time.perf_counter() - t0 < 5.0  # nothing was built or driven


def test_drive_and_eval_refuse_an_output_path_through_a_file(suite, tmp_path, capsys):  # noqa: F811
    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    assert cli.main(["drive", "--out", str(afile / "sub"), "--quiet"]) == 2
    assert f"{afile / 'sub'} cannot be created: {afile} is a file" in capsys.readouterr().err
    assert cli.main(["eval", "--suite", suite, "--out", str(afile), "--quiet"]) == 2
    assert f"{afile} is a file, not a directory" in capsys.readouterr().err
    assert cli.main(["eval", "--suite", suite, "--out", str(tmp_path / "e"), "--route-timeout", "0",
                     "--quiet"]) == 2
    assert "route_timeout=0.0 must be a positive finite number" in capsys.readouterr().err
    assert afile.read_text() == "not a folder" and not (tmp_path / "e").exists()
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "run.json").write_text('{"agent": "route_')
    with pytest.raises(ValueError, match=r"run\.json is unreadable"):
        evaluate("route_follower", suite, out=bad, max_routes=1, progress=False)
