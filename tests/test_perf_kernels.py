"""``v2xbench perf`` (``benchmarks/perf_kernels.py``): symbol names and the report's table. The
sampling itself needs Linux ``perf`` and is not run here."""

from __future__ import annotations

from v2xbench.benchmarks import perf_kernels as pk


def test_demangle_numba_symbols():
    sym = "_ZN8v2xbench4envs16v2x_intersection3jit14leaders_kernelB4v309B56c8tJTIeFIjxB2IKSgE5ArrayIdLi1E"
    assert pk.demangle(sym) == "jit.leaders_kernel"
    assert pk.demangle("_ZN5numba5typed10listobject12impl_getitem12_3clocals_3e21integer_non_none_implB4v2") == \
        "numba.typed.listobject.impl_getitem.<locals>.integer_non_none_impl"
    assert pk.demangle("_PyEval_EvalFrameDefault") == "_PyEval_EvalFrameDefault"


def test_render_names_the_compiling_share():
    report = {"mode": "batched", "seconds": 5.0, "when": "now", "compiling_percent": 12.0,
              "by_object": [{"object": "numba JIT", "percent": 30.0}],
              "top_symbols": [{"object": "numba JIT", "symbol": "jit.leaders_kernel", "percent": 9.2}]}
    text = pk.render(report)
    assert "12.0 % of the samples were numba compiling" in text
    assert "| `jit.leaders_kernel` | numba JIT | 9.20 |" in text
    assert "run it again" in text
