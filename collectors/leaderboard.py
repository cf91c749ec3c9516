"""Leaderboard over evaluation result directories: ranked tables per track, bar plots, breakdown.

``v2xbench leaderboard results/* --out leaderboard`` reads each directory's ``summary.json``
(written by :func:`~.evaluate.evaluate`) and writes into ``--out`` (atomically,
``v2xbench.files``):

- ``leaderboard.md``: runs are ranked only against comparable runs, as CARLA's leaderboard ranks
  each track apart: one table per **group** of runs with the same suite, the same routes (the
  selection's route ids), the same number of seeds, the same observation mode (the *track*:
  ``objects``, ``sensors``, ``bev``) and the same world settings (the env overrides other than
  the agent's own choices: obs/action mode, roadside policy, sensor settings and the payload limit
  its messages need, ``max_payload_floats``). Within a group
  rows are sorted by driving score: agent, roadside policy, sensor settings (from the env
  overrides; ``default`` when none), routes x seeds, runs with results, DS with the half-width of
  its bootstrap 95% CI, RC, IS, Efficiency, Comfortness, BPS and the DS (with its CI) and
  Efficiency of the routes that contain a V2X scenario type; privileged agents (the built-in
  expert and oracles, as the harness decided: ``interface.PRIVILEGED_AGENTS``) are marked ``*``,
  agents that ran in a separate process from the simulator (``--isolate-agent``) ``+``; then the
  group's per-scenario-type table (success rate % / mean DS per agent). Summaries written before
  these fields existed show ``unknown`` where they lack one; their routes were the suite's first
  ``n_routes`` (``--max-routes`` was the only selection then), read from the suite when it loads;
- with ``common=True`` (``--common``), every folder is scored on the same runs: the largest grid
  of routes x seed indices ``0 .. k-1`` whose runs every folder holds (:func:`common_runs`), its
  summary recomputed from the per-route results (``eval_summary.summarize``), so that evaluations
  still running, or of other lengths or selections, rank in one table; the group's label says
  it is such a grid. The folders must be of one suite;
- ``leaderboard.json``: the rows (with their ``group`` and ``rank``) and the groups as data;
- ``driving_score.png``, ``route_completion.png``, ``infraction_score.png``, ``bps.png``: bar
  plots, one set per group (``<metric>_g<k>.png`` for group ``k`` when there are several;
  matplotlib, ``Agg`` backend; skipped with a note when matplotlib is not installed; plots an
  earlier call left in ``--out`` are removed first).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from v2xbench.files import atomic_write, atomic_write_text

from . import jobs as J
from .eval_summary import sensor_settings, summarize
from .jobs import write_json_atomic

PLOTS = (
    ("driving_score", "Driving score"),
    ("route_completion", "Route completion (%)"),
    ("infraction_score", "Infraction score"),
    ("bps", "V2X bytes per second"),
)
COLUMNS = (
    ("route_completion", "RC", 1),
    ("infraction_score", "IS", 3),
    ("efficiency", "Efficiency", 1),
    ("comfortness", "Comfortness", 1),
    ("bps", "BPS", 0),
)
#: env overrides that are the agent's own choices, not world settings (they do not split groups)
AGENT_SIDE_KEYS = ("obs_mode", "rsu_policy", "action_mode")
#: channel settings an agent declares its messages need (``agent.channel``): a message is never
#: cut, so the limit changes nothing for the run but whether the message fits (not a world setting)
AGENT_CHANNEL_KEYS = ("max_payload_floats",)
UNKNOWN = "unknown"


def _num(x) -> float:
    return float("nan") if x is None else float(x)


def _f(x, nd: int = 1) -> str:
    x = _num(x)
    return f"{x:.{nd}f}" if np.isfinite(x) else "-"


def _ci_half(lo: float, hi: float) -> float:
    """Half-width of a confidence interval (NaN where a bound is missing)."""
    return (hi - lo) / 2.0 if np.isfinite(hi - lo) else float("nan")


def _setting(s: dict, key: str) -> str:
    """``obs_mode`` / ``rsu_policy`` / ``action_mode`` of a summary (older ones: from the env
    overrides, else ``unknown``)."""
    return str(s.get(key) or (s.get("config_overrides") or {}).get(key) or UNKNOWN)


def world_settings(overrides: dict) -> dict:
    """The env overrides that change the world (all but :data:`AGENT_SIDE_KEYS`,
    :data:`AGENT_CHANNEL_KEYS` and sensors)."""
    sensors = sensor_settings(overrides)
    return {
        k: v for k, v in sorted(overrides.items())
        if k not in AGENT_SIDE_KEYS and k not in AGENT_CHANNEL_KEYS and k not in sensors
    }


def _selection(s: dict) -> dict:
    """A summary's route selection; for a summary without one, the suite's first ``n_routes``
    routes (the only selection there was), or ``{}`` when the suite does not load."""
    if isinstance(s.get("selection"), dict):
        return s["selection"]
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

    try:
        ids = [r.id for r in load_suite_cached(str(s["suite"]))]
    except (ValueError, OSError):
        return {}
    n = int(s["n_routes"])
    label = f"all {n} routes" if n == len(ids) else f"first {n}"
    return {"label": label, "route_ids": ids[:n]}


def _group(s: dict, overrides: dict) -> tuple[str, str]:
    """``(key, label)`` of the group a summary is ranked in (module docstring)."""
    sel = _selection(s)
    ids = sel.get("route_ids")
    what = sel.get("label") or f"selection {UNKNOWN}"
    routes = what if what.startswith("all ") else f"{s['n_routes']} routes ({what})"
    world = world_settings(overrides)
    obs = _setting(s, "obs_mode")
    key = json.dumps(
        [s["suite"], ids if ids is not None else ["?", s["n_routes"]], s["seeds"], obs, world],
        sort_keys=True,
    )
    label = f"`{obs}` track on {s['suite']}: {routes} x {s['seeds']} seed(s)"
    if world:
        label += f", world `{json.dumps(world, sort_keys=True)}`"
    return key, label


def _row(d: Path, s: dict) -> dict:
    m, v = s["metrics"], s.get("v2x") or {}
    lo, hi = _num(m.get("driving_score_ci_low")), _num(m.get("driving_score_ci_high"))
    v_lo, v_hi = _num(v.get("driving_score_ci_low")), _num(v.get("driving_score_ci_high"))
    overrides = s.get("config_overrides") or {}
    key, label = _group(s, overrides)
    return {
        "run": d.name,
        "dir": str(d),
        "agent": s["agent_name"],
        "agent_spec": s["agent"],
        "privileged": bool(s.get("privileged")),
        "agent_process": s.get("agent_process", "in_process"),
        "suite": s["suite"],
        "seeds": s["seeds"],
        "n_routes": s["n_routes"],
        "n_jobs": s["n_jobs"],
        "n_results": s["n_results"],
        "obs_mode": _setting(s, "obs_mode"),
        "rsu_policy": _setting(s, "rsu_policy"),
        "action_mode": _setting(s, "action_mode"),
        "sensors": s["sensors"]
        if isinstance(s.get("sensors"), dict)
        else sensor_settings(overrides),
        "selection": _selection(s).get("label") or UNKNOWN,
        "fingerprint": s.get("fingerprint"),
        "group_key": key,
        "group": label,
        "driving_score": _num(m["driving_score"]),
        "ds_ci_low": lo,
        "ds_ci_high": hi,
        "ds_ci_half": _ci_half(lo, hi),
        **{k: _num(m.get(k)) for k, _, _ in COLUMNS},
        "v2x_driving_score": _num(v.get("driving_score")),
        "v2x_ds_ci_half": _ci_half(v_lo, v_hi),
        "v2x_efficiency": _num(v.get("efficiency")),
        "per_scenario": s.get("per_scenario", {}),
        "config_overrides": overrides,
    }


def _ds_key(r: dict) -> float:
    return -r["driving_score"] if np.isfinite(r["driving_score"]) else np.inf


def common_runs(result_dirs: list[str | Path]) -> tuple[str, list[str], int]:
    """``(suite, route_ids, seeds)``: the largest grid of the suite's routes x seed indices
    ``0 .. seeds - 1`` whose every run has a result in every folder (most runs; on a tie, more
    seeds), routes in suite order.

    Raises:
        ValueError: fewer than two folders, a folder without ``run.json``, folders of different
            suites, or no run that every folder holds.
    """
    dirs = [Path(d) for d in result_dirs]
    if len(dirs) < 2:
        raise ValueError("--common compares folders on the runs they share: give two or more")
    suites = {}
    for d in dirs:
        try:
            suites[d] = str(json.loads((d / "run.json").read_text())["suite"])
        except (OSError, ValueError, KeyError) as e:
            raise ValueError(f"{d} is not an evaluation folder (run.json: {type(e).__name__}: {e})") from None
    if len(set(suites.values())) > 1:
        raise ValueError("--common needs folders of one suite; these are of "
                         + ", ".join(f"{d}: {s}" for d, s in suites.items()))
    suite = suites[dirs[0]]
    ids = _suite_ids(suite)
    held = [{p.stem for p in J.routes_dir(d).glob("*.json")} for d in dirs]
    shared = set.intersection(*held)
    best: tuple[int, int, list[str]] = (0, 0, [])
    k = 1
    while True:
        routes = [r for r in ids if all(J.job_id(r, s) in shared for s in range(k))]
        if not routes:
            break
        if len(routes) * k >= best[0]:
            best = (len(routes) * k, k, routes)
        k += 1
    if not best[0]:
        raise ValueError(f"the {len(dirs)} folders share no run of suite {suite}: "
                         + ", ".join(f"{d} holds {len(h)}" for d, h in zip(dirs, held)))
    return suite, best[2], best[1]


def common_summaries(result_dirs: list[str | Path], n_boot: int = 2000) -> list[tuple[Path, dict]]:
    """Each folder's summary over the runs all of them hold (:func:`common_runs`), recomputed
    from its per-route results; the selection's label names the grid."""
    from .route_selection import selected_jobs

    suite, route_ids, seeds = common_runs(result_dirs)
    _, _, jobs = selected_jobs(suite, seeds, routes=route_ids)
    label = f"runs all {len(result_dirs)} folders hold"
    record = {"routes": None, "scenario": None, "v2x_only": False, "max_routes": None,
              "common": True, "label": label, "route_ids": route_ids}
    return [(Path(d), summarize(d, jobs, n_boot=n_boot, selection=record)) for d in result_dirs]


def _suite_ids(suite: str) -> list[str]:
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

    return [r.id for r in load_suite_cached(suite)]


def load_rows(result_dirs: list[str | Path], common: bool = False) -> list[dict]:
    """One row per directory with a ``summary.json``, grouped (module docstring) and ranked by
    driving score within each group (best first); groups with more runs come first. With
    ``common``, every directory's summary over the runs all hold (:func:`common_summaries`).

    Raises:
        ValueError: none of the directories has a summary, or a summary does not parse (with
            ``common``: :func:`common_runs`' errors).
    """
    if common:
        return _ranked([_row(d, s) for d, s in common_summaries(result_dirs)], result_dirs)
    rows = []
    for d in map(Path, result_dirs):
        p = d / "summary.json"
        if not p.is_file():
            continue
        try:
            s = json.loads(p.read_text())
            rows.append(_row(d, s))
        except (ValueError, KeyError, TypeError) as e:
            raise ValueError(
                f"{p} is not an evaluation summary ({type(e).__name__}: {e})"
            ) from None
    return _ranked(rows, result_dirs)


def _ranked(rows: list[dict], result_dirs: list[str | Path]) -> list[dict]:
    """The rows grouped, sorted and ranked, with display labels (:func:`load_rows`)."""
    if not rows:
        raise ValueError(
            f"no summary.json in {', '.join(map(str, result_dirs)) or 'no directories'}; "
            "run `v2xbench eval` first"
        )
    size = {k: sum(r["group_key"] == k for r in rows) for k in {r["group_key"] for r in rows}}
    rows.sort(key=lambda r: (-size[r["group_key"]], r["group"], r["group_key"], _ds_key(r)))
    rank, last = 0, None
    for r in rows:
        rank = rank + 1 if r["group_key"] == last else 1
        r["rank"], last = rank, r["group_key"]
    names = [r["agent"] for r in rows]
    for r in rows:  # the same agent twice (e.g. two configs): tell the rows apart by directory
        r["label"] = r["agent"] if names.count(r["agent"]) == 1 else f"{r['agent']} ({r['run']})"
    return rows


def groups(rows: list[dict]) -> list[list[dict]]:
    """The rows of :func:`load_rows` split by group, in order."""
    out: list[list[dict]] = []
    for r in rows:
        if not out or out[-1][0]["group_key"] != r["group_key"]:
            out.append([])
        out[-1].append(r)
    return out


def _sensors(r: dict) -> str:
    return "default" if not r["sensors"] else ", ".join(f"{k}={v}" for k, v in r["sensors"].items())


def _group_markdown(rows: list[dict]) -> list[str]:
    lines = [
        "| # | agent | RSU policy | sensors | routes x seeds | runs | DS | "
        + " | ".join(c for _, c, _ in COLUMNS)
        + " | V2X-type DS | V2X-type Efficiency |",
        "|---" * (len(COLUMNS) + 9) + "|",
    ]
    for r in rows:
        star = ("*" if r["privileged"] else "") + ("+" if r["agent_process"] == "isolated" else "")
        cells = " | ".join(_f(r[key], nd) for key, _, nd in COLUMNS)
        lines.append(
            f"| {r['rank']} | {r['label']}{star} | {r['rsu_policy']} | {_sensors(r)} | "
            f"{r['n_routes']} x {r['seeds']} | {r['n_results']}/{r['n_jobs']} | "
            f"{_f(r['driving_score'])} +- {_f(r['ds_ci_half'])} | {cells} | "
            f"{_f(r['v2x_driving_score'])} +- {_f(r['v2x_ds_ci_half'])} | "
            f"{_f(r['v2x_efficiency'])} |"
        )
    types = sorted({t for r in rows for t in r["per_scenario"]})
    if types:
        lines += [
            "",
            "### Per scenario type",
            "",
            "Success rate % (passed, no collision in the "
            "scenario window, no timeout) / mean DS of the runs whose route contains the type.",
            "",
            "| scenario type | V2X | " + " | ".join(r["label"] for r in rows) + " |",
            "|---|---" + "|---" * len(rows) + "|",
        ]
        for t in types:
            v2x = next(r["per_scenario"][t]["v2x"] for r in rows if t in r["per_scenario"])
            cells = []
            for r in rows:
                p = r["per_scenario"].get(t)
                cells.append(f"{_f(p['success_rate'], 0)} / {_f(p['mean_ds'])}" if p else "-")
            lines.append(f"| {t} | {'yes' if v2x else 'no'} | " + " | ".join(cells) + " |")
    return lines


def leaderboard_markdown(rows: list[dict]) -> str:
    """One ranked table per group, each with its per-scenario-type breakdown (module docstring)."""
    parts = groups(rows)
    lines = [
        "# V2XBench leaderboard",
        "",
        "Runs are ranked only against comparable runs: one table per suite, route selection, "
        "number of seeds, observation-mode track and world settings (as CARLA's leaderboard "
        "ranks each track apart). DS: mean over routes x seeds (failed or missing runs count "
        "0) +- half-width of the bootstrap 95% CI. `*`: privileged agent (reads the simulator "
        "state). `+`: the agent ran in a separate process from the simulator.",
        "",
    ]
    for k, part in enumerate(parts, 1):
        lines += [f"## {k}. {part[0]['group']}", ""]
        lines += _group_markdown(part) + [""]
    return "\n".join(lines).rstrip("\n") + "\n"


def save_plots(rows: list[dict], out: Path, suffix: str = "") -> list[Path]:
    """Bar plots of DS (with CI), RC, IS and BPS of ``rows``, one PNG each
    (``<metric><suffix>.png``, written atomically); raises ImportError without matplotlib."""
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
        p = out / f"{key}{suffix}.png"
        with atomic_write(p, "wb") as f:
            fig.savefig(f, format="png")
        plt.close(fig)
        paths.append(p)
    return paths


def build_leaderboard(
    result_dirs: list[str | Path], out: str | Path = "leaderboard", plots: bool = True,
    common: bool = False,
) -> dict:
    """Write ``leaderboard.md``, ``leaderboard.json`` and the plots into ``out`` (atomically);
    ``common``: every folder scored on the runs all of them hold (module docstring).

    Returns:
        ``{"rows": [...], "groups": [labels], "markdown": path, "plots": [paths],
        "note": str | None}``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = load_rows(result_dirs, common=common)
    parts = groups(rows)
    md = atomic_write_text(out / "leaderboard.md", leaderboard_markdown(rows))
    write_json_atomic(
        {
            "rows": rows,
            "groups": [{"group": p[0]["group"], "runs": [r["run"] for r in p]} for p in parts],
        },
        out / "leaderboard.json",
    )
    paths, note = [], None
    for key, _ in PLOTS:  # plots of an earlier grouping would look current
        for old in (out / f"{key}.png", *out.glob(f"{key}_g*.png")):
            old.unlink(missing_ok=True)
    if plots:
        try:
            for k, part in enumerate(parts, 1):
                paths += save_plots(part, out, "" if len(parts) == 1 else f"_g{k}")
        except ImportError:
            note = "matplotlib is not installed: no plots (pip install matplotlib)"
    return {
        "rows": rows,
        "groups": [p[0]["group"] for p in parts],
        "markdown": str(md),
        "plots": [str(p) for p in paths],
        "note": note,
    }
