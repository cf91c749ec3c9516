"""Shared pieces of the AURORA planner tests (``test_aurora_planners.py``,
``test_aurora_route_frame.py``): the waypoint times, a turning trajectory and the overfitting
loop every planner test runs."""

from __future__ import annotations

import torch

T = 6
TIMES = torch.arange(1, T + 1) * 0.5


def turn(speed: float, radius: float, side: float = 1.0) -> torch.Tensor:
    """``(T, 2)`` waypoints on a circle to the left (``side=1``) or right."""
    a = speed * TIMES / radius
    return torch.stack([radius * torch.sin(a), side * radius * (1 - torch.cos(a))], -1)


def overfit(planner, crit, batch: dict, h: torch.Tensor, command: torch.Tensor, steps: int,
            gt: torch.Tensor | None = None, **inputs) -> dict:
    """Train ``planner`` on one batch for ``steps`` Adam steps (lr 5e-3, cosine schedule) with
    ``crit``; ``gt`` goes to the planner as its target (the VAE's), ``inputs`` as keywords
    (``route=``, ``path=``). Returns the last step's loss parts; leaves it in eval mode."""
    opt = torch.optim.Adam(planner.parameters(), lr=5e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    planner.train()
    parts: dict = {}
    for _ in range(steps):
        loss, parts = crit(planner(h, command, gt, **inputs), batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    planner.eval()
    return parts
