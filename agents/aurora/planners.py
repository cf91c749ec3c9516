"""AURORA's planning decoders (seed paper, section 4.3 and appendix stage 4).

Every planner reads the language model's final-layer hidden state at ``<wp>`` (``h_wp``,
``(B, H)``), the navigation command (``(B,)`` codes of ``COMMAND_NAMES``) and, with
``cfg.plan_route_points`` = K > 0, the K route points ahead (``route``, ``(B, K, 2)`` m, ego
frame: :func:`~.route_input.planner_route_points`) and predicts ``cfg.plan_waypoints`` ego-frame
waypoints ``cfg.plan_dt`` apart (``(B, T, 2)`` metres: the data set's
``expert_waypoints[:, :T]``). The context is ``MLP(h_wp) + Embedding(command)`` (+ ``MLP(route /
plan_traj_scale)`` with K > 0; K = 0 builds no route encoder: the paper's inputs and the weights
of runs made before it); trajectories are handled normalized by ``cfg.plan_traj_scale``.

Output frame (``cfg.plan_frame``): ``"ego"`` (runs made before it): the trajectories are
ego-frame x, y. ``"route"`` (the default): they are route-frame ``(s, d)`` per waypoint, the arc
length along the observed route (the ``(B, N, 2)`` polyline ``path``,
:func:`~.route_input.planner_route_path`, batch key ``route_path``) and the lateral offset from
it, turned into ego-frame x, y by :func:`~.route_input.route_to_ego` (differentiable); the
outputs (``waypoints``, ``per_command``, ``mode_trajs``) are ego-frame x, y in both frames, so
the losses (:mod:`.planner_losses`) and open-loop metrics are unchanged, and ``route_sd`` holds
the chosen trajectory's ``(s, d)``. The MLP and VAE keep ``s`` at or above 0 and non-decreasing
(each step along the route is made non-negative, ``cfg.plan_route_step``: the default
``"relu_ste"`` is ``relu(u)`` whose gradient is 1 also below 0 (a straight-through estimator:
a standing step is exactly 0, yet a start-from-rest sample still moves it); ``"abs"`` is ``|u|``;
``"softplus"`` (the fourth run's, sharpness :data:`SOFT_BETA`) saturates where the standing
frames push it far below 0: docs/aurora.md, "A fifth run"); the diffusion planner's
anchors are route-frame k-means centres (``s >= 0``) and its inference output's ``s`` is
clipped at 0. A route-frame planner following the route by default learns only deviations from
it and the speed along it (docs/aurora.md, "A fourth run").

- :class:`MLPPlanner`: direct regression; one trajectory per command (the output is the given
  command's: "command-conditioned", as VAD / ORION), each the cumulative sum of predicted steps.
- :class:`VAEPlanner` (the default): a present Gaussian ``N(mu_p, sigma_p)`` from the context
  and a future Gaussian ``N(mu_f, sigma_f)`` from the context and the expert trajectory
  (training only); the latent is sampled from the future one in training (reparametrized) and
  is the present one's mean at inference (``sample=True``: a sample); a GRU rolls the latent out
  into one step per waypoint for every command. ``KL(future || present)`` is in
  :mod:`.planner_losses`. Both Gaussians start narrow (log-variance :data:`INIT_LOGVAR`) so
  that early latent noise does not drown the decoder.
- :class:`DiffusionPlanner`: truncated diffusion around trajectory anchors (DiffusionDrive):
  ``K`` anchors are k-means centres of training trajectories (:func:`fit_anchors`, stored as a
  buffer); training noises the anchors to a random step ``t < TRUNCATE`` of a 1000-step DDPM
  schedule and the denoiser predicts, per anchor, a mode logit and the clean trajectory (an
  offset from its anchor); inference starts from the anchors at step ``TRUNCATE - 1`` (no noise:
  repeatable) and runs ``cfg.plan_diffusion_steps`` DDIM steps, returning the trajectory of the
  highest-scoring mode.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .config import AuroraConfig
from .det_decoder import mlp
from .route_input import PATH_KEY, PATH_SPACING, ego_to_route, route_to_ego

LOGVAR_CLAMP = 10.0
INIT_LOGVAR = -4.0  # initial log-variance of the VAE's Gaussians
DIFFUSION_STEPS = 1000  # DDPM schedule length
TRUNCATE = 50  # truncated diffusion: steps used around the anchors
SOFT_BETA = 10.0  # route frame: sharpness of the softplus of a step along the route (normalized)


class Planner(nn.Module):
    """Shared context of the planners (module docstring)."""

    def __init__(self, cfg: AuroraConfig, in_width: int) -> None:
        super().__init__()
        self.t, self.c, h = cfg.plan_waypoints, cfg.num_commands, cfg.plan_hidden
        self.in_width = in_width
        self.register_buffer("scale", torch.tensor(cfg.plan_traj_scale), persistent=False)
        self.ctx = nn.Sequential(nn.Linear(in_width, h), nn.LayerNorm(h), nn.ReLU(),
                                 nn.Linear(h, h))
        self.cmd = nn.Embedding(self.c, h)
        self.k_route = cfg.plan_route_points
        if self.k_route:  # the route points ahead (module docstring)
            self.route = mlp([2 * self.k_route, h, h])
        self.frame = cfg.plan_frame
        self.route_step = cfg.plan_route_step

    def check_path(self, path: torch.Tensor | None, b: int) -> torch.Tensor | None:
        """The route polyline ``(B, N, 2)`` of a route-frame planner (``None`` in the ego
        frame); ``ValueError`` when it is missing or misshapen."""
        if self.frame == "ego":
            return None
        if path is None:
            raise ValueError(f"{type(self).__name__}: no route path; this planner plans in the "
                             f"route frame (plan_frame='route'; batch key {PATH_KEY!r}, shape "
                             f"({b}, N, 2): route_input.planner_route_path)")
        if path.dim() != 3 or path.shape[0] != b or path.shape[1] < 2 or path.shape[2] != 2:
            raise ValueError(f"{type(self).__name__}: route path has shape {tuple(path.shape)}; "
                             f"expected ({b}, N >= 2, 2)")
        return path

    def to_ego(self, traj: torch.Tensor, path: torch.Tensor | None) -> torch.Tensor:
        """Trajectories ``(B, ..., T, 2)`` m of the planner's frame -> ego-frame x, y."""
        return traj if path is None else route_to_ego(traj, path, PATH_SPACING)

    def steps_to_traj(self, steps: torch.Tensor) -> torch.Tensor:
        """Normalized per-waypoint steps ``(B, C, T, 2)`` -> trajectories (m) of the planner's
        frame: their cumulative sum; in the route frame the step along the route is first made
        non-negative (``cfg.plan_route_step``: ``relu(u)`` with a straight-through gradient,
        ``|u|`` or a softplus; ``s`` starts at 0 and never decreases)."""
        if self.frame == "route":
            u = steps[..., :1]
            if self.route_step == "relu_ste":  # forward relu(u), gradient 1 (straight through)
                along = u + (u.clamp_min(0.0) - u).detach()
            elif self.route_step == "abs":
                along = u.abs()
            else:
                along = nn.functional.softplus(u, beta=SOFT_BETA)
            steps = torch.cat([along, steps[..., 1:]], -1)
        return steps.cumsum(-2) * self.scale

    def context(self, h_wp: torch.Tensor, command: torch.Tensor,
                route: torch.Tensor | None = None) -> torch.Tensor:
        """``(B, plan_hidden)`` context; ``ValueError`` on bad shapes or command codes, or a
        missing or misshaped ``route`` ``(B, K, 2)`` where the planner has K > 0 route points."""
        if h_wp.dim() != 2 or h_wp.shape[1] != self.in_width:
            raise ValueError(f"{type(self).__name__}: h_wp has shape {tuple(h_wp.shape)}; "
                             f"expected (B, {self.in_width})")
        if tuple(command.shape) != (h_wp.shape[0],):
            raise ValueError(f"{type(self).__name__}: command has shape {tuple(command.shape)}; "
                             f"expected ({h_wp.shape[0]},)")
        if command.numel() and (int(command.min()) < 0 or int(command.max()) >= self.c):
            raise ValueError(f"{type(self).__name__}: command codes outside [0, {self.c})")
        ctx = self.ctx(h_wp) + self.cmd(command.long())
        if not self.k_route:
            if route is not None and route.numel():
                raise ValueError(f"{type(self).__name__}: route points of shape "
                                 f"{tuple(route.shape)} given to a planner without route input "
                                 "(plan_route_points=0)")
            return ctx
        want = (h_wp.shape[0], self.k_route, 2)
        if route is None:
            raise ValueError(f"{type(self).__name__}: no route points; this planner conditions "
                             f"on plan_route_points={self.k_route} (batch key 'route_points', "
                             f"shape {want}: route_input.planner_route_points)")
        if tuple(route.shape) != want:
            raise ValueError(f"{type(self).__name__}: route points have shape "
                             f"{tuple(route.shape)}; expected {want}")
        norm = route.to(ctx.dtype) / self.scale.to(ctx.dtype)
        return ctx + self.route(norm.flatten(1))

    def check_target(self, target: torch.Tensor | None, b: int) -> torch.Tensor | None:
        """The first ``T`` expert waypoints ``(B, T, 2)`` (m) of ``target`` or ``None``."""
        if target is None:
            return None
        if target.dim() != 3 or target.shape[0] != b or target.shape[1] < self.t \
                or target.shape[2] != 2:
            raise ValueError(f"{type(self).__name__}: expert waypoints have shape "
                             f"{tuple(target.shape)}; expected ({b}, >= {self.t}, 2)")
        return target[:, :self.t].float()

    @staticmethod
    def select(per_command: torch.Tensor, command: torch.Tensor) -> torch.Tensor:
        """``(B, C, T, 2)`` -> ``(B, T, 2)``: each sample's command's trajectory."""
        return per_command[torch.arange(per_command.shape[0]), command.long()]


class MLPPlanner(Planner):
    """Direct regression of one trajectory per command (module docstring)."""

    def __init__(self, cfg: AuroraConfig, in_width: int) -> None:
        super().__init__(cfg, in_width)
        h = cfg.plan_hidden
        self.head = mlp([h, h, self.c * self.t * 2])

    def forward(self, h_wp: torch.Tensor, command: torch.Tensor,
                target: torch.Tensor | None = None, *, route: torch.Tensor | None = None,
                path: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """``waypoints`` ``(B, T, 2)`` m of the command, ``per_command`` ``(B, C, T, 2)``
        (ego frame; ``route_sd``: the command's ``(s, d)`` in the route frame)."""
        x = self.context(h_wp, command, route)
        path = self.check_path(path, h_wp.shape[0])
        steps = self.head(torch.relu(x)).view(-1, self.c, self.t, 2)
        native = self.steps_to_traj(steps)
        per = self.to_ego(native, path)
        out = {"waypoints": self.select(per, command), "per_command": per}
        if path is not None:
            out["route_sd"] = self.select(native, command)
        return out


class VAEPlanner(Planner):
    """Present / future Gaussians and a GRU decoder (module docstring)."""

    def __init__(self, cfg: AuroraConfig, in_width: int) -> None:
        super().__init__(cfg, in_width)
        h, z = cfg.plan_hidden, cfg.plan_latent
        self.latent = z
        self.present = mlp([h, h, 2 * z])
        self.traj_enc = mlp([self.t * 2, h, h])
        self.future = mlp([2 * h, h, 2 * z])
        self.init = nn.Linear(h + z, h)
        self.step_embed = nn.Embedding(self.t, h)
        self.gru = nn.GRUCell(z + h, h)
        self.out = nn.Linear(h, self.c * 2)
        for head in (self.present, self.future):  # start with narrow Gaussians (std ~0.14) so
            nn.init.constant_(head[-1].bias[z:], INIT_LOGVAR)  # the decoder is not drowned

    @staticmethod
    def _gaussian(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mu, logvar = x.chunk(2, -1)
        return mu, logvar.clamp(-LOGVAR_CLAMP, LOGVAR_CLAMP)

    def decode(self, ctx: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """GRU roll-out of latent ``z`` ``(B, Z)``: ``(B, C, T, 2)`` metres (planner's frame)."""
        hid = torch.tanh(self.init(torch.cat([ctx, z], -1)))
        steps = []
        for i in range(self.t):
            inp = torch.cat([z, self.step_embed.weight[i].expand(z.shape[0], -1)], -1)
            hid = self.gru(inp, hid)
            steps.append(self.out(hid).view(-1, self.c, 2))
        return self.steps_to_traj(torch.stack(steps, 2))

    def forward(self, h_wp: torch.Tensor, command: torch.Tensor,
                target: torch.Tensor | None = None, sample: bool = False, *,
                route: torch.Tensor | None = None, path: torch.Tensor | None = None
                ) -> dict[str, torch.Tensor]:
        """``waypoints`` ``(B, T, 2)`` m, ``per_command``, ``mu_p`` / ``logvar_p`` and, with a
        ``target`` (expert waypoints, ``(B, >= T, 2)`` m, ego frame; the future Gaussian reads
        them in the planner's frame), ``mu_f`` / ``logvar_f``."""
        ctx = self.context(h_wp, command, route)
        path = self.check_path(path, h_wp.shape[0])
        mu_p, logvar_p = self._gaussian(self.present(torch.relu(ctx)))
        out = {"mu_p": mu_p, "logvar_p": logvar_p}
        target = self.check_target(target, h_wp.shape[0])
        if target is not None:
            native = target if path is None else ego_to_route(target, path, PATH_SPACING)
            enc = self.traj_enc((native / self.scale).flatten(1))
            mu_f, logvar_f = self._gaussian(self.future(torch.relu(torch.cat([ctx, enc], -1))))
            out.update(mu_f=mu_f, logvar_f=logvar_f)
            mu, logvar = mu_f, logvar_f
            sample = True
        else:
            mu, logvar = mu_p, logvar_p
        z = mu + torch.randn_like(mu) * (0.5 * logvar).exp() if sample else mu
        native = self.decode(ctx, z)
        per = self.to_ego(native, path)
        out.update(waypoints=self.select(per, command), per_command=per)
        if path is not None:
            out["route_sd"] = self.select(native, command)
        return out


# ---------------------------------------------------------------------- diffusion
def fit_anchors(trajectories: torch.Tensor, k: int, iters: int = 50, seed: int = 0
                ) -> torch.Tensor:
    """k-means centres ``(k, T, 2)`` of trajectories ``(N, T, 2)`` (k-means++ seeding with a
    seeded generator, Lloyd iterations; empty clusters re-seeded at the farthest trajectory)."""
    x = torch.as_tensor(trajectories, dtype=torch.float32)
    if x.dim() != 3 or x.shape[-1] != 2:
        raise ValueError(f"fit_anchors: trajectories have shape {tuple(x.shape)}; "
                         "expected (N, T, 2)")
    n = x.shape[0]
    if n < k:
        raise ValueError(f"fit_anchors: {n} trajectories cannot give {k} anchors")
    flat = x.flatten(1)
    g = torch.Generator().manual_seed(seed)
    centres = flat[torch.randint(n, (1,), generator=g)]
    while centres.shape[0] < k:
        d2 = torch.cdist(flat, centres).amin(1).square()
        p = d2 / d2.sum() if float(d2.sum()) > 0 else torch.full((n,), 1.0 / n)
        centres = torch.cat([centres, flat[torch.multinomial(p, 1, generator=g)]])
    for _ in range(iters):
        assign = torch.cdist(flat, centres).argmin(1)
        new = centres.clone()
        for j in range(k):
            members = flat[assign == j]
            if len(members):
                new[j] = members.mean(0)
            else:
                new[j] = flat[torch.cdist(flat, new).amin(1).argmax()]
        if torch.allclose(new, centres):
            break
        centres = new
    return centres.view(k, *x.shape[1:])


def timestep_embedding(t: torch.Tensor, dim: int) -> torch.Tensor:
    """Sinusoidal embedding ``(B, dim)`` of integer diffusion steps ``(B,)``."""
    half = dim // 2
    freq = torch.exp(-math.log(10000.0) * torch.arange(half, device=t.device) / max(half, 1))
    x = t.float()[:, None] * freq[None]
    emb = torch.cat([x.sin(), x.cos()], -1)
    return nn.functional.pad(emb, (0, dim - 2 * half))


class DiffusionPlanner(Planner):
    """Truncated diffusion around k-means anchors (module docstring)."""

    def __init__(self, cfg: AuroraConfig, in_width: int) -> None:
        super().__init__(cfg, in_width)
        h, k = cfg.plan_hidden, cfg.plan_anchors
        self.k, self.steps = k, cfg.plan_diffusion_steps
        self.register_buffer("anchors", torch.zeros(k, self.t, 2))  # saved with the weights
        self.register_buffer("anchors_set", torch.tensor(False))
        betas = torch.linspace(1e-4, 0.02, DIFFUSION_STEPS)
        self.register_buffer("alpha_bar", torch.cumprod(1 - betas, 0), persistent=False)
        self.traj_in = mlp([self.t * 2, h, h])
        self.time = mlp([h, h, h])
        heads = 4 if h % 4 == 0 else 1
        self.mix = nn.TransformerEncoderLayer(h, heads, 2 * h, dropout=0.0, batch_first=True)
        self.cls = nn.Linear(h, 1)
        self.reg = nn.Linear(h, self.t * 2)
        nn.init.zeros_(self.reg.weight)
        nn.init.zeros_(self.reg.bias)

    def set_anchors(self, anchors: torch.Tensor) -> None:
        """Install anchors ``(K, T, 2)`` metres in the planner's frame (e.g. :func:`fit_anchors`
        of the train split's expert trajectories; route frame: their ``(s, d)``,
        :func:`~.route_input.ego_to_route`)."""
        if tuple(anchors.shape) != tuple(self.anchors.shape):
            raise ValueError(f"DiffusionPlanner: anchors have shape {tuple(anchors.shape)}; "
                             f"expected {tuple(self.anchors.shape)}")
        self.anchors.copy_(anchors)
        self.anchors_set.fill_(True)

    def denoise(self, ctx: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Noisy normalized trajectories ``(B, K, T, 2)`` at steps ``t`` ``(B,)`` -> mode logits
        ``(B, K)`` and clean normalized trajectories ``(B, K, T, 2)``."""
        emb = self.traj_in(x_t.flatten(2)) + self.time(timestep_embedding(t, ctx.shape[1]))[:, None]
        y = self.mix(emb + ctx[:, None])
        anchors = (self.anchors / self.scale)[None]
        return self.cls(y)[..., 0], anchors + self.reg(y).view(y.shape[0], self.k, self.t, 2)

    def _noised(self, x0: torch.Tensor, t: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        ab = self.alpha_bar[t].view(-1, 1, 1, 1)
        return ab.sqrt() * x0 + (1 - ab).sqrt() * noise

    def forward(self, h_wp: torch.Tensor, command: torch.Tensor,
                target: torch.Tensor | None = None, *, route: torch.Tensor | None = None,
                path: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """``waypoints`` ``(B, T, 2)`` m of the best mode, ``mode_logits`` ``(B, K)``,
        ``mode_trajs`` ``(B, K, T, 2)`` m, ``anchors`` m (ego frame: ``(K, T, 2)``; route frame:
        each sample's ``(B, K, T, 2)``, and ``route_sd`` the best mode's ``(s, d)``). In training
        mode the anchors are noised to a random step; in eval mode :attr:`steps` DDIM steps run
        from the anchors (route frame: ``s`` clipped at 0 at the end)."""
        if not bool(self.anchors_set):
            raise ValueError("DiffusionPlanner: no anchors (set_anchors(fit_anchors(train "
                             "trajectories, cfg.plan_anchors)) before use)")
        ctx = self.context(h_wp, command, route)
        b = ctx.shape[0]
        path = self.check_path(path, b)
        x0 = (self.anchors / self.scale).expand(b, -1, -1, -1)
        if self.training:
            t = torch.randint(TRUNCATE, (b,), device=ctx.device)
            logits, clean = self.denoise(ctx, self._noised(x0, t, torch.randn_like(x0)), t)
        else:
            ts = torch.linspace(TRUNCATE - 1, 0, self.steps + 1).round().long().tolist()
            x_t = self._noised(x0, torch.full((b,), ts[0], device=ctx.device), torch.zeros_like(x0))
            for i in range(self.steps):
                t = torch.full((b,), ts[i], device=ctx.device)
                logits, clean = self.denoise(ctx, x_t, t)
                if i + 1 < self.steps:  # DDIM (eta = 0) to the next step
                    ab = self.alpha_bar[t].view(-1, 1, 1, 1)
                    eps = (x_t - ab.sqrt() * clean) / (1 - ab).sqrt()
                    t_next = torch.full((b,), ts[i + 1], device=ctx.device)
                    x_t = self._noised(clean, t_next, eps)
        native = clean * self.scale
        best = logits.argmax(1)
        if path is None:
            return {"waypoints": native[torch.arange(b), best], "mode_logits": logits,
                    "mode_trajs": native, "anchors": self.anchors}
        if not self.training:  # s >= 0 (training keeps the gradient of a negative s)
            native = torch.cat([native[..., :1].clamp_min(0.0), native[..., 1:]], -1)
        trajs = self.to_ego(native, path)
        return {"waypoints": trajs[torch.arange(b), best], "mode_logits": logits,
                "mode_trajs": trajs, "route_sd": native[torch.arange(b), best],
                "anchors": self.to_ego(self.anchors.expand(b, -1, -1, -1), path)}


PLANNER_CLASSES = {"vae": VAEPlanner, "mlp": MLPPlanner, "diffusion": DiffusionPlanner}


def build_planner(cfg: AuroraConfig, in_width: int) -> Planner:
    """The planner named by ``cfg.planner`` reading ``h_wp`` of width ``in_width``."""
    return PLANNER_CLASSES[cfg.planner](cfg, in_width)


__all__ = ["PLANNER_CLASSES", "DiffusionPlanner", "MLPPlanner", "Planner", "VAEPlanner",
           "build_planner", "fit_anchors", "timestep_embedding"]
