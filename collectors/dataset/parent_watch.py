"""Worker processes that end when their parent dies.

A collect worker whose parent was killed would otherwise wait on its pipe for minutes, holding
hundreds of MB. :func:`exit_with_parent` (the pool's ``initializer``) starts a daemon thread
that polls ``os.getppid()`` and ends the process with ``os._exit`` as soon as it is no longer
the parent's child (re-parented to init or a subreaper). Temporary shard folders that such a
worker leaves are removed by the next ``collect`` on the same folder.
"""

from __future__ import annotations

import os
import sys
import threading
import time

POLL_S = 0.5
EXIT_CODE = 70  # the parent is gone: nobody reads it, but it tells apart from a crash in ps/logs


def _watch(parent_pid: int, poll_s: float) -> None:
    while True:
        if os.getppid() != parent_pid:
            try:
                print(f"v2xbench worker {os.getpid()}: parent {parent_pid} is gone; exiting",
                      file=sys.stderr, flush=True)
            except (OSError, ValueError):
                pass
            os._exit(EXIT_CODE)
        time.sleep(poll_s)


def exit_with_parent(parent_pid: int, poll_s: float = POLL_S) -> threading.Thread:
    """End this process (``os._exit``) within ``poll_s`` seconds of ``parent_pid`` dying.

    Args:
        parent_pid: the pid of the process that started this one (``os.getpid()`` there).
        poll_s: seconds between checks.

    Returns:
        The started daemon thread.
    """
    if not isinstance(parent_pid, int) or parent_pid < 1:
        raise ValueError(f"exit_with_parent: parent_pid={parent_pid!r} must be a positive pid")
    if not poll_s > 0:
        raise ValueError(f"exit_with_parent: poll_s={poll_s!r} must be > 0")
    t = threading.Thread(target=_watch, args=(parent_pid, poll_s), name="exit-with-parent",
                         daemon=True)
    t.start()
    return t


__all__ = ["EXIT_CODE", "POLL_S", "exit_with_parent"]
