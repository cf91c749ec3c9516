"""Output-directory locks (v2xbench.locks): a second holder is refused with the holder named."""

import multiprocessing as mp

import pytest

from v2xbench.locks import DirectoryLocked, dir_lock


def _try_lock(path, q):
    try:
        with dir_lock(path):
            q.put("got")
    except DirectoryLocked as e:
        q.put(str(e))


def test_second_process_is_refused_and_lock_is_released(tmp_path):
    ctx = mp.get_context("spawn")
    with dir_lock(tmp_path / "out", "eval"):
        q = ctx.Queue()
        p = ctx.Process(target=_try_lock, args=(tmp_path / "out", q))
        p.start()
        p.join(60)
        msg = q.get(timeout=5)
        assert "in use by pid" in msg
    q = ctx.Queue()
    p = ctx.Process(target=_try_lock, args=(tmp_path / "out", q))
    p.start()
    p.join(60)
    assert q.get(timeout=5) == "got"


def test_file_is_not_a_directory(tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    with pytest.raises(NotADirectoryError, match="is a file"):
        with dir_lock(f):
            pass
