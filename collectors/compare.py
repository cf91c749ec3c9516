"""``v2xbench compare``: two or more agents on the runs they share, paired run by run.

Two evaluation folders of the same suite hold runs of the same jobs (route and seed index, e.g.
``test50_003_s1``): the same world, the same scenario instances, the same traffic. Comparing the
agents on the runs both hold, *paired* (the difference of DS run by run), removes the variation
between routes that dominates the unpaired CIs of a suite summary: on 10 routes x 3 seeds two
agents' CIs are about +-10 DS wide each, the paired difference's often half that.

For the first folder against each other one: both agents' summaries over the common runs
(``metrics.aggregate``: DS with its bootstrap CI, RC, infractions per km), the mean paired DS
difference (first minus other) with its percentile-bootstrap 95 % CI over the common runs
(``metrics.bootstrap_ci``), the same over the runs of routes with a V2X-specific scenario type
(the suite summary's V2X-type subset), how many runs the first scores higher, lower or equal, and whether
both folders ran on the same platform (``same``, ``different`` or ``not recorded``) (``platform`` of each result: a learned agent's runs on
another machine are another draw, docs/baselines.md "Same code, another machine").

And the scenario instances of the common runs, paired instance by instance (every route holds the
same instances in both runs), all of them and those of V2X-specific types: how many each agent
*succeeds* on (passed, no collision in the scenario window, no timeout), on how many only one of
them does, the two-sided exact sign test on those (McNemar's exact test: is one agent's success
more likely where they differ?), and how many each *reaches* (triggers) and *collides* in. A DS
difference says by how much; this says whether it comes from the scenarios themselves.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from v2xbench.envs.v2x_intersection.evaluation.metrics import aggregate, bootstrap_ci

from v2xbench.files import atomic_write_text

from .jobs import all_results

#: DS differences at most this far apart count as a tie (float noise, not driving)
TIE_DS = 1e-6


def _runs(folder: str | Path) -> dict[str, dict]:
    """Job id -> result of every run of an eval folder."""
    return {r["job_id"]: r for r in all_results(folder)}


def _platforms(runs: list[dict]) -> list[str]:
    """The distinct platform records of ``runs`` as canonical JSON (``[]``: none recorded)."""
    return sorted({json.dumps(r["platform"], sort_keys=True) for r in runs if r.get("platform")})


def _is_v2x_route(result: dict) -> bool:
    """Whether the run's route holds a V2X-specific scenario type (from its suite's route file)."""
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

    from .route_selection import is_v2x_route

    return is_v2x_route(next(r for r in load_suite_cached(str(result["suite"])) if r.id == result["route_id"]))


def sign_test_p(k: int, n: int) -> float:
    """Two-sided exact binomial p-value of ``k`` successes in ``n`` trials at probability 1/2
    (1.0 for ``n == 0``)."""
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(k, n - k) + 1)) / 2.0 ** n
    return min(1.0, 2.0 * tail)


def scenario_pairs(mine: list[dict], theirs: list[dict], names: tuple[str, str],
                   v2x: bool | None = None) -> dict:
    """The scenario instances of paired runs (same jobs, in order), compared instance by instance;
    ``v2x``: only instances of V2X-specific types (``True``), only the others (``False``) or all.

    Raises:
        ValueError: two paired runs whose scenario lists differ (not the same route).
    """
    a, b = names
    n = sa = sb = only_a = only_b = ca = cb = ra = rb = 0
    for ra_, rb_ in zip(mine, theirs):
        xs, ys = ra_.get("scenarios") or [], rb_.get("scenarios") or []
        if [x["type"] for x in xs] != [y["type"] for y in ys]:
            raise ValueError(f"compare: run {ra_['job_id']} holds other scenario instances in the two "
                             "folders (another suite file?)")
        for x, y in zip(xs, ys):
            if v2x is not None and bool(x.get("v2x")) != v2x:
                continue
            n += 1
            sa, sb = sa + bool(x["success"]), sb + bool(y["success"])
            only_a += bool(x["success"]) and not y["success"]
            only_b += bool(y["success"]) and not x["success"]
            ca, cb = ca + bool(x["collision"]), cb + bool(y["collision"])
            ra, rb = ra + bool(x["triggered"]), rb + bool(y["triggered"])
    return {"instances": n, "success": {a: sa, b: sb}, "only": {a: only_a, b: only_b},
            "sign_test_p": sign_test_p(only_a, only_a + only_b),
            "collision": {a: ca, b: cb}, "reached": {a: ra, b: rb}}


def compare_pair(first: tuple[str, str | Path], other: tuple[str, str | Path]) -> dict:
    """The paired comparison of two ``(name, eval folder)`` on the runs both hold.

    Raises:
        ValueError: the two folders share no run (other suites or route selections), or the
            two names are the same.
    """
    (a, da), (b, db) = first, other
    if a == b:
        raise ValueError(f"compare: two folders named {a!r}; name them NAME=DIR")
    mine, theirs = _runs(da), _runs(db)
    common = sorted(set(mine) & set(theirs))
    if not common:
        raise ValueError(f"compare: {da} and {db} share no run (job ids such as "
                         f"{next(iter(mine))!r} and {next(iter(theirs))!r}): another suite or "
                         "route selection")
    diff = np.array([mine[j]["metrics"]["driving_score"] - theirs[j]["metrics"]["driving_score"]
                     for j in common], np.float64)
    v2x = np.array([_is_v2x_route(mine[j]) for j in common], bool)
    pa, pb = _platforms([mine[j] for j in common]), _platforms([theirs[j] for j in common])
    recorded = all(r.get("platform") for j in common for r in (mine[j], theirs[j]))
    return {
        "jobs": common, "runs_only_in": {a: len(mine) - len(common), b: len(theirs) - len(common)},
        a: aggregate([mine[j]["metrics"] for j in common], len(common)),
        b: aggregate([theirs[j]["metrics"] for j in common], len(common)),
        "paired_ds_difference": float(np.mean(diff)),
        "paired_ds_difference_ci": list(bootstrap_ci(diff)),
        "runs_higher": int((diff > TIE_DS).sum()), "runs_lower": int((diff < -TIE_DS).sum()),
        "runs_equal": int((np.abs(diff) <= TIE_DS).sum()),
        "v2x_runs": int(v2x.sum()),
        "v2x_paired_ds_difference": float(np.mean(diff[v2x])) if v2x.any() else None,
        "v2x_paired_ds_difference_ci": list(bootstrap_ci(diff[v2x])) if v2x.any() else None,
        "platform": ("not recorded" if not recorded else
                     "same" if pa == pb and len(pa) == 1 else "different"),
        "platforms": {a: [json.loads(p) for p in pa], b: [json.loads(p) for p in pb]},
        "scenarios": {which: scenario_pairs([mine[j] for j in common], [theirs[j] for j in common],
                                            (a, b), v2x=flag)
                      for which, flag in (("all", None), ("v2x", True))},
    }


def compare(named: list[tuple[str, str | Path]], out: str | Path | None = None) -> dict[str, dict]:
    """The first ``(name, folder)`` against each of the others (:func:`compare_pair`), keyed
    ``"A vs B"``; with ``out``, also ``out.json`` and ``out.md`` (atomically).

    Raises:
        ValueError: fewer than two folders, or a pair that shares no run.
    """
    if len(named) < 2:
        raise ValueError("compare: give at least two eval folders (NAME=DIR NAME=DIR)")
    first = named[0]
    result = {f"{first[0]} vs {o[0]}": compare_pair(first, o) for o in named[1:]}
    if out is not None:
        out = Path(out)
        atomic_write_text(out.with_suffix(".json"), json.dumps(result, indent=1) + "\n")
        atomic_write_text(out.with_suffix(".md"), compare_markdown(result))
    return result


def compare_markdown(result: dict[str, dict]) -> str:
    """One table per pair: each agent on the common runs, then the paired difference."""
    parts, nan = [], float("nan")
    for title, d in result.items():
        a, b = title.split(" vs ", 1)
        rows = ["| agent | runs | DS [95% CI] | RC | red lights / km | vehicle collisions / km |",
                "|---|---|---|---|---|---|"]
        for who in (a, b):
            s = d[who]
            rows.append(f"| {who} | {len(d['jobs'])} | {s['driving_score']:.1f} "
                        f"[{s['driving_score_ci_low']:.1f}, {s['driving_score_ci_high']:.1f}] | "
                        f"{s['route_completion']:.1f} | {s.get('red_light_per_km', nan):.2f} | "
                        f"{s.get('collision_vehicle_per_km', nan):.2f} |")
        lo, hi = d["paired_ds_difference_ci"]
        plat = {"same": "both on the same platform",
                "different": "**on different platforms**: a learned agent's runs differ across machines",
                "not recorded": "platform not recorded in every run (results written before 2026-11-29)"
                }[d["platform"]]
        parts.append(f"### {title}\n\n" + "\n".join(rows) + "\n\n"
                     f"Paired DS difference ({a} minus {b}, run by run): "
                     f"**{d['paired_ds_difference']:+.1f}** [{lo:+.1f}, {hi:+.1f}]; {a} higher on "
                     f"{d['runs_higher']}, lower on {d['runs_lower']}, equal on {d['runs_equal']} "
                     f"of {len(d['jobs'])} runs; {plat}."
                     + (f" On the {d['v2x_runs']} runs of V2X-type routes: "
                        f"**{d['v2x_paired_ds_difference']:+.1f}** [{d['v2x_paired_ds_difference_ci'][0]:+.1f}, "
                        f"{d['v2x_paired_ds_difference_ci'][1]:+.1f}]." if d["v2x_runs"] else "") + "\n"
                     + _scenario_markdown(d.get("scenarios"), a, b))
    return "\n".join(parts)


def _scenario_markdown(sc: dict | None, a: str, b: str) -> str:
    """The scenario-instance table of a pair (empty for results without scenarios)."""
    if not sc or not sc["all"]["instances"]:
        return ""
    rows = ["\nScenario instances of these runs, paired (success: passed, no collision, no timeout; "
            "p: exact sign test on the instances only one succeeds on):\n",
            f"| instances | n | {a} succeeds | {b} succeeds | only {a} | only {b} | p | "
            f"{a} collides | {b} collides | {a} reached | {b} reached |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for which, label in (("all", "all"), ("v2x", "V2X-specific types")):
        d = sc[which]
        if not d["instances"]:
            continue
        rows.append(f"| {label} | {d['instances']} | {d['success'][a]} | {d['success'][b]} | "
                    f"{d['only'][a]} | {d['only'][b]} | {d['sign_test_p']:.2f} | {d['collision'][a]} | "
                    f"{d['collision'][b]} | {d['reached'][a]} | {d['reached'][b]} |")
    return "\n".join(rows) + "\n"


__all__ = ["compare", "compare_markdown", "compare_pair", "scenario_pairs", "sign_test_p"]
