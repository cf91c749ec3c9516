"""UniMM-V2X in closed loop: UniV2X's roadside policy and ego driver
(:mod:`..univ2x.policy`) with UniMM-V2X's message (:mod:`.message`: perception and motion
queries plus occupancy).

- **Roadside** (:class:`UniMMV2XRoadside`): the roadside half (:class:`~.model.RoadsideNet`) on
  the unit's camera every tick a unit serves the ego; the message goes out as a raw payload.
- **Ego** (:class:`UniMMV2XDriver`): the ego half on the six cameras with the received message
  (or the empty one) and ``E_{r->e}``; its waypoints and AURORA's target speed go to the shared
  waypoint controller (AURORA's, as UniV2X).
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np
import torch
from v2xbench.agents.aurora.rsu_agent import received_payload, received_pose

from ..univ2x.policy import UniV2XDriver, UniV2XRoadside
from .message import deserialize_message, empty_message, rsu_message, serialize_message


class UniMMV2XRoadside(UniV2XRoadside):
    """UniMM-V2X's roadside policy (module docstring; arguments as UniV2X's)."""

    @torch.no_grad()
    def message(self, rsu_obs: Mapping) -> dict[str, torch.Tensor]:
        """The message tensors (:func:`~.message.rsu_message`, batch 1) of one observation."""
        t0 = time.perf_counter()
        msg = rsu_message(self.branch(self.inputs(rsu_obs)), self.ucfg)
        self.infer_s += time.perf_counter() - t0
        return msg

    def act(self, rsu_obs: Mapping) -> np.ndarray:
        """The message of this tick as a raw payload (:func:`~.message.serialize_message`)."""
        payload = serialize_message(self.message(rsu_obs))
        self.messages += 1
        return payload


class UniMMV2XDriver(UniV2XDriver):
    """The ego half of a trained :class:`~.model.UniMMV2X` (module docstring; arguments as
    UniV2X's driver)."""

    def _message(self, obs: Mapping) -> tuple[dict[str, torch.Tensor], torch.Tensor, bool]:
        payload = np.asarray(obs["v2x_payload"])
        if self.fusion and payload.shape[-1] < self.need_floats:
            raise ValueError(f"UniMM-V2X: v2x_payload holds {payload.shape[-1]} floats; the "
                             f"roadside message needs {self.need_floats}: evaluate with --set "
                             f"max_payload_floats={self.need_floats}")
        raw = received_payload(obs) if self.fusion else None
        if raw is None:
            return empty_message(self.cfg, 1), torch.eye(4)[None], False
        return deserialize_message(raw, self.cfg), received_pose(obs["v2x_info"])[None], True


__all__ = ["UniMMV2XDriver", "UniMMV2XRoadside"]
