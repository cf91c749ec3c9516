"""What the planner reads of the ego's speed (issue #33, docs/aurora.md "A sixth run"): the
stage-4 switch ``--speed-dropout``, kept by stage 5, and the agent's ``speed`` option."""

from __future__ import annotations

import json

import pytest
from v2xbench.agents.aurora.agent import AuroraAgent

from tests.dataset_helpers import ONE_STEP, branches_run


def test_speed_dropout_set_at_stage_4_kept_by_stage_5_and_read_by_the_agent(
        tiny_dataset, tmp_path, monkeypatch):
    from v2xbench.agents.aurora.stages import train_late_stage

    data, run = branches_run(tiny_dataset, tmp_path)
    common = ONE_STEP
    with pytest.raises(ValueError, match="applies to stage 4"):
        train_late_stage(data, run, 3, speed_dropout=1.0, **common)
    train_late_stage(data, run, 3, **common)
    train_late_stage(data, run, 4, speed_dropout=1.0, **common)
    info4 = json.loads((run / "stage4" / "aurora.json").read_text())
    assert info4["config"]["plan_speed_dropout"] == 1.0
    with pytest.raises(ValueError, match="stage 5 continues it"):
        train_late_stage(data, run, 5, speed_dropout=0.5, **common)
    with pytest.raises(ValueError, match="other settings"):  # a resume with another value
        train_late_stage(data, run, 4, **common)
    train_late_stage(data, run, 5, **common)
    info5 = json.loads((run / "stage5" / "aurora.json").read_text())
    assert info5["config"]["plan_speed_dropout"] == 1.0

    auto = AuroraAgent(run=str(run))  # the planner never read a speed: the prompt says none
    said = AuroraAgent(run=str(run), speed="said")
    assert not auto.say_speed and not auto.policy.module.say_speed
    assert said.say_speed and said.policy.module.say_speed
    assert "prompt_speed=unknown" in auto.fingerprint()
    assert "prompt_speed" not in said.fingerprint()
    four = AuroraAgent(run=str(run), stage=3)  # stage 3: the scale's 0.15, the speed is said
    assert four.say_speed and "prompt_speed" not in four.fingerprint()
    with pytest.raises(ValueError, match="speed='fast'"):
        AuroraAgent(run=str(run), speed="fast")

    # the inertia probe on the same run: each pass's prompts say what it asked for
    from v2xbench.agents.aurora import pairs as pairs_mod
    from v2xbench.agents.aurora.speed_probe import probe_speed

    said = []
    real = pairs_mod.build_prompt

    def spy(speed, *args, **kw):
        said.append(speed)
        return real(speed, *args, **kw)

    monkeypatch.setattr(pairs_mod, "build_prompt", spy)
    r = probe_speed(data, run=run, split="all", stride=8, prompts=("frame", 2.5, "unknown"),
                    out=tmp_path / "probe", progress=False)
    n = len(said) // 3
    assert len(said) == 3 * n and n > 0
    assert all(s is not None for s in said[:n]) and set(said[n:2 * n]) == {2.5}
    assert set(said[2 * n:]) == {None}
    assert sum(row["frames"] for row in r["rows"]) == r["frames"] > 0
    assert all(len(row["model_speed"]) == 3 for row in r["rows"])
    assert (tmp_path / "probe" / "metrics.md").read_text() == r["table"]
    with pytest.raises(ValueError, match="not 'frame', 'unknown' or a speed"):
        probe_speed(data, run=run, prompts=("fast",), out=tmp_path / "probe2")
