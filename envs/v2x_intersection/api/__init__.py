"""The public adapters over one :class:`~..sim.world.World`: Gymnasium (:mod:`.gym_env`), PettingZoo
(:mod:`.parallel_env`), TorchRL (:mod:`.torchrl_env`), batched worlds (:mod:`.batch`), and what
they share: observations (:mod:`.observations`, with its kernel :mod:`.jit_observations`) and
action modes (:mod:`.actions`).

:mod:`.observations`'s NumPy path is the reference the ``objects``-mode kernel is tested against
(``tests/api/test_obs_bounds.py``, ``tests/core/test_jit.py``) and the fallback without numba.
"""
