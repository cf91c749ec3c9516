"""UniMM-V2X's Mixture-of-Experts layer: a router and ``E`` expert FFNs with top-k gating.

For a token ``x`` the router gives probabilities ``p(x) = softmax(W_r x)`` over the experts;
the ``k`` most probable (``I_k(x)``) run, weighted by their renormalized probabilities::

    MoE(x) = sum_{i in I_k(x)} G_i(x) f_i(x),   G_i(x) = p_i(x) / sum_{j in I_k(x)} p_j(x)

(the paper's formula; ``f_i``: Linear-GELU-Linear). The **balance loss** is the paper's
``Var(p) + Var(l)`` over the experts, of the *importance* ``p_e`` (the mean router probability
of expert ``e`` over the tokens) and the *load* ``l_e`` (the fraction of the ``N k`` routing
slots that went to ``e``), times ``E^2`` so that it does not shrink with the number of experts:
0 for uniform routing, ``> 0`` otherwise (:func:`balance_loss`). Only ``p`` carries gradient
(the load counts assignments). Padding tokens (``mask`` False) are neither routed nor counted.
"""

from __future__ import annotations

import torch
from torch import nn


def balance_loss(probs: torch.Tensor, top_idx: torch.Tensor, num_experts: int) -> torch.Tensor:
    """``E^2 (Var(p) + Var(l))`` of router probabilities ``(N, E)`` and the chosen experts
    ``(N, k)`` (module docstring); 0 when there is no token."""
    if probs.shape[0] == 0:
        return probs.new_zeros(())
    importance = probs.mean(0)  # (E,)
    load = torch.bincount(top_idx.reshape(-1), minlength=num_experts).to(probs.dtype)
    load = load / top_idx.numel()
    var = ((importance - importance.mean()) ** 2).mean() + ((load - load.mean()) ** 2).mean()
    return var * num_experts ** 2


class MoEFFN(nn.Module):
    """Router + ``num_experts`` expert FFNs of hidden width ``hidden``, top-``top_k`` gating.

    ``forward(x (..., D), mask (...) bool or None) -> (y (..., D), balance ())``; ``y`` is 0 at
    padding tokens. :attr:`last_load` holds the load ``(E,)`` of the last call (diagnostics).
    """

    def __init__(self, width: int, hidden: int, num_experts: int, top_k: int) -> None:
        super().__init__()
        if not 1 <= top_k <= num_experts:
            raise ValueError(f"MoEFFN: top_k={top_k} must be in [1, num_experts={num_experts}]")
        self.num_experts, self.top_k = num_experts, top_k
        self.router = nn.Linear(width, num_experts)
        self.experts = nn.ModuleList(
            nn.Sequential(nn.Linear(width, hidden), nn.GELU(), nn.Linear(hidden, width))
            for _ in range(num_experts))
        self.last_load = torch.zeros(num_experts)

    def route(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Tokens ``(N, D)`` -> router probabilities ``(N, E)``, chosen experts ``(N, k)`` and
        their gates ``(N, k)`` (renormalized: each row sums to 1)."""
        probs = self.router(x).softmax(-1)
        top, idx = probs.topk(self.top_k, dim=-1)
        return probs, idx, top / top.sum(-1, keepdim=True).clamp_min(1e-9)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        shape = x.shape
        flat = x.reshape(-1, shape[-1])
        keep = (torch.ones(flat.shape[0], dtype=torch.bool, device=x.device) if mask is None
                else mask.reshape(-1).bool())
        rows_in = keep.nonzero().squeeze(1)
        tokens = flat[rows_in]
        probs, idx, gates = self.route(tokens)
        out = torch.zeros_like(tokens)
        for e, expert in enumerate(self.experts):
            rows, slot = (idx == e).nonzero(as_tuple=True)
            if len(rows):
                out = out.index_add(0, rows, gates[rows, slot, None] * expert(tokens[rows]))
        y = torch.zeros_like(flat).index_put((rows_in,), out)
        with torch.no_grad():
            self.last_load = torch.bincount(idx.reshape(-1), minlength=self.num_experts).cpu()
        return y.view(shape), balance_loss(probs, idx, self.num_experts)


__all__ = ["MoEFFN", "balance_loss"]
