"""Exported baseline weights: what a registered baseline agent needs of a trained run, checked
by SHA-256 (AURORA's export format, :mod:`v2xbench.agents.aurora.export`, for the baselines).

``v2xbench baselines export univ2x --run RUN`` writes ``agents/baselines/weights/univ2x``::

    OUT/checkpoint.safetensors   the run's model weights, float32, byte for byte (so the export
                                 drives exactly as the run)
    OUT/<method>.json            the run file (model config, camera size, data, ...)
    OUT/manifest.json            both files' SHA-256 and size, the method, scale, planner
                                 switches, parameter count, source run, command, git commit, date

The folder is a run for :func:`~.train.BaselineRun.load_run`; the registered agents
(:class:`~.agent.BaselineAgent`) load :data:`SHIPPED` ``/ <method>`` when no run is given, after
:func:`verify` checked every file.
"""

from __future__ import annotations

import importlib
import json
import shutil
from pathlib import Path
from typing import Any

from v2xbench.agents.aurora.export import (  # AURORA's export format, for the baselines
    MANIFEST,
    check_export_target,
    finish_export,
    sha256_file,
    verify_export,
)

#: Where the repository's shipped baseline weights live (one folder per method).
SHIPPED = Path(__file__).resolve().parents[1] / "weights"
FORMAT = "v2xbench-baseline-export/1"


def _run_module(method: str) -> Any:
    """The method's :class:`~.train.BaselineRun` (``ValueError``: unknown method)."""
    from v2xbench.agents.baselines import BASELINES

    if method not in BASELINES:
        raise ValueError(f"unknown baseline {method!r}; known: {', '.join(sorted(BASELINES))}")
    return importlib.import_module(BASELINES[method] + ".train").RUN


def export_dir(method: str, out: str | Path | None = None) -> Path:
    """Where ``export_run`` writes: ``out``, else :data:`SHIPPED` ``/ method``."""
    return Path(out) if out is not None else SHIPPED / method


def export_run(method: str, run: str | Path, out: str | Path | None = None, *,
               command: str | None = None) -> dict:
    """Export the trained ``run`` of ``method`` into ``out`` (default :data:`SHIPPED` ``/
    method``; replaced atomically). Returns the manifest.

    Raises:
        ValueError: unknown method. FileNotFoundError: not a trained run of the method.
    """
    from v2xbench.agents.baselines.common.train import CHECKPOINT

    spec = _run_module(method)
    model, cfg, info = spec.load_run(run)  # checks the run loads into the method's model
    out = check_export_target(export_dir(method, out), run,
                              f"baselines export {method}")
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    shutil.copyfile(info["checkpoint"], tmp / CHECKPOINT)
    run_info = {k: v for k, v in info.items() if k != "checkpoint"}
    (tmp / spec.run_file).write_text(json.dumps(run_info, indent=1))
    manifest = {
        "format": FORMAT, "method": method, "scale": cfg.scale,
        "plan_frame": cfg.plan_frame, "plan_ego_speed": cfg.plan_ego_speed,
        "parameters": int(sum(p.numel() for p in model.parameters())),
        "message_floats": int(cfg.message_floats()),
        "source": {"run": str(Path(run).resolve()),
                   "checkpoint_sha256": sha256_file(info["checkpoint"])},
    }
    return finish_export(tmp, out, manifest, command)


def verify(path: str | Path, method: str) -> dict:
    """The manifest of an exported folder of ``method`` after checking every file it lists.

    Raises:
        FileNotFoundError: a missing manifest or file. ValueError: a changed file, another
            format or another method's weights.
    """
    m = verify_export(path, FORMAT, f"{method} weights",
                      f"v2xbench baselines export {method} --run RUN --out DIR")
    if m.get("method") != method:
        raise ValueError(f"{method} weights: {path} holds {m.get('method')!r} weights")
    return m


__all__ = ["FORMAT", "MANIFEST", "SHIPPED", "export_dir", "export_run", "verify"]
