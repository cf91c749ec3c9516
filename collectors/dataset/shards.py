"""Shards on disk: one episode per TensorDict memmap folder, written atomically, with checksums.

Layout of a data set root::

    <root>/manifest.json                 what was asked (suite, config) and every finished shard
    <root>/shards/<episode_id>/          one episode (route x seed index), batch size [T]
        data/                            TensorDict memmap (``TensorDict.load_memmap``)
        images/t00010_cam_front.png ...  keyframe camera images (6 ego + rsu_cam), for Chat-V2XBench
        keyframes.jsonl                  keyframe facts (privileged state, :mod:`..chat.facts`)
        shard.json                       episode metadata + size and CRC32 of every file above

A shard is built in ``<root>/shards/.tmp-<episode_id>-<pid>`` and renamed into place once
``shard.json`` (written last) is complete, so a shard folder either is whole or does not exist;
temporary folders left by an interrupted run are removed when collection resumes.
:func:`validate` re-reads every file and reports missing, unlisted and corrupt shards by name.
"""

from __future__ import annotations

import json
import os
import shutil
import zlib
from pathlib import Path
from typing import Any

SHARD_FORMAT = "v2xbench-shard/1"
MANIFEST_FORMAT = "v2xbench-dataset/1"
_CHUNK = 1 << 20


def write_json_atomic(obj: Any, path: str | Path) -> None:
    """Write JSON to ``path`` through a temporary file and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1, sort_keys=True)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def shards_dir(root: str | Path) -> Path:
    """``<root>/shards``."""
    return Path(root) / "shards"


def file_crc(path: Path) -> int:
    """CRC32 of a file's bytes."""
    crc = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            crc = zlib.crc32(chunk, crc)
    return crc


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file() and p.name != "shard.json")


def temp_shard(root: str | Path, episode_id: str) -> Path:
    """A fresh temporary folder for building shard ``episode_id``."""
    tmp = shards_dir(root) / f".tmp-{episode_id}-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    return tmp


def finish_shard(tmp: Path, root: str | Path, episode_id: str, meta: dict) -> Path:
    """Checksum every file of ``tmp``, write its ``shard.json`` and rename it into place.

    Returns:
        The final shard folder. If another worker finished the same shard first, ``tmp`` is
        discarded (episodes are deterministic, so both are the same).
    """
    files = {p.relative_to(tmp).as_posix(): [p.stat().st_size, file_crc(p)] for p in _files(tmp)}
    meta = dict(meta, format=SHARD_FORMAT, id=episode_id, files=files)
    with open(tmp / "shard.json", "w") as f:
        json.dump(meta, f, indent=1, sort_keys=True)
        f.flush()
        os.fsync(f.fileno())
    final = shards_dir(root) / episode_id
    try:
        os.rename(tmp, final)
    except OSError:
        if (final / "shard.json").exists():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            raise
    return final


def clear_temp(root: str | Path) -> list[str]:
    """Remove temporary shard folders of interrupted runs; returns their names."""
    d = shards_dir(root)
    if not d.exists():
        return []
    gone = []
    for p in d.glob(".tmp-*"):
        shutil.rmtree(p, ignore_errors=True)
        gone.append(p.name)
    return gone


def read_meta(folder: Path) -> dict | None:
    """A shard's ``shard.json`` (``None`` if absent or unreadable)."""
    try:
        return json.loads((folder / "shard.json").read_text())
    except (OSError, ValueError):
        return None


def finished_shards(root: str | Path) -> dict[str, dict]:
    """``{episode_id: shard.json}`` of every complete shard folder."""
    d = shards_dir(root)
    out = {}
    if d.exists():
        for p in sorted(d.iterdir()):
            if p.is_dir() and not p.name.startswith("."):
                m = read_meta(p)
                if m is not None:
                    out[p.name] = m
    return out


def load_manifest(root: str | Path) -> dict:
    """The data set's manifest (raises ``FileNotFoundError`` with the path when absent)."""
    path = Path(root) / "manifest.json"
    if not path.exists():
        raise FileNotFoundError(f"no data set at {root}: {path} is missing (run `v2xbench collect`)")
    return json.loads(path.read_text())


def load_shard(root: str | Path, episode_id: str):
    """The TensorDict memmap of a shard (read-only view of the files)."""
    from tensordict import TensorDict

    return TensorDict.load_memmap(shards_dir(root) / episode_id / "data")


def check_shard(folder: Path, deep: bool = True) -> list[str]:
    """Problems of one shard folder (empty list: sound).

    Checks ``shard.json``, every listed file's presence, size and (``deep``) CRC32, files not
    listed, and that the memmap loads with ``frames`` rows.
    """
    meta = read_meta(folder)
    if meta is None:
        return ["shard.json missing or unreadable"]
    problems = []
    listed = meta.get("files", {})
    for rel, (size, crc) in listed.items():
        p = folder / rel
        if not p.exists():
            problems.append(f"missing file {rel}")
        elif p.stat().st_size != size:
            problems.append(f"size of {rel} is {p.stat().st_size}, expected {size}")
        elif deep and file_crc(p) != crc:
            problems.append(f"checksum mismatch in {rel}")
    extra = sorted(set(p.relative_to(folder).as_posix() for p in _files(folder)) - set(listed))
    problems += [f"unlisted file {rel}" for rel in extra]
    if not problems:
        try:
            from tensordict import TensorDict

            td = TensorDict.load_memmap(folder / "data")
            if td.batch_size[0] != meta.get("frames"):
                problems.append(f"data has {td.batch_size[0]} frames, shard.json says {meta.get('frames')}")
        except Exception as e:  # noqa: BLE001  (any load failure is a finding)
            problems.append(f"data does not load: {type(e).__name__}: {e}")
    return problems


def validate(root: str | Path, deep: bool = True) -> dict:
    """Check a data set: every manifest shard present and sound, no unlisted shards.

    Returns:
        ``{"ok": bool, "shards": n checked, "missing": [ids], "corrupt": {id: [problems]},
        "unlisted": [ids], "pending": [planned ids not collected yet], "temporary": [names]}``.
    """
    man = load_manifest(root)
    d = shards_dir(root)
    listed = man.get("shards", {})
    on_disk = {p.name for p in d.iterdir() if p.is_dir()} if d.exists() else set()
    report: dict = {"missing": [], "corrupt": {}, "unlisted": [], "shards": len(listed),
                    "temporary": sorted(n for n in on_disk if n.startswith("."))}
    for sid in sorted(listed):
        if sid not in on_disk:
            report["missing"].append(sid)
            continue
        problems = check_shard(d / sid, deep)
        if problems:
            report["corrupt"][sid] = problems
    report["unlisted"] = sorted(n for n in on_disk - set(listed) if not n.startswith("."))
    report["pending"] = [e for e in man.get("episodes", []) if e not in listed]
    report["ok"] = not (report["missing"] or report["corrupt"] or report["unlisted"])
    return report


__all__ = ["MANIFEST_FORMAT", "SHARD_FORMAT", "check_shard", "clear_temp", "file_crc",
           "finish_shard", "finished_shards", "load_manifest", "load_shard", "read_meta",
           "shards_dir", "temp_shard", "validate", "write_json_atomic"]
