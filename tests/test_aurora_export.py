"""Exported AURORA weights (issue #33 item 7, shipped weights): export a tiny run, check the
manifest, load it as the agents do (SHA-256 first), drive the same actions as from the run."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from v2xbench.agents.aurora import export as export_mod
from v2xbench.agents.aurora.agent import AuroraAgent, NoFusionAgent
from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.pipeline import run_pipeline
from v2xbench.agents.aurora.policy import SPEED
from v2xbench.agents.aurora.rsu_agent import message_floats
from v2xbench.collectors.chat.export import build as build_qa
from v2xbench.envs.v2x_intersection.api.observations import ego_observation
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World

from v2xbench.cli import main

CFG = AuroraConfig.for_scale("tiny")


@pytest.fixture(scope="module")
def run(tiny_dataset, tmp_path_factory):
    torch.set_num_threads(1)
    base = tmp_path_factory.mktemp("aurora_export")
    data = base / "data"
    shutil.copytree(tiny_dataset, data)
    build_qa(data)
    run_pipeline(data, base / "run", scale="tiny", progress=False, say=lambda _: None)
    return base / "run"


def _observations(n: int = 3) -> list[dict]:
    w = World(make_config(town="Town05", obs_mode="sensors", camera_images=("rgb",),
                          camera_size=(32, 16), num_vehicles=3, num_pedestrians=1,
                          num_bicycles=0, max_payload_floats=message_floats(CFG)))
    w.reset(seed=3)
    out = []
    for _ in range(n):
        w.step(np.array([0.5, 0.0, 0.0]))
        out.append(ego_observation(w))
    return out


def _actions(agent, observations) -> np.ndarray:
    return np.stack([agent.act(o)["waypoints"] for o in observations])


def test_export_round_trip(run, tmp_path, capsys):
    w32, w16 = tmp_path / "w32", tmp_path / "w16"
    assert main(["aurora", "export", "--run", str(run), "--out", str(w32), "--dtype",
                 "float32"]) == 0
    assert "manifest.json" in capsys.readouterr().out
    assert main(["aurora", "export", "--run", str(run), "--stage", "5", "--out", str(w16)]) == 0
    m = json.loads((w16 / "manifest.json").read_text())
    assert m["stage"] == 5 and m["fusion"] and m["scale"] == "tiny" and m["dtype"] == "float16"
    assert m["command"].startswith("v2xbench aurora export --run")
    assert m["git_commit"] is None or len(m["git_commit"]) == 40
    assert set(m["files"]) == {"weights.safetensors", "aurora.json", "lm/config.json",
                               "lm/tokenizer.json", "lm/tokenizer_config.json"}
    for rel, f in m["files"].items():
        assert export_mod.sha256_file(w16 / rel) == f["sha256"]
        assert (w16 / rel).stat().st_size == f["bytes"]
    size = {d: (d / "weights.safetensors").stat().st_size for d in (w32, w16)}
    assert size[w16] < 0.6 * size[w32]  # half-size floats
    ckpt = run / "stage5" / "checkpoint.safetensors"
    assert m["source"]["checkpoint_sha256"] == export_mod.sha256_file(ckpt)

    obs = _observations()
    from_run = AuroraAgent(run=str(run))
    a_run = _actions(from_run, obs)
    exported = AuroraAgent(weights=str(w32))
    assert np.array_equal(_actions(exported, obs), a_run)  # float32: the same actions
    assert exported.channel == from_run.channel and exported.sensors == from_run.sensors
    assert exported.fingerprint() == from_run.fingerprint()
    half = _actions(AuroraAgent(weights=str(w16)), obs)
    assert np.abs(half - a_run).max() < 0.05  # m: float16 storage rounds the weights only

    # one changed byte: refused before loading, naming the file
    blob = bytearray((w32 / "weights.safetensors").read_bytes())
    blob[-1] ^= 0x01
    (w32 / "weights.safetensors").write_bytes(bytes(blob))
    with pytest.raises(ValueError, match="weights.safetensors fails its SHA-256 check"):
        AuroraAgent(weights=str(w32))
    (w16 / "lm" / "tokenizer.json").unlink()
    with pytest.raises(FileNotFoundError, match="tokenizer.json is listed"):
        AuroraAgent(weights=str(w16))
    with pytest.raises(ValueError, match="either run or weights"):
        AuroraAgent(run=str(run), weights=str(w16))


def test_agents_load_shipped_weights_by_default(run, tmp_path, monkeypatch):
    monkeypatch.setattr(export_mod, "SHIPPED", tmp_path / "weights")
    with pytest.raises(FileNotFoundError, match="no shipped weights at .*weights/no_fusion"):
        NoFusionAgent()
    assert main(["aurora", "export", "--run", str(run), "--out",
                 str(tmp_path / "weights" / "aurora")]) == 0
    agent = AuroraAgent()
    assert agent.run == str(tmp_path / "weights" / "aurora")
    assert agent.checkpoint[0].endswith("weights.safetensors")
    assert agent.channel == {"max_payload_floats": message_floats(CFG)}


def test_shipped_weights_load_never_hear_the_speed_and_follow_the_route():
    """The shipped weights (the sixth run of docs/aurora.md, stages 4-5 with speed dropout 1)
    load strictly from the SHA-256-checked folder, are never told the ego speed (``speed=auto``
    reads the run's dropout) and plan in the route frame: a bent route bends the plan, while
    the speed written in the prompt changes nothing (it says "unknown")."""
    info = json.loads((export_mod.SHIPPED / "aurora" / "aurora.json").read_text())
    cfg = AuroraConfig.from_dict(info["config"])
    assert cfg.plan_speed_dropout == 1.0 and cfg.plan_route_points > 0
    agent = AuroraAgent()  # the shipped folder, SHA-256 checked, strict state-dict load
    assert agent.fingerprint() == ("stage=5 fusion=True planner=vae speed=wp0-wp1 route=4x5m "
                                   "frame=route step=relu_ste prompt_speed=unknown")
    assert NoFusionAgent().fingerprint().startswith("stage=5 fusion=False ")
    w = World(make_config(town="Town05", obs_mode="sensors", camera_images=("rgb",),
                          camera_size=agent.sensors["camera_size"], num_vehicles=2,
                          num_pedestrians=0, num_bicycles=0,
                          max_payload_floats=message_floats(cfg)))
    w.reset(seed=3)
    for _ in range(20):
        w.step(np.array([0.6, 0.0, 0.0]))
    obs = ego_observation(w)
    bent = {**obs, "route": obs["route"].copy()}
    bent["route"][:, 1] += 0.05 * bent["route"][:, 0] ** 2  # the same command, another path
    faster = {**obs, "ego": obs["ego"].copy()}
    faster["ego"][SPEED] += 5.0  # what a prompt that said the speed would read
    a, b, c = agent.act(obs), agent.act(bent), agent.act(faster)
    assert not np.allclose(a["waypoints"], b["waypoints"], atol=1e-3)
    np.testing.assert_allclose(a["waypoints"], c["waypoints"], atol=1e-5)
