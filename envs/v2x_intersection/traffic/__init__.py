"""Traffic: NPC vehicles and bicycles (:mod:`.vehicles`), traffic lights (:mod:`.signals`),
pedestrians (:mod:`.pedestrians`) and populating a world at reset (:mod:`.spawn`).

Each NumPy model has its numba kernel beside it: :mod:`.vehicles` / :mod:`.jit_vehicles`
(car-following leaders, IDM, stop rules, junction yielding), :mod:`.pedestrians` /
:mod:`.jit_walkers`, :mod:`.spawn` / :mod:`.jit_spawn`. The NumPy path is the reference: the
kernels are tested against it (same actor table, same generator state; ``tests/core/test_jit.py``)
and it is the fallback without numba (``V2XBENCH_NO_JIT=1``). Imports: ``core`` and ``town``.
"""
