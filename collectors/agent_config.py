"""``--agent-config FILE``: the keyword arguments an agent is built with.

The file holds one JSON object; ``eval`` passes it to the agent's constructor as keyword
arguments (``agents.interface.build_agent``), in the harness, in every worker and in an isolated
agent's process, and records its contents in the run's fingerprint (``agent_fingerprint.py``).
JSON only: YAML would need PyYAML, which V2XBench does not depend on.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any


def load_agent_config(path: str | Path) -> dict:
    """The JSON object in ``path``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not JSON (line and column named), not an object, or a YAML file.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"agent config {str(p)!r} not found (--agent-config)")
    if p.suffix.lower() in (".yaml", ".yml"):
        raise ValueError(
            f"agent config {str(p)!r}: YAML is not read (PyYAML is not a dependency); "
            "write the keyword arguments as a JSON object"
        )
    try:
        data = json.loads(p.read_text())
    except UnicodeDecodeError as e:
        raise ValueError(f"agent config {str(p)!r} is not UTF-8 text ({e})") from None
    except json.JSONDecodeError as e:
        raise ValueError(
            f"agent config {str(p)!r} is not valid JSON: {e.msg} at line {e.lineno}, "
            f"column {e.colno}"
        ) from None
    return check_agent_config(data, str(p))


def check_agent_config(config: Any, where: str = "agent_config") -> dict:
    """``config`` as a plain JSON object of keyword arguments (a copy).

    Raises:
        ValueError: not a mapping with string keys whose values are JSON data (numbers, strings,
            booleans, null, lists, objects; no NaN).
    """
    if not isinstance(config, Mapping):
        raise ValueError(
            f"{where}: the agent config must be a JSON object of keyword arguments, "
            f"got {type(config).__name__}"
        )
    bad = [k for k in config if not isinstance(k, str) or not k.isidentifier()]
    if bad:
        raise ValueError(
            f"{where}: agent config keys must be Python identifiers (keyword "
            f"arguments), got {bad!r}"
        )
    try:
        return json.loads(json.dumps(dict(config), allow_nan=False))
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: agent config values must be JSON data ({e})") from None


def resolve_agent_config(config: Mapping | str | Path | None) -> tuple[dict | None, str | None]:
    """``(config dict or None, file it came from or None)`` from a path, a mapping or ``None``."""
    if config is None:
        return None, None
    if isinstance(config, (str, Path)):
        return load_agent_config(config), str(config)
    return check_agent_config(config), None
