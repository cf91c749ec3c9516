"""Where the numba kernels' compiled code is cached: one user cache shared by every clone.

numba's default cache sits in ``__pycache__`` beside each source file and is keyed by that
file's path and modification time, so every fresh clone (and every CI run) compiles all kernels
again (~100 s), and a kernel that calls one from another module keeps its stale code when only
the callee changes. This module installs a numba cache locator for the package's own kernels
that keys the cache by the *content* of every kernel source file of the package together:

``<cache root>/numba/py<X.Y>-numba<version>-<sha1 of all kernel sources>/<module>/``

- Any clone, virtualenv or process with the same kernel sources finds the same compiled code.
- Editing any kernel file invalidates every kernel (no stale cross-module caches; no manual
  ``find -name '*.nb[ic]' -delete`` needed).
- The cache root is ``$V2XBENCH_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/v2xbench``, else
  ``~/.cache/v2xbench``. Only the newest few source versions are kept.

``v2xbench warmup`` compiles everything ahead of time with a progress bar. Functions outside the
package are left to numba's own locators. If numba's (private) locator API changes, the package
falls back to numba's default behaviour.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import tempfile
from pathlib import Path

#: Kernel-source versions kept in the cache (older ones are removed when a new one is created).
KEEP_VERSIONS = 3
_HERE = Path(__file__).resolve()
#: The package folders whose kernels this locator caches (``v2xbench.envs``, ``v2xbench.agents``).
_PACKAGE_ROOTS = (str(_HERE.parents[2]), str(_HERE.parents[3] / "agents"))


def cache_root() -> Path:
    """The v2xbench user cache folder (``$V2XBENCH_CACHE_DIR``, XDG, or ``~/.cache/v2xbench``)."""
    env = os.environ.get("V2XBENCH_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "v2xbench"


def kernel_sources() -> list[Path]:
    """Every package source file that defines numba kernels (sorted)."""
    files = []
    for root in _PACKAGE_ROOTS:
        for p in sorted(Path(root).rglob("*.py")):
            try:
                text = p.read_text()
            except OSError:
                continue
            if "_njit" in text or "numba." in text:
                files.append(p)
    return files


def kernel_hash() -> str:
    """SHA-1 over the package's kernel sources (names relative to their root, and contents)."""
    h = hashlib.sha1()
    for p in kernel_sources():
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


def _version_tag(numba_version: str) -> str:
    return f"py{sys.version_info[0]}.{sys.version_info[1]}-numba{numba_version}"


def kernel_cache_dir(numba_version: str) -> Path:
    """The folder of this source version's compiled kernels."""
    return cache_root() / "numba" / f"{_version_tag(numba_version)}-{kernel_hash()}"


def _prune(current: Path) -> None:
    """Remove all but the newest :data:`KEEP_VERSIONS` kernel-source versions."""
    try:
        versions = sorted((p for p in current.parent.iterdir() if p.is_dir()),
                          key=lambda p: p.stat().st_mtime, reverse=True)
    except OSError:
        return
    for old in versions[KEEP_VERSIONS:]:
        if old != current:
            shutil.rmtree(old, ignore_errors=True)


def install(numba_module) -> Path | None:
    """Put the package's kernels in :func:`kernel_cache_dir`; returns it (``None``: fallback)."""
    try:
        from numba.core import caching
    except ImportError:  # pragma: no cover
        return None
    base = getattr(caching, "_CacheLocator", None)
    impl = getattr(caching, "CacheImpl", None)
    if base is None or impl is None or not hasattr(impl, "_locator_classes"):
        return None  # pragma: no cover - numba changed its private API
    directory = kernel_cache_dir(numba_module.__version__)
    stamp = directory.name

    class PackageKernelLocator(base):
        """numba cache locator for v2xbench kernels (keyed by the package's kernel sources)."""

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = str(directory / Path(py_file).stem)

        def ensure_cache_path(self):
            new = not directory.exists()
            os.makedirs(self._cache_path, exist_ok=True)
            tempfile.TemporaryFile(dir=self._cache_path).close()
            if new:
                _prune(directory)

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            return stamp

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            path = os.path.abspath(py_file)
            if not any(path.startswith(root + os.sep) for root in _PACKAGE_ROOTS):
                return None
            self = cls(py_func, py_file)
            try:
                self.ensure_cache_path()
            except OSError:
                return None  # not writable: numba's own locators take over
            return self

    classes = [c for c in impl._locator_classes if c.__name__ != "PackageKernelLocator"]
    impl._locator_classes = [PackageKernelLocator, *classes]
    return directory
