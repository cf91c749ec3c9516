"""Registration of the built-in agents (imported by :func:`~.interface.load_agent`)."""

from __future__ import annotations

import numpy as np

from .aurora.agent import AuroraAgent, NoFusionAgent
from .baselines.codriving.agent import CoDrivingAgent
from .baselines.unimm_v2x.agent import UniMMV2XAgent
from .baselines.univ2x.agent import UniV2XAgent
from .baselines.v2x_vit.agent import V2XViTAgent
from .interface import register_agent
from .route_follower import RouteFollower

register_agent("route_follower")(RouteFollower)
register_agent("aurora")(AuroraAgent)  # the learned model (agents/aurora/agent.py)
register_agent("no_fusion")(NoFusionAgent)  # the same without the roadside input
register_agent("univ2x")(UniV2XAgent)  # UniV2X baseline (agents/baselines/univ2x/agent.py)
register_agent("unimm_v2x")(UniMMV2XAgent)  # UniMM-V2X (agents/baselines/unimm_v2x/agent.py)
register_agent("v2x_vit")(V2XViTAgent)  # V2X-ViT (agents/baselines/v2x_vit/agent.py)
register_agent("codriving")(CoDrivingAgent)  # CoDriving (agents/baselines/codriving/agent.py)


@register_agent("random")
class RandomAgent:
    """Uniform random controls (a lower bound for every metric)."""

    obs_mode, privileged, rsu_policy = "objects", False, "none"

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)

    def reset(self, route_info: dict) -> None:
        self.rng = np.random.default_rng(route_info.get("seed", 0))

    def act(self, obs: dict) -> np.ndarray:
        return self.rng.uniform([0.0, -1.0, 0.0], [1.0, 1.0, 1.0]).astype(np.float32)


@register_agent("constant_speed")
class ConstantSpeedAgent:
    """Follows the route at a constant speed (6 m/s by default) and ignores everything else (a
    blind baseline)."""

    obs_mode, privileged, rsu_policy = "objects", False, "none"

    def __init__(self, speed: float = 6.0) -> None:
        """``speed``: the constant speed, m/s (an ``--agent-config`` file ``{"speed": 4.0}``)."""
        number = isinstance(speed, (int, float)) and not isinstance(speed, bool)
        if not number or not 0.0 <= speed <= 30.0:
            raise ValueError(f"constant_speed: speed={speed!r} must be a number of m/s in [0, 30]")
        self.speed = float(speed)

    def reset(self, route_info: dict) -> None:
        pass

    def act(self, obs: dict) -> dict:
        return {"waypoints": obs["route"][:, :2], "speed": self.speed}
