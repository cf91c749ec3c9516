"""Helpers shared by the sub-command modules."""

from __future__ import annotations

import json


def parse_set(items: list[str]) -> dict:
    """``key=value`` pairs of ``--set`` (values parsed as JSON when possible: 10, 0.5, null)."""
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--set {item!r}: expected key=value (an EnvConfig field)")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out
