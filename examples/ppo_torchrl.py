"""PPO with TorchRL on V2XBench's native batched env: a policy that learns to follow its route.

Run::

    python examples/ppo_torchrl.py                      # the measured run below (~3.5 min)
    python examples/ppo_torchrl.py --frames 200000 --num-worlds 8 --plot curve.png
    python examples/ppo_torchrl.py --tiny               # a smoke test (seconds)

One page, top to bottom: the env (``V2XTorchEnv``, ``num_worlds`` worlds stepped as one batch),
a feature module, a ``TanhNormal`` actor and a value head, a ``Collector``, ``GAE`` and
``ClipPPOLoss``. Route completion and the share of episodes ended by a collision are measured
for the deterministic policy on 16 fixed evaluation routes before training, during it and at the
end, next to a standing car (full brake) and uniform random actions on the same routes.

Settings chosen to make learning feasible on a CPU in minutes (``ENV_CONFIG``): ``action_mode=
"accel_steer"`` (one signed acceleration and steer: in the CARLA-style default a Gaussian
policy's centre stands still), ``objects`` observation (the policy reads ``ego``, the next 20
route points and the 8 nearest objects the ego sees), 150 m routes in Town01 (300 m by default),
fewer road users (10 vehicles, 5 parked, 5 pedestrians, 2 bicycles; defaults 30, 10, 12, 3), no
V2X messages, and the episode ends at a collision. Reward: ``episode.py``'s terms unchanged (the
continuous progress term, collisions, infractions, comfort). Three choices in the policy keep it
out of the standing car's trap (an early collision's -10 teaches braking before steering is
learnt): a near-zero start of the mean (no random steering bias), a narrow initial steering
spread (``INIT_STD``), and a bounded pre-tanh mean (``LOC_BOUND``); the actor's and the
critic's gradients are clipped apart.

Measured (2 shared CPU cores, ``torch.set_num_threads(1)``, default arguments
``--frames 1000000 --num-worlds 16``; 1,001,472 frames in 202 s of training, 205 s in all;
route completion % / episodes ended by a collision % on the 16 evaluation routes)::

    seed  standing car   uniform random  PPO at start   PPO at 1.0 M frames
    0     1.5 / 6        25.4 / 94       1.5 / 6        93.5 / 19   (92.1 at 0.2 M)
    1     1.3 / 6        18.7 / 94       6.2 / 6        89.7 / 31   (93.9 at 0.5 M)
    2     1.2 / 6        23.9 / 81       8.7 / 0        90.5 / 31   (90.5 at 0.5 M)

The policy learns to drive its route (route completion from 1-9 % to 90-94 %) but not to avoid
the other road users: a fifth to a third of its episodes still end in a collision (a standing
car is hit in 6 %). ``docs/media/ppo_learning_curve.png`` is seed 0's curve (``--plot``).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from v2xbench.envs.v2x_intersection import V2XTorchEnv
from v2xbench.envs.v2x_intersection.evaluation.episode import COLLISIONS

ENV_CONFIG = {
    "obs_mode": "objects", "action_mode": "accel_steer", "route_length": 150.0,
    "num_vehicles": 10, "num_parked": 5, "num_pedestrians": 5, "num_bicycles": 2,
    "rsu_policy": "none", "terminate_on_collision": True,
}
#: the ``--tiny`` smoke test: two worlds, two short batches, 40-tick episodes
TINY = {"frames": 256, "num_worlds": 2, "steps_per_batch": 64, "eval_worlds": 2, "max_steps": 40}
#: ``ego`` feature scales (``observations.EGO_FEATURES``: m/s, m/s^2, rad/s, controls, light
#: state, m to the stop line, route completion %) and route point scales (m, m, command code)
EGO_SCALE = (0.1, 0.25, 1.0, 1.0, 1.0, 1.0, 0.3, 0.02, 0.01)
ROUTE_SCALE = (0.05, 0.05, 0.2)
#: ``objects`` column scales (``observations.OBJECT_FEATURES``: present, class id, x, y, yaw,
#: length, width, height, vx, vy, visibility; m, rad, m/s)
OBJECT_SCALE = (1.0, 0.1, 0.05, 0.05, 0.3, 0.2, 0.5, 0.3, 0.1, 0.1, 1.0)
#: the nearest objects the policy reads (rows are sorted by distance)
NEAREST = 8
#: initial standard deviations (before the tanh) of the actor's (accel, steer): wide in accel,
#: narrow in steer (wild steering ends most early episodes in a collision, whose -10 teaches
#: standing still before the policy has learnt to follow the route)
INIT_STD = (1.0, 0.3)
#: ``TanhNormal(tanh_loc=True, upscale=LOC_BOUND)``: the mean before the tanh stays inside
#: +-LOC_BOUND, so exploration never dies in a saturated full brake (the standing car's trap)
LOC_BOUND = 1.5


def mlp(n_in: int, n_out: int, width: int = 64) -> nn.Sequential:
    """Two tanh hidden layers."""
    return nn.Sequential(nn.Linear(n_in, width), nn.Tanh(), nn.Linear(width, width), nn.Tanh(),
                         nn.Linear(width, n_out))


class Features(nn.Module):
    """``ego (B, 9)``, ``route (B, P, 3)`` and the ``NEAREST`` first rows of ``objects (B, M, 11)``
    -> scaled features ``(B, 9 + 3P + 11 NEAREST)``."""

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("ego_scale", torch.tensor(EGO_SCALE))
        self.register_buffer("route_scale", torch.tensor(ROUTE_SCALE))
        self.register_buffer("object_scale", torch.tensor(OBJECT_SCALE))

    def forward(self, ego: torch.Tensor, route: torch.Tensor,
                objects: torch.Tensor) -> torch.Tensor:
        route = (route * self.route_scale).flatten(-2)  # (B, 3P)
        near = (objects[..., :NEAREST, :] * self.object_scale).flatten(-2)  # (B, 11 NEAREST)
        return torch.cat([ego * self.ego_scale, route, near], -1).clamp(-10.0, 10.0)


class GaussianHead(nn.Module):
    """``features (B, F)`` -> ``loc (B, D)`` from an MLP that starts near zero (CleanRL's 0.01
    gain on the last layer: no random steering bias) and a learned state-independent
    ``scale (B, D)`` started at ``init_std``, as most PPO implementations for continuous control."""

    def __init__(self, n_in: int, init_std: tuple[float, ...]) -> None:
        super().__init__()
        self.loc = mlp(n_in, len(init_std))
        with torch.no_grad():
            self.loc[-1].weight.mul_(0.01)
            self.loc[-1].bias.zero_()
        self.log_std = nn.Parameter(torch.tensor(init_std).log())

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.loc(features)
        return loc, self.log_std.exp().expand_as(loc)


def make_env(num_worlds: int, seed: int, **overrides) -> V2XTorchEnv:
    """``num_worlds`` worlds of :data:`ENV_CONFIG` (``overrides`` on top), seeded."""
    env = V2XTorchEnv(num_worlds=num_worlds, **{**ENV_CONFIG, **overrides})
    env.set_seed(seed)
    return env


def make_modules(env: V2XTorchEnv) -> tuple[ProbabilisticActor, TensorDictSequential]:
    """The actor (``TanhNormal`` over the action box) and the critic, sharing ``Features``."""
    n_feat = 9 + 3 * env.observation_spec["route"].shape[-2] + len(OBJECT_SCALE) * NEAREST
    if env.action_spec.shape[-1] != len(INIT_STD):
        raise ValueError(f"this example drives with action_mode='accel_steer' ({len(INIT_STD)} "
                         f"action components), got action spec {tuple(env.action_spec.shape)}")
    features = TensorDictModule(Features(), in_keys=["ego", "route", "objects"],
                                out_keys=["features"])
    params = TensorDictModule(GaussianHead(n_feat, INIT_STD), in_keys=["features"],
                              out_keys=["loc", "scale"])
    box = env.action_spec.space
    actor = ProbabilisticActor(
        TensorDictSequential(features, params), in_keys=["loc", "scale"], spec=env.action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": box.low[0], "high": box.high[0], "tanh_loc": True,
                             "upscale": LOC_BOUND}, return_log_prob=True)
    critic = TensorDictSequential(features, ValueOperator(mlp(n_feat, 1), in_keys=["features"]))
    return actor, critic


def evaluate(env: V2XTorchEnv, policy, seed: int) -> dict[str, float]:
    """One episode per world on the routes of ``seed`` (``policy`` maps an observation
    TensorDict to one with ``action``): mean route completion (%) and the share of episodes that
    ended in a collision (%)."""
    env.set_seed(seed)
    td = env.reset()
    n = env.batch_size[0]
    final, collided = torch.full((n,), math.nan), torch.zeros(n)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        while final.isnan().any():
            out = env.step(policy(td))
            done = out["next", "done"].reshape(n) & final.isnan()
            final[done] = out["next", "route_completion"].reshape(n)[done]
            for i in done.nonzero().flatten().tolist():  # read before the world is reset
                collided[i] = float(env.worlds[i].monitor.counts[list(COLLISIONS)].sum() > 0)
            td = env.maybe_reset(step_mdp(out))
    return {"route_completion": float(final.mean()),
            "collision_pct": 100.0 * float(collided.mean())}


def standing(env: V2XTorchEnv):
    """Full brake, straight: a car that stays where it starts."""
    low = env.action_spec.space.low

    def policy(td: TensorDictBase) -> TensorDictBase:
        return td.set("action", low.clone().index_fill_(-1, torch.tensor([1]), 0.0))
    return policy


def uniform_random(env: V2XTorchEnv):
    """Uniform random actions in the action box."""
    return lambda td: td.set("action", env.action_spec.rand())


def _show(name: str, m: dict[str, float]) -> str:
    return (f"{name}: route completion {m['route_completion']:5.1f} %, "
            f"collisions {m['collision_pct']:3.0f} %")


def train(frames: int, num_worlds: int, steps_per_batch: int = 128, eval_worlds: int = 16,
          evals: int = 11, seed: int = 0, max_steps: int | None = None, lr: float = 3e-4,
          epochs: int = 4, minibatch: int = 512, gamma: float = 0.99, lmbda: float = 0.95,
          log=print) -> dict:
    """PPO for ``frames`` environment steps; returns the measured numbers and the curve
    (``curve``: ``(frames, evaluation)`` pairs, the first before training)."""
    torch.manual_seed(seed)
    extra = {} if max_steps is None else {"max_steps": max_steps}
    env = make_env(num_worlds, seed, **extra)
    eval_env = make_env(eval_worlds, seed, **extra)
    eval_seed = 10_000 + seed  # the same evaluation routes every time
    actor, critic = make_modules(env)
    gae = GAE(gamma=gamma, lmbda=lmbda, value_network=critic, average_gae=True)
    loss = ClipPPOLoss(actor, critic, clip_epsilon=0.2, entropy_coeff=1e-3, critic_coeff=0.5,
                       loss_critic_type="l2")
    optim = torch.optim.Adam(loss.parameters(), lr=lr)
    batch = num_worlds * steps_per_batch
    n_iters = max(-(-frames // batch), 1)
    collector = Collector(env, actor, frames_per_batch=batch, total_frames=n_iters * batch,
                          auto_register_policy_transforms=False)
    result = {"env_config": {**ENV_CONFIG, **extra}, "num_worlds": num_worlds, "frames": 0,
              "standing": evaluate(eval_env, standing(eval_env), eval_seed),
              "uniform_random": evaluate(eval_env, uniform_random(eval_env), eval_seed),
              "curve": []}
    log(_show("standing car  ", result["standing"]))
    log(_show("uniform random", result["uniform_random"]))
    t0 = time.perf_counter()
    eval_at = {round(k * n_iters / max(evals - 1, 1)) for k in range(evals - 1)}
    for it, data in enumerate(collector):
        if it in eval_at:  # the policy that collected this batch, before it learns from it
            result["curve"].append((result["frames"], evaluate(eval_env, actor, eval_seed)))
            log(_show(f"frames {result['frames']:>8d}", result["curve"][-1][1])
                + f"  ({time.perf_counter() - t0:.0f} s)")
        with torch.no_grad():
            gae(data)
        flat = data.reshape(-1)
        for _ in range(epochs):
            for idx in torch.randperm(len(flat)).split(minibatch):
                parts = loss(flat[idx])
                total = parts["loss_objective"] + parts["loss_critic"] + parts["loss_entropy"]
                optim.zero_grad()
                total.backward()
                for group in (actor.parameters(), critic.parameters()):  # apart: the critic's
                    nn.utils.clip_grad_norm_(group, 0.5)  # -10 collisions must not mute the actor
                optim.step()
        collector.update_policy_weights_()
        result["frames"] += data.numel()
    collector.shutdown()
    result["curve"].append((result["frames"], evaluate(eval_env, actor, eval_seed)))
    result["wall_s"] = time.perf_counter() - t0
    result["start"], result["end"] = result["curve"][0][1], result["curve"][-1][1]
    log(_show(f"frames {result['frames']:>8d}", result["end"]) + f"  ({result['wall_s']:.0f} s)")
    return result


def plot(result: dict, path: str | Path) -> None:
    """The evaluation route completion against frames, with the two baselines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = [f for f, _ in result["curve"]]
    y = [m["route_completion"] for _, m in result["curve"]]
    fig, ax = plt.subplots(figsize=(5, 3), dpi=100)
    ax.plot(x, y, "o-", label="PPO (deterministic policy)")
    ax.axhline(result["uniform_random"]["route_completion"], color="gray", ls="--",
               label="uniform random")
    ax.axhline(result["standing"]["route_completion"], color="k", ls=":", label="standing car")
    ax.set(xlabel="environment frames", ylabel="route completion (%)", ylim=(0, 100),
           title=f"PPO on V2XTorchEnv ({result['num_worlds']} worlds)")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict:
    """Parse the options, train, print the numbers (and write them with ``--out``)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=1_000_000, help="environment steps to train on")
    p.add_argument("--num-worlds", type=int, default=16, help="worlds stepped as one batch")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--tiny", action="store_true", help="a smoke test of a few seconds")
    p.add_argument("--out", default=None, help="write the numbers to this JSON file")
    p.add_argument("--plot", default=None, help="save the learning curve to this PNG")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    if args.tiny:
        result = train(**TINY, seed=args.seed, evals=2)
    else:
        result = train(args.frames, args.num_worlds, seed=args.seed)
    result["total_wall_s"] = time.perf_counter() - t0  # with the env set-up and the baselines
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1))
    if args.plot:
        plot(result, args.plot)
    return result


if __name__ == "__main__":
    main()
