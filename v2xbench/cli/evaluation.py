"""``v2xbench eval``, ``leaderboard``, ``incidents`` and ``compare``: closed-loop evaluation and its tables."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from v2xbench.cli.common import parse_set
from v2xbench.collectors.eval_workers import DEFAULT_ROUTE_TIMEOUT_S


def default_out_name(agent: str) -> str:
    """The folder name of an agent's results: a registered name as it is, ``path/file.py:Class``
    as ``Class``, anything else reduced to letters, digits, ``-`` and ``_``."""
    name = agent.rsplit(":", 1)[-1] if ":" in agent else Path(agent).stem
    return re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_") or "agent"


def _eval(args: argparse.Namespace) -> int:
    """Run the evaluation; exit 1 when any route failed (error or wall-clock timeout)."""
    from v2xbench.collectors.evaluate import evaluate, summary_markdown

    if args.out is None:  # one folder per agent, so a second agent never meets the first's results
        args.out = str(Path("results") / default_out_name(args.agent_name or args.agent))
    summary = evaluate(args.agent, suite=args.suite, seeds=args.seeds, workers=args.workers, out=args.out,
                       video=args.video, max_routes=args.max_routes, config=parse_set(args.set),
                       agent_name=args.agent_name, progress=not args.quiet,
                       isolate_agent=args.isolate_agent, route_timeout=args.route_timeout,
                       agent_config=args.agent_config, routes=args.routes, scenario=args.scenario,
                       v2x_only=args.v2x_only, overwrite=args.overwrite,
                       retry_failed=args.retry_failed, backend=args.backend,
                       address=args.address)
    print(summary_markdown(summary))
    print(f"results: {Path(args.out) / 'routes'}, summary: {Path(args.out) / 'summary.md'}")
    failed = summary["failed"]
    n = sum(failed.values())
    if n:
        kinds = ", ".join(f"{v} {k}" for k, v in failed.items() if v)
        print(f"v2xbench: {n} of {summary['n_jobs']} route runs failed ({kinds}); see "
              f"{Path(args.out) / 'summary.md'}", file=sys.stderr)
        return 1
    return 0


def _leaderboard(args: argparse.Namespace) -> int:
    from v2xbench.collectors.leaderboard import build_leaderboard

    res = build_leaderboard(args.results, args.out, plots=not args.no_plots, common=args.common)
    print(Path(res["markdown"]).read_text())
    if res["note"]:
        print(res["note"], file=sys.stderr)
    print(f"wrote {res['markdown']}" + (f" and {len(res['plots'])} plots" if res["plots"] else ""))
    return 0


def _named(folders: list[str]) -> list[tuple[str, str]]:
    """``[NAME=]DIR`` arguments as ``(name, dir)`` (no name: the folder's name)."""
    return [tuple(x.split("=", 1)) if "=" in x else (Path(x).name, x) for x in folders]


def _say_wrote(out: str | None) -> None:
    """The files a ``--out PATH`` table command wrote (``PATH.md``, ``PATH.json``)."""
    if out:
        print(f"wrote {Path(out).with_suffix('.md')} and {Path(out).with_suffix('.json')}")


def _incidents(args: argparse.Namespace) -> int:
    from v2xbench.collectors.incidents import build_incidents, incidents_markdown

    print(incidents_markdown(build_incidents(_named(args.results), args.out)))
    _say_wrote(args.out)
    return 0


def _compare(args: argparse.Namespace) -> int:
    from v2xbench.collectors.compare import compare, compare_markdown

    print(compare_markdown(compare(_named(args.results), args.out)))
    _say_wrote(args.out)
    return 0


def register(sub) -> None:
    """Add this module's sub-commands to the ``v2xbench`` parser."""
    ev = sub.add_parser("eval", help="evaluate an agent on a route suite (resumable)",
                        description="Closed-loop evaluation through TorchRL collectors. Writes "
                        "OUT/routes/<route>_s<k>.json per run and OUT/summary.{json,md}; running "
                        "again on the same OUT resumes when the run's fingerprint (agent code, "
                        "declared checkpoint, agent config, --set overrides, obs/RSU/action mode) "
                        "is the same, and is refused, naming what differs, when it is not "
                        "(--overwrite starts afresh). Exits 1 when any route failed (error or "
                        "timeout). The file given to --agent path.py:Class is executed (imported) "
                        "in this process and in every worker: run only code you trust, or see "
                        "docs/evaluation.md for what --isolate-agent does and does not protect.")
    ev.add_argument("--agent", default="route_follower",
                    help="registered agent name (route_follower, expert, ...) or path/to/file.py:ClassName")
    ev.add_argument("--suite", default="test50", help="suite name (test50, val, train) or suite JSON path")
    ev.add_argument("--seeds", type=int, default=1,
                    help="number of seeds per route (seed indices 0..N-1; default 1)")
    ev.add_argument("--workers", type=int, default=1,
                    help="worker processes (or Ray tasks) running routes at a time")
    ev.add_argument("--out", default=None,
                    help="output folder (default: results/<agent name>, e.g. results/expert)")
    ev.add_argument("--video", action="store_true", help="save a top-down GIF per route in OUT/videos")
    ev.add_argument("--max-routes", type=int, default=None,
                    help="only the first N of the (selected) routes of the suite")
    ev.add_argument("--routes", default=None, metavar="ID,ID",
                    help="only these route ids (comma-separated), e.g. test50_000,test50_007")
    ev.add_argument("--scenario", action="append", default=None, metavar="TYPE",
                    help="only routes containing this scenario type (repeatable or "
                    "comma-separated)")
    ev.add_argument("--v2x-only", action="store_true",
                    help="only routes containing a V2X scenario type")
    ev.add_argument("--agent-config", default=None, metavar="FILE",
                    help="JSON object passed to the agent's constructor as keyword arguments "
                    "(recorded in the run's fingerprint)")
    ev.add_argument("--overwrite", action="store_true",
                    help="delete the results already in OUT first and run afresh")
    ev.add_argument("--retry-failed", action="store_true",
                    help="run again the selected routes whose result is a failure (error or "
                    "timeout); the fingerprint must be the same")
    ev.add_argument("--set", action="append", metavar="KEY=VALUE",
                    help="environment config override, e.g. --set num_vehicles=10 (repeatable); "
                    "sensors: --set camera_size=[256,128] --set camera_images=rgb,depth --set "
                    "lidar_scale=0.5 (an agent's declared sensors configure the env by "
                    "default; a --set that differs from them is refused)")
    ev.add_argument("--agent-name", default=None, help="display name in the summary and leaderboard")
    ev.add_argument("--isolate-agent", action="store_true",
                    help="run the agent in a separate process that receives only route_info and its "
                    "observations (it cannot read or patch the simulator); not for the privileged "
                    "built-in expert and oracles")
    ev.add_argument("--route-timeout", type=float, default=DEFAULT_ROUTE_TIMEOUT_S, metavar="SECONDS",
                    help="wall-clock limit of one route (default %(default)g s): a route that "
                    "runs longer is killed and recorded as failed (timeout), and the run goes on")
    ev.add_argument("--backend", choices=("local", "ray"), default="local",
                    help="where the routes run: local worker processes (default) or Ray tasks on "
                    "a Ray cluster, one CPU each (needs pip install -e \".[ray]\"; "
                    "docs/evaluation.md); results are written here either way")
    ev.add_argument("--address", default=None, metavar="ADDR",
                    help="--backend ray: the Ray cluster to run on (HEAD:6379, or auto); default: "
                    "RAY_ADDRESS, else a local Ray instance with --workers CPUs")
    ev.add_argument("--quiet", action="store_true", help="no progress bar")
    ev.set_defaults(func=_eval)
    lb = sub.add_parser("leaderboard", help="leaderboard table and plots from evaluation result dirs")
    lb.add_argument("results", nargs="+", help="result directories (each with a summary.json)")
    lb.add_argument("--out", default="leaderboard")
    lb.add_argument("--no-plots", action="store_true", help="only the markdown and JSON tables")
    lb.add_argument("--common", action="store_true",
                    help="score every folder on the runs all of them hold (the largest grid of "
                         "routes x seeds), e.g. evaluations still running; one suite")
    lb.set_defaults(func=_leaderboard)
    inc = sub.add_parser("incidents", help="how an agent's red lights and vehicle collisions happened "
                         "(from eval result dirs)")
    inc.add_argument("results", nargs="+", metavar="[NAME=]DIR",
                     help="eval output folders (routes/*.json), optionally named NAME=DIR")
    inc.add_argument("--out", default=None, metavar="PATH",
                     help="also write PATH.md and PATH.json (atomically)")
    inc.set_defaults(func=_incidents)
    cmp = sub.add_parser("compare", help="agents on the runs they share, paired run by run (DS "
                         "difference with its bootstrap CI)",
                         description="The first eval folder against each other one on the runs "
                         "both hold (same route and seed): both summaries on those runs, the mean "
                         "paired DS difference with its bootstrap 95%% CI, runs higher / lower / "
                         "equal, and whether both ran on the same platform.")
    cmp.add_argument("results", nargs="+", metavar="[NAME=]DIR",
                     help="eval output folders (routes/*.json), optionally named NAME=DIR; the "
                     "first is compared with each of the others")
    cmp.add_argument("--out", default=None, metavar="PATH",
                     help="also write PATH.md and PATH.json (atomically)")
    cmp.set_defaults(func=_compare)
