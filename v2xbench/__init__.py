"""V2XBench: cooperative (vehicle + roadside unit) closed-loop driving benchmark.

Importing ``v2xbench`` registers the Gymnasium ids (``V2XIntersection-v0`` and
``v2xbench:V2XIntersection-v0`` both work with ``gym.make``).
"""

from __future__ import annotations

__version__ = "0.1.0"

ENV_ID = "V2XIntersection-v0"


def _register() -> None:
    import gymnasium as gym

    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="v2xbench.envs.v2x_intersection.api.gym_env:V2XIntersectionEnv",
                     vector_entry_point="v2xbench.envs.v2x_intersection.api.batch:V2XVectorEnv")


_register()
