"""``N`` worlds stepped as one batch, with observations in preallocated ``(N, ...)`` arrays.

:class:`WorldBatch` is the core of the batched APIs: the native TorchRL env
(:class:`~.torchrl_env.V2XTorchEnv`) and the Gymnasium vector env (:class:`V2XVectorEnv`, what
``gym.make_vec("V2XIntersection-v0", num_envs=N)`` returns). Per tick it

1. validates all ``(N, D)`` actions at once (same checks and clipping as the single env; ``D``
   is 3 or 2 by ``config.action_mode``, mapped to ``(N, 3)`` controls, :mod:`.actions`);
2. advances every world by one tick with its built-in RSU policy (``World.step_builtin``, the
   fixed step order of :mod:`.world`), stage by stage: each stage (the message, the traffic's
   move, scenario hooks, events, perception, delivery) runs over all worlds before the next,
   which keeps each kernel's code and the town's tables in the CPU's caches;
3. writes each world's observation into row ``i`` of the batch buffers (no per-step stacking of
   dicts) and fills ``(N,)`` reward / terminated / truncated arrays.

A batch of ``N`` worlds gives exactly the observations, rewards and flags of ``N`` single
:class:`~.gym_env.V2XIntersectionEnv` s reset with the same seeds and driven with the same actions
(``tests/api/test_batch.py``).

What is vectorized across worlds in this version: action validation, the reward/flag arrays and
the observation buffers (with numba, in ``objects`` mode, each world's observation kernel writes
straight into its row). The world tick itself (traffic, pedestrians, scenarios, perception) runs
world after world within each stage; ``benchmarks/`` measures where the time goes.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..core.jit import HAVE_JIT
from ..core.validation import Int, check_options
from ..evaluation.episode import EpisodeTracker, v2x_bps
from ..sim.config import make_config, plain_scalar
from ..sim.jit_batch import PerceiveBatch, TrafficBatch
from ..sim.world import TICK_STAGES, StepError, World
from .actions import action_space, validate_actions
from .observations import ego_observation, ego_space, fill_objects_observation

#: worlds in one batch (each holds its own actor table, sensors and observation rows)
NUM_WORLDS_RULE = Int(1, 1024, "worlds")


def validate_controls(actions, n: int, mode: str = "carla") -> np.ndarray:
    """Check ``(n, D)`` ego actions of action ``mode`` (``config.action_mode``), clip them into
    range and map them to ``(n, 3)`` controls (``actions.validate_actions``)."""
    return validate_actions(actions, n, mode)


def _alloc(space: gym.Space, n: int):
    if isinstance(space, gym.spaces.Dict):
        return {k: _alloc(v, n) for k, v in space.spaces.items()}
    return np.zeros((n, *space.shape), space.dtype)


def _write(buf, obs, i: int) -> None:
    for k, v in obs.items():
        if isinstance(v, dict):
            _write(buf[k], v, i)
        else:
            buf[k][i] = v


def _copy(buf):
    return {k: _copy(v) if isinstance(v, dict) else v.copy() for k, v in buf.items()}


class WorldBatch:
    """``N`` :class:`~.world.World` s with shared ``(N, ...)`` observation buffers.

    Attributes:
        worlds: the worlds. trackers: their :class:`~.episode.EpisodeTracker` (``None`` before the
            first reset). obs: nested dict of ``(N, ...)`` arrays (``observations.ego_space``
            layout), row ``i`` = world ``i``'s observation of its current tick.
        reward, terminated, truncated: ``(N,)`` results of the last :meth:`step`.
        route_completion, v2x_bps: ``(N,)`` float32 route completion (%) and V2X bytes per
            simulated second of each world's episode so far (after the last reset or step).
        infos: per-world info dicts of the last reset/step (``episode.EpisodeTracker.info``;
            with ``with_infos=False`` only resets refresh them).
    """

    def __init__(self, num_worlds: int, config=None, with_infos: bool = True, **kwargs: Any) -> None:
        NUM_WORLDS_RULE.check(num_worlds, "num_worlds")
        self.config = make_config(config, **kwargs)
        self.n = num_worlds
        self.worlds = [World(self.config) for _ in range(num_worlds)]
        self.trackers: list[EpisodeTracker | None] = [None] * num_worlds
        self.space = ego_space(self.config)
        self.obs = _alloc(self.space, num_worlds)
        self.reward = np.zeros(num_worlds, np.float64)
        self.terminated = np.zeros(num_worlds, bool)
        self.truncated = np.zeros(num_worlds, bool)
        self.route_completion = np.zeros(num_worlds, np.float32)  # percent, after the last reset/step
        self.v2x_bps = np.zeros(num_worlds, np.float32)  # bytes sent / simulated seconds of the episode
        self.infos: list[dict] = [{} for _ in range(num_worlds)]
        self.with_infos = with_infos  # False: step() leaves ``infos`` as they were (TorchRL reads none)
        # objects mode with numba: the observation kernel writes straight into row views of the buffers
        direct = HAVE_JIT and self.config.obs_mode == "objects"
        self._rows = [{k: v[i] for k, v in self.obs.items()} for i in range(num_worlds)] if direct else None
        # with numba, the traffic's move of all worlds is one kernel call (jit_batch)
        self._traffic = TrafficBatch(self.worlds) if HAVE_JIT and num_worlds > 1 else None
        self._perceive = PerceiveBatch(self.worlds) if HAVE_JIT and num_worlds > 1 else None

    def __getstate__(self) -> dict:
        """For copy and pickle: without the jit_batch holders (numba's typed lists cannot be
        pickled); :meth:`__setstate__` makes new ones over the copied worlds, and new row views of
        the copied observation buffers."""
        state = self.__dict__.copy()
        state["_traffic"] = state["_perceive"] = None
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if self._rows is not None:  # row views of the copy's own buffers (a copied view is not a view)
            self._rows = [{k: v[i] for k, v in self.obs.items()} for i in range(self.n)]
        many = HAVE_JIT and self.n > 1
        self._traffic = TrafficBatch(self.worlds) if many else None
        self._perceive = PerceiveBatch(self.worlds) if many else None

    def _observe(self, i: int) -> None:
        """Write world ``i``'s observation into row ``i`` of the buffers."""
        if self._rows is not None:
            fill_objects_observation(self.worlds[i], self._rows[i])
        else:
            _write(self.obs, ego_observation(self.worlds[i]), i)

    def reset_world(self, i: int, seed: int | None = None, **episode: Any) -> None:
        """Reset world ``i`` (``episode``: ``route``/``scenarios``/``spec`` of ``World.reset``)."""
        w = self.worlds[i]
        w.reset(seed=seed, **episode)
        self.trackers[i] = EpisodeTracker(w)
        self._observe(i)
        self.reward[i], self.terminated[i], self.truncated[i] = 0.0, False, False
        self.infos[i] = self.trackers[i].info()
        self._progress(i)

    def _progress(self, i: int) -> None:
        """Refresh world ``i``'s ``route_completion`` and ``v2x_bps``."""
        w = self.worlds[i]
        self.route_completion[i] = w.monitor.route_completion
        self.v2x_bps[i] = v2x_bps(w)

    def reset(self, seeds, mask=None) -> None:
        """Reset the worlds where ``mask (N,)`` is true (all by default) with ``seeds[i]``."""
        mask = np.ones(self.n, bool) if mask is None else np.asarray(mask, bool).reshape(self.n)
        for i in np.flatnonzero(mask):
            self.reset_world(int(i), None if seeds[i] is None else int(seeds[i]))

    def step(self, actions, active=None) -> None:
        """Advance the worlds (those where ``active (N,)`` is true; all by default) by one tick.

        Raises:
            ValueError: bad actions (shape, dtype, NaN/inf; out-of-range values are clipped).
            StepError: a world to step was never reset (``World.step`` also raises for a world
                that has ended; the episode tracker's own end is left to the caller's resets).
        """
        controls = validate_controls(actions, self.n, self.config.action_mode)
        idx = list(range(self.n)) if active is None else [int(i) for i in np.flatnonzero(np.asarray(active, bool))]
        for i in idx:  # check them all first: a bad world raises before any world has moved
            if self.trackers[i] is None:
                raise StepError(f"world {i}: step() called before reset()")
            self.worlds[i]._check_running()
        # World.step_builtin stage by stage, each stage over all worlds before the next: the same
        # kernel back to back stays in the CPU's caches (the worlds are independent, so each one
        # sees exactly the order of its own step)
        worlds = [self.worlds[i] for i in idx]
        for w in worlds:
            w.send_builtin()
        if self._traffic is None or not self._traffic.step(idx, controls):
            for i, w in zip(idx, worlds):
                w.move_traffic(controls[i])
        for stage in TICK_STAGES[:-1]:
            for w in worlds:
                stage(w)
        if self._perceive is None or not self._perceive.step(idx):  # TICK_STAGES[-1]: World.perceive
            for w in worlds:
                TICK_STAGES[-1](w)
        events = [w.deliver() for w in worlds]
        for i, ev in zip(idx, events):
            r, te, tc, info = self.trackers[i].after_step(ev, self.with_infos)
            self.reward[i], self.terminated[i], self.truncated[i] = r, te, tc
            if info is not None:
                self.infos[i] = info
            self._progress(i)
        for i in idx:
            self._observe(i)

    def copy_obs(self) -> dict:
        """A copy of the observation buffers (the buffers are overwritten by the next step)."""
        return _copy(self.obs)


class V2XVectorEnv(VectorEnv):
    """Gymnasium vector env over a :class:`WorldBatch` (``gym.make_vec``'s vector entry point).

    ``gym.make_vec("V2XIntersection-v0", num_envs=N, **config)`` builds it (``vectorization_mode``
    ``"sync"``/``"async"`` still give Gymnasium's wrappers of ``N`` single envs). Autoreset is
    Gymnasium's default ``NEXT_STEP`` mode: the step after an episode ends resets that world
    (reward 0, not done) and ignores its action. Seeding: ``reset(seed=s)`` resets world ``i``
    with seed ``s + i`` (a list gives each world its own); the same seeds make the same episodes
    as single envs. Infos are Gymnasium's batched dicts (``info[key]`` arrays plus ``_key``
    masks).
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, render_mode: str | None = None, **config: Any) -> None:
        if render_mode is not None:
            raise ValueError("V2XVectorEnv does not render; use gym.make for render_mode='rgb_array'")
        self.batch = WorldBatch(num_envs, **config)
        self.num_envs = num_envs
        self.config = self.batch.config
        self.single_observation_space = self.batch.space
        self.single_action_space = action_space(self.config.action_mode)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.render_mode = None
        self._autoreset = np.zeros(num_envs, bool)
        self._seed_rng = np.random.default_rng(self.config.seed)

    def _infos(self) -> dict:
        infos: dict = {}
        for i, info in enumerate(self.batch.infos):
            infos = self._add_info(infos, info, i)
        return infos

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        n = self.num_envs
        seed = plain_scalar(seed)  # a NumPy integer is an int seed
        if seed is None:
            seeds = [int(s) for s in self._seed_rng.integers(2**31, size=n)]
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(n)]
        else:
            if len(seed) != n:
                raise ValueError(f"reset: {len(seed)} seeds for {n} worlds")
            seeds = [int(s) if s is not None else int(self._seed_rng.integers(2**31)) for s in seed]
        options = check_options(options, ("reset_mask",), "V2XVectorEnv.reset")
        mask = None
        if "reset_mask" in options:
            mask = np.asarray(options["reset_mask"])
            if mask.shape != (n,) or mask.dtype != bool:
                raise ValueError(f"V2XVectorEnv.reset: options['reset_mask'] must be a bool "
                                 f"array of shape ({n},), got {mask.dtype} {mask.shape}")
        self.batch.reset(seeds, mask)
        self._autoreset[:] = False if mask is None else self._autoreset & ~mask
        return self.batch.copy_obs(), self._infos()

    def step(self, actions):
        b = self.batch
        again = self._autoreset.copy()
        b.step(actions, active=~again)
        for i in np.flatnonzero(again):
            b.reset_world(int(i), int(self._seed_rng.integers(2**31)))
        self._autoreset = b.terminated | b.truncated
        return (b.copy_obs(), b.reward.copy(), b.terminated.copy(), b.truncated.copy(), self._infos())


__all__ = ["V2XVectorEnv", "WorldBatch", "validate_controls"]
