"""Shards on disk: one episode per TensorDict memmap folder, written atomically, with checksums.

Layout of a data set root::

    <root>/manifest.json                 what was asked (suite, config) and every finished shard
    <root>/shards/<episode_id>/          one episode (route x seed index), batch size [T]
        data/                            TensorDict memmap (read with :func:`open_shard`)
        images/t00010_cam_front.png ...  keyframe camera images (6 ego + rsu_cam), for Chat-V2XBench
        keyframes.jsonl                  keyframe facts (privileged state, :mod:`..chat.facts`)
        shard.json                       episode metadata + size and CRC32 of every file above

A shard is built in ``<root>/shards/.tmp-<episode_id>-<pid>``; its files are fsynced, listed
with their sizes and CRCs in ``shard.json`` (written last), made read-only, and the folder is
renamed into place, so a shard folder either is whole or does not exist; temporary folders
left by an interrupted run are removed when collection resumes.

Reading never trusts the files (a data set may come from someone else): the manifest and
``shard.json`` are checked JSON (shard names are plain names, listed files plain relative
paths), every listed file must be present with its listed size and no other file or link may
be there, and the memmap is opened by :mod:`.safe_memmap` (exactly the record schema of the
manifest's settings, sizes checked before mapping, copy-on-write mapping, nothing unpickled).
:func:`validate` also re-reads every file's CRC and reports missing, unlisted and corrupt
shards by name.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import stat
import zlib
from pathlib import Path

from v2xbench.files import atomic_write_json

from .safe_memmap import ShardDataError, open_memmap

SHARD_FORMAT = "v2xbench-shard/1"
MANIFEST_FORMAT = "v2xbench-dataset/1"
READ_ONLY = stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH
MAX_JSON_BYTES = 64 << 20  # manifest.json / shard.json larger than this are refused unread
_CHUNK = 1 << 20
_ID = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,199}$")


def shards_dir(root: str | Path) -> Path:
    """``<root>/shards``."""
    return Path(root) / "shards"


def check_id(sid, where: str) -> str:
    """``sid`` when it is a plain shard name (letters, digits, ``_.-``; no path, not hidden).

    Raises:
        ValueError: naming ``where`` it came from.
    """
    if not isinstance(sid, str) or not _ID.fullmatch(sid) or sid.strip(".") == "":
        raise ValueError(f"{where}: {sid!r} is not a plain shard name (refused)")
    return sid


def file_crc(path: Path) -> int:
    """CRC32 of a file's bytes."""
    crc = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            crc = zlib.crc32(chunk, crc)
    return crc


def _entries(folder: Path) -> tuple[list[str], list[str]]:
    """``(regular files, other entries: links, fifos, ...)`` under ``folder`` as relative paths,
    without following links; ``shard.json`` is left out."""
    files, other = [], []
    for dirpath, dirnames, filenames in os.walk(folder, followlinks=False):
        base = Path(dirpath)
        for name in list(dirnames):
            if (base / name).is_symlink():
                other.append((base / name).relative_to(folder).as_posix())
                dirnames.remove(name)
        for name in filenames:
            p = base / name
            rel = p.relative_to(folder).as_posix()
            if rel == "shard.json":
                continue
            (files if stat.S_ISREG(os.lstat(p).st_mode) else other).append(rel)
    return sorted(files), sorted(other)


def temp_shard(root: str | Path, episode_id: str) -> Path:
    """A fresh temporary folder for building shard ``episode_id``."""
    tmp = shards_dir(root) / f".tmp-{episode_id}-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    return tmp


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def finish_shard(tmp: Path, root: str | Path, episode_id: str, meta: dict) -> Path:
    """Checksum and fsync every file of ``tmp``, write its ``shard.json``, make every file
    read-only and rename the folder into place.

    Returns:
        The final shard folder. If another worker finished the same shard first, ``tmp`` is
        discarded (episodes are deterministic, so both are the same).
    """
    files = {}
    for rel in _entries(tmp)[0]:
        p = tmp / rel
        files[rel] = [p.stat().st_size, file_crc(p)]
        _fsync(p)
    meta = dict(meta, format=SHARD_FORMAT, id=episode_id, files=files)
    atomic_write_json(tmp / "shard.json", meta, indent=1, sort_keys=True)
    for rel in [*files, "shard.json"]:
        os.chmod(tmp / rel, READ_ONLY)  # a finished shard is never written again
    for dirpath, _, _ in os.walk(tmp):
        _fsync(Path(dirpath))
    final = shards_dir(root) / episode_id
    try:
        os.rename(tmp, final)
    except OSError:
        if (final / "shard.json").exists():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            raise
    _fsync(final.parent)
    return final


def clear_temp(root: str | Path) -> list[str]:
    """Remove temporary shard folders of interrupted runs; returns their names.

    Only call it while holding the data set's lock (``collect`` does): another run's folder
    in progress would be removed too.
    """
    d = shards_dir(root)
    if not d.exists():
        return []
    gone = []
    for p in sorted(d.glob(".tmp-*")):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        if not os.path.lexists(p):
            gone.append(p.name)
    return gone


def load_json(path: Path, what: str):
    """A JSON file's content; a missing, oversized or malformed file raises naming ``path``.

    Raises:
        FileNotFoundError: no such file. ValueError: not a regular file, too large, bad JSON.
    """
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {path} is missing") from None
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{what} {path} is not a regular file (refused)")
    if st.st_size > MAX_JSON_BYTES:
        raise ValueError(f"{what} {path} is {st.st_size} bytes, more than {MAX_JSON_BYTES}")
    try:
        return json.loads(path.read_bytes())
    except (ValueError, UnicodeDecodeError) as e:
        raise ValueError(f"{what} {path} is not valid JSON: {e}") from None


def read_meta(folder: Path) -> dict | None:
    """A shard's ``shard.json`` (``None`` if absent or unreadable; see :func:`load_shard_meta`)."""
    try:
        return load_shard_meta(folder)
    except (OSError, ValueError):
        return None


def load_shard_meta(folder: Path) -> dict:
    """A shard's ``shard.json``, checked: ``frames`` a positive int, ``split`` a string,
    ``files`` maps plain relative paths to ``[size, crc32]``.

    Raises:
        FileNotFoundError / ValueError: naming the shard and what is wrong.
    """
    folder = Path(folder)
    path = folder / "shard.json"
    meta = load_json(path, f"shard {folder.name}:")
    where = f"shard {folder.name}: {path}"
    if not isinstance(meta, dict):
        raise ValueError(f"{where} is not a JSON object")
    frames = meta.get("frames")
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"{where}: frames={frames!r} is not a positive int")
    if not isinstance(meta.get("split"), str):
        raise ValueError(f"{where}: split={meta.get('split')!r} is not a string")
    files = meta.get("files")
    if not isinstance(files, dict):
        raise ValueError(f"{where}: files={type(files).__name__} is not a JSON object")
    for rel, entry in files.items():
        parts = rel.split("/")
        if rel.startswith("/") or any(q in ("", ".", "..") for q in parts) or "\\" in rel:
            raise ValueError(f"{where}: listed file {rel!r} is not a plain relative path (refused)")
        if (not isinstance(entry, list) or len(entry) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0
                           for v in entry)):
            raise ValueError(f"{where}: files[{rel!r}]={entry!r} is not [size, crc32]")
    return meta


def finished_shards(root: str | Path) -> dict[str, dict]:
    """``{episode_id: shard.json}`` of every complete shard folder."""
    d = shards_dir(root)
    out = {}
    if d.exists():
        for p in sorted(d.iterdir()):
            if p.is_dir() and not p.is_symlink() and not p.name.startswith("."):
                m = read_meta(p)
                if m is not None:
                    out[p.name] = m
    return out


def load_manifest(root: str | Path) -> dict:
    """The data set's manifest, checked: a JSON object with ``config`` (object), ``episodes``
    (list) and ``shards`` (object keyed by plain shard names).

    Raises:
        FileNotFoundError: no manifest (the message names the path). ValueError: malformed.
    """
    path = Path(root) / "manifest.json"
    if not os.path.lexists(path):
        raise FileNotFoundError(f"no data set at {root}: {path} is missing "
                                "(run `v2xbench collect`)")
    man = load_json(path, "manifest")
    if not isinstance(man, dict):
        raise ValueError(f"manifest {path} is not a JSON object")
    if man.get("format", MANIFEST_FORMAT) != MANIFEST_FORMAT:
        raise ValueError(f"manifest {path}: format {man.get('format')!r}, "
                         f"expected {MANIFEST_FORMAT}")
    for key, kind in (("config", dict), ("episodes", list), ("shards", dict)):
        if not isinstance(man.get(key, kind()), kind):
            raise ValueError(f"manifest {path}: {key} is not a JSON {kind.__name__}")
    for sid in man.get("shards", {}):
        check_id(sid, f"manifest {path}: shards")
    return man


def dataset_schema(root: str | Path, manifest: dict | None = None) -> dict:
    """The record schema (``record.record_schema``) of the data set's settings (its manifest's
    ``config``); every shard's memmap must match it exactly."""
    from .collect import CollectConfig

    man = manifest if manifest is not None else load_manifest(root)
    try:
        return CollectConfig.from_json(man.get("config", {})).record_schema()
    except (TypeError, ValueError) as e:
        raise ValueError(f"manifest {Path(root) / 'manifest.json'}: config: {e}") from None


def _file_problems(folder: Path, meta: dict, deep: bool) -> list[str]:
    """Listed files missing, of another size or (``deep``) CRC; unlisted files; links."""
    problems = []
    listed = meta["files"]
    for rel, (size, crc) in listed.items():
        p = folder / rel
        try:
            st = os.lstat(p)
        except (FileNotFoundError, NotADirectoryError):
            problems.append(f"missing file {rel}")
            continue
        if not stat.S_ISREG(st.st_mode):
            problems.append(f"{rel} is not a regular file (refused)")
        elif st.st_size != size:
            problems.append(f"size of {rel} is {st.st_size}, expected {size}")
        elif deep and file_crc(p) != crc:
            problems.append(f"checksum mismatch in {rel}")
    files, other = _entries(folder)
    problems += [f"unlisted file {rel}" for rel in files if rel not in listed]
    problems += [f"{rel} is a link or special file (refused)" for rel in other]
    return problems


def open_shard(folder: str | Path, schema: dict, meta: dict | None = None):
    """A shard's TensorDict, after checking its files against ``shard.json`` (presence, size)
    and its memmap against ``schema`` (:func:`.safe_memmap.open_memmap`: nothing is unpickled,
    the files are mapped copy-on-write, so in-place ops never reach the disk).

    Raises:
        ShardDataError: naming the shard and its first problem.
    """
    folder = Path(folder)
    meta = meta if meta is not None else load_shard_meta(folder)
    problems = _file_problems(folder, meta, deep=False)
    if problems:
        more = f" (and {len(problems) - 1} more: v2xbench data validate)"
        raise ShardDataError(folder.name, problems[0] + (more if len(problems) > 1 else ""))
    return open_memmap(folder / "data", schema, meta["frames"], folder.name)


def load_shard(root: str | Path, episode_id: str):
    """The TensorDict of a shard (:func:`open_shard`; batch size ``[frames]``)."""
    man = load_manifest(root)
    check_id(episode_id, "load_shard")
    return open_shard(shards_dir(root) / episode_id, dataset_schema(root, man))


def check_shard(folder: Path, schema: dict, deep: bool = True) -> list[str]:
    """Problems of one shard folder (empty list: sound).

    Checks ``shard.json``, every listed file's presence, size and (``deep``) CRC32, files not
    listed, links, and the memmap against ``schema`` (keys, dtypes, shapes, file sizes).
    """
    try:
        meta = load_shard_meta(folder)
    except (OSError, ValueError) as e:
        return [str(e)]
    problems = _file_problems(folder, meta, deep)
    try:
        open_memmap(folder / "data", schema, meta["frames"], folder.name)
    except ShardDataError as e:
        problems.append(e.problem)
    return problems


def validate(root: str | Path, deep: bool = True) -> dict:
    """Check a data set: every manifest shard present and sound, no unlisted shards.

    Returns:
        ``{"ok": bool, "shards": n checked, "missing": [ids], "corrupt": {id: [problems]},
        "unlisted": [ids], "pending": [planned ids not collected yet], "temporary": [names]}``.
    """
    man = load_manifest(root)
    schema = dataset_schema(root, man)
    d = shards_dir(root)
    listed = man.get("shards", {})
    on_disk = {p.name: p for p in d.iterdir()} if d.is_dir() else {}
    report: dict = {"missing": [], "corrupt": {}, "unlisted": [], "shards": len(listed),
                    "temporary": sorted(n for n in on_disk if n.startswith("."))}
    for sid in sorted(listed):
        p = on_disk.get(sid)
        if p is None:
            report["missing"].append(sid)
        elif p.is_symlink() or not p.is_dir():
            report["corrupt"][sid] = ["the shard is a link or a file, not a folder (refused)"]
        else:
            problems = check_shard(p, schema, deep)
            if problems:
                report["corrupt"][sid] = problems
    report["unlisted"] = sorted(n for n in set(on_disk) - set(listed) if not n.startswith("."))
    report["pending"] = [e for e in man.get("episodes", []) if e not in listed]
    report["ok"] = not (report["missing"] or report["corrupt"] or report["unlisted"])
    return report


__all__ = ["MANIFEST_FORMAT", "SHARD_FORMAT", "ShardDataError", "check_id", "check_shard",
           "clear_temp", "dataset_schema", "file_crc", "finish_shard", "finished_shards",
           "load_json", "load_manifest", "load_shard", "load_shard_meta", "open_shard",
           "read_meta", "shards_dir", "temp_shard", "validate"]
