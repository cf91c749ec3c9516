"""Native TorchRL environment over ``N`` worlds (``batch_size=[N]``), single agent (the ego).

Specs (all float32 unless noted, leading dim ``N``): observation keys as
``observations.ego_space`` (``ego``, ``route``, ``objects``, ``v2x_objects``, ``v2x_info``) plus
``route_completion (1,)`` and ``v2x_bps (1,)``; ``action (3,)`` bounded (throttle, steer, brake);
``reward (1,)``; ``done``/``terminated``/``truncated (1,)`` bool. The RSU runs the built-in
``config.rsu_policy``. Partial resets follow TorchRL's ``"_reset"`` mask; as in Gymnasium, stepping
a world whose episode ended without resetting it raises ``StepError``, and ``reset`` refuses
arguments and options it does not take. Seeding: ``set_seed``
seeds a generator from which every world's reset seeds are drawn, so a run is reproducible.

The worlds live in one :class:`~.batch.WorldBatch`: actions are validated as one ``(N, 3)``
array and observations are written into preallocated ``(N, ...)`` buffers that become the output
tensors (one copy per key, no per-world dict stacking). For several processes wrap it in TorchRL's
``MultiSyncCollector`` (``benchmarks/suite.py`` measures both).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from .batch import NUM_WORLDS_RULE, WorldBatch
from .config import make_config
from .observations import ego_space
from .validation import check_options
from .world import StepError

#: the keys ``reset(options=...)`` takes (none yet: every world draws its episode from its seed)
RESET_OPTIONS: tuple[str, ...] = ()

_EXTRA = ("route_completion", "v2x_bps")


def _spec(space, n: int, device) -> Composite | Unbounded:
    """A TorchRL spec with leading batch dim ``n`` mirroring a Gymnasium ``Dict``/``Box`` space."""
    if hasattr(space, "spaces"):
        return Composite({k: _spec(v, n, device) for k, v in space.spaces.items()}, shape=(n,), device=device)
    dtype = torch.from_numpy(np.zeros(0, space.dtype)).dtype
    return Unbounded(shape=(n, *space.shape), dtype=dtype, device=device)


def _tensors(buf: dict, device) -> dict:
    """Copy (nested) ``(N, ...)`` NumPy buffers into (nested) tensors (a NumPy copy wrapped by
    ``torch.from_numpy`` costs a third of ``torch.tensor``'s)."""
    cpu = torch.device(device).type == "cpu"
    return {k: _tensors(v, device) if isinstance(v, dict)
            else torch.from_numpy(v.copy()) if cpu else torch.tensor(v, device=device) for k, v in buf.items()}


class V2XTorchEnv(EnvBase):
    """Batched V2XIntersection worlds as one TorchRL ``EnvBase`` (see module docstring)."""

    batch_locked = True

    def __init__(self, num_worlds: int = 1, device: str | torch.device = "cpu", **config: Any) -> None:
        NUM_WORLDS_RULE.check(num_worlds, "num_worlds")
        super().__init__(batch_size=torch.Size([num_worlds]), device=device)
        self.config = make_config(**config)
        self.batch = WorldBatch(num_worlds, self.config, with_infos=False)
        self._seed_rng = np.random.default_rng(self.config.seed)
        self._started = np.zeros(num_worlds, bool)
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

    @property
    def worlds(self) -> list:
        """The ``N`` worlds (``self.batch.worlds``)."""
        return self.batch.worlds

    def _outputs(self) -> dict:
        b = self.batch
        return _tensors({**b.obs, **{k: getattr(b, k)[:, None] for k in _EXTRA}}, self.device)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        options = kwargs.pop("options", None)
        if kwargs:
            names = ", ".join(map(repr, sorted(kwargs)))
            raise ValueError(f"V2XTorchEnv.reset: unknown argument(s) {names} (it takes a "
                             "tensordict with a '_reset' mask; seed with set_seed())")
        check_options(options, RESET_OPTIONS, "V2XTorchEnv.reset")
        n = self.batch_size[0]
        mask = np.ones(n, bool)
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(n).cpu().numpy().astype(bool)
        mask |= ~self._started
        rows = np.flatnonzero(mask)
        for i in rows:
            self.batch.reset_world(int(i), int(self._seed_rng.integers(2**31)))
        self._started |= mask
        out = self._outputs()
        false = torch.zeros(n, 1, dtype=torch.bool, device=self.device)
        return TensorDict({**out, "done": false, "terminated": false.clone(), "truncated": false.clone()},
                          batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        n = self.batch_size[0]
        b = self.batch
        ended = [i for i, tr in enumerate(b.trackers) if tr is not None and tr.done]
        if ended:
            raise StepError(f"world {ended[0]}: step() called after the episode ended; reset it "
                            "first (env.reset(), or a '_reset' mask as step_and_maybe_reset does)")
        actions = tensordict.get("action").detach().cpu().numpy()
        b.step(actions)  # checked and clipped there
        out = self._outputs()
        t = lambda a: torch.as_tensor(a, device=self.device)  # noqa: E731
        term, trunc = b.terminated.reshape(n, 1).copy(), b.truncated.reshape(n, 1).copy()
        return TensorDict({**out, "reward": t(b.reward.astype(np.float32).reshape(n, 1)), "done": t(term | trunc),
                           "terminated": t(term), "truncated": t(trunc)},
                          batch_size=self.batch_size, device=self.device)

    def _set_seed(self, seed: int | None) -> None:
        self._seed_rng = np.random.default_rng(seed)
