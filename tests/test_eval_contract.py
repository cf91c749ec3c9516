"""One observation contract, agent configs and route selection (issue 30, items 2 and 9).

- a protocol agent's ``act`` gets exactly the Gymnasium observation of its ``obs_mode`` (every
  value inside ``ego_space``), and the step's info only when its signature asks for it;
- an SB3 ``PPO`` made (not trained) on the gym id, saved and loaded by an agent file, drives
  through ``v2xbench eval`` (with the extra keys eval used to add, SB3 raised ``KeyError``);
- ``--agent-config`` reaches the constructor as keyword arguments and bad ones are refused up
  front; ``--routes`` / ``--scenario`` / ``--v2x-only`` select routes, unknown names refused with a
  did-you-mean.

Routes are the three-route tiny suite of ``test_evaluate`` with a 10-40 tick budget.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from v2xbench.agents.interface import act_info_style, call_act
from v2xbench.collectors.agent_process import IsolatedAgent
from v2xbench.collectors.eval_env import EvalEnv, copy_policy
from v2xbench.collectors.evaluate import evaluate
from v2xbench.collectors.route_selection import select_routes
from v2xbench.envs.v2x_intersection.api.observations import ego_space
from v2xbench.envs.v2x_intersection.scenarios import get_scenario
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

from tests.test_evaluate import CFG, suite  # noqa: F401  (fixture)
from v2xbench import cli

SB3_AGENT = '''
import numpy as np
import torch
from stable_baselines3 import PPO


class SB3Driver:
    """A saved SB3 PPO model (made on the gym id) as a V2XBench agent."""
    obs_mode, rsu_policy = "objects", "share_objects"

    def __init__(self, model_path):
        torch.set_num_threads(1)
        self.checkpoint = model_path  # hashed into the run's fingerprint
        self.model = PPO.load(model_path, device="cpu")

    def reset(self, route_info):
        pass

    def act(self, obs):
        space = self.model.observation_space
        if set(obs) != set(space.spaces):
            raise KeyError(f"observation keys {sorted(obs)} != {sorted(space.spaces)}")
        if not space.contains(obs):
            bad = [k for k, s in space.spaces.items() if not s.contains(obs[k])]
            raise ValueError(f"observation outside its space: {bad}")
        action, _ = self.model.predict(obs, deterministic=True)
        return np.asarray(action, np.float32)
'''

INFO_AGENT = '''
import numpy as np


class InfoDriver:
    """Throttle from the step's info: proves ``info`` reaches ``act`` (isolated, too)."""
    obs_mode, rsu_policy = "objects", "none"

    def reset(self, route_info):
        pass

    def act(self, obs, info):
        assert "route_completion" not in obs and "v2x_bps" not in obs
        return np.array([min(1.0, 0.1 + info["tick"] / 10.0), 0.0, 0.0], np.float32)
'''


class Recorder:
    """Records every observation and info it is given (in-process only)."""

    obs_mode, rsu_policy = "objects", "share_objects"

    def __init__(self) -> None:
        self.seen: list[tuple[dict, dict]] = []

    def reset(self, route_info: dict) -> None:
        pass

    def act(self, obs: dict, *, info: dict | None = None) -> np.ndarray:
        self.seen.append(({k: np.array(v, copy=True) for k, v in obs.items()}, dict(info or {})))
        return np.array([0.6, 0.0, 0.0], np.float32)


class ObsOnly(Recorder):
    def act(self, obs: dict) -> np.ndarray:  # no info
        self.seen.append((obs, {}))
        return np.array([0.6, 0.0, 0.0], np.float32)


def _results(out: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in sorted((out / "routes").glob("*.json"))}


# ------------------------------------------------------------------------------- item 2


def test_act_gets_exactly_the_gym_observation_inside_its_space(suite, tmp_path):  # noqa: F811
    env = EvalEnv(suite, tmp_path / "rec", agent=Recorder, max_routes=1, config=CFG)
    space = ego_space(env.config)
    env.rollout(CFG["max_steps"] + 5, policy=copy_policy(), break_when_any_done=True)
    seen = env.agent.seen
    assert len(seen) >= CFG["max_steps"] - 1
    assert set(env.observation_spec.keys()) >= {"route_completion", "v2x_bps"}  # TorchRL's view
    for obs, info in seen:
        assert set(obs) == set(space.spaces)  # no route_completion, v2x_bps, agent_action, job
        assert space.contains(obs), [k for k, s in space.spaces.items() if not s.contains(obs[k])]
        assert {"tick", "route_completion", "v2x_bps", "events"} <= set(info)
    assert [i["tick"] for _, i in seen[:3]] == [0, 1, 2]  # the reset's info, then each step's
    assert seen[-1][1]["route_completion"] == pytest.approx(float(seen[-1][0]["ego"][8]), abs=1e-3)
    env.close()
    plain = EvalEnv(suite, tmp_path / "plain", agent=ObsOnly, max_routes=1, config=CFG)
    plain.reset()
    assert plain._info_style is None and plain._info is None  # info is not even built
    assert set(plain.agent.seen[0][0]) == set(space.spaces)
    plain.close()


def test_info_style_is_read_from_the_signature():
    class A:
        def act(self, obs): ...

    class B:
        def act(self, obs, info): ...

    class C:
        def act(self, obs, *, info=None): ...

    class D:
        def act(self, obs, deterministic=True): ...

    class E:
        def act(self, observation, extra, /): ...

    styles = [act_info_style(c()) for c in (A, B, C, D, E)]
    assert styles == [None, "keyword", "keyword", None, "positional"]
    e = E()
    e.act = lambda obs, extra, /: (obs, extra)
    assert call_act(e, 1, 2) == (1, 2)


def test_isolated_agent_gets_info(suite, tmp_path):  # noqa: F811
    path = tmp_path / "info_agent.py"
    path.write_text(INFO_AGENT)
    agent = IsolatedAgent(f"{path}:InfoDriver")
    try:
        assert agent.takes_info and agent.declared == {"checkpoint": {}, "fingerprint": None}
        agent.reset({})
        obs = {k: np.zeros(s.shape, s.dtype) for k, s in ego_space(make_config()).spaces.items()}
        assert agent.act(obs, {"tick": 5})[0] == pytest.approx(0.6)
    finally:
        agent.close()
    slow = IsolatedAgent("constant_speed", config={"speed": 2.0})  # the config reaches its process
    try:
        assert not slow.takes_info
        slow.reset({})
        assert slow.act(obs)["speed"] == 2.0
    finally:
        slow.close()
    with pytest.raises(ValueError, match="constructor takes: speed"):
        IsolatedAgent("constant_speed", config={"sped": 2.0})


@pytest.fixture(scope="module")
def ppo_zip(tmp_path_factory) -> Path:
    """An SB3 PPO made (not trained) on the gym id, saved."""
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    env = gym.make("v2xbench:V2XIntersection-v0", num_vehicles=2, num_pedestrians=0)
    model = PPO("MultiInputPolicy", env, n_steps=64, batch_size=32, seed=0, device="cpu")
    path = tmp_path_factory.mktemp("sb3") / "ppo.zip"
    model.save(path)
    env.close()
    return path


def test_sb3_ppo_made_on_the_gym_id_runs_in_eval(suite, ppo_zip, tmp_path, capsys):  # noqa: F811
    agent = tmp_path / "sb3_agent.py"
    agent.write_text(SB3_AGENT)
    conf = tmp_path / "sb3.json"
    conf.write_text(json.dumps({"model_path": str(ppo_zip)}))
    out = tmp_path / "out"
    rc = cli.main(
        [
            "eval",
            "--agent",
            f"{agent}:SB3Driver",
            "--agent-config",
            str(conf),
            "--suite",
            suite,
            "--out",
            str(out),
            "--max-routes",
            "2",
            "--quiet",
            "--set",
            "max_steps=15",
            "--set",
            "num_vehicles=2",
            "--set",
            "num_pedestrians=1",
        ]
    )
    res = _results(out)
    assert rc == 0, [r["error"] for r in res.values()]
    assert sorted(res) == ["tiny_0_s0", "tiny_1_s0"]
    for r in res.values():
        assert r["error"] is None and r["ticks"] == 15
    run = json.loads((out / "run.json").read_text())
    comp = run["fingerprint"]["components"]
    assert comp["checkpoint"] == {str(ppo_zip): hashlib.sha256(ppo_zip.read_bytes()).hexdigest()}
    assert comp["agent_config"] == {"model_path": str(ppo_zip)} and run["agent_config_file"] == str(
        conf
    )
    assert "SB3Driver" in capsys.readouterr().out


# ------------------------------------------------------------------------------- item 9


def test_agent_config_reaches_the_constructor(suite, tmp_path, capsys):  # noqa: F811
    conf = tmp_path / "speed.json"
    conf.write_text('{"speed": 2.0}')
    out = tmp_path / "cs"
    rc = cli.main(
        [
            "eval",
            "--agent",
            "constant_speed",
            "--agent-config",
            str(conf),
            "--suite",
            suite,
            "--out",
            str(out),
            "--routes",
            "tiny_0",
            "--quiet",
            "--set",
            "max_steps=40",
            "--set",
            "num_vehicles=0",
            "--set",
            "num_pedestrians=0",
            "--set",
            "num_parked=0",
        ]
    )
    assert rc == 0
    (r,) = _results(out).values()
    assert max(r["record"]["ego_speed"]) < 2.6  # 6 m/s by default
    summary = json.loads((out / "summary.json").read_text())
    assert summary["agent_config"] == {"speed": 2.0}
    assert "Agent config" in (out / "summary.md").read_text()
    capsys.readouterr()
    bad = [
        ("nope.json", None, "not found"),
        ("c.yaml", "speed: 2", "YAML"),
        ("c.json", "{speed: 2}", "not valid JSON"),
        ("c.json", "[2.0]", "JSON object"),
        ("c.json", '{"sped": 2.0}', "takes: speed"),
    ]
    for name, text, message in bad:
        path = tmp_path / name
        if text is not None:
            path.write_text(text)
        rc = cli.main(
            [
                "eval",
                "--agent",
                "constant_speed",
                "--agent-config",
                str(path),
                "--suite",
                suite,
                "--out",
                str(tmp_path / "bad"),
                "--quiet",
            ]
        )
        err = capsys.readouterr().err
        assert rc == 2 and message in err, (name, err)
        assert not (tmp_path / "bad" / "run.json").exists()  # refused before anything ran


def test_route_selection(suite):  # noqa: F811
    routes = load_suite_cached(suite)
    ids = [r.id for r in routes]
    sel = select_routes(routes, "tiny", route_ids="tiny_2,tiny_0")
    assert sel.indices == [0, 2] and sel.route_ids == ["tiny_0", "tiny_2"]  # suite order
    assert select_routes(routes, "tiny").label == "all 3 routes"
    first = routes[1].scenarios[0].type
    by_type = select_routes(routes, "tiny", scenario=[first])
    assert by_type.route_ids == [r.id for r in routes if first in {s.type for s in r.scenarios}]
    v2x = [r.id for r in routes if any(get_scenario(s.type).v2x for s in r.scenarios)]
    if v2x:
        assert select_routes(routes, "tiny", v2x_only=True).route_ids == v2x
    assert select_routes(routes, "tiny", max_routes=2).route_ids == ids[:2]
    with pytest.raises(ValueError, match="unknown route id 'tiny_9'.*Did you mean 'tiny_"):
        select_routes(routes, "tiny", route_ids="tiny_0,tiny_9")
    with pytest.raises(
        ValueError, match="unknown scenario type 'Acident'.*Did you mean 'Accident'"
    ):
        select_routes(routes, "tiny", scenario="Acident")
    absent = next(
        t
        for t in ("HighwayExit", "ControlLoss", "BlockedIntersection")
        if t not in {s.type for r in routes for s in r.scenarios}
    )
    with pytest.raises(
        ValueError, match=f"no route of suite tiny contains scenario type '{absent}'"
    ):
        select_routes(routes, "tiny", scenario=absent)
    other = next(
        s.type
        for r in routes[1:]
        for s in r.scenarios
        if s.type not in {x.type for x in routes[0].scenarios}
    )
    with pytest.raises(
        ValueError, match="no route of suite tiny passes routes tiny_0 and scenario"
    ):
        select_routes(routes, "tiny", route_ids="tiny_0", scenario=other)


def test_route_selection_through_eval(suite, tmp_path, capsys):  # noqa: F811
    out = tmp_path / "sel"
    summary = evaluate(
        "route_follower",
        suite,
        out=out,
        routes=["tiny_2"],
        config={**CFG, "max_steps": 10},
        progress=False,
    )
    assert sorted(_results(out)) == ["tiny_2_s0"] and summary["n_routes"] == 1
    assert (
        summary["selection"]["route_ids"] == ["tiny_2"]
        and "tiny_2" in summary["selection"]["label"]
    )
    assert "1 routes (routes tiny_2) x 1 seeds" in (out / "summary.md").read_text()
    rc = cli.main(
        ["eval", "--suite", suite, "--out", str(tmp_path / "typo"), "--routes", "tiny_O", "--quiet"]
    )
    err = capsys.readouterr().err
    assert rc == 2 and "unknown route id 'tiny_O'" in err and "Did you mean" in err
    rc = cli.main(
        [
            "eval",
            "--suite",
            suite,
            "--out",
            str(tmp_path / "typo"),
            "--scenario",
            "Acident",
            "--quiet",
        ]
    )
    assert rc == 2 and "Did you mean 'Accident'" in capsys.readouterr().err
    rc = cli.main(
        [
            "eval",
            "--agent",
            "route_folower",
            "--suite",
            suite,
            "--out",
            str(tmp_path / "typo"),
            "--quiet",
        ]
    )
    assert rc == 2 and "Did you mean 'route_follower'" in capsys.readouterr().err
    assert not (tmp_path / "typo" / "run.json").exists()
