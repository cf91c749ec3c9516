"""Core: what every room builds on, and nothing above it.

The actor table (:mod:`.actors`), object classes, geometry, ego dynamics and IDM
(:mod:`.dynamics`), cheap random draws, the C-library math the NumPy paths share with the
kernels (:mod:`.libm`), field validation, the 2.5D ray-casting core (:mod:`.raycast`), and the
numba plumbing: :mod:`.jit` (``_njit``, ``HAVE_JIT``, lane-polyline kernels), :mod:`.jit_cache`,
:mod:`.jit_args`, :mod:`.jit_rng` (NumPy's PCG64 draws inside kernels), :mod:`.jit_grid`.

NumPy / numba pairs here: :mod:`.raycast` / :mod:`.jit_raycast`, :mod:`.dynamics` (IDM and the
ego's bicycle, both paths in one module), ``town.model.PolylineIndex`` / :mod:`.jit`'s
``project_kernel`` and ``pose_at_kernel``. The NumPy path is the reference: the kernels are
tested against it bit for bit (``tests/core/test_jit.py``) and it is the fallback without numba.
Modules here import only each other (and ``town.model`` for lane tables' types).
"""
