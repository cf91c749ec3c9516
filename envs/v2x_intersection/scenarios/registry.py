"""Scenario registry: ``register_scenario`` decorator, lookup with clear errors, listing."""

from __future__ import annotations

from .base import Scenario

SCENARIOS: dict[str, type[Scenario]] = {}


def register_scenario(cls: type[Scenario]) -> type[Scenario]:
    """Class decorator adding a scenario type to :data:`SCENARIOS` under ``cls.name``."""
    if not cls.name or cls.name in SCENARIOS:
        raise ValueError(f"scenario name {cls.name!r} missing or registered twice")
    SCENARIOS[cls.name] = cls
    return cls


def get_scenario(name: str) -> type[Scenario]:
    """The scenario class called ``name``; ``ValueError`` listing the known names otherwise."""
    if name not in SCENARIOS:
        import difflib

        close = difflib.get_close_matches(name, SCENARIOS, n=1)
        hint = f" Did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"unknown scenario {name!r}.{hint} Known: {', '.join(sorted(SCENARIOS))}")
    return SCENARIOS[name]
