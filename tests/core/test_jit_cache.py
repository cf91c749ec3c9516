"""The numba kernel cache (envs/v2x_intersection/core/jit_cache.py): one user cache keyed by content."""

import json
import os
import subprocess
import sys

import pytest
from v2xbench.envs.v2x_intersection.core import jit, jit_cache

pytestmark = pytest.mark.skipif(not jit.HAVE_JIT, reason="numba not available")

_PROBE = (
    "import json; from v2xbench.envs.v2x_intersection.core import jit; jit._fmin(1.0, 2.0); "
    "s = jit._fmin.stats; print(json.dumps({'hits': sum(s.cache_hits.values()), "
    "'misses': sum(s.cache_misses.values()), 'dir': str(jit.KERNEL_CACHE_DIR)}))"
)


def _probe(cache_dir) -> dict:
    env = dict(os.environ, V2XBENCH_CACHE_DIR=str(cache_dir))
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True,
                         check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_second_process_loads_kernels_from_the_user_cache(tmp_path):
    first = _probe(tmp_path)
    assert first["dir"].startswith(str(tmp_path))
    assert first["misses"] == 1 and first["hits"] == 0
    second = _probe(tmp_path)
    assert second["hits"] == 1 and second["misses"] == 0
    assert any((tmp_path / "numba").rglob("*.nbi"))


def test_cache_key_follows_kernel_source_content(tmp_path, monkeypatch):
    (tmp_path / "k.py").write_text("from x import _njit\n")
    (tmp_path / "plain.py").write_text("x = 1\n")
    monkeypatch.setattr(jit_cache, "_PACKAGE_ROOTS", (str(tmp_path),))
    assert [p.name for p in jit_cache.kernel_sources()] == ["k.py"]
    h0 = jit_cache.kernel_hash()
    (tmp_path / "plain.py").write_text("x = 2\n")
    assert jit_cache.kernel_hash() == h0
    (tmp_path / "k.py").write_text("from x import _njit\n# edited\n")
    assert jit_cache.kernel_hash() != h0


def test_cache_root_is_overridable(monkeypatch, tmp_path):
    monkeypatch.setenv("V2XBENCH_CACHE_DIR", str(tmp_path / "c"))
    assert jit_cache.cache_root() == tmp_path / "c"
    monkeypatch.delenv("V2XBENCH_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert jit_cache.cache_root() == tmp_path / "x" / "v2xbench"
