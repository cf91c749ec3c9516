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

from ..univ2x.policy import UniV2XDriver, UniV2XRoadside
from . import message as unimm_message


class UniMMV2XRoadside(UniV2XRoadside):
    """UniMM-V2X's roadside policy (module docstring; arguments as UniV2X's): its message."""

    wire = unimm_message


class UniMMV2XDriver(UniV2XDriver):
    """The ego half of a trained :class:`~.model.UniMMV2X` (module docstring; arguments as
    UniV2X's driver): its message."""

    title, wire = "UniMM-V2X", unimm_message


__all__ = ["UniMMV2XDriver", "UniMMV2XRoadside"]
