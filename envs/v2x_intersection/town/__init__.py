"""Road networks: data model, procedural templates and the named towns.

Named towns: ``Town01`` to ``Town06`` are training towns; ``Town12`` is the larger held-out test
town (as the paper's Town12 test split) and is never used for training routes; its template
(``metro2``) builds road structures no training town has: per-street lane widths and speed limits,
a curved arterial, five-way and skewed junctions and a roundabout.
"""

from __future__ import annotations

import difflib
import functools
import json
from pathlib import Path

from .model import COMMAND_NAMES, LaneIndex, Town
from .templates import TEMPLATES, generate_town

#: name -> (template, seed, size)
NAMED_TOWNS: dict[str, tuple[str, int, int | None]] = {
    "Town01": ("grid", 1, 3),
    "Town02": ("tjunction", 2, 4),
    "Town03": ("arterial", 3, 3),
    "Town04": ("highway", 4, 3),
    "Town05": ("grid", 5, 2),
    "Town06": ("tjunction", 6, 3),
    "Town12": ("metro2", 12, 4),
}
TRAIN_TOWNS = ("Town01", "Town02", "Town03", "Town04", "Town05", "Town06")
TEST_TOWNS = ("Town12",)


def town_hint(name: object) -> str:
    """``"; did you mean 'Town01'?"`` for a near miss of a named town (``town01``, ``Town1``,
    ``Twon01``), else ``""``."""
    if not isinstance(name, str):
        return ""
    same_case = {n.lower(): n for n in NAMED_TOWNS}
    close = [same_case[name.lower()]] if name.lower() in same_case else []
    if not close and name.lower().startswith("town") and name[4:].isdigit():
        close = [n for n in NAMED_TOWNS if int(n[4:]) == int(name[4:])]
    close = close or difflib.get_close_matches(name, NAMED_TOWNS, n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


@functools.lru_cache(maxsize=16)
def get_town(name: str) -> Town:
    """A named town (cached). Raises ``ValueError`` for unknown names (with a near match)."""
    if name not in NAMED_TOWNS:
        raise ValueError(f"unknown town {name!r}{town_hint(name)} "
                         f"(known: {', '.join(NAMED_TOWNS)})")
    template, seed, size = NAMED_TOWNS[name]
    return generate_town(template, seed, size, name=name)


def save_town(town: Town, path: str | Path) -> None:
    """Write a town to JSON atomically (write to a temporary file, then rename)."""
    path = Path(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(town.to_dict()))
    tmp.replace(path)


def load_town(path: str | Path) -> Town:
    """Read a town JSON file written by :func:`save_town`."""
    return Town.from_dict(json.loads(Path(path).read_text()))


__all__ = [
    "COMMAND_NAMES", "LaneIndex", "NAMED_TOWNS", "TEMPLATES", "TEST_TOWNS", "TRAIN_TOWNS", "Town",
    "generate_town", "get_town", "load_town", "save_town", "town_hint",
]
