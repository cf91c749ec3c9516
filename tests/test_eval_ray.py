"""The Ray backend of ``v2xbench eval`` (issue 35, item 3; ``collectors/eval_ray.py``).

- three short test50 routes give the same per-route results (metrics, events, scenario outcomes,
  everything but wall-clock time) as Ray tasks on a local 2-CPU Ray instance as with the local
  worker processes; an interrupted Ray run resumes (only the missing job runs) and a complete one
  runs nothing; the summary records the backend;
- a ``path.py:Class`` agent with ``--agent-config``, ``--isolate-agent`` and ``--set`` runs on Ray
  as locally; an agent that kills its Ray worker (``os._exit``) fails its route alone;
- without Ray installed ``--backend ray`` is refused naming ``pip install -e ".[ray]"``,
  ``--address`` needs ``--backend ray``, and an address where nothing answers is refused, all
  before anything is written.

Ray comes with the ``dev`` extra, so CI runs all of it; the module is skipped only where Ray is
not installed (a user without the ``ray`` extra).
"""

from __future__ import annotations

import json
import socket
import sys
from pathlib import Path

import pytest
from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

from v2xbench import cli

ray = pytest.importorskip("ray", reason='the Ray backend needs the extra: pip install -e ".[ray]"')

ROUTES = ["test50_025", "test50_034", "test50_016"]  # the three shortest routes of test50
WALL_CLOCK = ("wall_seconds",)  # the only fields that may differ between two runs of a job


@pytest.fixture
def ray_down():
    """Ray is not running before the test, and is shut down after it whatever happens."""
    if ray.is_initialized():
        ray.shutdown()
    yield
    if ray.is_initialized():
        ray.shutdown()


def _eval(out: Path, routes: list[str], *extra: str, agent: str = "route_follower") -> int:
    return cli.main(["eval", "--agent", agent, "--suite", "test50", "--routes", ",".join(routes),
                     "--workers", "2", "--out", str(out), "--quiet", *extra])


def _results(out: Path) -> dict[str, dict]:
    """The result of each job of ``out``, without its wall-clock fields."""
    res = {}
    for p in sorted((out / "routes").glob("*.json")):
        d = json.loads(p.read_text())
        for k in WALL_CLOCK:
            d.pop(k)
        res[p.stem] = d
    return res


def _mtimes(out: Path) -> dict[str, int]:
    return {p.stem: p.stat().st_mtime_ns for p in (out / "routes").glob("*.json")}


def _run_info(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())["run"]


@pytest.mark.timeout(1500)  # Ray's start-up and 2 workers: ~2 min idle, >10 min on a loaded machine
def test_ray_results_match_local_and_resume(tmp_path, ray_down):
    local, on_ray = tmp_path / "local", tmp_path / "ray"
    assert _eval(local, ROUTES) == 0
    assert _run_info(local)["backend"] == "local" and "ray_address" not in _run_info(local)
    # an interrupted Ray run: two of the three jobs (same fingerprint: the selection is no part)
    assert _eval(on_ray, ROUTES[:2], "--backend", "ray") == 0
    assert not ray.is_initialized()  # the local instance the backend started is shut down
    run = _run_info(on_ray)
    assert run["backend"] == "ray" and run["ray_address"] is None and run["ray_cpus"] == 2
    assert run["jobs_run"] == 2 and run["workers_started"] == 2
    first = _mtimes(on_ray)
    assert _eval(on_ray, ROUTES, "--backend", "ray") == 0  # resumes: only the missing job runs
    assert _run_info(on_ray)["jobs_run"] == 1 and _run_info(on_ray)["workers_started"] == 1
    assert {k: v for k, v in _mtimes(on_ray).items() if k in first} == first
    expected, got = _results(local), _results(on_ray)
    assert sorted(got) == [f"{r}_s0" for r in sorted(ROUTES)] and sorted(expected) == sorted(got)
    for job in expected:
        assert got[job]["metrics"] == expected[job]["metrics"], job
        assert got[job]["record"] == expected[job]["record"], job  # per-tick events, infractions
        assert got[job] == expected[job], job
    assert not list(on_ray.glob("claims/*"))
    assert not list(on_ray.glob("**/.*.tmp*"))
    before = _mtimes(on_ray)
    assert _eval(on_ray, ROUTES, "--backend", "ray") == 0  # complete: skips every job
    assert _mtimes(on_ray) == before and _run_info(on_ray)["jobs_run"] == 0
    summary = {k: v for k, v in json.loads((on_ray / "summary.json").read_text()).items()
               if k != "run"}
    local_summary = {k: v for k, v in json.loads((local / "summary.json").read_text()).items()
                     if k != "run"}
    assert summary == local_summary  # the same tables and bootstrap CIs


AGENT = """
import os

import numpy as np

CRASH_SEED = {crash_seed}


class Careful:
    obs_mode, rsu_policy = "objects", "none"

    def __init__(self, token=None, crash=False):
        if token != "from-agent-config":
            raise ValueError(f"token {{token!r}}: --agent-config did not reach the agent")
        self.crash = crash

    def reset(self, route_info):
        self.seed = int(route_info["seed"])

    def act(self, obs):
        if self.seed == CRASH_SEED:
            if self.crash:
                os._exit(3)  # kills the process the agent runs in
            raise RuntimeError("this route fails")
        return np.array([0.3, 0.0, 0.0], np.float32)
"""


@pytest.mark.timeout(1500)  # Ray's start-up and 2 workers: ~2 min idle, >10 min on a loaded machine
def test_file_agent_config_isolation_and_crash_on_ray(tmp_path, ray_down, capsys):
    seeds = {s.id: s.seed for s in load_suite_cached("test50")}
    path = tmp_path / "careful.py"
    path.write_text(AGENT.format(crash_seed=seeds[ROUTES[1]]))
    spec, routes = f"{path}:Careful", ROUTES[:2]
    conf = tmp_path / "conf.json"
    conf.write_text(json.dumps({"token": "from-agent-config"}))
    common = ("--agent-config", str(conf), "--set", "max_steps=15", "--set", "num_vehicles=2")
    ray.init(address="local", num_cpus=2, include_dashboard=False)  # the backend uses it
    iso = tmp_path / "iso"
    assert _eval(iso, routes, *common, "--isolate-agent", "--backend", "ray", agent=spec) == 1
    assert ray.is_initialized()  # not the backend's to shut down
    ok, bad = (json.loads((iso / "routes" / f"{r}_s0.json").read_text()) for r in routes)
    assert ok["failure"] is None and ok["ticks"] == 15 and ok["agent_process"] == "isolated"
    assert ok["config_overrides"]["max_steps"] == 15 and ok["agent"] == spec
    assert bad["failure"] == "error" and "this route fails" in bad["error"]
    local = tmp_path / "iso_local"
    assert _eval(local, routes, *common, "--isolate-agent", agent=spec) == 1
    assert _results(local) == _results(iso)
    # in the Ray worker's process: os._exit kills the worker, which fails that route alone
    crash = tmp_path / "conf_crash.json"
    crash.write_text(json.dumps({"token": "from-agent-config", "crash": True}))
    out = tmp_path / "crash"
    capsys.readouterr()
    assert _eval(out, routes, "--agent-config", str(crash), "--set", "max_steps=15",
                 "--backend", "ray", agent=spec) == 1
    ok, bad = (json.loads((out / "routes" / f"{r}_s0.json").read_text()) for r in routes)
    assert ok["failure"] is None and ok["ticks"] == 15 and ok["agent_process"] == "in_process"
    assert bad["failure"] == "error" and "Ray worker running this job died" in bad["error"]
    assert _run_info(out)["workers_died"] == 1
    assert "1 of 2 route runs failed (1 error)" in capsys.readouterr().err


def test_missing_ray_and_address_without_ray_backend(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    out = tmp_path / "out"
    assert _eval(out, ROUTES[:1], "--backend", "ray") == 2
    err = capsys.readouterr().err
    assert "--backend ray needs Ray" in err and 'pip install -e ".[ray]"' in err
    assert not out.exists()  # refused before anything was written
    monkeypatch.undo()
    assert _eval(out, ROUTES[:1], "--address", "127.0.0.1:6379") == 2
    assert "--address '127.0.0.1:6379' is the address of a Ray cluster: it needs --backend ray" in (
        capsys.readouterr().err)
    assert not out.exists()
    with socket.socket() as s:  # a port where nothing listens
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert _eval(out, ROUTES[:1], "--backend", "ray", "--address", f"127.0.0.1:{port}") == 2
    assert f"no Ray cluster answers at 127.0.0.1:{port}" in capsys.readouterr().err
    assert not out.exists() and not ray.is_initialized()
