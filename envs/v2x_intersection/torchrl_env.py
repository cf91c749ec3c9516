"""Native TorchRL environment over ``N`` worlds (``batch_size=[N]``), single agent (the ego).

Specs (all float32 unless noted, leading dim ``N``): observation keys as
``observations.ego_space`` (``ego``, ``route``, ``objects``, ``v2x_objects``, ``v2x_info``) plus
``route_completion (1,)`` and ``v2x_bps (1,)``; ``action (3,)`` bounded (throttle, steer, brake);
``reward (1,)``; ``done``/``terminated``/``truncated (1,)`` bool. The RSU runs the built-in
``config.rsu_policy``. Partial resets follow TorchRL's ``"_reset"`` mask. Seeding: ``set_seed``
seeds a generator from which every world's reset seeds are drawn, so a run is reproducible.

The worlds are stepped one after another in this version; see ``benchmarks/`` for throughput.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from .config import make_config
from .episode import EpisodeTracker
from .observations import ego_observation, ego_space, validate_control
from .world import World

_EXTRA = ("route_completion", "v2x_bps")


def _spec(space, n: int, device) -> Composite | Unbounded:
    """A TorchRL spec with leading batch dim ``n`` mirroring a Gymnasium ``Dict``/``Box`` space."""
    if hasattr(space, "spaces"):
        return Composite({k: _spec(v, n, device) for k, v in space.spaces.items()}, shape=(n,), device=device)
    dtype = torch.from_numpy(np.zeros(0, space.dtype)).dtype
    return Unbounded(shape=(n, *space.shape), dtype=dtype, device=device)


def _stack_nested(per_world: list[dict], device) -> dict:
    """Stack a list of (nested) observation dicts into (nested) tensors."""
    out = {}
    for k, v in per_world[0].items():
        if isinstance(v, dict):
            out[k] = _stack_nested([o[k] for o in per_world], device)
        else:
            out[k] = torch.as_tensor(np.stack([o[k] for o in per_world]), device=device)
    return out


class V2XTorchEnv(EnvBase):
    """Batched V2XIntersection worlds as one TorchRL ``EnvBase`` (see module docstring)."""

    batch_locked = True

    def __init__(self, num_worlds: int = 1, device: str | torch.device = "cpu", **config: Any) -> None:
        if not isinstance(num_worlds, int) or num_worlds < 1:
            raise ValueError(f"num_worlds={num_worlds!r} must be a positive int")
        super().__init__(batch_size=torch.Size([num_worlds]), device=device)
        self.config = make_config(**config)
        self.worlds = [World(self.config) for _ in range(num_worlds)]
        self.trackers: list[EpisodeTracker | None] = [None] * num_worlds
        self._seed_rng = np.random.default_rng(self.config.seed)
        self._last_obs: list[dict | None] = [None] * num_worlds
        n = num_worlds
        obs = _spec(ego_space(self.config), n, self.device)
        for k in _EXTRA:
            obs[k] = Unbounded(shape=(n, 1), dtype=torch.float32, device=self.device)
        self.observation_spec = obs
        self.action_spec = Bounded(low=torch.tensor([0.0, -1.0, 0.0]).expand(n, 3),
                                   high=torch.tensor([1.0, 1.0, 1.0]).expand(n, 3),
                                   shape=(n, 3), dtype=torch.float32, device=self.device)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32, device=self.device)
        flag = Categorical(n=2, shape=(n, 1), dtype=torch.bool, device=self.device)
        self.done_spec = Composite(done=flag, terminated=flag.clone(), truncated=flag.clone(), shape=(n,))

    def _obs(self, i: int) -> dict:
        w = self.worlds[i]
        o = ego_observation(w)
        o["route_completion"] = np.array([w.monitor.route_completion], np.float32)
        bytes_sent = w.channel.stats()["bytes_sent_total"]
        o["v2x_bps"] = np.array([bytes_sent / (w.tick * w.config.dt) if w.tick else 0.0], np.float32)
        self._last_obs[i] = o
        return o

    def _stack(self, per_world: list[dict]) -> dict:
        return _stack_nested(per_world, self.device)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n = self.batch_size[0]
        mask = np.ones(n, bool)
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(n).cpu().numpy().astype(bool)
        for i in range(n):
            if mask[i] or self._last_obs[i] is None:
                self.worlds[i].reset(seed=int(self._seed_rng.integers(2**31)))
                self.trackers[i] = EpisodeTracker(self.worlds[i])
                self._obs(i)
        out = self._stack(self._last_obs)
        false = torch.zeros(n, 1, dtype=torch.bool, device=self.device)
        return TensorDict({**out, "done": false, "terminated": false.clone(), "truncated": false.clone()},
                          batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get("action").detach().cpu().numpy()
        n = self.batch_size[0]
        reward = np.zeros((n, 1), np.float32)
        term = np.zeros((n, 1), bool)
        trunc = np.zeros((n, 1), bool)
        for i, w in enumerate(self.worlds):
            control = validate_control(actions[i], f"action[{i}]")
            events = w.step(control, w.default_rsu_message())
            r, te, tr, _ = self.trackers[i].after_step(events)
            reward[i, 0], term[i, 0], trunc[i, 0] = r, te, tr
            self._obs(i)
        out = self._stack(self._last_obs)
        t = lambda a: torch.as_tensor(a, device=self.device)  # noqa: E731
        return TensorDict({**out, "reward": t(reward), "done": t(term | trunc), "terminated": t(term),
                           "truncated": t(trunc)}, batch_size=self.batch_size, device=self.device)

    def _set_seed(self, seed: int | None) -> None:
        self._seed_rng = np.random.default_rng(seed)
