"""Native TorchRL environment over ``N`` worlds (``batch_size=[N]``), single agent (the ego).

Specs (all float32 unless noted, leading dim ``N``): observation keys as
``observations.ego_space`` (``ego``, ``route``, ``objects``, ``v2x_objects``, ``v2x_info``,
``v2x_payload``) plus
``route_completion (1,)`` and ``v2x_bps (1,)``; ``action`` bounded, by ``config.action_mode``
(:mod:`.actions`): ``(3,)`` throttle, steer, brake (``carla``) or ``(2,)`` accel, steer
(``accel_steer``);
``reward (1,)``; ``done``/``terminated``/``truncated (1,)`` bool; ``info``, the episode
information of the Gymnasium env's ``info`` (collisions, infractions and every event count, the
reward terms, route completion, channel statistics; :data:`INFO_SPECS`). The RSU runs the built-in
``config.rsu_policy``. Partial resets follow TorchRL's ``"_reset"`` mask; as in Gymnasium, stepping
a world whose episode ended without resetting it raises ``StepError``, and ``reset`` refuses
arguments and options it does not take. Seeding: ``set_seed``
seeds a generator from which every world's reset seeds are drawn, so a run is reproducible.

The worlds live in one :class:`~.batch.WorldBatch`: actions are validated as one ``(N, D)``
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

from ..core.validation import check_options
from ..evaluation.episode import COLLISIONS, INFRACTIONS, REWARD_WEIGHTS
from ..evaluation.infractions import NUM_EVENTS
from ..sim.config import make_config
from ..sim.world import StepError
from .actions import get_mode
from .batch import NUM_WORLDS_RULE, WorldBatch
from .observations import ego_space

#: the keys ``reset(options=...)`` takes (none yet: every world draws its episode from its seed)
RESET_OPTIONS: tuple[str, ...] = ()

_EXTRA = ("route_completion", "v2x_bps")

_F, _I = torch.float64, torch.int64
#: the ``"info"`` entry of every reset and step TensorDict, ``key: (dtype, width)``, each an
#: ``(N, width)`` tensor: every key of the Gymnasium env's ``info``
#: (``episode.EpisodeTracker.info``, the same values; floats as float64, counts as int64), then
#: ``collisions`` and ``infractions``, the episode's counts of the events of
#: ``episode.COLLISIONS`` and ``episode.INFRACTIONS``
INFO_SPECS: dict[str, tuple[torch.dtype, int]] = {
    "tick": (_I, 1), "route_completion": (_F, 1), "route_length": (_F, 1), "speed": (_F, 1),
    "events": (_I, NUM_EVENTS), "outside_lanes_m": (_F, 1), "driven_m": (_F, 1),
    "active_rsu": (_I, 1), "v2x_bytes_total": (_I, 1), "v2x_bps": (_F, 1), "v2x_peak_bps": (_F, 1),
    "v2x_messages_lost": (_I, 1), "v2x_messages_dropped": (_I, 1),
    **{f"reward_{term}": (_F, 1) for term in REWARD_WEIGHTS},
    "collisions": (_I, 1), "infractions": (_I, 1),
}
_DERIVED = {"collisions": list(COLLISIONS), "infractions": list(INFRACTIONS)}


class _InfoRows:
    """``(N, width)`` NumPy buffers of :data:`INFO_SPECS`, filled from the worlds' info dicts."""

    def __init__(self, n: int) -> None:
        self.buf = {k: np.zeros((n, w), torch.empty(0, dtype=dt).numpy().dtype)
                    for k, (dt, w) in INFO_SPECS.items()}

    def fill(self, infos: list[dict], rows) -> None:
        """Write the info dicts of worlds ``rows`` into their buffer rows (one write per key)."""
        rows = list(rows)
        sub = [infos[i] for i in rows]
        for k, col in self.buf.items():  # "events" comes before the counts derived from it
            if k in _DERIVED:
                col[rows, 0] = self.buf["events"][rows][:, _DERIVED[k]].sum(1)
            elif col.shape[1] == 1:
                col[rows, 0] = [d[k] for d in sub]
            else:
                col[rows] = [d[k] for d in sub]


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

    def __init__(self, num_worlds: int = 1, device: str | torch.device = "cpu", info: bool = True,
                 **config: Any) -> None:
        """``info=False`` leaves out the ``"info"`` entry (:data:`INFO_SPECS`) for throughput runs:
        its 19 tensors cost ~0.4 ms per step, mostly TorchRL's per-key handling (measured on 2
        shared cores: 2.1 against 1.7 ms per step of 16 worlds in ``objects`` mode)."""
        NUM_WORLDS_RULE.check(num_worlds, "num_worlds")
        if not isinstance(info, bool):
            raise ValueError(f"V2XTorchEnv: info must be True or False, got {info!r}")
        super().__init__(batch_size=torch.Size([num_worlds]), device=device)
        self.config = make_config(**config)
        self.batch = WorldBatch(num_worlds, self.config, with_infos=info)
        self._seed_rng = np.random.default_rng(self.config.seed)
        self._started = np.zeros(num_worlds, bool)
        n = num_worlds
        obs = _spec(ego_space(self.config), n, self.device)
        for k in _EXTRA:
            obs[k] = Unbounded(shape=(n, 1), dtype=torch.float32, device=self.device)
        self._info = _InfoRows(n) if info else None
        if info:
            obs["info"] = Composite({k: Unbounded(shape=(n, w), dtype=dt, device=self.device)
                                     for k, (dt, w) in INFO_SPECS.items()},
                                    shape=(n,), device=self.device)
        self.observation_spec = obs
        mode = get_mode(self.config.action_mode)
        d = len(mode.fields)
        self.action_spec = Bounded(low=torch.tensor(mode.low).expand(n, d),
                                   high=torch.tensor(mode.high).expand(n, d),
                                   shape=(n, d), dtype=torch.float32, device=self.device)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32, device=self.device)
        flag = Categorical(n=2, shape=(n, 1), dtype=torch.bool, device=self.device)
        self.done_spec = Composite(done=flag, terminated=flag.clone(), truncated=flag.clone(), shape=(n,))

    @property
    def worlds(self) -> list:
        """The ``N`` worlds (``self.batch.worlds``)."""
        return self.batch.worlds

    def _outputs(self, rows=None) -> dict:
        """The observation tensors, ``info`` included (refreshed for worlds ``rows``; all by
        default)."""
        b = self.batch
        extra = {k: getattr(b, k)[:, None] for k in _EXTRA}
        if self._info is not None:
            self._info.fill(b.infos, range(b.n) if rows is None else rows)
            extra["info"] = self._info.buf
        return _tensors({**b.obs, **extra}, self.device)

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
        out = self._outputs(rows)
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
