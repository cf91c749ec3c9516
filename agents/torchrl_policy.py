"""Adapter: a TorchRL / tensordict policy as a V2XBench agent.

Any ``TensorDictModule`` (or callable ``TensorDict -> TensorDict``) whose ``in_keys`` are
observation keys (``"ego"``, ``"route"``, ``"objects"``, ``"v2x_objects"``, ... of the chosen
``obs_mode``; nested keys as tuples for the sensors mode) drives through the agent interface::

    from tensordict.nn import TensorDictModule
    policy = TensorDictModule(my_net, in_keys=["ego", "route"], out_keys=["action"])
    agent = TensorDictPolicyAgent(policy)              # "action": (3,) throttle, steer, brake
    agent = TensorDictPolicyAgent(policy, waypoints=True)  # "action": (K*2,) ego-frame waypoints

``v2xbench eval`` accepts such an agent from a file (``--agent file.py:ClassName`` with a class
that builds its policy in ``__init__``) or as an instance passed to
:func:`v2xbench.collectors.evaluate.evaluate`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDict


def obs_tensors(obs: dict, device: str | torch.device = "cpu") -> dict:
    """(Nested) NumPy observation dict -> (nested) dict of tensors."""
    return {k: obs_tensors(v, device) if isinstance(v, dict) else torch.as_tensor(np.asarray(v), device=device)
            for k, v in obs.items()}


def obs_to_tensordict(obs: dict, device: str | torch.device = "cpu") -> TensorDict:
    """A batch-of-one ``TensorDict`` from an observation dict (NumPy arrays, nested dicts)."""
    return TensorDict(obs_tensors(obs, device), batch_size=[], device=device).unsqueeze(0)


class TensorDictPolicyAgent:
    """Wraps a tensordict policy (see module docstring).

    Args:
        policy: ``TensorDictModule`` or callable ``TensorDict -> TensorDict``.
        action_key: output key read after the call.
        waypoints: the output is ``(K * 2,)`` or ``(K, 2)`` ego-frame waypoints (0.5 s apart),
            followed by the shared waypoint controller; otherwise ``(3,)`` controls.
        obs_mode, rsu_policy: as in the agent interface.
        device: where observations are put.
    """

    privileged = False

    def __init__(
        self,
        policy: Any,
        action_key: str | tuple[str, ...] = "action",
        waypoints: bool = False,
        obs_mode: str = "objects",
        rsu_policy: str = "share_objects",
        device: str | torch.device = "cpu",
    ) -> None:
        self.policy, self.action_key, self.waypoints = policy, action_key, waypoints
        self.obs_mode, self.rsu_policy, self.device = obs_mode, rsu_policy, device

    def reset(self, route_info: dict) -> None:
        """A new route: a recurrent policy with a ``reset`` method is reset."""
        if callable(getattr(self.policy, "reset", None)):
            self.policy.reset()

    @torch.no_grad()
    def act(self, obs: dict, info: dict | None = None) -> np.ndarray | dict:
        """Run the policy on ``obs``; an action (``(3,)``, or ``(2,)`` under ``action_mode=
        "accel_steer"``; checked by ``interface.to_control``) or ``{"waypoints": (K, 2)}``.
        With the step's ``info`` the policy also sees ``route_completion`` and ``v2x_bps`` as
        ``(1,)`` entries, as in ``V2XTorchEnv``'s observation."""
        if info is not None:
            extra = [k for k in ("route_completion", "v2x_bps") if k in info and k not in obs]
            obs = {**obs, **{k: np.array([info[k]], np.float32) for k in extra}}
        out = self.policy(obs_to_tensordict(obs, self.device))
        if self.action_key not in out.keys(include_nested=True):
            raise KeyError(f"policy output has no {self.action_key!r} (keys: {list(out.keys(True))})")
        a = out.get(self.action_key)[0].detach().cpu().numpy().astype(np.float32)
        if not np.all(np.isfinite(a)):
            raise ValueError(f"policy output {self.action_key!r} contains NaN or inf")
        if self.waypoints:
            return {"waypoints": a.reshape(-1, 2)}
        return a.reshape(-1)
