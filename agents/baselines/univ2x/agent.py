"""The registered agent ``univ2x``: UniV2X's ego half drives, its roadside half is the unit.

``v2xbench eval --agent univ2x --agent-config univ2x.json`` with ``univ2x.json`` = ``{"run":
"runs/univ2x"}`` (a run of ``v2xbench baselines train univ2x``). The agent observes in
``sensors`` mode and declares the sensors of its training data (``camera_size`` of the data set,
``rgb`` only); its ``rsu_policy`` is :class:`~.policy.UniV2XRoadside` (the roadside half of the
same checkpoint; the message a raw payload through the channel) and it declares ``channel =
{"max_payload_floats": <the message's floats>}`` so that ``eval`` sets the env's limit
(``agents/interface.py``, "Channel"). ``checkpoint`` names the weights, ``fingerprint()`` the
scale and the target-speed rule. Each step: :meth:`~.policy.UniV2XDriver.plan` -> the shared
waypoint controller. Without a run it loads the shipped weights
(``agents/baselines/weights/univ2x``) where the repository has them.

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

from ..common.agent import BaselineAgent


class UniV2XAgent(BaselineAgent):
    """UniV2X (Yu et al., AAAI 2025) as a driver (module docstring;
    :class:`~..common.agent.BaselineAgent`)."""

    method = "univ2x"
    driver_cls, roadside_cls = "UniV2XDriver", "UniV2XRoadside"

    def _sensors(self, info: dict):
        """The sensors declaration and the setting its driver takes."""
        size = tuple(int(v) for v in info["camera_size"])
        return {"camera_size": size, "camera_images": ("rgb",)}, size


__all__ = ["UniV2XAgent"]
