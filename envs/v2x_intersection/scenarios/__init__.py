"""Scenarios: the paper's 38 safety-critical types, a registry and episode building.

``build_episode(name, town, rng)`` picks a site for scenario ``name`` in ``town``, builds a route
through it and returns the route and the placed scenario. The modules below register their types
on import.
"""

from __future__ import annotations

import numpy as np

from ..town.model import Town
from ..town.routes import Route
from . import control_loss, flows, highway, junctions, obstacles, parking, v2x, v2x_junction  # noqa: F401  (registers the types)
from .base import Scenario, Site
from .placement import pick_site, route_through
from .registry import SCENARIOS, get_scenario, register_scenario


def build_episode(name: str, town: Town, rng: np.random.Generator,
                  params: dict | None = None) -> tuple[Route, list[Scenario]]:
    """A route through a random site of scenario ``name`` and the placed scenario instance."""
    cls = get_scenario(name)
    site = pick_site(cls, town, rng)
    route, conflict_s = route_through(town, rng, site)
    return route, [cls(route, site, conflict_s, params)]


__all__ = ["SCENARIOS", "Scenario", "Site", "build_episode", "get_scenario", "register_scenario"]
