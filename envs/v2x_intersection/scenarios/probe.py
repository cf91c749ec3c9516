"""Run one scenario with a driver and record what happened (for tests, galleries and docs).

``probe(name, seed)`` builds an episode for scenario ``name``, drives it with a driver (default:
the observation-only :class:`~v2xbench.agents.route_follower.RouteFollower`) and returns a
:class:`ProbeRecord` with per-tick ego and hazard states and who could see the hazard.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..api.observations import ego_observation
from ..sim.config import make_config
from ..sim.world import World
from ..town import get_town
from . import build_episode, get_scenario


@dataclass
class ProbeRecord:
    """Per-tick log of a scenario run (``T`` ticks, ``H`` hazard actors).

    Attributes:
        ego_xy: ``(T, 2)``; ego_s: ``(T,)`` route progress (m); ego_speed: ``(T,)``.
        hazard_xy: ``(T, H, 2)``; hazard_speed: ``(T, H)``.
        ego_vis, rsu_vis: ``(T, H)`` visible fractions of each hazard from the ego / active RSU.
        triggered: ``(T,)`` bool. events: event counts at the end. scenario: the instance.
    """

    ego_xy: np.ndarray
    ego_s: np.ndarray
    ego_speed: np.ndarray
    hazard_xy: np.ndarray
    hazard_speed: np.ndarray
    ego_vis: np.ndarray
    rsu_vis: np.ndarray
    triggered: np.ndarray
    events: np.ndarray
    scenario: object
    world: object = field(repr=False, default=None)


def probe(name: str, seed: int = 0, town: str | None = None, max_ticks: int = 600, driver=None,
          params: dict | None = None, stop_after_pass: float = 3.0, on_tick=None, **config) -> ProbeRecord:
    """Run scenario ``name`` once (see module docstring).

    Args:
        name: scenario type.
        seed: world seed (also picks the site).
        town: town name (default: the scenario's first preferred town, else ``Town01``).
        max_ticks: hard cap on the run.
        driver: object with ``act(obs) -> control``; default ``RouteFollower()``.
        params: scenario parameters.
        stop_after_pass: seconds to keep running after the ego passed the scenario.
        on_tick: optional ``callback(world)`` called after every tick (e.g. to render frames).
        **config: extra :class:`EnvConfig` keys (e.g. a smaller background population).
    """
    from v2xbench.agents.route_follower import RouteFollower

    cls = get_scenario(name)
    town_name = town or (cls.towns[0] if cls.towns else "Town01")
    world = World(make_config(town=town_name, **config))
    rng = np.random.default_rng(seed)
    route, scenarios = build_episode(name, get_town(town_name), rng, params)
    world.reset(seed=seed, route=route, scenarios=scenarios)
    sc = scenarios[0]
    driver = driver or RouteFollower()
    rows = np.array(sc.hazard_rows, np.int64)
    log: dict[str, list] = {k: [] for k in ("ego_xy", "ego_s", "ego_speed", "hazard_xy", "hazard_speed",
                                            "ego_vis", "rsu_vis", "triggered")}
    passed_at = None
    for _ in range(max_ticks):
        world.step(driver.act(ego_observation(world)), world.default_rsu_message())
        if on_tick is not None:
            on_tick(world)
        t = world.table
        rows = np.array(sc.hazard_rows, np.int64)
        log["ego_xy"].append(t.pos[0].copy())
        log["ego_s"].append(sc.ego_s(world))
        log["ego_speed"].append(float(t.speed[0]))
        log["hazard_xy"].append(t.pos[rows].copy())
        log["hazard_speed"].append(t.speed[rows].copy())
        log["ego_vis"].append(world.ego_vis[rows].copy())
        log["rsu_vis"].append(world.rsu_vis[0, rows].copy())
        log["triggered"].append(sc.triggered)
        if sc.passed and passed_at is None:
            passed_at = world.tick
        if passed_at is not None and world.tick - passed_at > stop_after_pass / world.config.dt:
            break
        if world.is_route_complete():
            break
    arr = {k: np.array(v) for k, v in log.items()}
    return ProbeRecord(**arr, events=world.monitor.counts.copy(), scenario=sc, world=world)


def hidden_seconds(rec: ProbeRecord, hazard: int = 0, threshold: float = 0.1) -> float:
    """Longest continuous time (s) after the trigger during which hazard ``hazard`` was hidden
    from the ego (visible fraction below ``threshold``) *and* visible from the active RSU,
    ending before the ego reached the conflict point."""
    sc = rec.scenario
    before = (rec.ego_s < sc.conflict_s) & rec.triggered
    ok = before & (rec.ego_vis[:, hazard] < threshold) & (rec.rsu_vis[:, hazard] >= threshold)
    best = run = 0
    for v in ok:
        run = run + 1 if v else 0
        best = max(best, run)
    return best * 0.1
