"""The simulation: configuration (:mod:`.config`) and the world with its fixed step order
(:mod:`.world`), plus the kernels that run a tick's moving part (:mod:`.jit_tick`) and a batch of
worlds (:mod:`.jit_batch`) in one call.

``World.step`` runs the subsystems (traffic, v2x, evaluation, perception) in the order its module
docstring gives; the NumPy stage methods are the reference the one-call kernels are tested
against (``tests/core/test_jit.py``, ``tests/sim/test_jit_batch.py``). :mod:`.docgen` writes
the configuration tables of ``docs/environment.md`` from :mod:`.config`.
"""
