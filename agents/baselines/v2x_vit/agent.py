"""The registered agent ``v2x_vit``: V2X-ViT's ego half drives, its roadside half is the unit.

``v2xbench eval --agent v2x_vit --agent-config v2x_vit.json`` with ``v2x_vit.json`` = ``{"run":
"runs/v2x_vit"}`` (a run of ``v2xbench baselines train v2x_vit``). The agent observes in
``sensors`` mode and declares the sensors of its training data: no camera images and the data
set's ``lidar_scale`` (``agents/interface.py``, "Sensors"); its ``rsu_policy`` is
:class:`~.policy.V2XViTRoadside` (the roadside half of the same checkpoint; the message a raw
payload through the channel) and it declares ``channel = {"max_payload_floats": <the message's
floats>}`` so that ``eval`` sets the env's limit. ``checkpoint`` names the weights,
``fingerprint()`` the scale and the target-speed rule. Each step:
:meth:`~.policy.V2XViTDriver.plan` -> the shared waypoint controller (V2X-ViT is a perception
method; its waypoints come from a simple waypoint head, docs/baselines.md). Without a run it
loads the shipped weights (``agents/baselines/weights/v2x_vit``) where the repository has them.

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

from ..common.agent import BaselineAgent


class V2XViTAgent(BaselineAgent):
    """V2X-ViT (Xu et al., ECCV 2022) as a driver (module docstring;
    :class:`~..common.agent.BaselineAgent`)."""

    method = "v2x_vit"
    driver_cls, roadside_cls = "V2XViTDriver", "V2XViTRoadside"

    def _sensors(self, info: dict):
        """The sensors declaration and the setting its driver takes."""
        scale = float(info["lidar_scale"])
        return {"camera_images": (), "lidar_scale": scale}, scale


__all__ = ["V2XViTAgent"]
