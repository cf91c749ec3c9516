"""Per-tick log of one evaluation route and the result dict written for it.

:class:`RouteLog` follows a :class:`~v2xbench.envs.v2x_intersection.sim.world.World` tick by tick and
keeps what :class:`~v2xbench.envs.v2x_intersection.evaluation.metrics.RouteRecord` needs (ego pose and speed,
the surrounding traffic's mean speed, route progress), when each scenario was passed, and the
video frames. :func:`build_result` turns it into the JSON-ready result of a job.

Scenario outcome (per instance on the route): ``triggered``, ``passed`` and ``timed_out`` come
from the scenario; ``collision`` is whether the ego had a collision (pedestrian, vehicle or static)
inside the scenario's window, from its trigger tick to the tick it was passed (or the end of the
route); ``success = passed and not collision and not timed_out``.
"""

from __future__ import annotations

import traceback
from pathlib import Path

import numpy as np
from v2xbench.envs.v2x_intersection.evaluation import infractions as inf
from v2xbench.envs.v2x_intersection.evaluation.episode import time_budget_steps
from v2xbench.envs.v2x_intersection.evaluation.metrics import (
    ENDED_BLOCKED,
    ENDED_BY_NAMES,
    ENDED_COLLISION,
    ENDED_COMPLETED,
    ENDED_ERROR,
    ENDED_ROUTE_DEVIATION,
    ENDED_TIMEOUT,
    RouteRecord,
    compute_metrics,
    surrounding_mean_speed,
)
from v2xbench.envs.v2x_intersection.scenarios import get_scenario

from v2xbench.platform_info import run_platform

COLLISION_CODES = (inf.COLLISION_PEDESTRIAN, inf.COLLISION_VEHICLE, inf.COLLISION_STATIC)
#: How a failed route failed (result key ``failure``; ``ended_by`` is ``"error"`` for both, DS 0):
#: ``"error"``: the agent, the world or the worker process raised or died; ``"timeout"``: the job
#: overran the harness's wall-clock limit (``--route-timeout``) and its worker was killed.
#: (``ended_by = "timeout"`` is another thing: the route's simulated time budget ran out.)
FAILURE_KINDS = ("error", "timeout")


def ended_by_code(world, terminated: bool, truncated: bool) -> int:
    """``ENDED_*`` code of a route that just ended (termination reasons of ``episode.py``)."""
    counts = world.monitor.counts
    if world.is_route_complete():
        return ENDED_COMPLETED
    if counts[inf.ROUTE_DEVIATION] > 0:
        return ENDED_ROUTE_DEVIATION
    if counts[inf.BLOCKED] > 0:
        return ENDED_BLOCKED
    if terminated and world.config.terminate_on_collision:
        return ENDED_COLLISION
    return ENDED_TIMEOUT


class RouteLog:
    """What one route logs per tick (see module docstring).

    Args:
        world: a world just reset on the job's route.
        video_every: keep a top-down frame every this many ticks (0: no video).
        video_size: frame side in pixels.
    """

    def __init__(self, world, video_every: int = 0, video_size: int = 256) -> None:
        self.world = world
        self.xy: list[np.ndarray] = []
        self.yaw: list[float] = []
        self.speed: list[float] = []
        self.bg_speed: list[float] = []
        self.route_s: list[float] = []
        self.pass_tick = [-1] * len(world.scenarios)
        self.v2x_age: list[int] = []  # per tick: age (ticks) of the ego's last message, -1: none
        self.video_every, self.video_size = int(video_every), int(video_size)
        self.frames: list[np.ndarray] = []
        self._frame()

    def _frame(self) -> None:
        if self.video_every > 0 and self.world.tick % self.video_every == 0:
            from v2xbench.envs.v2x_intersection.render.topdown import render_topdown

            self.frames.append(render_topdown(self.world, self.video_size))

    def after_step(self) -> None:
        """Log the state reached by the tick just simulated."""
        w = self.world
        t = w.table
        self.xy.append(t.pos[0].copy())
        self.yaw.append(float(t.yaw[0]))
        self.speed.append(float(t.speed[0]))
        self.bg_speed.append(surrounding_mean_speed(t))
        self.route_s.append(float(w.route.s[w.monitor.progress]))
        self.v2x_age.append(-1 if w.inbox is None else int(w.tick - w.inbox[1]))
        for k, sc in enumerate(w.scenarios):
            if sc.passed and self.pass_tick[k] < 0:
                self.pass_tick[k] = w.tick
        self._frame()

    def record(self, ended_by: int, route_id: str, seed: int) -> RouteRecord:
        """The :class:`RouteRecord` of the route so far."""
        w = self.world
        stats = w.channel.stats()
        return RouteRecord(
            route_length=w.route.length,
            route_completion=min(w.monitor.route_completion, 100.0),
            ego_xy=np.asarray(self.xy, np.float64).reshape(-1, 2),
            ego_yaw=self.yaw,
            ego_speed=self.speed,
            background_speed=self.bg_speed,
            route_s=self.route_s,
            events=np.asarray(w.monitor.events, np.float64).reshape(-1, 4),
            outside_lanes_m=w.monitor.outside_m,
            driven_m=w.monitor.driven_m,
            bytes_sent=int(stats["bytes_sent_total"]),
            peak_bps=float(stats["peak_bps"]),
            sim_seconds=len(self.speed) * w.config.dt,
            ended_by=ended_by,
            dt=w.config.dt,
            route_id=route_id,
            seed=seed,
        )

    def scenario_outcomes(self) -> list[dict]:
        """Per scenario instance: type, v2x, triggered, passed, timed_out, collision, success."""
        w = self.world
        ev = np.asarray(w.monitor.events, np.float64).reshape(-1, 4)
        hits = ev[np.isin(ev[:, 0].astype(np.int64), COLLISION_CODES), 1]
        out = []
        for k, sc in enumerate(w.scenarios):
            end = self.pass_tick[k] if self.pass_tick[k] >= 0 else w.tick
            coll = bool(sc.triggered and np.any((hits >= sc.trigger_tick) & (hits <= end)))
            out.append({
                "type": sc.name, "v2x": bool(sc.v2x), "triggered": bool(sc.triggered),
                "passed": bool(sc.passed), "timed_out": bool(sc.timed_out), "collision": coll,
                "success": bool(sc.passed and not coll and not sc.timed_out),
                "trigger_tick": int(sc.trigger_tick), "pass_tick": int(self.pass_tick[k]),
            })
        return out

    def v2x_summary(self) -> dict:
        """The channel as the route saw it: its settings, message counters and the age of the
        message the ego held (``world.inbox``), in ticks, over the ticks that held one."""
        w = self.world
        st = w.channel.stats()
        age = np.asarray([a for a in self.v2x_age if a >= 0], np.float64)
        return {
            "latency_ticks": int(w.config.latency_ticks), "loss_prob": float(w.config.loss_prob),
            "bandwidth_bytes_per_s": w.config.bandwidth_bytes_per_s,
            **{k: int(st[k]) for k in ("messages_sent", "messages_lost",
                                       "messages_dropped_bandwidth", "messages_delivered")},
            "ticks_with_message": int(len(age)),
            "message_age_ticks": {"min": float(age.min()), "mean": float(age.mean()),
                                  "max": float(age.max())} if len(age) else None,
        }

    def save_video(self, path: Path) -> str | None:
        """Write the frames as a GIF (``None`` when there are none)."""
        if not self.frames:
            return None
        from v2xbench.envs.v2x_intersection.render.topdown import save_video

        fps = max(1, round(10 / self.video_every))
        return str(save_video(self.frames, path, fps=fps))


def empty_record(spec, seed: int, ended_by: int = ENDED_ERROR) -> RouteRecord:
    """A zero-tick record (a route whose world or agent failed before the first tick)."""
    length = 0.0
    try:
        from v2xbench.envs.v2x_intersection.suites.route_files import build_episode_from_spec

        length = build_episode_from_spec(spec)[0].length
    except Exception:  # noqa: BLE001  (the failure is already being reported)
        pass
    z = np.zeros(0)
    return RouteRecord(length, 0.0, np.zeros((0, 2)), z, z, z, z, np.zeros((0, 4)), 0.0, 0.0, 0, 0.0,
                       0.0, ended_by, route_id=spec.id, seed=seed)


def build_result(*, job, spec, seed: int, suite: str, agent: str, agent_name: str,
                 privileged: bool, log: RouteLog | None, ended_by: int, wall_s: float,
                 agent_process: str = "in_process",
                 error: BaseException | None = None, video: str | None = None,
                 config: dict | None = None, failure: str | None = None,
                 fingerprint: str | None = None) -> dict:
    """The JSON-ready result of one job (see ``jobs.py`` for where it is written).

    ``privileged`` is the harness's decision (``interface.granted_privilege``) and
    ``agent_process`` how the agent ran: ``"in_process"`` or ``"isolated"`` (its own process).
    A route that ended with ``error`` is recorded with ``ended_by = ENDED_ERROR`` and a driving
    score of 0 (the suite's DS counts it as 0 too); the RC reached before the error is kept.
    ``failure`` says how it failed (:data:`FAILURE_KINDS`; default ``"error"`` when there is an
    ``error``, ``None`` for a route that ran to its end). ``fingerprint`` is the digest of the
    run's fingerprint (``agent_fingerprint.py``): the results of a directory share one. ``v2x``
    is what the channel did on the route (:meth:`RouteLog.v2x_summary`: settings, message
    counts, the age of the ego's last message); ``platform`` the machine and library versions
    that computed it (``platform_info.run_platform``: a run repeats to the last digit on its own
    machine only).
    """
    if failure is not None and failure not in FAILURE_KINDS:
        raise ValueError(f"failure={failure!r} must be one of {FAILURE_KINDS}")
    if failure is not None and error is None:
        raise ValueError("a failed route needs its error")
    if error is not None:
        ended_by = ENDED_ERROR
        failure = failure or "error"
    rec = log.record(ended_by, spec.id, seed) if log is not None else empty_record(spec, seed, ended_by)
    metrics = compute_metrics(rec)
    if ended_by == ENDED_ERROR:
        metrics["driving_score"] = 0.0
    scen = log.scenario_outcomes() if log is not None else [
        {"type": s.type, "v2x": bool(get_scenario(s.type).v2x), "triggered": False, "passed": False,
         "timed_out": False, "collision": False, "success": False, "trigger_tick": -1, "pass_tick": -1}
        for s in spec.scenarios]
    return {
        "job_id": job.job_id, "route_id": spec.id, "seed_index": job.seed_index, "seed": seed,
        "suite": suite, "town": spec.town, "weather": spec.weather, "time_of_day": spec.time_of_day,
        "agent": agent, "agent_name": agent_name, "privileged": bool(privileged),
        "agent_process": str(agent_process),
        "scenario_types": [s.type for s in spec.scenarios], "scenarios": scen,
        "ended_by": ENDED_BY_NAMES[ended_by], "ticks": len(rec.ego_speed),
        "metrics": metrics, "record": rec.to_dict(), "wall_seconds": round(float(wall_s), 3),
        "time_budget_ticks": time_budget_steps(log.world) if log is not None else None,
        "failure": failure,
        "error": None if error is None else f"{type(error).__name__}: {error}",
        "traceback": None if error is None else "".join(
            traceback.format_exception(type(error), error, error.__traceback__)),
        "video": video, "config_overrides": dict(config or {}), "fingerprint": fingerprint,
        "v2x": log.v2x_summary() if log is not None else None,
        "platform": run_platform(),
    }
