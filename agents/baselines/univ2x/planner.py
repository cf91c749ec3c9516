"""UniV2X's query-based planner (UniAD's planning head, which UniV2X keeps).

One ego query: a learned embedding plus the navigation command's embedding plus an MLP of the
ego's speed (0 with ``plan_ego_speed`` off) and the route points ahead
(:func:`~v2xbench.agents.aurora.route_input.route_points_ahead`; AURORA's planner input, a
deviation from the paper, whose nuScenes-style planner reads the command alone). Each of
``cfg.plan_layers`` post-norm layers lets it attend to the fused agent queries (position
embedding of their ego-frame references, padding masked), then to the fused BEV tokens, then an
FFN; an MLP gives ``T`` displacement steps whose cumulative sum are the ``T`` waypoints (ego
frame, ``cfg.plan_dt`` apart). With ``cfg.plan_frame = "route"`` the steps are AURORA's
route-relative ones (along the observed route, never backwards, and across it;
:func:`~v2xbench.agents.aurora.route_input.route_to_ego`), a deviation from the paper that gives
the baseline the output frame that makes AURORA's planner follow the route.
"""

from __future__ import annotations

import torch
from torch import nn
from v2xbench.agents.aurora.det_decoder import mlp

from ..common.plan_frame import planner_speed, steps_to_waypoints
from .config import UniV2XConfig


class PlanLayer(nn.Module):
    """Post-norm: attention to agents, attention to the BEV, FFN."""

    def __init__(self, width: int, heads: int, ffn: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.agents = nn.MultiheadAttention(width, heads, dropout=dropout, batch_first=True)
        self.bev = nn.MultiheadAttention(width, heads, dropout=dropout, batch_first=True)
        self.ffn = nn.Sequential(nn.Linear(width, ffn), nn.ReLU(), nn.Linear(ffn, width))
        self.norms = nn.ModuleList(nn.LayerNorm(width) for _ in range(3))

    def forward(self, x: torch.Tensor, agents: torch.Tensor, agent_pos: torch.Tensor,
                agent_mask: torch.Tensor, bev: torch.Tensor, bev_pos: torch.Tensor
                ) -> torch.Tensor:
        """``x`` ``(B, 1, D)``; agents / agent_pos ``(B, N, D)``, agent_mask ``(B, N)`` True =
        valid (at least one per row); bev / bev_pos ``(B, S, D)``."""
        y = self.agents(x, agents + agent_pos, agents, key_padding_mask=~agent_mask,
                        need_weights=False)[0]
        x = self.norms[0](x + y)
        x = self.norms[1](x + self.bev(x, bev + bev_pos, bev, need_weights=False)[0])
        return self.norms[2](x + self.ffn(x))


class QueryPlanner(nn.Module):
    """Ego query -> ``(B, T, 2)`` waypoints (module docstring)."""

    def __init__(self, cfg: UniV2XConfig) -> None:
        super().__init__()
        d = cfg.width
        self.cfg = cfg
        self.query = nn.Parameter(torch.randn(1, 1, d) * 0.02)
        self.command = nn.Embedding(cfg.num_commands, d)
        self.state = mlp([1 + 2 * cfg.plan_route_points, d, d])
        self.layers = nn.ModuleList(PlanLayer(d, cfg.heads, cfg.ffn, cfg.dropout)
                                    for _ in range(cfg.plan_layers))
        self.head = mlp([d, d, 2 * cfg.plan_waypoints])

    def forward(self, agents: torch.Tensor, agent_pos: torch.Tensor, agent_mask: torch.Tensor,
                bev: torch.Tensor, bev_pos: torch.Tensor, command: torch.Tensor,
                speed: torch.Tensor, route: torch.Tensor, path: torch.Tensor | None = None
                ) -> torch.Tensor:
        """Waypoints ``(B, T, 2)`` (m, ego frame) from the fused agents, the fused BEV tokens,
        the command ``(B,)``, the speed ``(B,)`` (m/s) and the route points ``(B, R, 2)``; in
        the route frame also the route polyline ``path`` ``(B, N, 2)`` (batch key
        ``route_path``)."""
        b = agents.shape[0]
        cmd = command.long().clamp(0, self.cfg.num_commands - 1)
        speed = planner_speed(speed, self.cfg)  # 0 m/s with plan_ego_speed off
        state = torch.cat([speed.float()[:, None] / 10.0, route.float().flatten(1) / 20.0], -1)
        x = self.query.expand(b, -1, -1) + self.command(cmd)[:, None] + self.state(state)[:, None]
        for layer in self.layers:
            x = layer(x, agents, agent_pos, agent_mask, bev, bev_pos)
        steps = self.head(x[:, 0]).view(b, self.cfg.plan_waypoints, 2)
        return steps_to_waypoints(steps, self.cfg, path, "QueryPlanner")


__all__ = ["PlanLayer", "QueryPlanner"]
