"""The regroup by subsystem (issue #36): every old module path listed in ``CHANGELOG.md`` has an
importable new home, the documented old paths still work through deprecated aliases, and no code
of the repository imports an alias."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest
import v2xbench.envs.v2x_intersection as pkg

ROOT = Path(__file__).resolve().parents[1]
MOVE = re.compile(r"^- `(v2xbench\.envs\.v2x_intersection\.\w+)` -> "
                  r"`(v2xbench\.envs\.v2x_intersection[\w.]+)`", re.M)


def _moves() -> list[tuple[str, str]]:
    text = (ROOT / "CHANGELOG.md").read_text()
    section = text.split("## Unreleased: module moves", 1)[1].split("\n## ", 1)[0]
    return MOVE.findall(section)


def test_changelog_lists_every_move_to_an_importable_module():
    moves = _moves()
    assert len(moves) >= 50
    for old, new in moves:
        assert importlib.import_module(new).__name__ == new, old
    old_names = {old.rsplit(".", 1)[1] for old, _ in moves}
    assert set(pkg.DEPRECATED_ALIASES) <= old_names


@pytest.mark.parametrize("alias", pkg.DEPRECATED_ALIASES)
def test_documented_old_paths_warn_and_forward(alias):
    new = dict(_moves())[f"{pkg.__name__}.{alias}"]
    code = (f"import warnings; warnings.simplefilter('error', DeprecationWarning)\ntry:\n"
            f"    import {pkg.__name__}.{alias}\nexcept DeprecationWarning as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=ROOT)
    assert f"moved to {new}" in out.stdout
    with pytest.warns(DeprecationWarning):
        sys.modules.pop(f"{pkg.__name__}.{alias}", None)
        old = importlib.import_module(f"{pkg.__name__}.{alias}")
    target = importlib.import_module(new)
    public = [n for n in vars(target) if not n.startswith("_")]
    assert public and all(getattr(old, n) is getattr(target, n) for n in public)


def test_no_repository_code_imports_an_alias():
    names = "|".join(pkg.DEPRECATED_ALIASES)
    pattern = re.compile(rf"v2x_intersection\.({names})\b"
                         rf"|v2x_intersection import [\w, ]*\b({names})\b")
    offenders = []
    tops = ("envs", "agents", "collectors", "benchmarks", "v2xbench", "tests", "examples", "docs")
    for top in tops:
        for p in (ROOT / top).rglob("*"):
            if p.suffix in (".py", ".md") and p.parent != ROOT / "envs" / "v2x_intersection":
                if p.name != "test_module_moves.py" and pattern.search(p.read_text()):
                    offenders.append(str(p.relative_to(ROOT)))
    assert offenders == []
