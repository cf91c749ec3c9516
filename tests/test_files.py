"""The package's one atomic-write helper (v2xbench.files)."""

import json
import os

import pytest

from v2xbench.files import atomic_write, atomic_write_json, remove_stale_tmp, tmp_path


def test_atomic_write_replaces_and_leaves_no_tmp(tmp_path_factory):
    d = tmp_path_factory.mktemp("w")
    p = d / "a.json"
    atomic_write_json(p, {"x": 1})
    atomic_write_json(p, {"x": 2})
    assert json.loads(p.read_text()) == {"x": 2}
    assert [q.name for q in d.iterdir()] == ["a.json"]


def test_atomic_write_failure_keeps_old_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("w")
    p = d / "a.txt"
    p.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_write(p) as f:
            f.write("half")
            raise RuntimeError("killed")
    assert p.read_text() == "old"
    assert [q.name for q in d.iterdir()] == ["a.txt"]


def test_remove_stale_tmp_keeps_own_and_other_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("w")
    stale = d / ".r.json.999999.tmp"
    stale.write_text("x")
    own = tmp_path(d / "b.json")
    own.write_text("y")
    keep = d / "r.json"
    keep.write_text("{}")
    removed = remove_stale_tmp(d)
    assert removed == [stale]
    assert own.exists() and keep.exists() and not stale.exists()
    os.utime(d / "r.json")
    assert remove_stale_tmp(d / "missing") == []


def test_json_safe_turns_nan_inf_and_numpy_scalars_into_json():
    import json
    import math

    import numpy as np

    from v2xbench.files import json_safe

    got = json_safe({"a": math.nan, "b": np.float32(1.5), "c": [np.int64(3), -math.inf],
                     "d": (np.float64("nan"), "x")})
    assert got == {"a": None, "b": 1.5, "c": [3, None], "d": [None, "x"]}
    assert type(got["b"]) is float and type(got["c"][0]) is int
    json.dumps(got, allow_nan=False)  # strict JSON
