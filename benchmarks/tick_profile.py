"""Where a tick's time goes: per stage of the tick and per numba kernel (``v2xbench profile``).

For the duration of a run, the stages of a tick (``World``'s step methods in step order, the action
check, the episode tracker, the observation, resets) and every numba kernel the environment calls
from Python are wrapped with a timer. Then the run drives one of two workloads:

- ``objects``: the suite's objects row (``suite.OBJECTS_CONFIG``: ``gym.make``, a test50 route
  with its scenario, a constant action, resets included), one process;
- ``batched``: one native TorchRL env of ``worlds`` worlds (``V2XTorchEnv``, random actions,
  TorchRL's ``rollout``), in this process;
- ``test50``: every route of the test50 suite (the first ``routes`` of them) in turn, ``ticks /
  routes`` ticks each (``gym.make``, a constant action, resets included; the routes' construction
  is not timed), after an untimed pass of a few ticks over them all. Its report adds the time of
  each scenario type's hooks (``Scenario.tick`` and ``check_passed``, which the stages
  ``run_scenarios`` and ``check_events`` include) per tick that a scenario of the type is live.

It reports microseconds per tick (per world-step in ``batched``) of every stage and every kernel,
with calls per tick, and splits the tick into time inside kernels (numba's dispatch included)
and Python around them. With numba it also counts the arrays each kernel allocates per tick
(numba runtime's allocation statistics, switched on for the run): every ``np.empty`` or
returned array inside a kernel is a ``malloc`` / ``free`` pair plus atomic reference counts.
Kernels that call kernels inside numba are counted once, in the caller. Each timer adds ~0.2 us
per wrapped call, so the stages read a little high; the split is what to look at. Without
numba ``move_traffic`` runs as four stages (``move_ego``, ``update_signals``, ``move_followers``,
``move_walkers``), each listed; with numba it is one kernel. ``other`` is the tick minus its
stages: the env's own glue, Gymnasium's wrappers (objects), TorchRL and
TensorDict (batched).

Run ``v2xbench profile`` (or ``--mode batched`` / ``test50``); writes ``OUT/profile_<mode>.json``
and ``.md``.
Without numba (``V2XBENCH_NO_JIT=1``) there are no kernels and all the time is Python.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import pkgutil
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from datetime import datetime, timezone
from pathlib import Path

from .settle import settle

MODES = ("objects", "batched", "test50")
#: test50 routes (all of them)
TEST50_ROUTES = 50
#: ``World`` methods timed as stages, in the order a tick runs them (without numba, ``move_traffic``
#: calls the four after it)
WORLD_STAGES = ("send_builtin", "move_traffic", "move_ego", "update_signals", "move_followers", "move_walkers",
                "run_scenarios", "check_events", "perceive", "deliver", "reset")


class _Timers:
    """Accumulated seconds and call counts per key; ``outer`` sums only the calls made outside any
    other timed call of the same timers (a reset's own perception counts once in it), and
    ``parent`` / ``top_calls`` tell the stages that only ever run inside another one. With a
    ``counter`` (a running count, e.g. the one :func:`_nrt_statistics` yields), ``counts`` sums its
    growth over each key's calls."""

    def __init__(self, counter: Callable[[], int] | None = None) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.counts: dict[str, int] = defaultdict(int)
        self.counter = counter
        self.parent: dict[str, str] = {}  # key -> the timed call it ran inside (the first seen)
        self.top_calls: dict[str, int] = defaultdict(int)  # calls made outside any other timed call
        self.outer = 0.0
        self._stack: list[str] = []

    def clear(self) -> None:
        self.seconds.clear()
        self.calls.clear()
        self.counts.clear()
        self.parent.clear()
        self.top_calls.clear()
        self.outer = 0.0

    def wrap(self, fn: Callable, key: str) -> Callable:
        seconds, calls, clock, stack = self.seconds, self.calls, time.perf_counter, self._stack
        counter, counts = self.counter, self.counts

        def timed(*args, **kwargs):
            if stack:
                self.parent.setdefault(key, stack[-1])
            stack.append(key)
            c0 = counter() if counter else 0
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                dt = clock() - t0
                if counter:
                    counts[key] += counter() - c0
                stack.pop()
                seconds[key] += dt
                calls[key] += 1
                if not stack:
                    self.outer += dt
                    self.top_calls[key] += 1

        timed.__wrapped__ = fn
        return timed


class _ScenarioTimers:
    """Seconds in each scenario type's hooks, and the ticks in which one was live: a hook called
    inside another hook (``check_passed`` from ``tick``) counts once, in the outer one."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.ticks: dict[str, int] = defaultdict(int)
        self._depth = 0

    def clear(self) -> None:
        self.seconds.clear()
        self.ticks.clear()

    def watch(self, world) -> None:
        """Time the hooks of ``world``'s scenarios (call after each reset: new scenarios)."""
        for sc in world.scenarios:
            name = type(sc).__name__
            sc.tick = self._wrap(sc.tick, name, count=True)
            sc.check_passed = self._wrap(sc.check_passed, name, count=False)

    def _wrap(self, fn: Callable, name: str, count: bool) -> Callable:
        clock = time.perf_counter

        def timed(*args, **kwargs):
            if count:
                self.ticks[name] += 1
            if self._depth:
                return fn(*args, **kwargs)
            self._depth += 1
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds[name] += clock() - t0
                self._depth -= 1

        return timed


@contextlib.contextmanager
def _nrt_statistics(wanted: bool = True) -> Iterator[Callable[[], int] | None]:
    """numba runtime's allocation statistics switched on for the block (they are off by default
    and cost an atomic add per allocation); yields a function giving the allocations so far, or
    ``None`` where not ``wanted`` or numba (or this numba's switch) is missing."""
    if not wanted:
        yield None
        return
    try:
        from numba.core.runtime import _nrt_python
    except ImportError:
        yield None
        return
    if not hasattr(_nrt_python, "memsys_get_stats_alloc"):  # pragma: no cover - another numba
        yield None
        return
    was_on = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        yield _nrt_python.memsys_get_stats_alloc  # a C call (rtsys.get_allocation_stats: ~2 us)
    finally:
        if not was_on:
            _nrt_python.memsys_disable_stats()


@contextlib.contextmanager
def patched(patches: list[tuple[object, str, object]]) -> Iterator[None]:
    """Set ``owner.name = value`` for each patch; restore every original on exit (also used by
    ``kernel_floor``)."""
    saved = [(owner, name, getattr(owner, name)) for owner, name, _ in patches]
    try:
        for owner, name, value in patches:
            setattr(owner, name, value)
        yield
    finally:
        for owner, name, value in reversed(saved):
            setattr(owner, name, value)


def _env_modules() -> list:
    """The modules of the environment package (``v2xbench.envs.v2x_intersection`` and below),
    without the deprecated aliases of moved modules."""
    import v2xbench.envs.v2x_intersection as pkg

    mods = [pkg]
    aliases = {f"{pkg.__name__}.{a}" for a in pkg.DEPRECATED_ALIASES}
    for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        if info.name not in aliases:
            mods.append(importlib.import_module(info.name))
    return mods


def _code_names(code) -> set[str]:
    """Global names a code object (and the code objects nested in it) refers to."""
    names = set(code.co_names)
    for c in code.co_consts:
        if hasattr(c, "co_names"):
            names |= _code_names(c)
    return names


def _kernel_patches(timers: _Timers) -> list[tuple[object, str, object]]:
    """A timed stand-in for every module-level reference to a numba kernel that Python code calls
    (one timer per kernel, shared by the modules that import it). Names that a kernel of the same
    module calls stay as they are: numba resolves them when it compiles that kernel."""
    try:
        from numba.core.registry import CPUDispatcher
    except ImportError:  # pragma: no cover - numba is a dependency
        return []
    timed: dict[int, Callable] = {}
    patches = []
    for mod in _env_modules():
        kernels = [o for o in vars(mod).values() if isinstance(o, CPUDispatcher)]
        used = set().union(*(_code_names(k.py_func.__code__) for k in kernels))
        for name, obj in list(vars(mod).items()):
            if isinstance(obj, CPUDispatcher) and name not in used:
                if id(obj) not in timed:
                    timed[id(obj)] = timers.wrap(obj, obj.__name__)
                patches.append((mod, name, timed[id(obj)]))
    return patches


def _stage_patches(timers: _Timers, mode: str) -> list[tuple[object, str, object]]:
    """Timed stand-ins for the tick's stages (and the tuples and imports that reference them)."""
    from v2xbench.envs.v2x_intersection.api import batch, gym_env
    from v2xbench.envs.v2x_intersection.evaluation import episode
    from v2xbench.envs.v2x_intersection.sim import world

    timed = {name: timers.wrap(getattr(world.World, name), name) for name in WORLD_STAGES}
    patches: list[tuple[object, str, object]] = [(world.World, n, f) for n, f in timed.items()]
    stages = tuple(timed.get(f.__name__, f) for f in world.TICK_STAGES)
    patches += [(world, "TICK_STAGES", stages), (batch, "TICK_STAGES", stages)]
    patches.append((episode.EpisodeTracker, "after_step", timers.wrap(episode.EpisodeTracker.after_step, "after_step")))
    if mode in ("objects", "test50"):  # gym.make's single env
        patches.append((gym_env, "validate_action", timers.wrap(gym_env.validate_action, "validate_control")))
        patches.append((gym_env, "ego_observation", timers.wrap(gym_env.ego_observation, "observation")))
    else:
        from v2xbench.envs.v2x_intersection.sim import jit_batch

        patches.append((batch, "validate_controls", timers.wrap(batch.validate_controls, "validate_control")))
        # with numba the batch moves the traffic of all its worlds in one call (jit_batch)
        patches.append((jit_batch.TrafficBatch, "step", timers.wrap(jit_batch.TrafficBatch.step, "move_traffic")))
        patches.append((jit_batch.PerceiveBatch, "step", timers.wrap(jit_batch.PerceiveBatch.step, "perceive")))
        patches.append((batch.WorldBatch, "_observe", timers.wrap(batch.WorldBatch._observe, "observation")))
    return patches


def _run_objects(ticks: int, clear: Callable[[], None]) -> tuple[float, int, dict]:
    import gymnasium as gym
    import numpy as np

    import v2xbench  # noqa: F401  (registers the ids)

    from .env_speed import warm_up
    from .suite import OBJECTS_CONFIG

    env = gym.make("V2XIntersection-v0", **OBJECTS_CONFIG)
    action = np.array([0.3, 0.0, 0.0], np.float32)
    # warm-up: kernels compiled or loaded, caches filled, through an episode end (env_speed.warm_up)
    warm_up(env, action, seed=0, warmup=50)
    settle()
    clear()
    n, t0 = 0, time.perf_counter()
    while n < ticks:
        _, _, term, trunc, _ = env.step(action)
        n += 1
        if term or trunc:
            env.reset(seed=n)
    total = time.perf_counter() - t0
    env.close()
    return total, n, dict(OBJECTS_CONFIG)


def _run_test50(ticks: int, routes: int, clear: Callable[[], None],
                scenarios: _ScenarioTimers) -> tuple[float, int, dict]:
    import gymnasium as gym
    import numpy as np

    import v2xbench  # noqa: F401  (registers the ids)

    action = np.array([0.4, 0.0, 0.0], np.float32)
    per = max(ticks // routes, 1)

    def drive(env, n: int, timed: bool) -> float:
        """``n`` ticks (resets included) of ``env``; seconds taken."""
        w = env.unwrapped.world
        t0 = time.perf_counter()
        env.reset(seed=0)
        if timed:
            scenarios.watch(w)
        for k in range(n):
            _, _, term, trunc, _ = env.step(action)
            if term or trunc:
                env.reset(seed=k + 1)
                if timed:
                    scenarios.watch(w)
        return time.perf_counter() - t0

    envs = [gym.make("V2XIntersection-v0", suite="test50", route_index=i) for i in range(routes)]
    for env in envs:  # warm-up: every route's kernels compiled or loaded
        drive(env, 20, timed=False)
    settle()
    clear()
    total = sum(drive(env, per, timed=True) for env in envs)
    for env in envs:
        env.close()
    return total, per * routes, {"suite": "test50", "routes": routes, "ticks_per_route": per}


def _run_batched(ticks: int, worlds: int, clear: Callable[[], None]) -> tuple[float, int, dict]:
    import torch
    from v2xbench.envs.v2x_intersection import V2XTorchEnv

    torch.set_num_threads(1)
    env = V2XTorchEnv(num_worlds=worlds)
    env.set_seed(0)
    env.rollout(5, break_when_any_done=False)
    settle()
    clear()
    t0 = time.perf_counter()
    td = env.rollout(ticks, break_when_any_done=False)
    total = time.perf_counter() - t0
    return total, int(td.numel()), {"num_worlds": worlds}


def profile(mode: str = "objects", ticks: int = 3000, worlds: int = 32, routes: int = TEST50_ROUTES) -> dict:
    """Run the ``mode`` workload for ``ticks`` ticks (per world in ``batched``; over ``routes``
    routes in ``test50``) under the timers.

    Returns:
        a JSON-able report: ``us_per_tick`` (per world-step in ``batched``), ``stages`` and
        ``kernels`` (``{name: {"us": per tick, "calls": per tick, "inside": the stage that every
        call ran inside, or None}}``, largest first; kernels also ``"allocs"``: arrays numba
        allocated per tick inside them, ``None`` without the statistics), ``allocs_per_tick``
        (all of numba's allocations per tick, or ``None``),
        ``kernel_us`` / ``python_us`` (inside / outside kernels), ``other_us`` (outside the stages);
        in ``test50`` also ``scenarios`` (``{type: {"us_live": us per tick a scenario of the type
        was live, "ticks": those ticks, "us": us per tick of the run}}``, largest ``us`` first).

    Raises:
        ValueError: unknown ``mode``, or ``ticks`` / ``worlds`` / ``routes`` out of range.
    """
    if mode not in MODES:
        raise ValueError(f"profile: unknown mode {mode!r} (modes: {', '.join(MODES)})")
    if ticks < 1 or worlds < 1:
        raise ValueError(f"profile: ticks={ticks} and worlds={worlds} must be >= 1")
    if not 1 <= routes <= TEST50_ROUTES:
        raise ValueError(f"profile: routes={routes} must be in [1, {TEST50_ROUTES}]")
    from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT

    with _nrt_statistics(HAVE_JIT) as allocations:
        stage_t, kernel_t, scen_t = _Timers(), _Timers(allocations), _ScenarioTimers()
        start = 0  # allocations when the timers were cleared

        def clear() -> None:  # the workloads clear the timers after their warm-up
            nonlocal start
            stage_t.clear()
            kernel_t.clear()
            scen_t.clear()
            start = allocations() if allocations else 0

        with patched(_stage_patches(stage_t, mode) + _kernel_patches(kernel_t)):
            if mode == "objects":
                total, steps, config = _run_objects(ticks, clear)
            elif mode == "test50":
                total, steps, config = _run_test50(ticks, routes, clear, scen_t)
            else:
                total, steps, config = _run_batched(ticks, worlds, clear)
        allocs = (allocations() - start) / steps if allocations else None

    def per_tick(t: _Timers) -> dict:
        rows = sorted(t.seconds, key=lambda k: -t.seconds[k])
        out = {k: {"us": 1e6 * t.seconds[k] / steps, "calls": t.calls[k] / steps,
                   "inside": None if t.top_calls[k] else t.parent.get(k)} for k in rows}
        if t is kernel_t:
            for k, row in out.items():
                row["allocs"] = t.counts[k] / steps if allocations else None
        return out

    stages, kernels = per_tick(stage_t), per_tick(kernel_t)
    us = 1e6 * total / steps
    kernel_us = 1e6 * kernel_t.outer / steps
    report = {
        "benchmark": "tick_profile", "mode": mode, "config": config, "numba": bool(HAVE_JIT),
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), "steps": steps,
        "us_per_tick": us, "kernel_us": kernel_us, "python_us": us - kernel_us,
        "other_us": us - 1e6 * stage_t.outer / steps,
        "kernel_calls": sum(v["calls"] for v in kernels.values()), "allocs_per_tick": allocs,
        "stages": stages, "kernels": kernels,
    }
    if mode == "test50":
        names = sorted(scen_t.seconds, key=lambda k: -scen_t.seconds[k])
        report["scenarios"] = {k: {"us_live": 1e6 * scen_t.seconds[k] / max(scen_t.ticks[k], 1),
                                   "ticks": scen_t.ticks[k], "us": 1e6 * scen_t.seconds[k] / steps}
                               for k in names}
    return report


def table(report: dict) -> str:
    """The report as Markdown: the split, then the stages and the kernels."""
    unit = "world-step" if report["mode"] == "batched" else "tick"
    us = report["us_per_tick"]
    lines = [
        f"Tick profile, {report['mode']} ({report['config']}), {report['steps']} {unit}s, {report['date']}, "
        f"numba {'on' if report['numba'] else 'off'}",
        "",
        f"{us:.0f} us per {unit} ({1e6 / us:,.0f} per second): {report['kernel_us']:.0f} us inside "
        f"{report['kernel_calls']:.1f} kernel calls, {report['python_us']:.0f} us of Python around them."
        + ("" if report.get("allocs_per_tick") is None else
           f" numba allocated {report['allocs_per_tick']:.0f} arrays per {unit}."),
        "",
        "| stage | us per " + unit + " | calls | share |",
        "| --- | ---: | ---: | ---: |",
    ]
    for k, v in report["stages"].items():
        name = f"{k} (inside {v['inside']})" if v.get("inside") else k
        lines.append(f"| {name} | {v['us']:.1f} | {v['calls']:.2f} | {100 * v['us'] / us:.0f} % |")
    lines.append(f"| other | {report['other_us']:.1f} | | {100 * report['other_us'] / us:.0f} % |")
    if report["kernels"]:
        lines += ["", "| kernel | us per " + unit + " | calls | share | arrays allocated per " + unit + " |",
                  "| --- | ---: | ---: | ---: | ---: |"]
        for k, v in report["kernels"].items():
            allocs = "" if v.get("allocs") is None else f"{v['allocs']:.1f}"
            lines.append(f"| {k} | {v['us']:.1f} | {v['calls']:.2f} | {100 * v['us'] / us:.0f} % | {allocs} |")
    if report.get("scenarios"):
        lines += ["", "| scenario type (hooks) | us per live tick | live ticks | us per tick | share |",
                  "| --- | ---: | ---: | ---: | ---: |"]
        for k, v in report["scenarios"].items():
            lines.append(f"| {k} | {v['us_live']:.1f} | {v['ticks']} | {v['us']:.1f} | {100 * v['us'] / us:.0f} % |")
    return "\n".join(lines) + "\n"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mode", choices=MODES, default="objects", help="workload (default: objects)")
    p.add_argument("--ticks", type=int, default=3000, help="ticks to time (per world in batched; default 3000)")
    p.add_argument("--worlds", type=int, default=32, help="worlds of the batched env (default 32)")
    p.add_argument("--routes", type=int, default=TEST50_ROUTES,
                   help=f"test50 mode: the first ROUTES routes (default all {TEST50_ROUTES})")
    p.add_argument("--out", default="benchmarks/results", help="directory for profile_<mode>.json and .md")


def run(args: argparse.Namespace) -> int:
    from .suite import _write

    report = profile(args.mode, args.ticks, args.worlds, args.routes)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    md = table(report)
    _write(out / f"profile_{args.mode}.json", json.dumps(report, indent=2))
    _write(out / f"profile_{args.mode}.md", md)
    print(md)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="v2xbench profile", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
