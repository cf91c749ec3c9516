"""Checks the cooperative baselines' tests share (``tests/test_baselines_*.py``): the message's
bytes through the channel, overfitting two samples with a unit, and the CLI's train -> resume ->
refuse -> checkpoint round trip -> drive one route."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from v2xbench.envs.v2x_intersection.v2x.channel import Channel, ChannelConfig
from v2xbench.envs.v2x_intersection.v2x.wire import FORMAT_RAW, HEADER_SIZE, encode_message

from v2xbench.cli import main


def assert_channel_counts(payload: np.ndarray, f: int) -> None:
    """A payload of ``f`` floats costs the channel ``HEADER_SIZE + 2 f`` bytes, as encoded."""
    ch = Channel(ChannelConfig(max_payload_floats=f), np.random.default_rng(0))
    sent = ch.send(0, 0, f, payload, FORMAT_RAW)
    assert sent == HEADER_SIZE + 2 * f == len(encode_message(0, 0, payload, fmt=FORMAT_RAW))
    assert ch.stats()["bytes_sent_total"] == sent


def collect_lidar(root: Path) -> Path:
    """The tiny data set (``tests/dataset_helpers.TINY``) recorded into ``root`` with LiDAR points
    only (what the LiDAR baselines train on)."""
    import dataclasses

    from v2xbench.collectors.dataset.collect import collect

    from tests.dataset_helpers import TINY

    collect(dataclasses.replace(TINY, sensors=("lidar",)), root, workers=1, progress=False)
    return root


def unit_batch(ds) -> dict:
    """A batch of the first and the last sample of ``ds`` with a roadside unit."""
    from v2xbench.agents.aurora.data import collate

    with_unit = [i for i in range(len(ds)) if bool(ds[i]["has_rsu"])]
    assert with_unit, "the tiny data set has no frame with a roadside unit"
    return collate([ds[with_unit[0]], ds[with_unit[-1]]])


def overfit(model: torch.nn.Module, crit: torch.nn.Module, batch: dict, steps: int = 60
            ) -> tuple[list[float], list[dict[str, float]]]:
    """``(losses, parts)`` of ``steps`` AdamW steps (lr 3e-3) on one batch."""
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    losses, parts = [], []
    for _ in range(steps):
        loss, p = crit(model(batch), batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        parts.append(p)
    return losses, parts


def train_and_resume(method: str, data: Path, run: Path, capsys,
                     extra: tuple[str, ...] = ()) -> tuple[list[str], list[dict]]:
    """``(the train command, log rows)``: 3 steps, then the same command resumes and finishes
    the epoch (contiguous steps in ``log.jsonl``, ``(done)``); ``extra``: more arguments."""
    base = ["baselines", "train", method, "--data", str(data), "--out", str(run), "--scale",
            "tiny", "--quiet", "--threads", "1", *extra]
    assert main([*base, "--max-steps", "3"]) == 0
    assert "step 3/" in capsys.readouterr().out
    assert main(base) == 0  # resumes at step 3 and finishes the epoch
    out = capsys.readouterr().out
    log = [json.loads(x) for x in (run / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == list(range(1, len(log) + 1)) and "(done)" in out
    return base, log


def refused_error(base: list[str], capsys) -> str:
    """The error of the train command with another seed on the same run folder (exit 2)."""
    assert main([*base, "--seed", "1"]) == 2  # another run's settings on the same folder
    return capsys.readouterr().err


def assert_same_weights(model: torch.nn.Module, other: torch.nn.Module, path: Path) -> None:
    """Saving ``model`` to ``path`` and loading it into ``other`` gives the same weights."""
    from v2xbench.agents.aurora.trainer import load_weights, save_checkpoint

    save_checkpoint(model, path)
    load_weights(other, path)
    for (name, a), b in zip(model.state_dict().items(), other.state_dict().values()):
        assert torch.equal(a, b), name


def drive_one_route(method: str, run: Path | None, tmp_path: Path, f: int,
                    roadside: str, fixed_size: bool = True) -> dict:
    """``v2xbench eval --agent METHOD`` with ``{"run": RUN}`` (``None``: no agent config, the
    shipped weights) on one 15-tick route: no error, the channel limit set to the message's
    ``f`` floats, the method's roadside policy and, with ``fixed_size``, whole messages of
    ``16 + 2 f`` bytes sent (CoDriving's are as long as the cells its unit chooses, none when
    it chooses none). Returns the summary."""
    conf = tmp_path / f"{method}.json"
    conf.write_text(json.dumps({"run": str(run)}))
    res_dir = tmp_path / "eval"
    config = [] if run is None else ["--agent-config", str(conf)]
    assert main(["eval", "--agent", method, *config, "--suite", "test50",
                 "--max-routes", "1", "--set", "max_steps=15", "--out", str(res_dir),
                 "--quiet"]) == 0
    route = json.loads(next((res_dir / "routes").glob("*.json")).read_text())
    assert route["error"] is None and route["ticks"] == 15
    summ = json.loads((res_dir / "summary.json").read_text())
    assert summ["config_overrides"]["max_payload_floats"] == f
    assert summ["rsu_policy"] == f"custom:{roadside}"
    if fixed_size:
        sent = route["record"]["bytes_sent"]  # the channel's count: messages of 16 + 2F bytes
        assert sent > 0 and sent % (HEADER_SIZE + 2 * f) == 0 and summ["metrics"]["bps"] > 0
    return summ


def assert_export_is_the_run(method: str, run: Path, export: Path) -> None:
    """``v2xbench baselines export``'s folder: the run's checkpoint byte for byte, a manifest
    that names the method and its planner switches, loaded by the method's agent; a changed
    file is refused, naming it."""
    import importlib

    from v2xbench.agents.baselines import BASELINES
    from v2xbench.agents.baselines.common.export import verify

    assert (export / "checkpoint.safetensors").read_bytes() == \
        (run / "checkpoint.safetensors").read_bytes()
    m = verify(export, method)
    cfg = importlib.import_module(BASELINES[method] + ".train").load_run(run)[1]
    assert (m["method"], m["plan_frame"], m["plan_ego_speed"], m["scale"]) == \
        (method, cfg.plan_frame, cfg.plan_ego_speed, cfg.scale)
    with pytest.raises(ValueError, match="holds"):
        verify(export, "codriving" if method != "codriving" else "univ2x")
    agent_cls = _agent_class(method)
    assert agent_cls(run=str(export)).cfg == cfg
    bad = export.with_name("tampered")
    shutil.copytree(export, bad)
    f = bad / f"{method}.json"  # the run file (listed in the manifest)
    f.write_text(f.read_text().replace("\n", "\n ", 1))
    with pytest.raises(ValueError, match=f"{f.name} fails its SHA-256 check"):
        agent_cls(run=str(bad))
    for target in (run, run.parent):  # the export never replaces its run
        with pytest.raises(ValueError, match="is or holds the run"):
            main_export(method, run, target)
    other = export.with_name("not_an_export")
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    with pytest.raises(ValueError, match="is not an export"):
        main_export(method, run, other)
    assert (other / "keep.txt").read_text() == "mine"


def main_export(method: str, run: Path, out: Path) -> dict:
    """``export_run`` of the baselines (what ``v2xbench baselines export`` calls)."""
    from v2xbench.agents.baselines.common.export import export_run

    return export_run(method, run, out)


def assert_shipped_weights(method: str, roadside: str, tmp_path: Path,
                           fixed_size: bool = True) -> None:
    """The repository's shipped weights of ``method`` (``agents/baselines/weights/METHOD``):
    SHA-256 checked, the default scale, the planning table's planner (route frame, never told
    the speed, trained on the channel's message age), loaded by the agent without a run, and
    driving one route through ``v2xbench eval`` without an agent config."""
    import importlib

    from v2xbench.agents.baselines import BASELINES
    from v2xbench.agents.baselines.common.export import SHIPPED, verify

    m = verify(SHIPPED / method, method)
    assert (m["scale"], m["plan_frame"], m["plan_ego_speed"]) == ("default", "route", False)
    agent = _agent_class(method)()
    assert Path(agent.run) == SHIPPED / method
    assert agent.cfg.msg_latency_ticks == 1 and agent.cfg.message_floats() == m["message_floats"]
    model = importlib.import_module(BASELINES[method] + ".train").load_run(SHIPPED / method)[0]
    assert m["parameters"] == sum(p.numel() for p in model.parameters())
    drive_one_route(method, None, tmp_path, m["message_floats"], roadside, fixed_size)


def _agent_class(method: str) -> type:
    """The registered agent class of a baseline."""
    import importlib

    from v2xbench.agents.baselines import BASELINES

    mod = importlib.import_module(BASELINES[method] + ".agent")
    return next(v for v in vars(mod).values()
                if isinstance(v, type) and getattr(v, "method", None) == method)


def open_loop_matches_the_model(method: str, run: Path, data: Path, tmp_path: Path,
                                capsys) -> dict:
    """``v2xbench baselines eval-planning METHOD`` on every 5th frame of ``data``: its L2 at
    1 / 2 / 3 s is the trained model's own waypoints against the expert's, recomputed here.
    Returns the metrics."""
    import importlib

    from v2xbench.agents.aurora.data import collate
    from v2xbench.agents.aurora.eval_planning import HORIZONS
    from v2xbench.agents.baselines import BASELINES
    from v2xbench.envs.v2x_intersection.evaluation.metrics_perception import l2_at

    out = tmp_path / "open_loop"
    assert main(["baselines", "eval-planning", method, "--run", str(run), "--data", str(data),
                 "--split", "all", "--stride", "5", "--out", str(out), "--quiet"]) == 0
    assert "L2 model" in capsys.readouterr().out
    res = json.loads((out / "metrics.json").read_text())
    mod = importlib.import_module(BASELINES[method] + ".train")
    model, cfg, _ = mod.load_run(run)
    ds = mod.RUN.frames(data, "all", cfg, 5, False)
    batch = collate([ds[i] for i in range(len(ds))])
    with torch.no_grad():
        wps = model(batch)["waypoints"].double().numpy()
    exp = batch["expert_waypoints"][:, :cfg.plan_waypoints].double().numpy()
    ok = np.isfinite(exp).all((1, 2))
    want = l2_at(wps[ok], exp[ok], HORIZONS, cfg.plan_dt)
    assert res["frames"] == int(ok.sum()) > 0 and res["command"].startswith("v2xbench baselines")
    for k, v in want.items():
        assert abs(res["overall"]["model"][k] - v) < 1e-6, (k, res["overall"]["model"][k], v)
    # the ego-status probe: the model is told 0 m/s; the constant-velocity line keeps the truth
    assert main(["baselines", "eval-planning", method, "--run", str(run), "--data", str(data),
                 "--split", "all", "--stride", "5", "--out", str(out / "speed0"), "--ego-speed",
                 "0", "--quiet"]) == 0
    assert "told an ego speed of 0 m/s" in capsys.readouterr().out
    probe = json.loads((out / "speed0" / "metrics.json").read_text())
    with torch.no_grad():
        wps0 = model(dict(batch, ego_speed=torch.zeros_like(batch["ego_speed"])))["waypoints"]
    want0 = l2_at(wps0.double().numpy()[ok], exp[ok], HORIZONS, cfg.plan_dt)
    assert probe["ego_speed_input"] == 0.0 and res["ego_speed_input"] == "frame"
    assert probe["overall"]["constant_velocity"] == res["overall"]["constant_velocity"]
    if cfg.plan_ego_speed:  # the speed reaches the planner
        assert any(abs(want0[k] - want[k]) > 1e-6 for k in want), (want0, want)
    else:  # a planner never told the speed: the probe changes nothing
        assert want0 == want, (want0, want)
    for k, v in want0.items():
        assert abs(probe["overall"]["model"][k] - v) < 1e-6, (k, probe["overall"]["model"][k], v)
    return res


__all__ = ["assert_channel_counts", "assert_export_is_the_run", "assert_same_weights",
           "assert_shipped_weights", "drive_one_route",
           "open_loop_matches_the_model", "overfit", "refused_error", "train_and_resume",
           "unit_batch"]
