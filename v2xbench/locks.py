"""Exclusive locks on output directories, so two runs never write into one folder.

``eval`` and ``collect`` hold :func:`dir_lock` on their ``--out`` for the whole run. The lock is
an ``flock`` on ``<dir>/.v2xbench.lock``: the kernel releases it when the holder exits, even when
killed, so a stale lock file never blocks a later run. The file records who holds it (pid, host,
command, start time) for the error message of a run that is refused.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path

LOCK_NAME = ".v2xbench.lock"


class DirectoryLocked(ValueError):
    """Another live process holds the directory's lock (the message names it)."""


def _holder(path: Path) -> str:
    try:
        info = json.loads(path.read_text() or "{}")
    except (OSError, json.JSONDecodeError):
        return "another process"
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(info.get("started", 0)))
    return (f"pid {info.get('pid', '?')} on {info.get('host', '?')} since {when} "
            f"({info.get('command', '?')})")


@contextlib.contextmanager
def dir_lock(directory: str | Path, what: str = "run") -> Iterator[Path]:
    """Hold an exclusive lock on ``directory`` (created if missing) for the ``with`` block.

    Raises:
        DirectoryLocked: another process holds it; the message names the holder.
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise NotADirectoryError(f"{directory} is a file, not an output directory")
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise DirectoryLocked(
                f"{directory} is in use by {_holder(path)}; wait for it to finish or choose "
                f"another output directory for this {what}") from None
        info = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time(),
                "command": " ".join(sys.argv) or what}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        yield directory
    finally:
        os.close(fd)  # closing the descriptor releases the flock
