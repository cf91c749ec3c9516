"""Agents the harness does not have to trust (issue 29, item 7; ``route_info`` of item 3).

- privilege is granted by the harness (``interface.PRIVILEGED_AGENTS``), never by the agent;
- ``--isolate-agent`` runs the agent in its own process: it finds no live ``World`` there, its
  failures are route failures, and a deterministic agent drives exactly as in-process;
- ``route_info`` carries the route and its commands, no route id or scenario data.

Routes are the three-route tiny suite of ``test_evaluate`` with a 10-40 tick budget.
"""

from __future__ import annotations

import functools
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
from v2xbench.agents.expert import Expert
from v2xbench.agents.interface import (
    AGENTS,
    PRIVILEGED_AGENTS,
    ROUTE_INFO_KEYS,
    complete_agent,
    granted_privilege,
    load_agent,
)
from v2xbench.collectors import jobs as J
from v2xbench.collectors.agent_fingerprint import code_digests
from v2xbench.collectors.agent_process import AgentProcessError, IsolatedAgent
from v2xbench.collectors.eval_env import EvalEnv
from v2xbench.collectors.evaluate import evaluate
from v2xbench.collectors.leaderboard import build_leaderboard
from v2xbench.envs.v2x_intersection.evaluation.metrics import ENDED_TIMEOUT

from tests.test_evaluate import CFG, FLAKY_AGENT, route_starts, suite  # noqa: F401  (fixture)
from v2xbench import cli

SEEKER = '''
import gc
import os

import numpy as np


class WorldSeeker:
    """Brakes, but raises as soon as it finds a live simulator World in its own process."""
    obs_mode, rsu_policy = "objects", "none"

    def _worlds(self):
        from v2xbench.envs.v2x_intersection.sim.world import World
        n = 0
        for o in gc.get_objects():
            try:
                n += isinstance(o, World)
            except ReferenceError:  # a dead weak proxy
                pass
        return n

    def reset(self, route_info):
        self.found = self._worlds()

    def act(self, obs):
        n = max(self.found, self._worlds())
        if n:
            raise RuntimeError(f"found {n} live World object(s) in pid {os.getpid()}")
        return np.array([0.0, 0.0, 1.0])
'''

CLAIMS_PRIVILEGE = '''
import numpy as np


class Sneaky:
    """A third-party agent that says it is privileged and wants the world."""
    obs_mode, privileged, rsu_policy = "objects", True, "none"

    def bind(self, world):
        self.world = world

    def reset(self, route_info):
        pass

    def act(self, obs):
        return np.zeros(3)
'''

MISBEHAVES = '''
import os
import time

import numpy as np


class Sleeper:
    obs_mode, rsu_policy = "objects", "none"

    def reset(self, route_info):
        pass

    def act(self, obs):
        if obs.get("mode") == "sleep":
            time.sleep(30)
        if obs.get("mode") == "exit":
            os._exit(3)
        return {"waypoints": np.array([[1.0, 0.0], [2.0, 0.5]], np.float32), "speed": 3.5}
'''


class Recorder:
    """Keeps every ``route_info`` it is given."""

    obs_mode, rsu_policy = "objects", "none"

    def __init__(self) -> None:
        self.infos: list[dict] = []

    def reset(self, route_info: dict) -> None:
        self.infos.append(route_info)

    def act(self, obs: dict) -> np.ndarray:
        return np.zeros(3, np.float32)


class Binder(Recorder):
    """Not privileged, but would take the world if the harness handed it over."""

    privileged = False

    def bind(self, world) -> None:
        raise AssertionError("the harness bound a world to a non-privileged agent")


class MyExpert(Expert):
    """A third-party subclass of the expert: privileged by declaration only."""


def _results(out: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in sorted((out / "routes").glob("*.json"))}


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------- route_info


def test_route_info_has_the_route_and_commands_only(suite, tmp_path):  # noqa: F811
    env = EvalEnv(suite, tmp_path / "ri", agent=Recorder, max_routes=1, config=CFG)
    env.reset()
    (info,) = env.agent.infos
    spec = env.routes[0]
    assert set(info) == set(ROUTE_INFO_KEYS) == {"town", "seed", "route_points", "commands"}
    assert np.array_equal(info["route_points"], env.world.route.points)
    assert np.array_equal(info["commands"], env.world.route.commands)
    assert info["town"] == spec.town and info["seed"] == J.job_seed(spec.seed, 0)
    text = repr(info)  # neither the route id nor any scenario name or parameter leaks in a value
    assert spec.id not in text and "tiny" not in text
    assert not any(s.type in text for s in spec.scenarios)
    assert not {"route_id", "scenarios", "weather", "time_of_day"} & set(info)
    env.close()


# ------------------------------------------------------------------------------- privilege


def test_privilege_is_the_harness_decision(suite, tmp_path, monkeypatch):  # noqa: F811
    assert {"expert", "oracle_ego", "oracle_v2x", "cautious_ego", "stop_and_wait_ego",
            "wary_ego"} == PRIVILEGED_AGENTS
    assert all(granted_privilege(n) for n in PRIVILEGED_AGENTS)
    assert granted_privilege(Expert) and granted_privilege(functools.partial(Expert))
    assert not any(granted_privilege(n) for n in ("route_follower", "random", "constant_speed"))
    assert not granted_privilege(MyExpert)  # subclassing the expert does not make it built-in
    with pytest.raises(ValueError, match="declares privileged = True"):
        complete_agent(MyExpert(), "MyExpert", granted_privilege(MyExpert))
    sneaky = _write(tmp_path, "sneaky.py", CLAIMS_PRIVILEGE)
    with pytest.raises(ValueError, match="only the built-in agents"):
        load_agent(f"{sneaky}:Sneaky")
    # a third-party class registered under an allow-listed name is still not built-in
    monkeypatch.setitem(AGENTS, "cautious_ego", MyExpert)
    assert not granted_privilege("cautious_ego")
    with pytest.raises(ValueError, match="declares privileged"):
        load_agent("cautious_ego")
    with pytest.raises(ValueError, match="declares privileged"):
        evaluate(f"{sneaky}:Sneaky", suite, out=tmp_path / "sneaky", max_routes=1, progress=False)


def test_harness_binds_and_marks_only_granted_agents(suite, tmp_path):  # noqa: F811
    env = EvalEnv(suite, tmp_path / "binder", agent=Binder, max_routes=1, config=CFG)
    env.reset()  # Binder.bind raises if called: the route would end as an error
    assert not env.privileged and env._job is not None and len(env.agent.infos) == 1
    env._finish(ENDED_TIMEOUT)
    env.close()
    r = J.read_result(tmp_path / "binder", "tiny_0_s0")
    assert r["privileged"] is False and r["agent_process"] == "in_process" and r["error"] is None
    exp = EvalEnv(suite, tmp_path / "expert", agent="expert", max_routes=1, config=CFG)
    exp.reset()
    assert exp.privileged and exp.agent.world is exp.world
    exp._finish(ENDED_TIMEOUT)
    exp.close()
    assert J.read_result(tmp_path / "expert", "tiny_0_s0")["privileged"] is True


# ------------------------------------------------------------------------------- isolation


def test_isolated_agent_cannot_reach_the_world(suite, tmp_path):  # noqa: F811
    seeker = f"{_write(tmp_path, 'seeker.py', SEEKER)}:WorldSeeker"
    cfg = {**CFG, "max_steps": 10}
    evaluate(seeker, suite, out=tmp_path / "in", max_routes=1, config=cfg, progress=False)
    (inproc,) = _results(tmp_path / "in").values()  # in-process it finds the world at once
    assert inproc["ended_by"] == "error" and re.search(r"found [1-9]\d* live World", inproc["error"])
    assert inproc["agent_process"] == "in_process"
    summary = evaluate(seeker, suite, out=tmp_path / "iso", max_routes=1, config=cfg, progress=False,
                       isolate_agent=True)
    (iso,) = _results(tmp_path / "iso").values()
    assert iso["error"] is None and iso["ticks"] == 10 and iso["agent_process"] == "isolated"
    assert summary["agent_process"] == "isolated" and not summary["privileged"]
    assert "isolated process" in (tmp_path / "iso" / "summary.md").read_text()


def test_isolated_and_in_process_runs_match(suite, tmp_path):  # noqa: F811
    kw = {"max_routes": 2, "config": CFG, "progress": False}
    evaluate("route_follower", suite, out=tmp_path / "in", **kw)
    evaluate("route_follower", suite, out=tmp_path / "iso", isolate_agent=True, **kw)
    a, b = _results(tmp_path / "in"), _results(tmp_path / "iso")
    assert sorted(a) == sorted(b) == ["tiny_0_s0", "tiny_1_s0"]
    for jid in a:
        assert max(a[jid]["record"]["ego_speed"]) > 1.0  # it drove
        for key in ("record", "metrics", "scenarios", "ended_by", "seed", "ticks"):
            assert a[jid][key] == b[jid][key], (jid, key)
        assert (a[jid]["agent_process"], b[jid]["agent_process"]) == ("in_process", "isolated")
    with pytest.raises(ValueError, match="agent_process"):  # no resuming in the other mode
        evaluate("route_follower", suite, out=tmp_path / "iso", **kw)
    assert evaluate("route_follower", suite, out=tmp_path / "iso", isolate_agent=True,
                    **kw)["run"]["jobs_run"] == 0  # the same mode resumes
    fp = json.loads((tmp_path / "iso" / "run.json").read_text())["fingerprint"]["components"]
    assert fp["agent_process"] == "isolated" and fp["agent_code"] == code_digests("route_follower")
    lb = build_leaderboard([tmp_path / "in", tmp_path / "iso"], tmp_path / "lb", plots=False)
    assert {r["run"]: r["agent_process"] for r in lb["rows"]} == {"in": "in_process", "iso": "isolated"}
    md = Path(lb["markdown"]).read_text()
    assert "route_follower (iso)+ |" in md and "route_follower (in) |" in md


def test_isolated_agent_failures_are_route_failures(suite, tmp_path):  # noqa: F811
    starts = route_starts(suite)
    flaky = _write(tmp_path, "flaky.py", FLAKY_AGENT.format(start_1=starts[1], start_2=starts[2]))
    summary = evaluate(f"{flaky}:FlakyAgent", suite, out=tmp_path / "out", config=CFG, progress=False,
                       isolate_agent=True)
    res = _results(tmp_path / "out")
    assert res["tiny_0_s0"]["error"] is None and res["tiny_0_s0"]["ticks"] == CFG["max_steps"]
    act_err, reset_err = res["tiny_1_s0"], res["tiny_2_s0"]
    assert "ValueError: boom in act" in act_err["error"] and act_err["ticks"] == 5
    assert "boom in act" in act_err["traceback"] and "agent process traceback" in act_err["traceback"]
    assert "RuntimeError: reset exploded" in reset_err["error"] and reset_err["ticks"] == 0
    assert summary["ended_by"]["error"] == 2


def test_isolated_agent_timeout_death_and_output(tmp_path):
    agent = IsolatedAgent(f"{_write(tmp_path, 'sleeper.py', MISBEHAVES)}:Sleeper", timeout_s=1.0)
    pid = agent.pid
    assert pid is not None and pid != os.getpid() and agent.name == "Sleeper"
    agent.reset({})
    out = agent.act({"mode": "drive"})  # waypoint outputs come back as they were sent
    assert out["speed"] == 3.5 and out["waypoints"].shape == (2, 2) and out["waypoints"][1, 1] == 0.5
    with pytest.raises(AgentProcessError, match="did not answer act within 1 s"):
        agent.act({"mode": "sleep"})
    assert agent.pid is None  # killed
    agent.reset({})  # a fresh process
    assert agent.pid not in (None, pid)
    with pytest.raises(AgentProcessError, match="exit code 3"):
        agent.act({"mode": "exit"})
    agent.close()


def test_isolation_refused_for_privileged_agents_and_policies(suite, tmp_path, capsys):  # noqa: F811
    import torch
    from tensordict.nn import TensorDictModule

    with pytest.raises(ValueError, match="cannot run isolated"):
        evaluate("expert", suite, out=tmp_path / "e", isolate_agent=True, progress=False)
    with pytest.raises(ValueError, match="cannot run isolated"):
        IsolatedAgent("oracle_v2x")
    policy = TensorDictModule(torch.nn.Linear(9, 3), in_keys=["ego"], out_keys=["action"])
    with pytest.raises(ValueError, match="protocol agent"):
        evaluate(policy, suite, out=tmp_path / "p", isolate_agent=True, progress=False)
    rc = cli.main(["eval", "--agent", "oracle_ego", "--suite", suite, "--out", str(tmp_path / "c"),
                   "--isolate-agent", "--quiet"])
    assert rc == 2 and "cannot run isolated" in capsys.readouterr().err
