"""Honest resume (issue 30, item 3): results are keyed by a fingerprint of the agent.

- editing the agent file, changing its declared checkpoint, its ``--agent-config`` or the
  ``--set`` overrides makes a second ``eval`` on the same ``--out`` refuse, naming what differs;
- ``--overwrite`` deletes the old results (saying so) and runs everything again;
- ``--retry-failed`` runs again only the routes whose result is a failure, and ``eval`` exits 1
  while any route failed;
- directories without a fingerprint, results without ``run.json`` and results of another
  fingerprint are refused; built-in agents are fingerprinted by their modules' source.

Routes are the three-route tiny suite of ``test_evaluate`` with a 10-tick budget.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from v2xbench.collectors import jobs as J
from v2xbench.collectors.agent_fingerprint import code_digests, describe_differences
from v2xbench.collectors.evaluate import evaluate

from tests.test_evaluate import CFG, suite  # noqa: F401  (fixture)
from v2xbench import cli

FAST = {**CFG, "max_steps": 10}
SETS = [f"--set={k}={v}" for k, v in FAST.items()]

AGENT = """
import os

import numpy as np

FLAG = {flag!r}  # while this file exists, the route with world seed 11 (tiny_1) fails
THROTTLE = {throttle!r}


class Steady:
    obs_mode, rsu_policy = "objects", "none"

    def __init__(self, weights=None):
        self.checkpoint = weights

    def reset(self, route_info):
        if int(route_info["seed"]) == 11 and os.path.exists(FLAG):
            raise RuntimeError("flaky route")

    def act(self, obs):
        return np.array([THROTTLE, 0.0, 0.0], np.float32)
"""


def _agent(tmp_path: Path, throttle: float = 0.3) -> str:
    path = tmp_path / "steady.py"
    path.write_text(AGENT.format(flag=str(tmp_path / "fail_tiny_1"), throttle=throttle))
    return f"{path}:Steady"


def _eval(spec: str, suite: str, out: Path, *extra: str) -> int:  # noqa: F811
    return cli.main(
        [
            "eval",
            "--agent",
            spec,
            "--suite",
            suite,
            "--out",
            str(out),
            "--quiet",
            "--max-routes",
            "2",
            *SETS,
            *extra,
        ]
    )


def _mtimes(out: Path) -> dict[str, int]:
    return {p.stem: p.stat().st_mtime_ns for p in (out / "routes").glob("*.json")}


def test_edited_agent_file_is_refused_and_overwrite_reruns(suite, tmp_path, capsys):  # noqa: F811
    spec, out = _agent(tmp_path), tmp_path / "out"
    assert _eval(spec, suite, out) == 0
    first = _mtimes(out)
    assert sorted(first) == ["tiny_0_s0", "tiny_1_s0"]
    digest = json.loads((out / "run.json").read_text())["fingerprint"]["digest"]
    assert all(J.read_result(out, j)["fingerprint"] == digest for j in first)
    assert _eval(spec, suite, out) == 0  # same fingerprint: resumes, runs nothing
    assert _mtimes(out) == first
    assert json.loads((out / "summary.json").read_text())["run"]["jobs_run"] == 0
    capsys.readouterr()
    _agent(tmp_path, throttle=0.5)  # the agent file is edited
    assert _eval(spec, suite, out) == 2
    err = capsys.readouterr().err
    assert "holds results of another run" in err and "agent code: steady.py changed" in err
    assert "--overwrite" in err and _mtimes(out) == first  # nothing was touched
    assert _eval(spec, suite, out, "--overwrite") == 0
    err = capsys.readouterr().err
    assert f"--overwrite: deleted 2 result(s) of the previous run in {out}" in err
    again = _mtimes(out)
    assert sorted(again) == sorted(first) and all(again[j] != first[j] for j in first)
    assert json.loads((out / "summary.json").read_text())["run"]["jobs_run"] == 2
    assert json.loads((out / "run.json").read_text())["fingerprint"]["digest"] != digest


def test_config_checkpoint_and_overrides_are_in_the_fingerprint(
    suite,  # noqa: F811
    tmp_path,
    capsys,
):
    spec, out = _agent(tmp_path), tmp_path / "out"
    weights = tmp_path / "w.bin"
    weights.write_bytes(b"\x00" * 16)
    conf = tmp_path / "conf.json"
    conf.write_text(json.dumps({"weights": str(weights)}))
    assert _eval(spec, suite, out, "--agent-config", str(conf), "--max-routes", "1") == 0
    capsys.readouterr()
    weights.write_bytes(b"\x01" * 16)  # other weights behind the same path
    assert _eval(spec, suite, out, "--agent-config", str(conf), "--max-routes", "1") == 2
    assert f"checkpoint: {weights} changed (sha256" in capsys.readouterr().err
    weights.write_bytes(b"\x00" * 16)
    other = tmp_path / "w2.bin"
    other.write_bytes(b"\x00" * 16)
    conf2 = tmp_path / "conf2.json"
    conf2.write_text(json.dumps({"weights": str(other)}))
    assert _eval(spec, suite, out, "--agent-config", str(conf2), "--max-routes", "1") == 2
    assert "agent config (--agent-config)" in capsys.readouterr().err
    assert (
        _eval(
            spec,
            suite,
            out,
            "--agent-config",
            str(conf),
            "--max-routes",
            "1",
            "--set",
            "num_vehicles=4",
        )
        == 2
    )
    assert "env overrides (--set)" in capsys.readouterr().err
    assert _eval(spec, suite, out, "--max-routes", "1") == 2  # no config at all
    assert "agent config" in capsys.readouterr().err
    assert (
        _eval(spec, suite, out, "--agent-config", str(conf), "--max-routes", "1") == 0
    )  # as before
    bad = tmp_path / "missing.json"
    bad.write_text(json.dumps({"weights": str(tmp_path / "nothing.bin")}))
    assert _eval(spec, suite, tmp_path / "o2", "--agent-config", str(bad)) == 2
    assert "declares checkpoint" in capsys.readouterr().err


def test_retry_failed_reruns_only_the_failed_routes(suite, tmp_path, capsys):  # noqa: F811
    spec, out = _agent(tmp_path), tmp_path / "out"
    flag = tmp_path / "fail_tiny_1"
    flag.touch()
    assert _eval(spec, suite, out) == 1  # a route failed: non-zero, and it says how many
    assert "1 of 2 route runs failed (1 error)" in capsys.readouterr().err
    before = _mtimes(out)
    assert J.read_result(out, "tiny_1_s0")["failure"] == "error"
    flag.unlink()
    assert _eval(spec, suite, out) == 1  # a plain resume keeps the failure
    capsys.readouterr()
    assert _eval(spec, suite, out, "--retry-failed") == 0
    assert (
        "--retry-failed: running 1 failed route run(s) again: tiny_1_s0" in capsys.readouterr().err
    )
    after = _mtimes(out)
    assert after["tiny_0_s0"] == before["tiny_0_s0"]  # the good one is kept
    assert (
        after["tiny_1_s0"] != before["tiny_1_s0"]
        and J.read_result(out, "tiny_1_s0")["error"] is None
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["run"]["jobs_run"] == 1 and sum(summary["failed"].values()) == 0
    assert _eval(spec, suite, out, "--retry-failed", "--overwrite") == 2
    assert "give one of them" in capsys.readouterr().err


def test_unverifiable_directories_are_refused(suite, tmp_path):  # noqa: F811
    kw = {"config": FAST, "max_routes": 1, "progress": False}
    out = tmp_path / "out"
    evaluate("route_follower", suite, out=out, **kw)
    run = out / "run.json"
    manifest = json.loads(run.read_text())
    run.write_text(json.dumps({k: v for k, v in manifest.items() if k != "fingerprint"}))
    with pytest.raises(ValueError, match="before results were keyed by a fingerprint"):
        evaluate("route_follower", suite, out=out, **kw)
    run.unlink()
    with pytest.raises(ValueError, match="results but no run.json"):
        evaluate("route_follower", suite, out=out, **kw)
    run.write_text(json.dumps(manifest))
    res = json.loads(J.result_path(out, "tiny_0_s0").read_text())
    J.write_json_atomic({**res, "fingerprint": "0" * 64}, J.result_path(out, "tiny_0_s0"))
    with pytest.raises(J.ForeignResults, match="tiny_0_s0.json"):
        evaluate("route_follower", suite, out=out, **kw)
    assert evaluate("route_follower", suite, out=out, overwrite=True, **kw)["run"]["jobs_run"] == 1


def test_builtin_agents_are_fingerprinted_by_their_source():
    rf = code_digests("route_follower")
    assert set(rf) == {"agents/route_follower.py", "agents/controller.py"}
    expert = code_digests("expert")
    assert "agents/expert/planner.py" in expert and "agents/interface.py" not in expert
    assert "agents/expert/cautious.py" in code_digests("cautious_ego")
    diff = describe_differences(
        {"agent_code": rf, "agent": "route_follower"},
        {"agent_code": {**rf, "agents/controller.py": "f" * 64}, "agent": "random"},
    )
    assert diff[0].startswith("agent: 'route_follower' -> 'random'")
    assert diff[1].startswith("agent code: agents/controller.py changed (sha256 ")


def test_a_baselines_code_is_its_whole_method_package():
    """A baseline's agent loads its package's ``policy`` and ``train`` by name (importlib):
    its fingerprint holds every module of the package, the model the weights run in included."""
    for name in ("univ2x", "codriving"):
        code = code_digests(name)
        for mod in ("model", "policy", "train", "config", "message"):
            assert f"agents/baselines/{name}/{mod}.py" in code, (name, mod)
    assert not any(k.startswith("agents/baselines/") for k in code_digests("aurora"))


def test_torchrl_policy_weights_are_its_checkpoint(suite, tmp_path):  # noqa: F811
    import torch
    from tensordict.nn import TensorDictModule

    lin = torch.nn.Linear(9, 3)
    policy = TensorDictModule(lin, in_keys=["ego"], out_keys=["action"])
    kw = {"config": FAST, "max_routes": 1, "progress": False, "out": tmp_path / "p"}
    evaluate(policy, suite, **kw)
    assert evaluate(policy, suite, **kw)["run"]["jobs_run"] == 0
    with torch.no_grad():
        lin.bias.add_(0.1)
    with pytest.raises(ValueError, match="checkpoint: policy changed"):
        evaluate(policy, suite, **kw)


def test_shipped_weights_are_keyed_by_their_path_in_the_package(suite, tmp_path,  # noqa: F811
                                                                capsys):
    """Weights inside the installed package are keyed ``v2xbench/agents/...`` (one key from every
    clone); a run.json written before, keyed by an absolute path, resumes when the weights are the
    same (its results re-keyed) and is refused when they are not."""
    import v2xbench.agents.interface as iface
    from v2xbench.collectors.agent_fingerprint import checkpoint_key, make_fingerprint

    inside = str(Path(iface.__file__).resolve())
    assert checkpoint_key(inside) == "v2xbench/agents/interface.py"
    assert checkpoint_key(str(tmp_path / "w.bin")) == str(tmp_path / "w.bin")
    spec, out = _agent(tmp_path), tmp_path / "out"
    conf = tmp_path / "conf.json"
    conf.write_text(json.dumps({"weights": inside}))
    args = ("--agent-config", str(conf), "--max-routes", "1")
    assert _eval(spec, suite, out, *args) == 0
    run = json.loads((out / "run.json").read_text())
    comp = run["fingerprint"]["components"]
    assert list(comp["checkpoint"]) == ["v2xbench/agents/interface.py"]
    digest = run["fingerprint"]["digest"]

    def make_legacy(sha: str) -> str:  # as an earlier v2xbench wrote it from another clone
        old = dict(comp, checkpoint={"/elsewhere/clone/agents/interface.py": sha})
        fp = make_fingerprint(old)
        J.write_json_atomic({**run, "fingerprint": fp}, out / "run.json")
        return fp["digest"]

    legacy = make_legacy(comp["checkpoint"]["v2xbench/agents/interface.py"])
    assert J.retag_results(out, digest, legacy) == 1
    before = _mtimes(out)
    capsys.readouterr()
    assert _eval(spec, suite, out, *args) == 0  # same weights: re-keyed, nothing runs again
    assert "1 result(s) re-keyed and resumed" in capsys.readouterr().err
    assert json.loads((out / "summary.json").read_text())["run"]["jobs_run"] == 0
    assert J.read_result(out, "tiny_0_s0")["fingerprint"] == digest
    assert json.loads((out / "run.json").read_text())["fingerprint"]["digest"] == digest
    assert set(_mtimes(out)) == set(before)
    legacy = make_legacy("0" * 64)  # other weights under the old key: refused
    assert J.retag_results(out, digest, legacy) == 1
    assert _eval(spec, suite, out, *args) == 2
    assert "holds results of another run" in capsys.readouterr().err
    assert J.read_result(out, "tiny_0_s0")["fingerprint"] == legacy  # nothing touched


def test_legacy_match_rekeys_old_paths_of_the_same_file_only():
    from v2xbench.collectors.agent_fingerprint import legacy_match

    new = {"spec": "codriving", "fingerprint": "f",
           "checkpoint": {"v2xbench/agents/w/c.safetensors": "ab", "/runs/x.bin": "cd"}}
    old = dict(new, checkpoint={"/clone/agents/w/c.safetensors": "ab", "/runs/x.bin": "cd"})
    assert legacy_match(old, new)
    assert not legacy_match(new, new)  # equal is no legacy form
    assert not legacy_match(dict(old, fingerprint="g"), new)  # something else differs
    assert not legacy_match(dict(old, checkpoint={**old["checkpoint"],
                                                  "/clone/agents/w/c.safetensors": "ff"}), new)
    assert not legacy_match(dict(old, checkpoint={"/clone/other/w/d.safetensors": "ab",
                                                  "/runs/x.bin": "cd"}), new)
    assert legacy_match(dict(old, checkpoint={"agents/w/c.safetensors": "ab",
                                              "/runs/x.bin": "cd"}), new)  # relative to the clone
    assert not legacy_match(dict(old, checkpoint={"/clone/xagents/w/c.safetensors": "ab",
                                                  "/runs/x.bin": "cd"}), new)
