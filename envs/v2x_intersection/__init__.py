"""V2XIntersection: the V2XBench cooperative driving simulator and its three APIs.

- :func:`parallel_env` - PettingZoo ``ParallelEnv`` with agents ``"ego"`` and ``"rsu"``.
- ``gym.make("v2xbench:V2XIntersection-v0", **config)`` - :class:`V2XIntersectionEnv`.
- :class:`V2XTorchEnv` - native batched TorchRL ``EnvBase``.

All three wrap one :class:`World`; configuration keys are the fields of :class:`EnvConfig`.
"""

from .config import EnvConfig, make_config
from .gym_env import V2XIntersectionEnv
from .parallel_env import V2XParallelEnv, parallel_env
from .torchrl_env import V2XTorchEnv
from .world import StepError, World

__all__ = ["EnvConfig", "StepError", "V2XIntersectionEnv", "V2XParallelEnv", "V2XTorchEnv", "World",
           "make_config", "parallel_env"]
