"""The registered agent ``unimm_v2x``: UniMM-V2X's ego half drives, its roadside half is the unit.

``v2xbench eval --agent unimm_v2x --agent-config unimm_v2x.json`` with ``unimm_v2x.json`` =
``{"run": "runs/unimm_v2x"}`` (a run of ``v2xbench baselines train unimm_v2x``). As UniV2X's
agent (:class:`~..univ2x.agent.UniV2XAgent`: ``sensors`` mode, the training data's camera size,
``channel = {"max_payload_floats": F}``, AURORA's waypoint controller), with UniMM-V2X's model,
roadside policy and driver. Without a run it loads the shipped weights
(``agents/baselines/weights/unimm_v2x``) where the repository has them.

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

from ..univ2x.agent import UniV2XAgent


class UniMMV2XAgent(UniV2XAgent):
    """UniMM-V2X (Song et al., AAAI 2026) as a driver (module docstring)."""

    method = "unimm_v2x"
    driver_cls, roadside_cls = "UniMMV2XDriver", "UniMMV2XRoadside"


__all__ = ["UniMMV2XAgent"]
