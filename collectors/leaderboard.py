"""Leaderboard over evaluation result directories: a markdown table, bar plots, a breakdown.

``v2xbench leaderboard results/* --out leaderboard`` reads each directory's ``summary.json``
(written by :func:`~.evaluate.evaluate`) and writes into ``--out``:

- ``leaderboard.md``: one row per result directory, sorted by driving score: agent, DS with the
  half-width of its bootstrap 95% CI, RC, IS, Efficiency, Comfortness, BPS and the DS (with its
  CI) and Efficiency of the routes that contain a V2X scenario type; privileged agents (the
  built-in expert and oracles, as the harness decided: ``interface.PRIVILEGED_AGENTS``) are marked
  ``*``, agents that ran in a separate process from the simulator (``--isolate-agent``) ``+``;
  then a per-scenario-type table (success rate % / mean DS per agent);
- ``leaderboard.json``: the same rows as data;
- ``driving_score.png``, ``route_completion.png``, ``infraction_score.png``, ``bps.png``: bar
  plots (matplotlib, ``Agg`` backend; skipped with a note when matplotlib is not installed).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .jobs import write_json_atomic

PLOTS = (("driving_score", "Driving score"), ("route_completion", "Route completion (%)"),
         ("infraction_score", "Infraction score"), ("bps", "V2X bytes per second"))
COLUMNS = (("route_completion", "RC", 1), ("infraction_score", "IS", 3), ("efficiency", "Efficiency", 1),
           ("comfortness", "Comfortness", 1), ("bps", "BPS", 0))


def _num(x) -> float:
    return float("nan") if x is None else float(x)


def _f(x, nd: int = 1) -> str:
    x = _num(x)
    return f"{x:.{nd}f}" if np.isfinite(x) else "-"


def _ci_half(lo: float, hi: float) -> float:
    """Half-width of a confidence interval (NaN where a bound is missing)."""
    return (hi - lo) / 2.0 if np.isfinite(hi - lo) else float("nan")


def load_rows(result_dirs: list[str | Path]) -> list[dict]:
    """One row per directory with a ``summary.json``, sorted by driving score (best first).

    Raises:
        ValueError: none of the directories has a summary.
    """
    rows = []
    for d in map(Path, result_dirs):
        p = d / "summary.json"
        if not p.is_file():
            continue
        s = json.loads(p.read_text())
        m, v = s["metrics"], s.get("v2x") or {}
        lo, hi = _num(m.get("driving_score_ci_low")), _num(m.get("driving_score_ci_high"))
        v_lo, v_hi = _num(v.get("driving_score_ci_low")), _num(v.get("driving_score_ci_high"))
        rows.append({
            "run": d.name, "dir": str(d), "agent": s["agent_name"], "agent_spec": s["agent"],
            "privileged": bool(s.get("privileged")), "agent_process": s.get("agent_process", "in_process"),
            "suite": s["suite"], "seeds": s["seeds"],
            "n_jobs": s["n_jobs"], "n_results": s["n_results"],
            "driving_score": _num(m["driving_score"]), "ds_ci_low": lo, "ds_ci_high": hi,
            "ds_ci_half": _ci_half(lo, hi),
            **{k: _num(m.get(k)) for k, _, _ in COLUMNS},
            "v2x_driving_score": _num(v.get("driving_score")),
            "v2x_ds_ci_half": _ci_half(v_lo, v_hi),
            "v2x_efficiency": _num(v.get("efficiency")),
            "per_scenario": s.get("per_scenario", {}),
            "config_overrides": s.get("config_overrides") or {},
        })
    if not rows:
        raise ValueError(f"no summary.json in {', '.join(map(str, result_dirs)) or 'no directories'}; "
                         "run `v2xbench eval` first")
    rows.sort(key=lambda r: -r["driving_score"] if np.isfinite(r["driving_score"]) else np.inf)
    names = [r["agent"] for r in rows]
    for r in rows:  # the same agent twice (e.g. two configs): tell the rows apart by directory
        r["label"] = r["agent"] if names.count(r["agent"]) == 1 else f"{r['agent']} ({r['run']})"
    return rows


def leaderboard_markdown(rows: list[dict]) -> str:
    """Main table and per-scenario-type breakdown (see module docstring)."""
    suites = sorted({r["suite"] for r in rows})
    lines = ["# V2XBench leaderboard", "",
             f"Suite: {', '.join(suites)}. DS: mean over routes x seeds (failed or missing runs count "
             "0) +- half-width of the bootstrap 95% CI. `*`: privileged agent (reads the simulator "
             "state). `+`: the agent ran in a separate process from the simulator.", ""]
    if len(suites) > 1:
        lines += ["**Warning: the rows come from different suites and are not comparable.**", ""]
    configs = {json.dumps(r["config_overrides"], sort_keys=True) for r in rows}
    if len(configs) > 1:
        lines += ["**Warning: the rows were run with different config overrides:** "
                  + "; ".join(f"{r['label']}: `{r['config_overrides'] or 'defaults'}`" for r in rows), ""]
    lines += ["| # | agent | runs | DS | " + " | ".join(c for _, c, _ in COLUMNS)
              + " | V2X-type DS | V2X-type Efficiency |",
              "|---" * (len(COLUMNS) + 6) + "|"]
    for k, r in enumerate(rows, 1):
        star = ("*" if r["privileged"] else "") + ("+" if r["agent_process"] == "isolated" else "")
        cells = " | ".join(_f(r[key], nd) for key, _, nd in COLUMNS)
        lines.append(f"| {k} | {r['label']}{star} | {r['n_results']}/{r['n_jobs']} | "
                     f"{_f(r['driving_score'])} +- {_f(r['ds_ci_half'])} | {cells} | "
                     f"{_f(r['v2x_driving_score'])} +- {_f(r['v2x_ds_ci_half'])} | "
                     f"{_f(r['v2x_efficiency'])} |")
    types = sorted({t for r in rows for t in r["per_scenario"]})
    if types:
        lines += ["", "## Per scenario type", "", "Success rate % (passed, no collision in the scenario "
                  "window, no timeout) / mean DS of the runs whose route contains the type.", "",
                  "| scenario type | V2X | " + " | ".join(r["label"] for r in rows) + " |",
                  "|---|---" + "|---" * len(rows) + "|"]
        for t in types:
            v2x = next(r["per_scenario"][t]["v2x"] for r in rows if t in r["per_scenario"])
            cells = []
            for r in rows:
                p = r["per_scenario"].get(t)
                cells.append(f"{_f(p['success_rate'], 0)} / {_f(p['mean_ds'])}" if p else "-")
            lines.append(f"| {t} | {'yes' if v2x else 'no'} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def save_plots(rows: list[dict], out: Path) -> list[Path]:
    """Bar plots of DS (with CI), RC, IS and BPS, one PNG each; raises ImportError without
    matplotlib."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [r["label"] + ("*" if r["privileged"] else "") for r in rows]
    paths = []
    for key, title in PLOTS:
        vals = np.array([r[key] for r in rows], float)
        fig, ax = plt.subplots(figsize=(max(4.0, 0.9 * len(rows) + 2.0), 3.2), dpi=100)
        err = None
        if key == "driving_score":
            lo = np.array([r["ds_ci_low"] for r in rows], float)
            hi = np.array([r["ds_ci_high"] for r in rows], float)
            err = np.nan_to_num(np.stack([vals - lo, hi - vals]), nan=0.0).clip(min=0.0)
        colors = ["#888888" if r["privileged"] else "#2f6fb0" for r in rows]
        ax.bar(range(len(rows)), np.nan_to_num(vals), yerr=err, capsize=4, color=colors)
        ax.set_xticks(range(len(rows)), labels, rotation=20, ha="right", fontsize=8)
        ax.set_title(title)
        ax.grid(axis="y", alpha=0.3)
        fig.tight_layout()
        p = out / f"{key}.png"
        fig.savefig(p)
        plt.close(fig)
        paths.append(p)
    return paths


def build_leaderboard(result_dirs: list[str | Path], out: str | Path = "leaderboard",
                      plots: bool = True) -> dict:
    """Write ``leaderboard.md``, ``leaderboard.json`` and the plots into ``out``.

    Returns:
        ``{"rows": [...], "markdown": path, "plots": [paths], "note": str | None}``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = load_rows(result_dirs)
    md = out / "leaderboard.md"
    md.write_text(leaderboard_markdown(rows))
    write_json_atomic({"rows": rows}, out / "leaderboard.json")
    paths, note = [], None
    if plots:
        try:
            paths = save_plots(rows, out)
        except ImportError:
            note = "matplotlib is not installed: no plots (pip install matplotlib)"
    return {"rows": rows, "markdown": str(md), "plots": [str(p) for p in paths], "note": note}
