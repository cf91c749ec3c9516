"""The V2XBench benchmark suite: ``v2xbench bench`` (or ``python -m v2xbench.benchmarks.suite``).

Measures, in one run on this machine, and prints a table; writes ``OUT/suite.json``,
``OUT/suite.md`` (the table) and ``OUT/suite.png`` (plots):

- ``objects``: objects-mode ticks/s (``gym.make``, one core) on a test50 route with its scenario
  and the default population (30+ actors), next to highway-env ``intersection-v0`` and
  ``highway-fast-v0`` measured in the same run, taking turns (5 rounds, 10 s of each env in
  all), as ratios (``env_speed.py``);
- ``sensors``: full sensor rig ticks/s and the cost of every sensor (``sensor_speed.py``);
- ``batched``: agent-steps/s for N = 1, 4, 16, 64 worlds, 2 processes (``MultiSyncCollector``), and
  N = 64 through ``MultiAsyncCollector`` (``batched_speed.py``);
- ``eval``: wall time of ``v2xbench eval --agent expert --suite test50 --workers 2``
  (``eval_time.py``);
- ``scaling``: objects-mode ticks/s against the number of actors, 10 to 200 (``scaling.py``);
- ``memory``: resident memory over 10,000 episode resets (``memory.py``).

``--quick`` runs every row at tiny sizes (a CI smoke of the code paths, well under a minute of
measuring; its numbers mean nothing). ``--readme README.md`` replaces the part of the README
between ``<!-- bench:begin -->`` and ``<!-- bench:end -->`` with the table just written (date and
machine included) and copies the plot to ``docs/media/bench_suite.png`` beside it.
Single-core rows pin the process to one CPU and BLAS pools to one thread.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

ROWS = ("objects", "sensors", "batched", "eval", "scaling", "memory", "first_use")
GOALS = {"objects_ratio": 50.0, "sensors_ticks_per_s": 100.0, "batched_agent_steps_per_s": 20000.0,
         "eval_seconds": 600.0}
OBJECTS_CONFIG = {"suite": "test50", "route_index": 0}
BEGIN, END = "<!-- bench:begin -->", "<!-- bench:end -->"


def _collector_label(row: dict) -> str:
    """`` async`` for a row measured with ``MultiAsyncCollector`` (earlier results have no field)."""
    return " async" if row.get("collector") == "async" else ""


@contextlib.contextmanager
def one_core():
    """Pin this process to one CPU for the block (no-op where affinity is not supported)."""
    if not hasattr(os, "sched_getaffinity"):
        yield
        return
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(before)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def machine() -> str:
    import numpy as np

    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    return (f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, "
            f"{platform.python_implementation()} {platform.python_version()}, numpy {np.__version__}")


def run_rows(rows: tuple[str, ...], quick: bool) -> dict:
    """Run the selected measurements; returns ``{row: result}`` (JSON-able)."""
    res: dict = {}
    for row in rows:
        t0 = time.perf_counter()
        print(f"[bench] {row} ...", flush=True)
        if row == "objects":
            from . import env_speed

            with one_core():
                res[row] = env_speed.measure(0.3 if quick else env_speed.SECONDS, OBJECTS_CONFIG,
                                             rounds=1 if quick else env_speed.ROUNDS)
        elif row == "sensors":
            from . import sensor_speed

            with one_core():
                res[row] = sensor_speed.measure("Town01", 2 if quick else 40, 2 if quick else 20, 0, quick)
        elif row == "batched":
            from . import batched_speed

            res[row] = batched_speed.measure((1, 2) if quick else (1, 4, 16, 64), 40 if quick else 3000,
                                             min_seconds=0.0 if quick else batched_speed.MIN_SECONDS,
                                             async_worlds=(2,) if quick else (64,),
                                             warmup_seconds=0.0 if quick else batched_speed.WARMUP_SECONDS)
        elif row == "eval":
            from . import eval_time

            if quick:  # one short route, one worker: the code path only
                res[row] = eval_time.measure(1, 1, ["--set", "max_steps=10"])
            else:
                res[row] = eval_time.measure(2)
        elif row == "scaling":
            from . import scaling

            with one_core():
                res[row] = scaling.measure((10, 50) if quick else (10, 25, 50, 100, 150, 200), 20 if quick else 1000,
                                            warmup=5 if quick else 100)
        elif row == "memory":
            from . import memory

            res[row] = memory.measure(30 if quick else 10_000, 3 if quick else 20)
        elif row == "first_use":
            from . import first_use

            res[row] = first_use.measure(quick)
        else:
            raise ValueError(f"bench: unknown row {row!r} (rows: {', '.join(ROWS)})")
        res[row]["bench_seconds"] = time.perf_counter() - t0
    return res


def _status(ok: bool | None) -> str:
    return "" if ok is None else ("met" if ok else "missed")


def table(report: dict) -> str:
    """The markdown table of a report (what ``--readme`` puts in the README)."""
    r = report["results"]
    load = report.get("loadavg_start")
    lines = [f"Measured {report['date']} on {report['machine']}"
             + (f"; 1-min load average {load[0]:.1f} at the start (other work shares the cores when it is "
                f"above 0)" if load else "")
             + (" (quick smoke: the numbers mean nothing)" if report["quick"] else "") + ".",
             "", "| measurement | result | target | status |", "| --- | --- | --- | --- |"]

    def add(what: str, result: str, target: str = "", ok: bool | None = None) -> None:
        lines.append(f"| {what} | {result} | {target} | {_status(ok)} |")

    if "objects" in r:
        o = r["objects"]["results"]
        ours = o["v2xbench_objects"]
        sc = ", ".join(ours.get("scenarios", [])) or "no scenario"
        inter = o.get("intersection-v0")
        inter = None if inter is None or "error" in inter else inter
        target = f">= {GOALS['objects_ratio']:.0f}x intersection-v0 ticks/s"
        ok = None
        if inter is not None:
            goal = GOALS["objects_ratio"] * inter["steps_per_s"] * inter["frames_per_step"]
            target += f" (= {goal:,.0f} here)"
            ok = ours["steps_per_s"] >= goal
        cpu = f" ({ours['steps_per_cpu_s']:,.0f} per CPU second)" if "steps_per_cpu_s" in ours else ""
        add(f"objects mode, 1 core ({ours['actors']} actors, test50 route 0: {sc})",
            f"{ours['steps_per_s']:,.0f} ticks/s{cpu}", target, ok)
        for name in ("intersection-v0", "highway-fast-v0"):
            if name in o and "error" not in o[name]:
                h = o[name]
                ticks = h["steps_per_s"] * h["frames_per_step"]
                cpu = f", {h['steps_per_cpu_s']:,.1f} per CPU second" if "steps_per_cpu_s" in h else ""
                add(f"highway-env {name}, same run, 1 core",
                    f"{ticks:,.0f} ticks/s ({h['frames_per_step']} simulation frames per step: "
                    f"{h['steps_per_s']:,.1f} steps/s{cpu})",
                    f"V2XBench / this: {ours['steps_per_s'] / ticks:.1f}x ticks, "
                    f"{h['ratio_v2xbench_to_this']:.1f}x env steps, {h['sim_time_ratio']:.1f}x simulated time")
            elif name in o or "highway-env" in o:
                add(f"highway-env {name}", (o.get(name) or o["highway-env"])["error"])
    if "sensors" in r:
        s = r["sensors"]
        parts = s["parts"]
        per = ", ".join(f"{k} {v['wall_ms']:.1f}" for k, v in parts.items()
                        if k in ("scene", "ego_cameras_batched", "rsu_cam", "lidar", "rsu_lidar", "bev",
                                 "groundtruth"))
        env = s.get("env_plus_rig_ticks_per_s")
        with_step = f"; {env:,.1f} with the world step" if env else ""
        add("sensors mode, full rig, 1 core", f"{s['full_rig_ticks_per_s']:,.1f} ticks/s{with_step} (ms: {per})",
            f">= {GOALS['sensors_ticks_per_s']:.0f} ticks/s", s["full_rig_ticks_per_s"] >= GOALS["sensors_ticks_per_s"])
    if "batched" in r:
        rows = r["batched"]["rows"]
        best = max(x["agent_steps_per_s"] for x in rows)
        res = ", ".join(f"N={x['worlds']}{_collector_label(x)}: {x['agent_steps_per_s']:,.0f}" for x in rows)
        add("batched agent-steps/s (2 processes for N >= 2: MultiSyncCollector, async: MultiAsyncCollector)", res,
            f">= {GOALS['batched_agent_steps_per_s']:,.0f}", best >= GOALS["batched_agent_steps_per_s"])
    if "eval" in r:
        e = r["eval"]
        res = f"{e['seconds'] / 60:.1f} min" + ("" if e["returncode"] == 0 else f" (FAILED, exit {e['returncode']})")
        add("`v2xbench eval --agent expert --suite test50`, 2 workers" if not report["quick"]
            else "eval smoke (1 route, 10 ticks)", res, "<= 10 min",
            None if report["quick"] else (e["returncode"] == 0 and e["seconds"] <= GOALS["eval_seconds"]))
    if "scaling" in r:
        rows = r["scaling"]["rows"]
        res = ", ".join(f"{x['actors']}: {x['ticks_per_s']:,.0f}" for x in rows)
        add("objects ticks/s by active actors (plotted)", res)
    if "memory" in r:
        m = r["memory"]
        add(f"memory over {m['resets']:,} resets", f"RSS {m['rss_start_mib']:.0f} -> {m['rss_end_mib']:.0f} MiB "
            f"(max {m['rss_max_mib']:.0f}; +{m['growth_second_half_mib']:.1f} MiB in the second half)", "flat")
    if "first_use" in r:
        f = r["first_use"]

        def _secs(x: dict) -> str:
            return f"{x['seconds']:.0f} s" + ("" if x["returncode"] == 0 else " (FAILED)")

        cold = f"empty kernel cache {_secs(f['cold'])}, then " if f.get("cold") else ""
        add("first use: `v2xbench warmup` (compile every numba kernel)",
            f"{cold}cached {_secs(f['warm'])}", "documented in the README")
    return "\n".join(lines) + "\n"


def plot(report: dict, path: Path) -> None:
    """Scaling, batched throughput, memory trace and per-sensor cost, one panel each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = report["results"]
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    a = ax[0, 0]
    if "scaling" in r:
        rows = r["scaling"]["rows"]
        a.plot([x["actors"] for x in rows], [x["ticks_per_s"] for x in rows], "o-")
        a.set_xlabel("active actors")
        a.set_ylabel("ticks/s (objects mode, 1 core)")
        a.set_title("cost growth")
        a.grid(alpha=0.3)
    a = ax[0, 1]
    if "batched" in r:
        rows = r["batched"]["rows"]
        a.bar([f"{x['worlds']}{_collector_label(x)}" for x in rows], [x["agent_steps_per_s"] for x in rows])
        a.axhline(GOALS["batched_agent_steps_per_s"], color="r", ls="--", label="target")
        a.set_yscale("log")
        a.set_xlabel("worlds N")
        a.set_ylabel("agent-steps/s")
        a.set_title("batched worlds, 2 processes")
        a.legend()
    a = ax[1, 0]
    if "memory" in r:
        tr = r["memory"]["trace"]
        a.plot([k for k, _ in tr], [m for _, m in tr], ".-")
        a.set_xlabel("episode resets")
        a.set_ylabel("RSS (MiB)")
        a.set_title("memory over resets")
        a.grid(alpha=0.3)
    a = ax[1, 1]
    if "sensors" in r:
        parts = {k: v["wall_ms"] for k, v in r["sensors"]["parts"].items()
                 if k not in ("full_rig",) and not k.startswith("cam_")}
        a.barh(list(parts), list(parts.values()))
        a.set_xlabel("ms per tick")
        a.set_title(f"sensor rig: {r['sensors']['full_rig_ticks_per_s']:.1f} ticks/s")
    fig.suptitle(f"V2XBench benchmark suite, {report['date']}" + (" (quick)" if report["quick"] else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def update_readme(readme: Path, md: str, plot_rel: str | None = None) -> None:
    """Replace the README part between the bench markers with ``md`` (and the plot link)."""
    text = readme.read_text()
    if BEGIN not in text or END not in text:
        raise ValueError(f"{readme}: no {BEGIN} ... {END} section to replace")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    body = md + (f"\n![benchmark plots]({plot_rel})\n" if plot_rel else "")
    readme.write_text(f"{head}{BEGIN}\n{body}{END}{tail}")


def _write(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="v2xbench bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quick", action="store_true", help="tiny sizes: a smoke test of every row (CI)")
    p.add_argument("--only", default=",".join(ROWS), help=f"comma-separated rows (default: {','.join(ROWS)})")
    p.add_argument("--out", default="benchmarks/results", help="directory for suite.json, suite.md, suite.png")
    p.add_argument("--readme", default=None, help="README to update between the bench markers")
    p.add_argument("--from-json", default=None, metavar="SUITE_JSON",
                   help="measure nothing: rewrite the table, plot (and --readme) from a saved suite.json")


def run(args: argparse.Namespace) -> int:
    rows = tuple(x.strip() for x in args.only.split(",") if x.strip())
    bad = [x for x in rows if x not in ROWS]
    if bad:
        raise ValueError(f"bench: unknown rows {bad} (rows: {', '.join(ROWS)})")
    if args.from_json:
        report = json.loads(Path(args.from_json).read_text())
    else:
        t0 = time.perf_counter()
        load0 = os.getloadavg() if hasattr(os, "getloadavg") else None
        results = run_rows(rows, args.quick)
        load1 = os.getloadavg() if hasattr(os, "getloadavg") else None
        report = {"benchmark": "v2xbench-suite", "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                  "machine": machine(), "quick": bool(args.quick), "goals": GOALS, "results": results,
                  "seconds": time.perf_counter() - t0, "loadavg_start": load0, "loadavg_end": load1}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    md = table(report)
    _write(out / "suite.json", json.dumps(report, indent=2))
    _write(out / "suite.md", md)
    plot(report, out / "suite.png")
    print(md)
    print(f"wrote {out / 'suite.json'}, {out / 'suite.md'}, {out / 'suite.png'} ({report['seconds']:.0f} s)")
    if args.readme:  # the plot goes next to the README's other media (results/ is not tracked)
        import shutil

        readme = Path(args.readme)
        media = readme.parent / "docs" / "media"
        media.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(out / "suite.png", media / "bench_suite.png")
        update_readme(readme, md, "docs/media/bench_suite.png")
        print(f"updated {readme} and {media / 'bench_suite.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
