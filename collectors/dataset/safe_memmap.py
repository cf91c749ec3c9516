"""Opening a shard's TensorDict memmap without trusting it: no code runs, nothing is written.

``TensorDict.load_memmap`` follows whatever the folder's ``meta.json`` says: it unpickles
non-tensor entries (``NonTensorData`` sidecars) and looks up registered classes, maps every
file shared and writable (an in-place op on the result writes to disk), and extends a short
file with zeros. :func:`open_memmap` does none of that. It

- reads each ``meta.json`` as plain JSON (at most :data:`MAX_META_BYTES`) and accepts exactly
  the keys, dtypes and shapes of the record schema (``record.record_schema``): a missing key, a
  key outside the schema, a non-tensor entry, another dtype or shape is refused;
- refuses any file, folder or link in the memmap folder that the schema does not name (a
  ``.pkl``, a ``NonTensorData`` folder, a symlink), so nothing is ever unpickled;
- checks every file's size against ``frames x shape x itemsize`` *before* mapping it;
- opens every file read-only and maps it copy-on-write: an in-place op on the returned
  tensors changes this process's copy only, never the file.

Every problem raises :class:`ShardDataError` naming the shard and the file.
"""

from __future__ import annotations

import json
import math
import mmap
import os
import re
import stat
from pathlib import Path

import numpy as np

META = "meta.json"
MAX_META_BYTES = 1 << 20
#: the only ``_type`` a folder's ``meta.json`` may name (a plain TensorDict, no tensorclass)
TD_TYPE = "<class 'tensordict._td.TensorDict'>"
_LEAF_FIELDS = {"device", "shape", "dtype", "is_nested"}
_FOLDER_FIELDS = {"_type", "shape", "device"}
_KEY = re.compile(r"^[A-Za-z0-9_]+$")


class ShardDataError(ValueError):
    """A shard is not what its metadata and the record schema say (the message names the
    shard and the file; ``shard`` and ``problem`` hold them apart)."""

    def __init__(self, shard: str, problem: str) -> None:
        super().__init__(shard, problem)  # both in args: the error pickles across processes
        self.shard, self.problem = shard, problem

    def __str__(self) -> str:
        return f"shard {self.shard}: {self.problem}"


def _tree(schema: dict[tuple[str, ...], tuple]) -> dict:
    """``{key path: leaf}`` as nested dicts (a leaf is ``(dtype name, shape)``)."""
    root: dict = {}
    for path, leaf in schema.items():
        if not all(_KEY.match(part) for part in path):  # schema keys are plain names, not paths
            raise ValueError(f"record schema key {path!r} is not made of plain names")
        node = root
        for part in path[:-1]:
            node = node.setdefault(part, {})
        node[path[-1]] = leaf
    return root


def _fail(shard: str, rel: str, problem: str) -> ShardDataError:
    return ShardDataError(shard, f"data/{rel}: {problem}")


def _read_meta(folder: Path, shard: str, rel: str) -> dict:
    path = folder / META
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        raise _fail(shard, rel + META, "missing") from None
    if not stat.S_ISREG(st.st_mode):
        raise _fail(shard, rel + META, "not a regular file (refused)")
    if st.st_size > MAX_META_BYTES:
        raise _fail(shard, rel + META, f"{st.st_size} bytes, more than {MAX_META_BYTES}")
    try:
        meta = json.loads(path.read_bytes())
    except (ValueError, UnicodeDecodeError) as e:
        raise _fail(shard, rel + META, f"not valid JSON ({e})") from None
    if not isinstance(meta, dict):
        raise _fail(shard, rel + META, "not a JSON object")
    return meta


def _check_folder_meta(meta: dict, tree: dict, frames: int, shard: str, rel: str) -> None:
    where = rel + META
    if meta.get("_type") != TD_TYPE:
        raise _fail(shard, where, f"type {meta.get('_type')!r} is not a plain TensorDict "
                    "(refused: only tensors are loaded, nothing is unpickled)")
    if meta.get("shape") != [frames]:
        raise _fail(shard, where, f"batch shape {meta.get('shape')!r}, shard.json says "
                    f"[{frames}] frames")
    if meta.get("device") not in (None, "None", "cpu"):
        raise _fail(shard, where, f"device {meta.get('device')!r} (expected cpu)")
    for key, entry in meta.items():
        if key in _FOLDER_FIELDS:
            continue
        if key not in tree:
            raise _fail(shard, where, f"key {rel + key!r} is not in the record schema (refused)")
        sub = tree[key]
        if isinstance(sub, dict):
            if entry != {"type": "TensorDict"}:
                raise _fail(shard, where, f"key {rel + key!r}: {entry!r} is not a plain nested "
                            "TensorDict (refused: nothing is unpickled)")
            continue
        if not isinstance(entry, dict) or "type" in entry or not set(entry) <= _LEAF_FIELDS:
            raise _fail(shard, where, f"key {rel + key!r}: {entry!r} is not a tensor entry "
                        "(refused: nothing is unpickled)")
        dtype, shape = sub
        if entry.get("dtype") != f"torch.{dtype}":
            raise _fail(shard, where, f"key {rel + key!r} has dtype {entry.get('dtype')!r}, "
                        f"the schema says torch.{dtype}")
        if entry.get("shape") != [frames, *shape]:
            raise _fail(shard, where, f"key {rel + key!r} has shape {entry.get('shape')!r}, "
                        f"the schema says {[frames, *shape]}")
        if entry.get("is_nested", False) is not False or entry.get("device") not in (
                None, "None", "cpu"):
            raise _fail(shard, where, f"key {rel + key!r}: nested or non-cpu tensor (refused)")
    missing = sorted(set(tree) - set(meta))
    if missing:
        raise _fail(shard, where, f"keys {[rel + k for k in missing]} of the schema are missing")


def _check_listing(folder: Path, tree: dict, shard: str, rel: str) -> None:
    for entry in sorted(folder.iterdir()):
        name = entry.name
        st = os.lstat(entry)
        if stat.S_ISLNK(st.st_mode):
            raise _fail(shard, rel + name, "a symbolic link (refused)")
        if name == META:
            continue
        if stat.S_ISDIR(st.st_mode):
            if isinstance(tree.get(name), dict):
                continue
            raise _fail(shard, rel + name, "unexpected folder, not in the record schema (refused)")
        key = name[: -len(".memmap")] if name.endswith(".memmap") else None
        if not stat.S_ISREG(st.st_mode) or key is None or not isinstance(tree.get(key), tuple):
            raise _fail(shard, rel + name, "unexpected file, not in the record schema (refused)")


def _map(path: Path, dtype: str, shape: tuple[int, ...], shard: str, rel: str):
    import torch

    dt = np.dtype(dtype)
    need = math.prod(shape) * dt.itemsize
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except FileNotFoundError:
        raise _fail(shard, rel, "missing") from None
    except OSError as e:
        raise _fail(shard, rel, f"cannot be opened read-only ({e.strerror})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise _fail(shard, rel, "not a regular file (refused)")
        if st.st_size != need:
            raise _fail(shard, rel, f"{st.st_size} bytes, but {list(shape)} {dtype} needs {need} "
                        "(truncated or padded; nothing was mapped)")
        if need == 0:
            return torch.empty(shape, dtype=getattr(torch, dtype))
        buf = mmap.mmap(fd, need, access=mmap.ACCESS_COPY)  # private: writes never reach the file
    finally:
        os.close(fd)
    return torch.from_numpy(np.frombuffer(buf, dtype=dt).reshape(shape))


def _walk(folder: Path, tree: dict, frames: int, shard: str, rel: str, out: dict) -> None:
    st = os.lstat(folder) if os.path.lexists(folder) else None
    if st is None or not stat.S_ISDIR(st.st_mode):
        raise _fail(shard, rel or ".", "missing or not a folder")
    meta = _read_meta(folder, shard, rel)
    _check_folder_meta(meta, tree, frames, shard, rel)
    _check_listing(folder, tree, shard, rel)
    for key, sub in tree.items():
        if isinstance(sub, dict):
            out[key] = {}
            _walk(folder / key, sub, frames, shard, f"{rel}{key}/", out[key])
        else:
            dtype, shape = sub
            out[key] = _map(folder / f"{key}.memmap", dtype, (frames, *shape), shard,
                            f"{rel}{key}.memmap")


def open_memmap(folder: str | Path, schema: dict[tuple[str, ...], tuple], frames: int,
                shard: str):
    """The shard's TensorDict (batch size ``[frames]``) after checking it against ``schema``.

    Args:
        folder: the shard's ``data`` folder.
        schema: ``record.record_schema`` of the data set's settings.
        frames: the shard's frame count (``shard.json``).
        shard: the shard's name, for messages.

    Raises:
        ShardDataError: anything that is not exactly the schema (module docstring).
    """
    from tensordict import TensorDict

    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ShardDataError(shard, f"shard.json: frames={frames!r} is not a positive int")
    leaves: dict = {}
    _walk(Path(folder), _tree(schema), frames, shard, "", leaves)
    return TensorDict(leaves, batch_size=[frames])


__all__ = ["MAX_META_BYTES", "TD_TYPE", "ShardDataError", "open_memmap"]
