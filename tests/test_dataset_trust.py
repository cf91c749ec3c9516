"""A data set from someone else: loading it never runs code, never writes, and refuses what its
metadata and the record schema do not describe (#31 items 1, 2, 5, 10).

Every crafted data set here re-lists its files in ``shard.json`` with fresh sizes and CRCs
(:func:`_relist`), as an attacker would, so only the new checks can catch it.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tensordict import NonTensorData, TensorDict
from v2xbench.collectors.dataset import collect as C
from v2xbench.collectors.dataset.collect import CollectConfig, collect
from v2xbench.collectors.dataset.loader import V2XDataset
from v2xbench.collectors.dataset.parent_watch import EXIT_CODE, exit_with_parent
from v2xbench.collectors.dataset.safe_memmap import ShardDataError
from v2xbench.collectors.dataset.shards import (
    file_crc,
    load_manifest,
    load_shard,
    shards_dir,
    validate,
)
from v2xbench.envs.v2x_intersection.sensors import SensorRig

from v2xbench.cli import main
from v2xbench.locks import DirectoryLocked, dir_lock

SID = "train_000_s0"  # episode 0 of the tiny data set (sorted first)
#: a small, fast collection for the collect-side tests (1 route, 7 frames, no stored sensors)
SMALL = CollectConfig(max_routes=1, max_ticks=6, camera_size=(16, 8), lidar_scale=0.25,
                      sensors=())


@pytest.fixture
def root(tiny_dataset, tmp_path) -> Path:
    """A private copy of the shared tiny data set (finished shard files stay read-only)."""
    dst = tmp_path / "ds"
    shutil.copytree(tiny_dataset, dst)
    return dst


def _data(root: Path, sid: str = SID) -> Path:
    return shards_dir(root) / sid / "data"


def _writable(path: Path) -> Path:
    path.chmod(0o644)
    return path


def _relist(root: Path, sid: str = SID) -> None:
    """Re-list every regular file of a shard in its shard.json (fresh sizes and CRCs)."""
    folder = shards_dir(root) / sid
    meta = json.loads((folder / "shard.json").read_text())
    files = {}
    for dirpath, _, names in os.walk(folder):
        for n in names:
            p = Path(dirpath) / n
            rel = p.relative_to(folder).as_posix()
            if rel != "shard.json" and p.is_file() and not p.is_symlink():
                files[rel] = [p.stat().st_size, file_crc(p)]
    meta["files"] = files
    _writable(folder / "shard.json").write_text(json.dumps(meta))


def _bytes(root: Path) -> dict[str, bytes]:
    d = shards_dir(root)
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*"))
            if p.is_file() and not p.is_symlink()}


def _edit_meta(path: Path, fn) -> None:
    meta = json.loads(path.read_text())
    fn(meta)
    _writable(path).write_text(json.dumps(meta))


def _refused_everywhere(root: Path, capsys, *needles: str) -> None:
    """The data set fails to load (V2XDataset, load_shard) and to validate (deep, quick, CLI),
    each time naming the shard and every needle."""
    with pytest.raises(ShardDataError) as e:
        V2XDataset(root, "all")[0]
    with pytest.raises(ShardDataError) as e2:
        load_shard(root, SID)
    for msg in (str(e.value), str(e2.value)):
        assert SID in msg and all(n in msg for n in needles), msg
    for deep in (True, False):
        rep = validate(root, deep=deep)
        assert not rep["ok"] and list(rep["corrupt"]) == [SID], rep
        assert any(all(n in p for n in needles) for p in rep["corrupt"][SID]), rep["corrupt"]
    capsys.readouterr()
    assert main(["data", "validate", str(root), "--quick"]) == 1
    out = capsys.readouterr().out
    assert f"CORRUPT  {SID}:" in out and "FAILED" in out


class _Payload:
    """Unpickling this creates ``path`` (a stand-in for arbitrary code)."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def _pickle_folder(tmp: Path, marker: Path, frames: int) -> Path:
    """A NonTensorData key folder holding a pickle whose loading creates ``marker``."""
    td = TensorDict({"evil": NonTensorData(_Payload(marker), batch_size=[frames])},
                    batch_size=[frames])
    td.memmap_(tmp)
    assert (tmp / "evil" / "other.pickle").exists() and not marker.exists()
    return tmp / "evil"


@pytest.mark.parametrize("where", ["new_key", "replaces_ego_speed"])
def test_pickle_payload_is_refused_and_never_runs(root, tmp_path, capsys, where):
    marker = tmp_path / "MARKER"
    evil = _pickle_folder(tmp_path / "payload", marker, 41)
    data = _data(root)
    name = "evil" if where == "new_key" else "ego_speed"
    shutil.copytree(evil, data / name)
    if name == "ego_speed":
        (data / "ego_speed.memmap").unlink()

    def add(meta):
        meta[name] = {"type": "NonTensorData"}

    _edit_meta(data / "meta.json", add)
    _relist(root)
    _refused_everywhere(root, capsys, repr(name))
    assert not marker.exists()  # nothing was unpickled
    # the payload is real: tensordict's own loader, told to trust it, runs it
    TensorDict.load_memmap(data, allow_pickle=True)
    assert marker.exists()


def test_unlisted_pickle_file_and_links_are_refused(root, capsys):
    data = _data(root)
    (data / "calib" / "extra.pkl").write_bytes(b"\x80\x04K\x01.")
    _relist(root)
    _refused_everywhere(root, capsys, "data/calib/extra.pkl", "not in the record schema")
    (data / "calib" / "extra.pkl").unlink()
    tick = data / "tick.memmap"
    shutil.copy(tick, root / "tick_copy.memmap")
    tick.unlink()
    tick.symlink_to(root / "tick_copy.memmap")  # same bytes, but a link
    _relist(root)
    _refused_everywhere(root, capsys, "tick.memmap")


def _truncate_camera(data: Path) -> str:
    f = _writable(data / "cameras" / "cam_front" / "rgb.memmap")
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])  # frames 20..40 would read as zeros
    return "data/cameras/cam_front/rgb.memmap"


def _empty_ego_pose(data: Path) -> str:
    _writable(data / "ego_pose.memmap").write_bytes(b"")
    return "data/ego_pose.memmap"


def _retype_ego_pose(data: Path) -> str:
    def retype(meta):  # same item size: only the dtype check can tell
        meta["ego_pose"]["dtype"] = "torch.int64"

    _edit_meta(data / "meta.json", retype)
    return "data/meta.json"


@pytest.mark.parametrize("damage,relist", [(_truncate_camera, True), (_truncate_camera, False),
                                           (_empty_ego_pose, True), (_retype_ego_pose, True)])
def test_damaged_files_fail_by_name_and_stay_unchanged(root, capsys, damage, relist):
    rel = damage(_data(root))
    if relist:
        _relist(root)
    before = _bytes(root)
    _refused_everywhere(root, capsys, rel.split("/")[-1] if relist else rel)
    assert _bytes(root) == before  # nothing extended, zero-filled or rewritten


def test_in_place_ops_never_write_to_disk(root):
    before = _bytes(root)
    ds = V2XDataset(root, "all")
    td = ds.shard(0)
    td["ego_speed"].add_(1.0)
    td["cameras", "cam_front", "rgb"].zero_()
    td.apply_(lambda x: x.zero_())
    assert float(td["ego_pose"].abs().sum()) == 0.0  # the change is visible in this process ...
    frame = ds[5]
    frame["tick"].fill_(-1)
    shard = load_shard(root, "train_001_s0")
    shard["ego_pose"][3] = 1e9
    assert _bytes(root) == before  # ... and never reaches the files
    fresh = load_shard(root, SID)
    assert fresh["tick"][5] == 5 and float(fresh["ego_pose"].abs().sum()) > 0
    clone = pickle.loads(pickle.dumps(ds))  # DataLoader workers re-open, never copy, the maps
    assert len(pickle.dumps(ds)) < 100_000 and int(clone[5]["tick"]) == 5


def test_finished_shard_files_are_read_only(tiny_dataset):
    files = [p for p in shards_dir(tiny_dataset).rglob("*") if p.is_file()]
    assert len(files) > 100
    assert all(p.stat().st_mode & 0o222 == 0 for p in files)


def test_paths_and_json_in_the_metadata_are_checked(root, capsys):
    path = _writable(root / "manifest.json")
    original = path.read_text()
    man = json.loads(original)
    man["shards"]["../../outside"] = man["shards"][SID]
    path.write_text(json.dumps(man))
    for call in (lambda: V2XDataset(root, "all"), lambda: validate(root)):
        with pytest.raises(ValueError, match=r"'\.\./\.\./outside' is not a plain shard name"):
            call()
    path.write_text("{not json")
    capsys.readouterr()
    assert main(["data", "validate", str(root)]) == 2
    assert f"{path} is not valid JSON" in capsys.readouterr().err
    path.write_text(original)
    _edit_meta(shards_dir(root) / SID / "shard.json",
               lambda m: m["files"].update({"../../manifest.json": [1, 2]}))
    with pytest.raises(ValueError, match=r"shard train_000_s0.*'\.\./\.\./manifest\.json' is "
                       "not a plain relative path"):
        V2XDataset(root, "all")
    assert "not a plain relative path" in validate(root)["corrupt"][SID][0]


def test_every_sensor_matches_the_record_schema(tmp_path):
    cfg = CollectConfig(max_routes=1, max_ticks=2, camera_size=(16, 8), lidar_scale=0.25,
                        sensors=("rgb", "depth", "semantic", "lidar", "bev"))
    collect(cfg, tmp_path, progress=False)
    td = load_shard(tmp_path, "train_000_s0")  # exactly the schema, or it would not load
    keys = {k if isinstance(k, tuple) else (k,) for k in td.keys(True, True)}
    assert keys == set(cfg.record_schema())
    assert td["lidar", "rsu", "points"].shape[-1] == 6
    assert td["cameras", "rsu_cam", "depth"].shape == (3, 8, 16)
    assert validate(tmp_path)["ok"] and load_manifest(tmp_path)["complete"]


# --- collect: lock, orphaned workers, temporary folders (items 5 and 10) -------------------------


def test_collect_refuses_a_folder_in_use(tmp_path, capsys):
    with dir_lock(tmp_path, "test"):
        with pytest.raises(DirectoryLocked, match=f"in use by pid {os.getpid()}"):
            collect(SMALL, tmp_path, progress=False)
        capsys.readouterr()
        assert main(["collect", "--max-routes", "1", "--max-ticks", "6", "--camera-size", "16x8",
                     "--sensors", "", "--lidar-scale", "0.25", "--out", str(tmp_path),
                     "--quiet"]) == 2
        assert f"in use by pid {os.getpid()}" in capsys.readouterr().err
    assert not (tmp_path / "manifest.json").exists()  # refused before writing anything


def test_pool_workers_exit_with_their_parent(tmp_path, monkeypatch):
    """The worker pool starts every worker with the parent watch (run inline here)."""
    from concurrent.futures import Future

    seen = {}

    class InlinePool:
        def __init__(self, max_workers, mp_context, initializer, initargs):
            seen.update(workers=max_workers, initializer=initializer, initargs=initargs)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def submit(self, fn, *args):
            fut = Future()
            fut.set_result(fn(*args))
            return fut

    monkeypatch.setattr(C, "ProcessPoolExecutor", InlinePool)
    man = collect(CollectConfig(max_routes=2, max_ticks=2, camera_size=(16, 8), lidar_scale=0.25,
                                sensors=()), tmp_path, workers=2, progress=False)
    assert man["complete"] and seen == {"workers": 2, "initializer": exit_with_parent,
                                        "initargs": (os.getpid(),)}


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def test_orphaned_worker_exits_when_its_parent_is_killed():
    child = ("import os, time\n"
             "from v2xbench.collectors.dataset.parent_watch import exit_with_parent\n"
             "exit_with_parent(os.getppid(), poll_s=0.1)\n"
             "print('ready', flush=True)\n"
             "time.sleep(120)\n")
    parent = ("import subprocess, sys, time\n"
              f"p = subprocess.Popen([sys.executable, '-c', {child!r}])\n"
              "print(p.pid, flush=True)\n"
              "time.sleep(120)\n")
    proc = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE, text=True)
    worker = None
    try:
        worker = int(proc.stdout.readline())
        assert proc.stdout.readline().strip() == "ready" and _alive(worker)
        proc.send_signal(signal.SIGKILL)  # the parent dies without cleaning up
        proc.wait(10)
        deadline = time.monotonic() + 10
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(worker), "the orphaned worker kept running"
    finally:
        proc.kill()
        if worker is not None and _alive(worker):
            os.kill(worker, signal.SIGKILL)
    assert EXIT_CODE != 0
    with pytest.raises(ValueError, match="parent_pid"):
        exit_with_parent(0)


def test_temp_shard_folders_of_an_interrupted_collect_are_removed(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = SensorRig.capture

    def dying(self, world):
        calls["n"] += 1
        if calls["n"] > 3:
            raise KeyboardInterrupt("power cut")
        return real(self, world)

    monkeypatch.setattr(SensorRig, "capture", dying)
    with pytest.raises(KeyboardInterrupt):
        collect(SMALL, tmp_path, progress=False)
    monkeypatch.setattr(SensorRig, "capture", real)
    d = shards_dir(tmp_path)
    (left,) = d.glob(".tmp-*")
    assert any(p.is_file() for p in left.rglob("*"))  # a half-written episode
    # as a killed process (another pid) leaves it, with a read-only file and a manifest tmp
    dead = d / f".tmp-train_000_s0-{2**22 + 7}"
    left.rename(dead)
    ro = dead / "stale.bin"
    ro.write_bytes(b"x")
    ro.chmod(0o444)
    (tmp_path / f".manifest.json.{2**22 + 7}.tmp").write_text("{")
    assert validate(tmp_path)["temporary"] == [dead.name]
    man = collect(SMALL, tmp_path, progress=False)
    assert man["complete"]
    assert not dead.exists() and list(d.glob(".*")) == []
    assert list(tmp_path.glob(".manifest.json.*")) == []
    assert validate(tmp_path)["ok"] and validate(tmp_path)["temporary"] == []


def test_collect_arguments_are_checked_up_front(tmp_path, capsys):
    out = str(tmp_path / "x")
    base = ["collect", "--out", out, "--quiet"]
    for extra, needle in ((["--max-episodes", "-1"], "--max-episodes: -1 must be >= 1"),
                          (["--workers", "0"], "--workers: 0 must be >= 1"),
                          (["--camera-size", "128by64"], "expected WxH"),
                          (["--seeds", "0"], "--seeds: 0 must be >= 1")):
        with pytest.raises(SystemExit) as e:
            main(base + extra)
        assert e.value.code == 2 and needle in capsys.readouterr().err
    for extra, needle in ((["--set", "num_vehicles=-3"], "num_vehicles"),
                          (["--camera-size", "100000x64"], "camera_size"),
                          (["--workers", "100000"], "workers=100000")):
        assert main(base + extra) == 2
        assert needle in capsys.readouterr().err
    afile = tmp_path / "afile"
    afile.write_text("")
    assert main(["collect", "--out", str(afile / "sub"), "--quiet"]) == 2
    assert str(afile) in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # nothing was started
    with pytest.raises(ValueError, match="max_episodes=0"):
        collect(SMALL, tmp_path / "y", max_episodes=0)
    with pytest.raises(ValueError, match="keyframe_every=0"):
        CollectConfig(keyframe_every=0)
    with pytest.raises(ValueError, match="max_routes=-1"):
        CollectConfig(max_routes=-1)


def test_failed_episodes_exit_non_zero(tmp_path, monkeypatch, capsys):
    def broken(self, world):
        raise RuntimeError("sensor fault")

    monkeypatch.setattr(SensorRig, "capture", broken)
    args = ["collect", "--max-routes", "1", "--max-ticks", "3", "--camera-size", "16x8",
            "--sensors", "", "--lidar-scale", "0.25", "--out", str(tmp_path), "--quiet"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "FAILED train_000_s0: RuntimeError: sensor fault" in err and "1 episodes failed" in err
