"""Cost growth: objects-mode ticks/s against the number of actors (10 to 200).

Each row is ``gym.make("V2XIntersection-v0")`` on Town01 with the population scaled to ``A``
actors in total (ego + 55 % NPC vehicles, 15 % parked, 25 % pedestrians, 5 % bicycles; spawning
may place fewer when the town is full: the row reports the actors actually active), a constant
action and the built-in RSU policy, timed over ``steps`` env steps (single process) after
``warmup`` untimed ones (numba loads each kernel from its disk cache on its first call in a
process, and the first rows would otherwise pay for it: with 5 warm-up steps and 300 timed, 10
actors measured slower than 25).
"""

from __future__ import annotations

from .env_speed import timed_steps


def population(total: int) -> dict:
    """Config counts for about ``total`` actors including the ego."""
    a = max(total - 1, 0)
    veh, parked, peds = round(0.55 * a), round(0.15 * a), round(0.25 * a)
    return dict(num_vehicles=veh, num_parked=parked, num_pedestrians=peds,
                num_bicycles=max(a - veh - parked - peds, 0))


def measure(actors=(10, 25, 50, 100, 150, 200), steps: int = 1000, seed: int = 0, warmup: int = 100) -> dict:
    import gymnasium as gym
    import numpy as np

    import v2xbench  # noqa: F401

    rows = []
    action = np.array([0.3, 0.0, 0.0], np.float32)
    for total in actors:
        env = gym.make("V2XIntersection-v0", **population(total))
        env.reset(seed=seed)
        active = int(env.unwrapped.world.table.active.sum())
        wall, cpu = timed_steps(env, action, steps, seed, warmup)
        rows.append({"actors_requested": total, "actors": active, "ticks_per_s": steps / wall,
                     "ticks_per_s_cpu": steps / cpu, "ms_per_tick": 1e3 * wall / steps})
    return {"rows": rows}
