"""Which routes of a suite an evaluation runs: ``--routes``, ``--scenario``, ``--v2x-only``,
``--max-routes``.

Filters combine (a route runs when it passes all given); the selected routes keep the suite's
order, and ``--max-routes N`` keeps the first N of them. Unknown route ids and scenario types are
refused before anything runs, with a did-you-mean, and so is a selection that leaves no route.
The summary records the selection (:attr:`Selection.record`) and the leaderboard ranks together
only runs of the same routes.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from typing import NamedTuple

from v2xbench.envs.v2x_intersection.scenarios import SCENARIOS, get_scenario

from . import jobs as J


class Selection(NamedTuple):
    """The routes an evaluation runs.

    Attributes:
        indices: indices of the selected routes in the suite's route list (suite order).
        route_ids: their ids.
        label: short description: ``all 50 routes``, or the filters (``scenario Accident,
            first 3``).
        record: the filters as given (``routes``, ``scenario``, ``v2x_only``, ``max_routes``),
            the label and the route ids: JSON data for the summary.
    """

    indices: list[int]
    route_ids: list[str]
    label: str
    record: dict


def split_list(value: str | Sequence[str] | None) -> list[str] | None:
    """Comma-separated names (``"a,b"``, or a list of such strings) as a list; ``None`` stays."""
    if value is None:
        return None
    items = [value] if isinstance(value, str) else list(value)
    out = [p.strip() for item in items for p in str(item).split(",") if p.strip()]
    return out


def _hint(name: str, known: Sequence[str]) -> str:
    close = difflib.get_close_matches(name, known, n=1)
    return f" Did you mean {close[0]!r}?" if close else ""


def is_v2x_route(spec) -> bool:
    """Whether a route (``RouteSpec``) holds a V2X-specific scenario type (the suite summary's
    V2X-type subset, ``--v2x-only``)."""
    return any(get_scenario(s.type).v2x for s in spec.scenarios)


def select_routes(
    routes: Sequence,
    suite: str,
    route_ids: str | Sequence[str] | None = None,
    scenario: str | Sequence[str] | None = None,
    v2x_only: bool = False,
    max_routes: int | None = None,
) -> Selection:
    """The routes of ``routes`` (a suite's ``RouteSpec`` list) that pass the filters.

    Args:
        routes: the suite's routes. suite: its name, for messages.
        route_ids: only these route ids (comma-separated string or list).
        scenario: only routes containing one of these scenario types.
        v2x_only: only routes containing a V2X scenario type.
        max_routes: then only the first ``max_routes``.

    Raises:
        ValueError: an unknown route id or scenario type (did-you-mean), a scenario type no route
            of the suite contains, a bad ``max_routes``, or no route left.
    """
    if max_routes is not None and (
        isinstance(max_routes, bool) or not isinstance(max_routes, int) or max_routes < 1
    ):
        raise ValueError(f"max_routes={max_routes!r} must be a positive int or None (--max-routes)")
    ids = [r.id for r in routes]
    keep = list(range(len(routes)))
    parts = []
    wanted = split_list(route_ids)
    if wanted is not None:
        if not wanted:
            raise ValueError("--routes is empty; give route ids separated by commas")
        for rid in wanted:
            if rid not in ids:
                raise ValueError(
                    f"unknown route id {rid!r} in suite {suite}.{_hint(rid, ids)} "
                    f"Its {len(ids)} routes: {', '.join(ids[:5])}{', ...' if len(ids) > 5 else ''}"
                )
        keep = [i for i in keep if ids[i] in set(wanted)]
        parts.append(f"routes {','.join(ids[i] for i in keep)}")
    types = split_list(scenario)
    if types is not None:
        if not types:
            raise ValueError("--scenario is empty; give scenario types separated by commas")
        in_suite = sorted({s.type for r in routes for s in r.scenarios})
        for t in types:
            if t not in SCENARIOS:
                raise ValueError(
                    f"unknown scenario type {t!r}.{_hint(t, list(SCENARIOS))} "
                    f"Types in suite {suite}: {', '.join(in_suite)}"
                )
            if t not in in_suite:
                raise ValueError(
                    f"no route of suite {suite} contains scenario type {t!r}.{_hint(t, in_suite)} "
                    f"Types in it: {', '.join(in_suite)}"
                )
        keep = [i for i in keep if {s.type for s in routes[i].scenarios} & set(types)]
        parts.append(f"scenario {','.join(types)}")
    if v2x_only:
        keep = [i for i in keep if is_v2x_route(routes[i])]
        parts.append("V2X-type")
    if not keep:
        raise ValueError(f"no route of suite {suite} passes {' and '.join(parts)}")
    if max_routes is not None and max_routes < len(keep):
        keep = keep[:max_routes]
        parts.append(f"first {max_routes}")
    label = f"all {len(routes)} routes" if len(keep) == len(routes) else ", ".join(parts)
    record = {
        "routes": wanted,
        "scenario": types,
        "v2x_only": bool(v2x_only),
        "max_routes": max_routes,
        "label": label,
        "route_ids": [ids[i] for i in keep],
    }
    return Selection(keep, [ids[i] for i in keep], label, record)


def selected_jobs(
    suite: str,
    seeds: int = 1,
    *,
    routes: str | Sequence[str] | None = None,
    scenario: str | Sequence[str] | None = None,
    v2x_only: bool = False,
    max_routes: int | None = None,
) -> tuple[list, Selection, list[J.Job]]:
    """The route x seed jobs an evaluation of ``suite`` with these filters runs (``evaluate``
    and ``experiments status`` count the same ones).

    Returns:
        ``(suite_routes, selection, jobs)``: the suite's ``RouteSpec`` list, the
        :func:`select_routes` result and the jobs (seed-major, ``jobs.make_jobs``).

    Raises:
        ValueError: an unknown suite, a bad filter (:func:`select_routes`) or bad ``seeds``.
    """
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

    suite_routes = load_suite_cached(str(suite))
    selection = select_routes(suite_routes, str(suite), route_ids=routes, scenario=scenario,
                              v2x_only=v2x_only, max_routes=max_routes)
    jobs = J.make_jobs([r.id for r in suite_routes], seeds, indices=selection.indices)
    return suite_routes, selection, jobs
