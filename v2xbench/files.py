"""Atomic file writes: the one home for "write then rename" in the package.

Every data set, result, report and media file goes through :func:`atomic_write` (or one of its
wrappers): the bytes go to a hidden temporary file beside the target, are flushed and fsynced,
and the temporary file is renamed over the target, so a reader never sees a half-written file
and a crash leaves either the old file or the new one. :func:`remove_stale_tmp` removes the
temporary files that a killed writer left behind.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

TMP_SUFFIX = ".tmp"


def tmp_path(path: str | Path) -> Path:
    """The temporary file a writer of ``path`` in this process uses (hidden, beside it)."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}{TMP_SUFFIX}")


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w") -> Iterator[IO[Any]]:
    """Open a temporary file for writing; on success fsync it and rename it to ``path``.

    On an exception the temporary file is removed and ``path`` is left as it was.

    Args:
        path: the final file.
        mode: ``"w"`` (text) or ``"wb"`` (bytes).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path(path)
    try:
        with open(tmp, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    with atomic_write(path, "wb") as f:
        f.write(data)
    return Path(path)


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns ``path``."""
    with atomic_write(path, "w") as f:
        f.write(text)
    return Path(path)


def atomic_write_json(path: str | Path, obj: Any, **dump_kwargs: Any) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically (``dump_kwargs`` go to ``json.dumps``)."""
    return atomic_write_text(path, json.dumps(obj, **dump_kwargs))


def json_safe(obj: Any) -> Any:
    """JSON-safe copy of nested dicts / lists: NaN and inf become ``None``, NumPy scalars
    Python numbers (the evaluations' result files)."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if hasattr(obj, "item") and getattr(obj, "shape", None) == ():  # a NumPy scalar
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def remove_stale_tmp(directory: str | Path, older_than_s: float = 0.0) -> list[Path]:
    """Remove temporary files left by killed writers in ``directory`` (not recursive).

    A file counts as stale when it is named like :func:`tmp_path`'s files, was not written by
    this process, and was last modified more than ``older_than_s`` seconds ago. Returns the
    removed paths.
    """
    directory = Path(directory)
    if not directory.is_dir():
        return []
    now = time.time()
    mine = f".{os.getpid()}{TMP_SUFFIX}"
    removed = []
    for p in directory.iterdir():
        name = p.name
        if not (name.startswith(".") and name.endswith(TMP_SUFFIX)) or name.endswith(mine):
            continue
        try:
            if p.is_file() and now - p.stat().st_mtime >= older_than_s:
                p.unlink()
                removed.append(p)
        except FileNotFoundError:
            continue
    return removed


def check_output_dir(path: str | Path, what: str = "output directory") -> Path:
    """``path`` as a ``Path`` when it is a directory or can be made one; checked before a run.

    Raises:
        ValueError: ``path``, or a folder it would be made in, is a file (the message names it),
            or the nearest existing folder is not writable.
    """
    path = Path(path)
    for p in (path, *path.parents):
        if not p.exists():
            continue
        if not p.is_dir():
            where = "is a file" if p == path else f"cannot be created: {p} is a file"
            raise ValueError(f"{what} {path} {where}, not a directory")
        if not os.access(p, os.W_OK | os.X_OK):
            raise ValueError(f"{what} {path}: {p} is not writable")
        break
    return path
