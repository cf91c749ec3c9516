"""AURORA's ``lateral="route"`` diagnostic variant: the planner's waypoints moved onto the route
at the arc lengths the planner's path reaches (``agents/aurora/agent.py::route_guided``)."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.agents.aurora.agent import AuroraAgent, route_guided


def _bent_route() -> np.ndarray:
    """Straight for 6 m, then a quarter circle of radius 10 m to the left (ego frame rows)."""
    straight = [[x, 0.0, 0.0] for x in np.arange(0.0, 6.0, 2.0)]
    a = np.linspace(0.0, np.pi / 2, 16)
    arc = np.stack([6.0 + 10.0 * np.sin(a), 10.0 - 10.0 * np.cos(a), np.zeros_like(a)], 1)
    return np.vstack([straight, arc])


def test_waypoints_land_on_the_route_at_the_planned_arc_lengths():
    route = _bent_route()
    planned = np.stack([np.arange(1, 7) * 2.5, np.full(6, 0.3)], 1)  # straight on, 2.5 m apart
    out = route_guided(planned, route)
    # each output point is on the route's polyline (within the resampling step)
    seg_a, seg_b = route[:-1, :2], route[1:, :2]
    for p in out:
        t = np.clip(np.einsum("ij,ij->i", p - seg_a, seg_b - seg_a)
                    / np.einsum("ij,ij->i", seg_b - seg_a, seg_b - seg_a), 0, 1)
        assert np.min(np.linalg.norm(seg_a + t[:, None] * (seg_b - seg_a) - p, axis=1)) < 0.05
    # and as far along it as the planner's path (arc length, not straight-line distance)
    steps = np.linalg.norm(np.diff(np.vstack([[0.0, 0.0], out]), axis=0), axis=1)
    assert np.cumsum(steps) == pytest.approx(np.arange(1, 7) * 2.5, abs=0.3)
    assert out[-1, 1] > 2.0  # the route bends left: the planner's straight path did not


def test_a_standing_plan_stays_put_and_bad_options_are_refused():
    stand = np.tile([[0.02, 0.0]], (6, 1))
    assert np.array_equal(route_guided(stand, _bent_route()), stand)
    with pytest.raises(ValueError, match="lateral='sideways'"):
        AuroraAgent(run="nowhere", lateral="sideways")
