"""Experiments by one command (issue #35): ``v2xbench experiments run --config FILE --out DIR``
runs a config's jobs (data, trainings, perception / open-loop / closed-loop / VQA evaluations,
channel sweeps) resumably, and ``v2xbench experiments report DIR`` turns their results into the
paper's tables, ablations and channel-robustness plots.

- :mod:`.config`: the config format, its validation and expansion;
- :mod:`.job_kinds`: what each kind of job runs (the existing functions);
- :mod:`.runner`: the run (order, resume, failures, progress);
- :mod:`.report`, :mod:`.report_plots`: the tables and plots.

The shipped configs are in ``configs/`` (:func:`shipped_config`).
"""

from __future__ import annotations

from pathlib import Path

CONFIG_DIR = Path(__file__).parent / "configs"


def shipped_config(name: str) -> Path:
    """The path of a shipped config (``paper``, ``quick``, ``shipped``, ``robustness_oracles``).

    Raises:
        ValueError: no such config (the shipped ones named).
    """
    p = CONFIG_DIR / f"{name}.json"
    if not p.is_file():
        known = sorted(q.stem for q in CONFIG_DIR.glob("*.json"))
        raise ValueError(f"no shipped experiment config {name!r}; shipped: {known}")
    return p


__all__ = ["CONFIG_DIR", "shipped_config"]
