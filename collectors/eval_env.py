"""``EvalEnv``: one world that drives the jobs of an evaluation queue, as a TorchRL ``EnvBase``.

Built from picklable arguments only (so a worker process can create it from a
``functools.partial``; ``eval_workers.py`` runs one per worker under a ``Collector``). At every
reset it claims the next job of the queue that has neither a result nor a claim
(``jobs.try_claim``), resets the world with the job's route and seed and starts logging; when the
route ends it writes the job's result JSON. When no job is left it idles cheaply: reset returns a
zero observation with ``job = -1`` and step returns ``done=True`` without simulating, until its
worker stops the collector.

Two ways to drive:

- *Protocol agent* (``agent="route_follower"``, ``"path/to/file.py:Class"`` or a picklable
  zero-argument factory): by default the agent runs inside the env's process
  (``agent_process = "in_process"``); with ``isolate=True`` it runs in a process of its own
  (:class:`~.agent_process.IsolatedAgent`, ``agent_process = "isolated"``) that receives only
  ``route_info`` and the observations, so it cannot read or patch the world. Privilege is the
  harness's decision (``interface.granted_privilege``: the built-in expert and oracles only):
  those agents get ``agent.bind(world)`` after every reset and cannot be isolated (``ValueError``);
  any other agent declaring ``privileged = True`` is refused. Its ``act`` gets exactly the
  Gymnasium env's observation of ``config.obs_mode`` (the keys of ``observations.ego_space``,
  nothing more), and the Gymnasium env's ``info`` of the same tick when its signature asks for it
  (``interface.act_info_style``). Its control for the current observation is exposed as
  observation ``agent_action (3,)``; the collector's policy is :class:`CopyAgentAction`, so the
  collected ``action`` is the executed control. An agent whose ``rsu_policy`` is an object (its
  own roadside policy, ``roadside.py``) has it run in the roadside unit's place: each tick its
  ``act`` gets the unit's observation and its message goes over the channel (``World.step``)
  instead of the built-in policy's (the world's ``rsu_policy`` is then ``"none"``).
- *TorchRL policy* (``agent=None``): the collector's policy (any ``TensorDictModule`` reading the
  observation keys below and writing ``action``) drives; ``agent_action`` stays zero. It sees the
  keys of ``V2XTorchEnv``'s observation (the ego observation plus ``route_completion`` and
  ``v2x_bps``), so a policy trained there runs here.

Specs (float32 unless noted, batch_size ``[]``): the ego observation of ``config.obs_mode``
(``observations.ego_space``: ``ego``, ``route``, ``v2x_objects``, ``v2x_info`` and ``objects``,
or ``cameras`` + ``lidar``, or ``bev``; the mode defaults to the agent's ``obs_mode``),
``route_completion (1,)``, ``v2x_bps (1,)``,
``agent_action (3,)``, ``job (1,)`` int64 (index of the running job in the queue, -1 idle);
``action`` bounded (``(3,)`` for a protocol agent; a TorchRL policy's in ``config.action_mode``:
``(2,)`` accel, steer for ``accel_steer``, ``envs.v2x_intersection.actions``); ``reward (1,)``
(``episode.py``); ``done``/``terminated``/``truncated``.

Failures: an exception of the agent (``reset``, ``bind`` or ``act``), of the world, or an invalid
policy action (NaN) ends the route as failed (``ENDED_ERROR``, DS 0, message and traceback in the
result) and the queue goes on. So does a ``SystemExit`` or ``KeyboardInterrupt`` the agent raises
(recorded as :class:`AgentAborted`). A reset while a job runs restarts that job from its seed, so
a collector's extra resets never lose or change a job. What cannot be caught here (an agent that
never returns, ``os._exit``, a crash of the interpreter) is caught by the process that supervises
the env's worker (``eval_workers.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase
from v2xbench.agents.torchrl_policy import obs_tensors
from v2xbench.envs.v2x_intersection.api.actions import get_mode, validate_action
from v2xbench.envs.v2x_intersection.api.observations import (
    ego_observation,
    ego_space,
    validate_control,
)
from v2xbench.envs.v2x_intersection.evaluation.episode import EpisodeTracker
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

from . import jobs as J
from .roadside import roadside_runner
from .route_log import RouteLog, build_result, ended_by_code


class AgentAborted(RuntimeError):
    """The agent raised a ``BaseException`` that is not an ``Exception`` (``SystemExit``,
    ``KeyboardInterrupt``): its route fails like on any other exception of the agent."""


def call_agent(fn: Callable, *args: Any) -> Any:
    """``fn(*args)`` for a method of the agent; a ``SystemExit`` or ``KeyboardInterrupt`` (or any
    other non-``Exception``) it raises comes out as :class:`AgentAborted`, so it fails the route,
    not the evaluation."""
    try:
        return fn(*args)
    except Exception:
        raise
    except BaseException as e:  # noqa: BLE001  (the agent's, see docstring)
        detail = f": {e}" if str(e) else ""
        raise AgentAborted(f"the agent raised {type(e).__name__}{detail}") from e


def agent_label(agent: Any) -> tuple[str, str]:
    """``(spec, short name)`` of an agent argument: a spec string, a factory or a policy."""
    if agent is None:
        return "policy", "policy"
    if isinstance(agent, str):
        return agent, agent.rsplit(":", 1)[-1] if ":" in agent else agent
    name = getattr(agent, "__name__", type(agent).__name__)
    return name, name


def instantiate_agent(agent: Any, isolate: bool = False, config: dict | None = None) -> Any:
    """An agent instance from a spec string (``interface.load_agent``) or a factory, built with
    ``config`` as keyword arguments, or with ``isolate`` an
    :class:`~.agent_process.IsolatedAgent` proxy running it in its own process.

    Raises:
        ValueError: see ``interface.load_agent`` / ``build_agent`` / ``complete_agent``; a
            privileged agent with ``isolate``.
    """
    from v2xbench.agents.interface import build_agent, complete_agent, granted_privilege, load_agent

    if isolate:
        from .agent_process import IsolatedAgent

        return IsolatedAgent(agent, config=config)
    if isinstance(agent, str):
        return load_agent(agent, config)
    label = agent_label(agent)[0]
    return complete_agent(build_agent(agent, label, config), label, granted_privilege(agent))


def route_info(world, town: str, seed: int) -> dict:
    """What an agent learns about a route at reset (``interface.ROUTE_INFO_KEYS``): the route and
    its commands, the town and the world seed; no route id or scenario data."""
    r = world.route
    return {"town": str(town), "seed": int(seed), "route_points": r.points.copy(),
            "commands": r.commands.copy()}


def _spec(space, device) -> Composite | Unbounded:
    """A TorchRL spec mirroring a Gymnasium ``Dict``/``Box`` space (nested for sensor modes)."""
    if hasattr(space, "spaces"):
        return Composite({k: _spec(v, device) for k, v in space.spaces.items()}, shape=(), device=device)
    dtype = torch.from_numpy(np.zeros(0, space.dtype)).dtype
    return Unbounded(shape=space.shape, dtype=dtype, device=device)


def _zeros(space) -> dict | np.ndarray:
    """An all-zero observation of a (nested) space."""
    if hasattr(space, "spaces"):
        return {k: _zeros(v) for k, v in space.spaces.items()}
    return np.zeros(space.shape, space.dtype)


class CopyAgentAction(nn.Module):
    """The collector policy for protocol agents: ``action = agent_action`` (picklable)."""

    def forward(self, agent_action: torch.Tensor) -> torch.Tensor:
        return agent_action.clone()


def copy_policy():
    """A ``TensorDictModule`` copying ``agent_action`` into ``action``."""
    from tensordict.nn import TensorDictModule

    return TensorDictModule(CopyAgentAction(), in_keys=["agent_action"], out_keys=["action"])


class EvalEnv(EnvBase):
    """One world working through an evaluation queue (see module docstring).

    Args:
        suite: suite name (``test50``) or path to a suite JSON.
        out: output directory (results, claims, videos).
        agent: agent spec string, picklable zero-argument factory, or ``None`` (TorchRL policy).
        jobs: the queue (:class:`~.jobs.Job` list); default ``make_jobs(suite, seeds, max_routes)``.
        seeds, max_routes: used when ``jobs`` is ``None``.
        video: save a top-down GIF per route under ``<out>/videos``.
        config: ``EnvConfig`` overrides (e.g. smaller populations). ``obs_mode`` and
            ``rsu_policy`` default to the agent's declared ones, the sensor fields to its declared
            ``sensors`` (an override that differs is refused, ``agent_sensors.py``);
            ``suite``/``route_index`` are not allowed (jobs choose).
        video_every, video_size: a frame every this many ticks, of this many pixels.
        agent_name: display name in the results (default: from the spec or factory).
        isolate: run the protocol agent in a separate process (see module docstring).
        agent_config: keyword arguments of the agent's constructor (``--agent-config``).
        fingerprint: digest of the run's fingerprint, written into every result.
    """

    batch_locked = True

    def __init__(self, suite: str, out: str | Path, agent: Any = "route_follower",
                 jobs: Sequence[J.Job] | None = None, seeds: int = 1, max_routes: int | None = None,
                 video: bool = False, config: dict | None = None, video_every: int = 5,
                 video_size: int = 256, agent_name: str | None = None,
                 device: str | torch.device = "cpu", isolate: bool = False,
                 agent_config: dict | None = None, fingerprint: str | None = None) -> None:
        torch.set_num_threads(1)
        super().__init__(batch_size=torch.Size([]), device=device)
        self.suite, self.out = str(suite), Path(out)
        self.routes = load_suite_cached(self.suite)
        self.queue = list(jobs) if jobs is not None else J.make_jobs(
            [s.id for s in self.routes], seeds, max_routes)
        self.agent_spec, self.agent_name = agent_label(agent)
        if agent is None and agent_name:  # a TorchRL policy: its display name is its spec
            self.agent_spec = agent_name
        self.agent_name = agent_name or self.agent_name
        if isolate and agent is None:
            raise ValueError("isolate=True needs a protocol agent (a TorchRL policy runs in the "
                             "collector; wrap it in agents.torchrl_policy.TensorDictPolicyAgent)")
        from v2xbench.agents.interface import granted_privilege

        self.privileged = agent is not None and granted_privilege(agent)  # the harness decides
        self.agent_process = "isolated" if isolate else "in_process"
        self.agent = instantiate_agent(agent, isolate, agent_config) if agent is not None else None
        # the agent's own roadside policy, run in the unit's place (None: a built-in one)
        self._roadside = roadside_runner(self.agent) if self.agent is not None else None
        self.fingerprint = fingerprint
        overrides = dict(config or {})
        bad = {"suite", "route_index"} & set(overrides)
        if bad:
            raise ValueError(f"EvalEnv: config keys {sorted(bad)} are chosen by the job queue")
        self.overrides = dict(overrides)
        if self.agent is not None:  # its declarations configure the env (agent_sensors.py)
            from .agent_sensors import agent_env_overrides

            self.overrides, overrides = agent_env_overrides(self.agent, self.agent_spec,
                                                            overrides)
        overrides.setdefault("town", self.routes[0].town if self.routes else "Town01")
        self.config = make_config(**overrides)
        self.obs_keys = tuple(ego_space(self.config).spaces)  # what a protocol agent's act gets
        self._info_style = self._agent_info_style()
        self._info: dict | None = None  # the step's info, built only for an agent that takes it
        self.world = World(self.config)
        self.video_every = int(video_every) if video else 0
        self.video_size = int(video_size)
        self._job: J.Job | None = None  # running job (None: idle)
        self._job_index = -1
        self._log: RouteLog | None = None
        self._tracker: EpisodeTracker | None = None
        self._t0 = 0.0
        self._obs: dict[str, np.ndarray] = {}
        self._make_specs()

    def _agent_info_style(self) -> str | None:
        """How the agent's ``act`` takes ``info`` (``interface.act_info_style``; ``None``: not)."""
        from v2xbench.agents.interface import act_info_style

        from .agent_process import IsolatedAgent

        if self.agent is None:
            return None
        if isinstance(self.agent, IsolatedAgent):  # its process reported the agent's signature
            return "keyword" if self.agent.takes_info else None
        return act_info_style(self.agent)

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        obs = {k: _spec(s, self.device) for k, s in ego_space(self.config).spaces.items()}
        for k, n in (("route_completion", 1), ("v2x_bps", 1), ("agent_action", 3)):
            obs[k] = Unbounded(shape=(n,), dtype=torch.float32, device=self.device)
        obs["job"] = Unbounded(shape=(1,), dtype=torch.int64, device=self.device)
        self.observation_spec = Composite(obs, shape=())
        # a protocol agent's action is its executed (3,) control (``_act`` maps its output by the
        # config's action_mode); a TorchRL policy acts in the config's action_mode
        self.action_mode = "carla" if self.agent is not None else self.config.action_mode
        m = get_mode(self.action_mode)
        self.action_spec = Bounded(low=torch.tensor(m.low), high=torch.tensor(m.high),
                                   shape=m.shape, dtype=torch.float32, device=self.device)
        self.reward_spec = Unbounded(shape=(1,), dtype=torch.float32, device=self.device)
        flag = Categorical(n=2, shape=(1,), dtype=torch.bool, device=self.device)
        self.done_spec = Composite(done=flag, terminated=flag.clone(), truncated=flag.clone(), shape=())

    def _zero_obs(self) -> dict[str, np.ndarray]:
        o = {k: _zeros(s) for k, s in ego_space(self.config).spaces.items()}
        o.update(route_completion=np.zeros(1, np.float32), v2x_bps=np.zeros(1, np.float32),
                 agent_action=np.zeros(3, np.float32))
        o["job"] = np.array([self._job_index], np.int64)
        return o

    def _observe(self) -> dict[str, np.ndarray]:
        w = self.world
        o = ego_observation(w)
        o["route_completion"] = np.array([w.monitor.route_completion], np.float32)
        sent = w.channel.stats()["bytes_sent_total"]
        o["v2x_bps"] = np.array([sent / (w.tick * w.config.dt) if w.tick else 0.0], np.float32)
        o["agent_action"] = np.zeros(3, np.float32)
        o["job"] = np.array([self._job_index], np.int64)
        return o

    def _td(self, obs: dict, reward: float = 0.0, term: bool = False, trunc: bool = False,
            with_reward: bool = True) -> TensorDictBase:
        d = obs_tensors(obs, self.device)
        flag = lambda b: torch.tensor([bool(b)], device=self.device)  # noqa: E731
        d.update(done=flag(term or trunc), terminated=flag(term), truncated=flag(trunc))
        if with_reward:
            d["reward"] = torch.tensor([reward], dtype=torch.float32, device=self.device)
        return TensorDict(d, batch_size=self.batch_size, device=self.device)

    # ------------------------------------------------------------------ jobs
    def _start(self, job: J.Job) -> None:
        """Reset the world and the agent on ``job`` and compute the first action (may raise)."""
        spec = self.routes[job.route_index]
        self._log = None
        self._t0 = time.perf_counter()
        self.world.reset(seed=J.job_seed(spec.seed, job.seed_index), spec=spec)
        self._tracker = EpisodeTracker(self.world)
        self._log = RouteLog(self.world, self.video_every, self.video_size)
        obs = self._observe()
        if self.agent is not None:
            info = route_info(self.world, spec.town, J.job_seed(spec.seed, job.seed_index))
            call_agent(self.agent.reset, info)
            if self._roadside is not None:
                call_agent(self._roadside.reset, info)
            if self.privileged:
                call_agent(self.agent.bind, self.world)
            self._info = self._tracker.info() if self._info_style else None  # the reset's info
            obs["agent_action"] = self._act(obs)
        self._obs = obs

    def _act(self, obs: dict) -> np.ndarray:
        from v2xbench.agents.interface import call_act, to_control

        view = {k: obs[k] for k in self.obs_keys}  # the Gymnasium observation, nothing more
        out = call_agent(call_act, self.agent, view, self._info, self._info_style)
        control = to_control(out, view, self.config.action_mode)
        return validate_control(control, "agent output").astype(np.float32)

    def _finish(self, ended_by: int, error: BaseException | None = None) -> None:
        """Write the running job's result and go idle."""
        job = self._job
        spec = self.routes[job.route_index]
        video = None
        if self._log is not None and self.video_every:
            try:
                video = self._log.save_video(self.out / "videos" / f"{job.job_id}.gif")
            except Exception as e:  # noqa: BLE001  (a video problem must not lose the result)
                video = f"error: {e}"
        res = build_result(
            job=job, spec=spec, seed=J.job_seed(spec.seed, job.seed_index), suite=self.suite,
            agent=self.agent_spec, agent_name=self.agent_name,
            privileged=self.privileged, agent_process=self.agent_process, log=self._log,
            ended_by=ended_by, wall_s=time.perf_counter() - self._t0, error=error, video=video,
            config=self.overrides, fingerprint=self.fingerprint)
        J.write_json_atomic(res, J.result_path(self.out, job.job_id))
        self._job, self._job_index, self._log, self._tracker = None, -1, None, None

    def fail_running_job(self, error: BaseException) -> bool:
        """Record the running job (if any) as failed with ``error``, an exception that escaped the
        env (of the collector's policy, say); returns whether a job was running."""
        if self._job is None:
            return False
        self._finish(0, error=error)
        return True

    def _next_job(self) -> None:
        """Claim and start the next free job; failed starts are recorded; idle when none is left."""
        for i, job in enumerate(self.queue):
            if J.has_result(self.out, job.job_id) or not J.try_claim(self.out, job.job_id):
                continue
            self._job, self._job_index = job, i
            try:
                self._start(job)
                return
            except Exception as e:  # noqa: BLE001  (agent or world failure: record, go on)
                self._finish(0, error=e)
        self._job, self._job_index = None, -1
        self._obs = self._zero_obs()

    # ------------------------------------------------------------------ EnvBase
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        if self._job is not None:  # a reset in the middle of a job: restart it from its seed
            try:
                self._start(self._job)
            except Exception as e:  # noqa: BLE001
                self._finish(0, error=e)
                self._next_job()
        else:
            self._next_job()
        return self._td(self._obs, with_reward=False)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self._job is None:  # idle: nothing to simulate
            return self._td(self._zero_obs(), term=True)
        w = self.world
        try:
            control = validate_action(tensordict.get("action").detach().cpu().numpy().reshape(-1),
                                      self.action_mode, "policy action")
            if self._roadside is None:
                events = w.step_builtin(control)
            else:  # the agent's roadside policy speaks for the unit (from this tick's observation)
                events = w.step(control, call_agent(self._roadside.message, w))
            reward, term, trunc, self._info = self._tracker.after_step(
                events, with_info=self._info_style is not None)
            self._log.after_step()
        except Exception as e:  # noqa: BLE001
            self._finish(0, error=e)
            return self._td(self._zero_obs(), term=True)
        obs = self._observe()
        if term or trunc:  # the terminal observation is real; agent_action stays zero
            self._finish(ended_by_code(w, term, trunc))
            return self._td(obs, reward, term, trunc)
        if self.agent is not None:
            try:
                obs["agent_action"] = self._act(obs)
            except Exception as e:  # noqa: BLE001
                self._finish(0, error=e)
                return self._td(self._zero_obs(), reward, term=True)
        self._obs = obs
        return self._td(obs, reward)

    def _set_seed(self, seed: int | None) -> None:
        """No-op: every job is seeded by its route and seed index (``jobs.job_seed``)."""

    def close(self, *args, **kwargs) -> None:
        """Release the claim of a job left unfinished (so a later run can take it)."""
        if self._job is not None:
            (J.claims_dir(self.out) / self._job.job_id).unlink(missing_ok=True)
            self._job = None
        if callable(getattr(self.agent, "close", None)) and self.agent_process == "isolated":
            self.agent.close()
        super().close(*args, **kwargs)


def make_env_factory(**kwargs: Any) -> Callable[[], EvalEnv]:
    """A picklable zero-argument factory of :class:`EvalEnv` (``functools.partial``)."""
    import functools

    return functools.partial(EvalEnv, **kwargs)
