"""An agent declares the channel it needs (``channel = {"max_payload_floats": N}``) and
``v2xbench eval`` configures the env from it (issue #33: AURORA's 5,680-float message)."""

from __future__ import annotations

import pytest
from v2xbench.agents.interface import complete_agent, declared_channel
from v2xbench.collectors.agent_sensors import apply_agent_channel
from v2xbench.envs.v2x_intersection.sim.config import FIELD_RULES


class _Agent:
    obs_mode = "objects"
    rsu_policy = "share_objects"

    def __init__(self, channel=None) -> None:
        if channel is not None:
            self.channel = channel

    def reset(self, route_info: dict) -> None:
        pass

    def act(self, obs: dict):
        return {"waypoints": [[1.0, 0.0], [2.0, 0.0]], "speed": 0.0}


def test_declared_channel_is_validated():
    assert declared_channel(_Agent()) == {}
    assert declared_channel(_Agent({"max_payload_floats": 5680})) == {"max_payload_floats": 5680}
    hi = FIELD_RULES["max_payload_floats"].hi
    for bad, match in [([1], "must be a dict"), ({"latency_ticks": 2}, "unknown key"),
                       ({"max_payload_floats": 0}, "outside"),
                       ({"max_payload_floats": hi + 1}, f"outside .*{hi}"),
                       ({"max_payload_floats": True}, "expected an int"),
                       ({"max_payload_floats": 600.5}, "expected an int")]:
        with pytest.raises(ValueError, match=match):
            declared_channel(_Agent(bad), "mine")
    with pytest.raises(ValueError, match="'mine'.*channel"):  # checked when the agent is built
        complete_agent(_Agent({"max_payload_floats": -3}), "mine", False)


def test_eval_applies_the_declaration_and_refuses_a_conflicting_set():
    need = {"max_payload_floats": 5680}
    assert apply_agent_channel({"seed": 1}, need, "a") == {"seed": 1, "max_payload_floats": 5680}
    assert apply_agent_channel({"max_payload_floats": 5680}, need, "a")["max_payload_floats"] \
        == 5680
    assert apply_agent_channel({"max_payload_floats": 400}, {}, "a") == {"max_payload_floats": 400}
    with pytest.raises(ValueError, match="max_payload_floats=5680.*max_payload_floats=400"):
        apply_agent_channel({"max_payload_floats": 400}, need, "a")


def test_eval_cli_sets_the_declared_limit_and_refuses_a_conflicting_set(tmp_path, capsys):
    import json

    from v2xbench.cli import main

    f = tmp_path / "chan_agent.py"
    f.write_text("class Chan:\n    obs_mode = 'objects'\n    rsu_policy = 'share_objects'\n"
                 "    channel = {'max_payload_floats': 700}\n"
                 "    def reset(self, route_info):\n        pass\n"
                 "    def act(self, obs):\n        return [0.0, 0.0, 1.0]\n")
    base = ["eval", "--agent", f"{f}:Chan", "--suite", "val", "--max-routes", "1", "--quiet"]
    code = main([*base, "--set", "max_payload_floats=400", "--out", str(tmp_path / "no")])
    err = capsys.readouterr().err
    assert code == 2 and "max_payload_floats=700" in err and "max_payload_floats=400" in err
    assert not (tmp_path / "no" / "routes").exists()  # refused before any route ran
    code = main([*base, "--isolate-agent", "--set", "max_payload_floats=400", "--out",
                 str(tmp_path / "iso")])  # the agent's own process reports its declaration
    assert code == 2 and "max_payload_floats=700" in capsys.readouterr().err
    assert main([*base, "--set", "max_steps=2", "--out", str(tmp_path / "ok")]) == 0
    summ = json.loads((tmp_path / "ok" / "summary.json").read_text())
    assert summ["config_overrides"]["max_payload_floats"] == 700  # from the declaration
