"""``v2xbench experiments report DIR``: the paper's tables, ablations and channel studies from an
experiment folder, as Markdown, JSON and plots.

Tables (the methods of each are the config's ``report`` lists; a method's jobs are found by
``method`` and kind; its *main* closed-loop job is the one without ``channel`` settings):

- ``perception``: avg mAP, NDS, AP per class group, the message's bytes per second at 10 Hz and
  what was scored against which ground truth (a fusion AURORA run: its fused heads against
  ``gt/fused``, as the baselines' fused detections; No Fusion: its ego branch against ``gt/ego``);
- ``planning``: DS with its bootstrap 95% CI, RC, Efficiency, Comfortness, BPS (closed loop),
  open-loop L2 (mean of 1/2/3 s; ``n/a`` for a method without an open-loop job);
- ``fusion_ablation`` (mAP, NDS, DS, RC), ``planner_ablation`` and ``vqa_ablation`` (DS, RC, L2,
  open-loop collision rate; the VQA table adds the Chat-V2XBench scores of ``vqa`` jobs);
- ``per_scenario``: success rate / mean DS per scenario type, V2X types in their own table
  (``eval_summary.per_scenario``, the leaderboard's numbers), and the whole leaderboard of the
  main runs (``leaderboard.build_leaderboard``) in ``OUT/leaderboard/``;
- ``robustness``: DS against added latency, packet loss and bandwidth cap (the main run is the
  0 ms / 0 % point), plotted, and BPS against DS for every closed-loop run (the
  bandwidth-performance frontier).

Closed-loop numbers are recomputed from each run's per-route files by
``eval_summary.summarize`` (``metrics.aggregate``: DS over routes x seeds, failed or missing runs
count 0, percentile bootstrap CI), the code ``v2xbench eval`` and the leaderboard use. A table
whose results are incomplete is refused with a :class:`IncompleteResults` naming each missing
job and file, unless ``allow_partial`` (then the cells read ``missing``). Rows of methods that
are not available (an unregistered baseline) or jobs that found no switch they need read
``not available`` with the reason.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from v2xbench.files import atomic_write_json, atomic_write_text

from .config import Config, Job
from .job_kinds import method_available
from .runner import FAILED, RESULT, STATE, load_config_copy, read_result

MISSING = "missing"
NA = "n/a"


class IncompleteResults(ValueError):
    """The report needs results that the experiment folder lacks (each named)."""


class _Results:
    """Job results of an experiment folder, and what the tables found missing."""

    def __init__(self, root: Path, cfg: Config) -> None:
        self.root, self.cfg = root, cfg
        state = root / STATE
        self.state = json.loads(state.read_text()) if state.is_file() else {}
        self.missing: dict[str, list[str]] = {}
        self.table = ""
        self._summaries: dict[str, dict] = {}

    def job(self, method: str, kind: str, channel: dict | None = None) -> Job | None:
        """The method's job of a kind (closed loop: the one with these channel settings)."""
        for j in self.cfg.jobs:
            if j.method == method and j.kind == kind and (
                    kind != "closed_loop" or (j.get("channel") or {}) == (channel or {})):
                return j
        return None

    def unavailable(self, method: str, job: Job | None = None) -> str | None:
        why = method_available(self.cfg, method)
        if why is None and job is not None:
            rec = self.state.get("jobs", {}).get(job.id, {})
            if rec.get("status") == "not available":
                why = rec.get("reason")
        return why

    def result(self, job: Job | None) -> dict | str:
        """The job's result, or :data:`NA` (no such job), or :data:`MISSING` (recorded)."""
        if job is None:
            return NA
        if self.unavailable(job.method or "", job):
            return NA
        r = read_result(self.root, job.id)
        if r is not None:
            return r
        p = self.root / job.id / RESULT
        why = f"job {job.id!r}: {p} is missing"
        failed = self.root / job.id / FAILED
        if failed.is_file():
            try:
                why += f" (the job failed: {json.loads(failed.read_text())['error']})"
            except (ValueError, KeyError):
                why += f" (the job failed: {failed})"
        elif job.id not in self.state.get("jobs", {}):
            why += " (the job has not run)"
        seen = self.missing.setdefault(self.table, [])
        if why not in seen:
            seen.append(why)
        return MISSING

    def metric(self, job: Job | None, key: str) -> Any:
        r = self.result(job)
        return r if isinstance(r, str) else r["metrics"].get(key)

    def closed_loop(self, job: Job | None) -> dict | str:
        """The summary of a closed-loop job, recomputed from its route files."""
        r = self.result(job)
        if isinstance(r, str):
            return r
        d = r["outputs"]["eval"]
        if d not in self._summaries:
            self._summaries[d] = closed_loop_summary(d)
        return self._summaries[d]


def closed_loop_summary(eval_dir: str | Path) -> dict:
    """The summary of an evaluation folder recomputed from its per-route results with
    ``eval_summary.summarize`` (the selection and seeds of its ``summary.json``)."""
    from v2xbench.collectors.eval_summary import summarize
    from v2xbench.collectors.route_selection import selected_jobs

    d = Path(eval_dir)
    old = json.loads((d / "summary.json").read_text())
    sel = old["selection"]
    _, _, jobs = selected_jobs(str(old["suite"]), int(old["seeds"]), routes=sel["route_ids"])
    return summarize(d, jobs, selection=sel)


def _f(x: Any, nd: int = 1, scale: float = 1.0) -> str:
    if isinstance(x, str):
        return x
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{float(x) * scale:.{nd}f}"


def _ds(s: dict | str) -> str:
    if isinstance(s, str):
        return s
    m = s["metrics"]
    return f"{_f(m['driving_score'])} [{_f(m['driving_score_ci_low'])}, " \
           f"{_f(m['driving_score_ci_high'])}]"


def _m(s: dict | str, key: str) -> Any:
    return s if isinstance(s, str) else s["metrics"].get(key)


def _table(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _row_or_na(res: _Results, method: str, n: int, job: Job | None = None) -> list[str] | None:
    """A row saying why the method (or its ``job``) is not available, or ``None``."""
    why = res.unavailable(method, job)
    if why is None:
        return None
    return [res.cfg.label(method), f"not available ({why})"] + [""] * (n - 2)


def _perception(res: _Results, methods: list[str]) -> tuple[str, list[dict]]:
    head = ["method", "avg mAP", "NDS", "vehicle", "VRU", "traffic light", "traffic sign",
            "message B/s (10 Hz)", "scored (ground truth)"]
    keys = ("avg_mAP", "NDS", "vehicle", "vru", "traffic_light", "traffic_sign")
    rows, data = [], []
    for m in methods:
        j = res.job(m, "perception")
        na = _row_or_na(res, m, len(head), j)
        if na:
            rows.append(na)
            continue
        vals = [res.metric(j, k) for k in keys]
        how = {k: res.metric(j, k) for k in ("evaluator", "ground_truth")}
        scored = how["evaluator"] if isinstance(how["evaluator"], str) else "-"
        if isinstance(how["ground_truth"], str) and how["ground_truth"] != how["evaluator"]:
            scored += f" ({how['ground_truth']})"
        rows.append([res.cfg.label(m)] + [_f(v, 3) for v in vals]
                    + [_f(res.metric(j, "message_bps"), 0), scored])
        data.append({"method": m, **dict(zip(keys, vals)), **how})
    return _table(head, rows) + _branch_note(res, methods), data


def _branch_note(res: _Results, methods: list[str]) -> str:
    """Under a table with AURORA-family rows: what their perception numbers are."""
    if all(res.cfg.methods.get(m, {}).get("baseline") for m in methods):
        return ""
    return ("\nAURORA rows of a fusion run: its fused heads (`v2xbench aurora eval-perception "
            "--fused`: the roadside branch on the unit's recorded camera, its message serialized "
            "to float16 as in closed loop, CQAF, the fused detection head) against `gt/fused` "
            "(what the ego or the unit sees: the fused heads' training target and the "
            "baselines' ground), with their numbers against `gt/ego` and the same checkpoint's "
            "ego branch in the job's `perception.json`. No Fusion has no roadside input: its "
            "ego branch (stage 1) against `gt/ego` (what the ego's own sensors see). Baseline "
            "rows: their fused detections against `gt/fused`.\n")


def _open_loop(res: _Results, m: str) -> tuple[Any, Any]:
    j = res.job(m, "open_loop")
    return res.metric(j, "l2_avg"), res.metric(j, "collision_avg")


def _planning(res: _Results, methods: list[str]) -> tuple[str, list[dict]]:
    head = ["method", "routes x seeds", "DS [95% CI]", "RC", "Efficiency", "Comfortness",
            "open-loop L2 (m)", "BPS"]
    rows, data = [], []
    for m in methods:
        cl = res.job(m, "closed_loop")
        na = _row_or_na(res, m, len(head), cl)
        if na:
            rows.append(na)
            continue
        s = res.closed_loop(cl)
        l2, _ = _open_loop(res, m)
        rs = s if isinstance(s, str) else f"{s['n_routes']} x {s['seeds']}"
        rows.append([res.cfg.label(m), rs, _ds(s), _f(_m(s, "route_completion")),
                     _f(_m(s, "efficiency")), _f(_m(s, "comfortness")), _f(l2, 2),
                     _f(_m(s, "bps"), 0)])
        data.append({"method": m, "l2_avg": l2, **({} if isinstance(s, str) else {
            k: s["metrics"].get(k) for k in ("driving_score", "driving_score_ci_low",
                                             "driving_score_ci_high", "route_completion",
                                             "efficiency", "comfortness", "bps")})})
    return _table(head, rows), data


def _ablation(res: _Results, methods: list[str], kind: str) -> tuple[str, list[dict]]:
    if kind == "fusion":
        head = ["method", "avg mAP", "NDS", "ground truth", "DS [95% CI]", "RC"]
    else:
        head = ["method", "DS [95% CI]", "RC", "open-loop L2 (m)", "collision rate (%)"]
        if kind == "vqa":
            head += ["VQA closed accuracy", "VQA descriptive F1"]
    rows, data = [], []
    for m in methods:
        cl = res.job(m, "closed_loop")
        na = _row_or_na(res, m, len(head), cl)
        if na:
            rows.append(na)
            continue
        s = res.closed_loop(cl)
        d = {"method": m, "driving_score": _m(s, "driving_score"),
             "route_completion": _m(s, "route_completion")}
        if kind == "fusion":
            d.update(_common_ground(res, m))
            rows.append([res.cfg.label(m), _f(d["avg_mAP"], 3), _f(d["NDS"], 3),
                         d["ground_truth"], _ds(s), _f(d["route_completion"])])
        else:
            l2, col = _open_loop(res, m)
            d.update(l2_avg=l2, collision_avg=col)
            row = [res.cfg.label(m), _ds(s), _f(d["route_completion"]), _f(l2, 2),
                   _f(col, 2, 100.0)]
            if kind == "vqa":
                v = res.job(m, "vqa")
                d.update(vqa_closed=res.metric(v, "closed_accuracy"),
                         vqa_f1=res.metric(v, "descriptive_f1"))
                row += [_f(d["vqa_closed"], 3), _f(d["vqa_f1"], 3)]
            rows.append(row)
        data.append(d)
    paired = _paired_with_first(res, methods, data)
    return _table(head, rows) + (_FUSION_NOTE if kind == "fusion" else "") + paired, data


def _paired_with_first(res: _Results, methods: list[str], data: list[dict]) -> str:
    """Each other row's closed-loop runs against the first row's, paired run by run
    (``compare.compare_pair``): the text under an ablation table; the numbers go into the rows'
    ``paired_vs_first``. Empty when the first row has no closed-loop result."""
    from v2xbench.collectors.compare import compare_pair

    dirs = {}
    for m in methods:
        r = res.result(res.job(m, "closed_loop"))
        if isinstance(r, dict) and (r.get("outputs") or {}).get("eval"):
            dirs[m] = r["outputs"]["eval"]
    first = methods[0] if methods else None
    if first not in dirs:
        return ""
    lines = []
    for d in data:
        m = d["method"]
        if m == first or m not in dirs:
            continue
        try:
            c = compare_pair((first, dirs[first]), (m, dirs[m]))
        except ValueError as e:  # no shared run: said, not a table
            lines.append(f"- {res.cfg.label(m)}: not paired ({e})")
            continue
        lo, hi = c["paired_ds_difference_ci"]
        v = c["scenarios"]["v2x"]
        d["paired_vs_first"] = {"runs": len(c["jobs"]), "ds_difference": c["paired_ds_difference"],
                                "ds_difference_ci": [lo, hi],
                                "v2x_ds_difference": c["v2x_paired_ds_difference"],
                                "v2x_ds_difference_ci": c["v2x_paired_ds_difference_ci"],
                                "v2x_instances": v}
        text = (f"- {res.cfg.label(first)} minus {res.cfg.label(m)}, paired on the "
                f"{len(c['jobs'])} runs both hold: DS **{c['paired_ds_difference']:+.1f}** "
                f"[{lo:+.1f}, {hi:+.1f}]")
        if c["v2x_runs"]:
            vlo, vhi = c["v2x_paired_ds_difference_ci"]
            text += (f"; V2X-type routes ({c['v2x_runs']} runs) "
                     f"{c['v2x_paired_ds_difference']:+.1f} [{vlo:+.1f}, {vhi:+.1f}]")
        if v["instances"]:
            text += (f"; V2X-specific scenario instances succeeded {v['success'][first]} against "
                     f"{v['success'][m]} of {v['instances']} (exact sign test p = "
                     f"{v['sign_test_p']:.2f})")
        lines.append(text + ".")
    if not lines:
        return ""
    return ("\nPaired with the first row, run by run (`v2xbench compare`; CIs: bootstrap over "
            "the shared runs):\n\n" + "\n".join(lines) + "\n")


_FUSION_NOTE = ("\nmAP / NDS against `gt/ego` (what the ego's own sensors see), the ground both "
                "models can be scored on: AURORA's fused heads, No Fusion's ego branch (a row "
                "whose perception job has no `gt/ego` numbers, e.g. a baseline, shows its own "
                "ground). AURORA's fused heads against `gt/fused` are in the perception table.\n")


def _common_ground(res: _Results, m: str) -> dict:
    """A method's perception numbers for the fusion ablation: against ``gt/ego`` where its job
    has them (a fused evaluation's ``ego_gt``), else its own table's (and that ground)."""
    r = res.result(res.job(m, "perception"))
    if isinstance(r, str):
        return {"avg_mAP": r, "NDS": r, "ground_truth": r}
    met = r["metrics"]
    if isinstance(met.get("ego_gt"), dict):
        return {"avg_mAP": met["ego_gt"].get("avg_mAP"), "NDS": met["ego_gt"].get("NDS"),
                "ground_truth": "gt/ego"}
    return {"avg_mAP": met.get("avg_mAP"), "NDS": met.get("NDS"),
            "ground_truth": str(met.get("ground_truth", "-"))}


def _per_scenario(res: _Results, methods: list[str]) -> tuple[str, dict]:
    cols, per = [], {}
    for m in methods:
        if method_available(res.cfg, m):
            continue
        s = res.closed_loop(res.job(m, "closed_loop"))
        cols.append(m)
        per[m] = s if isinstance(s, str) else s["per_scenario"]
    types = sorted({t for p in per.values() if isinstance(p, dict) for t in p})
    v2x = {t: next(p[t]["v2x"] for p in per.values() if isinstance(p, dict) and t in p)
           for t in types}
    parts = []
    for title, want in (("V2X-specific scenario types", True), ("Other scenario types", False)):
        rows = []
        for t in (t for t in types if v2x[t] == want):
            cells = []
            for m in cols:
                p = per[m]
                c = p if isinstance(p, str) else p.get(t)
                if c is None:
                    cells.append("-")
                else:
                    cells.append(c if isinstance(c, str) else
                                 f"{_f(c['success_rate'], 0)} / {_f(c['mean_ds'])}")
            rows.append([t] + cells)
        parts.append(f"**{title}** (success % / mean DS)\n\n"
                     + _table(["scenario type"] + [res.cfg.label(m) for m in cols], rows))
    return "\n".join(parts), {m: per[m] for m in cols}


def _base(j: Job) -> dict:
    return {k: v for k, v in j.spec.items() if k not in ("id", "channel", "label")}


def _main_job(res: _Results, m: str) -> Job | None:
    """The method's closed-loop job without channel changes (``None``: it has none)."""
    return next((j for j in res.cfg.jobs if j.method == m and j.kind == "closed_loop"
                 and not j.get("channel")), None)


def _sweep_points(res: _Results, m: str, key: str) -> list[tuple[float, Job]]:
    """The method's closed-loop jobs that change only ``key`` of the channel, with the job of
    the same settings and no channel changes as the 0 point (0 ms, 0 %, no cap)."""
    sweep = [j for j in res.cfg.jobs if j.method == m and j.kind == "closed_loop"
             and set(j.get("channel") or {}) == {key}]
    pts = {float(j.get("channel")[key]): j for j in sweep}
    if sweep and 0.0 not in pts:
        zero = next((j for j in res.cfg.jobs if j.method == m and j.kind == "closed_loop"
                     and not j.get("channel") and _base(j) == _base(sweep[0])), None)
        if zero is not None:
            pts[0.0] = zero
    return sorted(pts.items(), key=lambda p: p[0])


def _robustness(res: _Results, methods: list[str]) -> tuple[str, dict]:
    data: dict = {}
    md = []
    for key, title, unit in (("latency_ms", "DS vs added latency", "ms"),
                             ("loss_pct", "DS vs packet loss", "%"),
                             ("bandwidth_bytes_per_s", "DS under a bandwidth cap", "B/s")):
        xs = sorted({x for m in methods for x, _ in _sweep_points(res, m, key)})
        if not xs:
            continue
        rows, data[key] = [], {}
        for m in methods:
            if method_available(res.cfg, m):
                rows.append([res.cfg.label(m), "not available"] + [""] * (len(xs) - 1))
                continue
            pts = {x: res.closed_loop(j) for x, j in _sweep_points(res, m, key)}
            main = None if pts else _main_job(res, m)
            if main is not None:  # a reference without a sweep (e.g. an ego-only agent, which
                # the channel cannot reach): its main run, the same at every point
                s = res.closed_loop(main)
                pts = dict.fromkeys(xs, s)
            data[key][m] = [{"x": x, "driving_score": _m(s, "driving_score"),
                             "ci_low": _m(s, "driving_score_ci_low"),
                             "ci_high": _m(s, "driving_score_ci_high"), "bps": _m(s, "bps"),
                             "reference": main is not None}
                            for x, s in pts.items()]
            label = res.cfg.label(m) + (" (no sweep: its main run)" if main is not None else "")
            rows.append([label] + [_ds(pts[x]) if x in pts else NA for x in xs])
        md.append(f"**{title}** (DS [95% CI])\n\n"
                  + _table(["method"] + [f"{_f(x, 0)} {unit}" if x or unit != "B/s"
                                          else "no cap" for x in xs], rows))
    return "\n".join(md), data


def _scatter_points(res: _Results, methods: list[str]) -> list[dict]:
    pts = []
    for m in methods:
        if method_available(res.cfg, m):
            continue
        for j in res.cfg.jobs:
            if j.method == m and j.kind == "closed_loop":
                s = res.closed_loop(j)
                if not isinstance(s, str):
                    pts.append({"method": m, "job": j.id, "channel": j.get("channel") or {},
                                "bps": s["metrics"]["bps"],
                                "driving_score": s["metrics"]["driving_score"]})
    return pts


TITLES = {"perception": "Perception (test split)", "planning": "Planning (closed loop)",
          "fusion_ablation": "Fusion ablation", "planner_ablation": "Planner ablation",
          "vqa_ablation": "VQA ablation (Chat-V2XBench loss in stages 3-5)",
          "per_scenario": "Success per scenario type", "robustness": "Robustness to the channel"}


def build_report(root: str | Path, out: str | Path | None = None, *,
                 allow_partial: bool = False, plots: bool = True) -> dict:
    """Write the tables of an experiment folder into ``out`` (default ``DIR/report``):
    ``report.md``, one ``<table>.md`` each, ``report.json`` and the plots.

    Raises:
        FileNotFoundError: ``root`` holds no experiment (no ``config.json``).
        IncompleteResults: a table lacks results (each missing job and file named) and
            ``allow_partial`` is false; nothing is written then.
    """
    root = Path(root)
    cfg = load_config_copy(root, "experiments report")
    res = _Results(root, cfg)
    tables: dict[str, str] = {}
    data: dict[str, Any] = {}
    for name, methods in cfg.report.items():
        res.table = name
        if name == "perception":
            tables[name], data[name] = _perception(res, methods)
        elif name == "planning":
            tables[name], data[name] = _planning(res, methods)
        elif name.endswith("_ablation"):
            tables[name], data[name] = _ablation(res, methods, name.split("_")[0])
        elif name == "per_scenario":
            tables[name], data[name] = _per_scenario(res, methods)
        else:
            tables[name], data[name] = _robustness(res, methods)
            res.table = "bps_vs_ds"
            data["bps_vs_ds"] = _scatter_points(res, methods)
    if res.missing and not allow_partial:
        lines = [f"- table {t!r}: {w}" for t, ws in res.missing.items() for w in ws]
        raise IncompleteResults("experiments report: incomplete results (run `v2xbench "
                                "experiments run` to finish them, or --allow-partial to mark "
                                "the cells missing):\n" + "\n".join(lines))
    out = Path(out) if out is not None else root / "report"
    out.mkdir(parents=True, exist_ok=True)
    md = _header(cfg, res, root)
    for name, text in tables.items():
        block = f"## {TITLES[name]}\n\n{text}"
        atomic_write_text(out / f"{name}.md", block)
        md.append(block)
    if res.missing:
        md.append("## Missing results\n\n" + "\n".join(
            f"- table {t!r}: {w}" for t, ws in res.missing.items() for w in ws) + "\n")
    written = [str(atomic_write_text(out / "report.md", "\n".join(md)))]
    atomic_write_json(out / "report.json", {"config": cfg.name, "tables": data,
                                            "missing": res.missing,
                                            "machine": res.state.get("machine")},
                      indent=1, default=str)
    if plots:
        from .report_plots import write_plots

        written += write_plots(data, cfg, out)
    if "per_scenario" in cfg.report:
        dirs = _main_eval_dirs(res, cfg.report["per_scenario"])
        if dirs:
            from v2xbench.collectors.leaderboard import build_leaderboard

            build_leaderboard(dirs, out / "leaderboard", plots=plots)
    return {"out": str(out), "tables": sorted(tables), "files": written,
            "missing": res.missing}


def _main_eval_dirs(res: _Results, methods: list[str]) -> list[str]:
    dirs = []
    for m in methods:
        j = res.job(m, "closed_loop")
        r = read_result(res.root, j.id) if j is not None else None
        if r is not None:
            dirs.append(r["outputs"]["eval"])
    return dirs


def _header(cfg: Config, res: _Results, root: Path) -> list[str]:
    """The report's title and its run: machine, jobs with results, their summed time."""
    st = res.state
    results = [r for r in (read_result(root, j.id) for j in cfg.jobs) if r is not None]
    total = sum(float(r.get("elapsed_s") or 0.0) for r in results)
    return [f"# Experiments: {cfg.name}", "", cfg.description, "",
            f"Made by `v2xbench experiments run` + `report` from `{root}`; machine of the run: "
            f"{st.get('machine', 'unknown')}; {len(results)} of {len(cfg.jobs)} jobs have "
            f"results, which took {total / 60:.1f} min of wall time in all (last run started "
            f"{st.get('started', '?')}).", ""]


__all__ = ["IncompleteResults", "build_report", "closed_loop_summary"]
