"""Expert data collection: atomic shards, resume to identical content, validation, loading."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from v2xbench.collectors.dataset.collect import CollectConfig, collect, route_split
from v2xbench.collectors.dataset.loader import V2XDataset, replay_buffer
from v2xbench.collectors.dataset.perturb import PerturbConfig, Perturber
from v2xbench.collectors.dataset.record import REASONS, unpack_bev
from v2xbench.collectors.dataset.shards import load_manifest, load_shard, shards_dir, validate
from v2xbench.envs.v2x_intersection.sensors import BEV_CHANNELS, SensorRig

from tests.dataset_helpers import TINY
from v2xbench.cli import main


def _shard_files(root):
    """{relative path: bytes} of every shard file (data, images, keyframes, shard.json)."""
    d = shards_dir(root)
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_manifest_and_shards(tiny_dataset):
    man = load_manifest(tiny_dataset)
    assert man["complete"] and man["episodes"] == ["train_000_s0", "train_001_s0"]
    assert set(man["shards"]) == set(man["episodes"])
    for sid, s in man["shards"].items():
        td = load_shard(tiny_dataset, sid)
        assert td.batch_size[0] == s["frames"] == 41
        assert torch.equal(td["tick"], torch.arange(41))
        assert s["keyframes"] == 5  # ticks 0, 10, 20, 30, 40
        assert td["cameras", "rsu_cam", "rgb"].shape == (41, 16, 32, 3)
        # expert labels: waypoints ahead of a moving ego, reasons are known codes
        assert (td["expert_reason"] < len(REASONS)).all()
        assert td["gt", "fused", "mask"].sum(-1).le(td["gt", "fused", "count"]).all()
        # ego/rsu sets are subsets of the fused set (by id)
        for t in (10, 30):
            ids = set(td["gt", "fused", "id"][t][td["gt", "fused", "mask"][t]].tolist())
            ego = set(td["gt", "ego", "id"][t][td["gt", "ego", "mask"][t]].tolist())
            assert ego <= ids
        bev = unpack_bev(td["bev_bits"][5].numpy())
        assert bev.shape == (len(BEV_CHANNELS), 128, 128) == (15, 128, 128) and bev.max() == 1


def test_interrupted_collection_resumes_to_same_content(tiny_dataset, tmp_path, monkeypatch):
    root = tmp_path / "resumed"
    collect(TINY, root, progress=False, max_episodes=1)  # stopped between episodes
    assert validate(root)["pending"] == ["train_001_s0"]
    calls = {"n": 0}
    real = SensorRig.capture

    def dying(self, world):
        calls["n"] += 1
        if calls["n"] > 17:
            raise KeyboardInterrupt("power cut")
        return real(self, world)

    monkeypatch.setattr(SensorRig, "capture", dying)
    with pytest.raises(KeyboardInterrupt):
        collect(TINY, root, progress=False)  # killed in the middle of the second episode
    monkeypatch.setattr(SensorRig, "capture", real)
    rep = validate(root)
    assert rep["ok"] and rep["temporary"] and rep["pending"] == ["train_001_s0"]
    assert not (shards_dir(root) / "train_001_s0").exists()  # no half shard in place
    man = collect(TINY, root, progress=False)
    assert man["complete"] and validate(root)["temporary"] == []
    assert _shard_files(root) == _shard_files(tiny_dataset)


def test_resume_with_other_settings_is_refused(tiny_dataset, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(tiny_dataset, root)
    with pytest.raises(ValueError, match="other settings"):
        collect(CollectConfig(max_routes=2, max_ticks=41), root, progress=False)


def test_corrupt_missing_and_unlisted_shards_are_named(tiny_dataset, tmp_path, capsys):
    root = tmp_path / "copy"
    shutil.copytree(tiny_dataset, root)
    assert validate(root)["ok"] and main(["data", "validate", str(root)]) == 0
    f = shards_dir(root) / "train_000_s0" / "data" / "ego_speed.memmap"
    raw = bytearray(f.read_bytes())
    raw[5] ^= 0xFF  # one flipped byte, same size
    f.chmod(0o644)  # finished shard files are read-only
    f.write_bytes(bytes(raw))
    rep = validate(root)
    assert not rep["ok"] and list(rep["corrupt"]) == ["train_000_s0"]
    assert "checksum mismatch in data/ego_speed.memmap" in rep["corrupt"]["train_000_s0"]
    assert validate(root, deep=False)["ok"]  # a size-only check cannot see it
    shutil.rmtree(shards_dir(root) / "train_001_s0")
    shutil.copytree(shards_dir(tiny_dataset) / "train_000_s0", shards_dir(root) / "stray")
    rep = validate(root)
    assert rep["missing"] == ["train_001_s0"] and rep["unlisted"] == ["stray"]
    capsys.readouterr()
    assert main(["data", "validate", str(root)]) == 1
    out = capsys.readouterr().out
    assert "CORRUPT  train_000_s0: checksum mismatch" in out and "MISSING  train_001_s0" in out
    (shards_dir(root) / "train_000_s0" / "images" / "t00010_cam_front.png").unlink()
    assert "missing file images/t00010_cam_front.png" in validate(root)["corrupt"]["train_000_s0"]


def test_dataset_splits_by_route_and_replay_buffer(tiny_dataset):
    splits = {s["route_id"]: s["split"] for s in load_manifest(tiny_dataset)["shards"].values()}
    assert splits == {r: route_split(r, "train", 0.5) for r in splits}
    assert set(splits.values()) == {"train", "val"}  # the hash puts one route in each here
    tr, va, al = (V2XDataset(tiny_dataset, s) for s in ("train", "val", "all"))
    assert len(tr) + len(va) == len(al) == 82
    assert not {m["route_id"] for m in tr.meta} & {m["route_id"] for m in va.meta}
    x = al[50]
    e, t = al.locate(50)
    assert (e, t) == (1, 9) and int(x["tick"]) == 9 and int(x["episode"]) == 1
    assert x["expert_waypoints"].shape == (8, 2) and x["gt", "fused", "boxes"].shape == (96, 9)
    assert x["calib", "T_world_cam"].shape == (7, 4, 4)
    with pytest.raises(IndexError):
        al[82]
    with pytest.raises(ValueError, match="split"):
        V2XDataset(tiny_dataset, "dev")
    speeds = al.columns("ego_speed")  # one array per episode, frames on axis 0
    assert [len(v) for v in speeds] == [m["frames"] for m in al.meta]
    assert float(speeds[1][9]) == pytest.approx(float(x["ego_speed"]))
    with pytest.raises(KeyError):
        V2XDataset(tiny_dataset, "all", keys=["no_such_column"]).columns("no_such_column")
    rb = replay_buffer(tiny_dataset, "all", batch_size=6, keys=["ego_speed", "expert_waypoints"])
    b = rb.sample()
    assert b.batch_size == torch.Size([6]) and b["expert_waypoints"].shape == (6, 8, 2)
    assert set(b.keys()) == {"ego_speed", "expert_waypoints", "episode"}


def test_perturbation_bursts_and_labels():
    p = Perturber(PerturbConfig(rate_per_s=10.0), seed=3)
    ctrl = np.array([0.4, 0.0, 0.0], np.float32)
    out, noisy = p.apply(0, ctrl, speed=8.0, reason="free")
    assert noisy and not np.allclose(out, ctrl) and len(p.events) == 1
    out, noisy = p.apply(1, ctrl, speed=8.0, reason="red")  # a binding constraint ends the burst
    assert not noisy and np.array_equal(out, ctrl)
    assert not Perturber(PerturbConfig(rate_per_s=10.0), 3).apply(0, ctrl, 1.0, "free")[1]  # too slow
    assert not Perturber(None, 3).apply(0, ctrl, 8.0, "free")[1]
    with pytest.raises(ValueError):
        PerturbConfig(steer=(0.3, 0.1))


def test_perturbed_frames_keep_the_expert_label(tmp_path, monkeypatch):
    import v2xbench.collectors.dataset.collect as C

    cfg = CollectConfig(max_routes=1, max_ticks=60, camera_size=(16, 8), lidar_scale=0.25,
                        sensors=(), env={"num_vehicles": 0, "num_pedestrians": 0})
    monkeypatch.setattr(C, "PerturbConfig", lambda: PerturbConfig(rate_per_s=5.0, min_speed=0.5))
    collect(cfg, tmp_path, progress=False)
    td = load_shard(tmp_path, "train_000_s0")
    noisy = td["perturbed"]
    assert noisy.any()
    diff = (td["control"] - td["expert_control"]).abs().sum(-1)
    assert (diff[noisy] > 0).all() and (diff[~noisy] == 0).all()
    meta = json.loads((shards_dir(tmp_path) / "train_000_s0" / "shard.json").read_text())
    assert sum(e[1] for e in meta["perturbations"]) >= int(noisy.sum())


def test_cli_collect_and_validate(tmp_path, capsys):
    out = tmp_path / "cli"
    args = ["collect", "--scale", "tiny", "--max-routes", "1", "--max-ticks", "12", "--camera-size", "16x8",
            "--lidar-scale", "0.25", "--sensors", "rgb", "--out", str(out), "--quiet"]
    assert main(args) == 0
    assert "1/1 episodes, 13 frames, 2 keyframes" in capsys.readouterr().out
    assert main(["data", "validate", str(out)]) == 0
    other = [a if a != "16x8" else "32x16" for a in args]
    assert main(other) == 2  # a resume with other settings is refused
    assert main(["collect", "--sensors", "radar", "--out", str(tmp_path / "x"), "--quiet"]) == 2


def test_failed_episode_is_recorded_and_retried(tmp_path, monkeypatch):
    cfg = CollectConfig(max_routes=1, max_ticks=5, camera_size=(16, 8), lidar_scale=0.25, sensors=())

    def broken(self, world):
        raise RuntimeError("sensor fault")

    real = SensorRig.capture
    monkeypatch.setattr(SensorRig, "capture", broken)
    man = collect(cfg, tmp_path, progress=False)
    assert man["failed"] == {"train_000_s0": "RuntimeError: sensor fault"} and not man["complete"]
    assert validate(tmp_path)["pending"] == ["train_000_s0"] and validate(tmp_path)["temporary"] == []
    monkeypatch.setattr(SensorRig, "capture", real)
    man = collect(cfg, tmp_path, progress=False)
    assert man["failed"] == {} and man["complete"] and validate(tmp_path)["temporary"] == []


@pytest.mark.slow  # spawns two worker processes (imports torch twice)
def test_two_worker_processes_write_the_same_shards(tiny_dataset, tmp_path):
    collect(TINY, tmp_path, workers=2, progress=False)
    assert _shard_files(tmp_path) == _shard_files(tiny_dataset)
