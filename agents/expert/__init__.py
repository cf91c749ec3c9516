"""The privileged expert driver and its restricted oracles (see :mod:`.planner`).

Registered agent names (import this package to register them):

- ``expert``: :class:`Expert`, the rule planner over every actor (privileged ground truth);
- ``oracle_ego``: :class:`EgoOnlyOracle`, the same planner on what the ego sees (+ 2 s memory);
- ``oracle_v2x``: :class:`V2XOracle`, that plus the objects received from the RSU;
- ``cautious_ego``: :class:`~.cautious.CautiousEgo`, the ego-only oracle slowing past standing
  large vehicles it sees (the fair ego-only reference);
- ``stop_and_wait_ego``: :class:`~.cautious.StopAndWaitEgo`, the ego-only oracle standing 5 s
  before each standing large vehicle it sees (a fairness check: it must gain nothing);
- ``wary_ego``: :class:`~.wary.WaryEgo`, ``cautious_ego`` slowing past every standing vehicle it
  sees, parked cars too (what caution alone buys, and its cost in time).
"""

from __future__ import annotations

from ..interface import AGENTS, register_agent
from .agents import EgoOnlyOracle, Expert, V2XOracle
from .cautious import CautiousEgo, StopAndWaitEgo
from .objects import Objects
from .planner import Plan, Planner, PlannerParams
from .wary import WaryEgo

for _name, _cls in (("expert", Expert), ("oracle_ego", EgoOnlyOracle), ("oracle_v2x", V2XOracle),
                    ("cautious_ego", CautiousEgo), ("stop_and_wait_ego", StopAndWaitEgo),
                    ("wary_ego", WaryEgo)):
    if _name not in AGENTS:
        register_agent(_name)(_cls)

__all__ = ["CautiousEgo", "EgoOnlyOracle", "Expert", "Objects", "Plan", "Planner", "PlannerParams",
           "StopAndWaitEgo", "V2XOracle", "WaryEgo"]
