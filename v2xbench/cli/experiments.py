"""``v2xbench experiments``: run a config of jobs (data, trainings, evaluations, channel sweeps)
resumably, then build the paper's tables, ablations and plots from the results
(:mod:`v2xbench.collectors.experiments`, docs/experiments.md)."""

from __future__ import annotations

import argparse


def _shipped() -> list[str]:
    """The shipped configs' names (``collectors/experiments/configs/*.json``)."""
    from v2xbench.collectors.experiments import CONFIG_DIR

    return sorted(q.stem for q in CONFIG_DIR.glob("*.json"))


def _config_file(config: str) -> str:
    """A config file's path, or the path of the shipped config of that name (``paper``)."""
    from v2xbench.collectors.experiments import shipped_config

    if "/" not in config and not config.endswith((".json", ".toml")):
        return str(shipped_config(config))
    return config


def _run(args: argparse.Namespace) -> int:
    from v2xbench.collectors.experiments.runner import run_experiments

    if (args.config is None) == (not args.quick):
        raise ValueError("experiments run: give --config FILE (or a shipped name: "
                         f"{', '.join(_shipped())}) or --quick")
    state = run_experiments(_config_file(args.config or "quick"), args.out, progress=args.verbose)
    c = state["counts"]
    return 1 if c["failed"] or c["blocked"] else 0


def _report(args: argparse.Namespace) -> int:
    from v2xbench.collectors.experiments.report import build_report

    r = build_report(args.dir, args.out, allow_partial=args.allow_partial,
                     plots=not args.no_plots)
    print(f"wrote {len(r['tables'])} tables ({', '.join(r['tables'])}) into {r['out']}: "
          + ", ".join(r["files"]))
    if r["missing"]:
        n = sum(len(v) for v in r["missing"].values())
        print(f"--allow-partial: {n} result(s) missing, marked `missing` in the tables")
    return 0


def _status(args: argparse.Namespace) -> int:
    from v2xbench.collectors.experiments.status import experiment_status, status_markdown

    config = None if args.config is None else _config_file(args.config)
    print(status_markdown(experiment_status(args.dir, config)), end="")
    return 0


def register(sub) -> None:
    """Add ``experiments run``, ``report`` and ``status`` to the ``v2xbench`` parser."""
    p = sub.add_parser("experiments", help="run the paper's experiments from a config "
                       "(resumable) and build their tables and plots", description=__doc__)
    esub = p.add_subparsers(dest="experiments_command", required=True)
    r = esub.add_parser("run", help="run (or resume) the jobs of a config into DIR",
                        description="Run the jobs of a config in dependency order, each into "
                        "DIR/<job id>/: a job whose result.json exists is skipped, a failing "
                        "job is recorded (failed.json) and the jobs that do not need it go on, "
                        "a method whose baseline is not registered is skipped as not "
                        "available. One line per job with its time. Exit 1 when a job failed.")
    r.add_argument("--config", default=None, help="config file (JSON or TOML), or a shipped "
                   "config's name: " + ", ".join(_shipped()))
    r.add_argument("--quick", action="store_true", help="the shipped quick config (tiny "
                   "models, a few minutes; for CI)")
    r.add_argument("--out", required=True, help="experiment folder DIR")
    r.add_argument("--verbose", action="store_true",
                   help="show each job's own progress bars and lines")
    r.set_defaults(func=_run)
    t = esub.add_parser("report", help="tables, JSON and plots from an experiment folder",
                        description="Build the perception, planning, ablation, per-scenario "
                        "and channel-robustness tables (Markdown + JSON) and plots from DIR. "
                        "Refuses, naming each missing job and file, when a table's results are "
                        "incomplete, unless --allow-partial.")
    t.add_argument("dir", help="experiment folder (experiments run --out)")
    t.add_argument("--out", default=None,
                   help="output folder (default DIR/report), e.g. docs/results/experiments")
    t.add_argument("--allow-partial", action="store_true",
                   help="build the tables anyway, marking missing cells `missing`")
    t.add_argument("--no-plots", action="store_true", help="only Markdown and JSON")
    t.set_defaults(func=_report)
    st = esub.add_parser("status", help="where an experiment run stands, job by job",
                         description="One line per job: done (with its time), failed (the "
                         "error), not available, blocked, or not finished; an unfinished "
                         "closed-loop job shows its runs with a result so far and the time left "
                         "at their pace. Reads files only: safe while a run works on DIR.")
    st.add_argument("dir", help="experiment folder (experiments run --out)")
    st.add_argument("--config", default=None, help="the config (default DIR/config.json, "
                    "written by the first run); a file or a shipped name")
    st.set_defaults(func=_status)
