"""V2XIntersection: the V2XBench cooperative driving simulator and its three APIs.

- :func:`parallel_env` - PettingZoo ``ParallelEnv`` with agents ``"ego"`` and ``"rsu"``.
- ``gym.make("v2xbench:V2XIntersection-v0", **config)`` - :class:`V2XIntersectionEnv`.
- :class:`V2XTorchEnv` - native batched TorchRL ``EnvBase``.

All three wrap one :class:`World`; configuration keys are the fields of :class:`EnvConfig`.

The package is grouped by subsystem: ``core/``, ``town/``, ``traffic/``, ``perception/``,
``v2x/``, ``evaluation/``, ``sensors/``, ``scenarios/``, ``suites/``, ``sim/`` (the world and its
step order), ``api/`` and ``render/``; imports flow from ``api`` down to ``core``
(``docs/architecture.md``).

``V2XTorchEnv`` is imported on first use: torch, tensordict and TorchRL take ~4 s to import, which
``gym.make`` and ``parallel_env`` (NumPy only) do not need.
"""

from typing import TYPE_CHECKING

from .api.gym_env import V2XIntersectionEnv
from .api.parallel_env import V2XParallelEnv, parallel_env
from .sim.config import EnvConfig, make_config
from .sim.world import StepError, World

#: old module paths kept for one release as deprecated aliases of their new homes (CHANGELOG.md)
DEPRECATED_ALIASES = ("channel", "docgen", "episode", "geometry", "infractions", "suites_build")

if TYPE_CHECKING:
    from .api.torchrl_env import V2XTorchEnv

__all__ = ["EnvConfig", "StepError", "V2XIntersectionEnv", "V2XParallelEnv", "V2XTorchEnv", "World",
           "make_config", "parallel_env"]


def __getattr__(name: str):
    if name == "V2XTorchEnv":  # imported on first use (torch is heavy to import)
        from .api.torchrl_env import V2XTorchEnv

        return V2XTorchEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | {"V2XTorchEnv"})
