"""Behaviour fingerprint: one hash per configuration of everything a run produces.

Speed work on the simulator must not change what it computes. ``v2xbench fingerprint`` drives a
fixed set of configurations (test50 routes with the expert and both oracles, a train route, random
and scripted actions in four towns, two RSU slots with latency and loss, BEV observations, the
batched TorchRL env) and hashes, every tick, the observation, reward, flags, info, events, the
whole actor table, the perception results, the active RSUs, the lane states and the ego's inbox.
Two code versions that print the same hashes computed the same bytes on these runs;
``V2XBENCH_NO_JIT=1`` gives the NumPy path's hashes, which must be the same too.

``--out F`` writes the hashes as JSON; ``--check F`` compares with such a file and exits 1 on a
difference (naming the configurations). ``--only NAME`` runs the configurations whose name
contains NAME.

Hashes compare code versions on one machine. Across machines they can differ with the same
code: NumPy picks its SIMD code for ``arctan2``, ``power``, ``exp``, ``log``, ``hypot`` ... by the
CPU (on AVX-512 CPUs it differs from other CPUs' results by an ulp on a few percent of inputs),
and those last bits grow into different trajectories. The file records the NumPy version and
the SIMD extensions NumPy found (``_platform``), and ``--check`` says when they differ.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from v2xbench.platform_info import numpy_platform

from .suite import _write as write_atomic


def _update(h, x) -> None:
    """Feed ``x`` (nested dicts / lists / arrays / tensors / scalars) into hash ``h``."""
    if isinstance(x, dict):
        for k in sorted(x, key=str):
            h.update(str(k).encode())
            _update(h, x[k])
    elif isinstance(x, (list, tuple)):
        for v in x:
            _update(h, v)
    elif isinstance(x, np.ndarray):
        h.update(str(x.dtype).encode() + str(x.shape).encode())
        h.update(np.ascontiguousarray(x).tobytes())
    elif type(x).__module__ == "torch":
        _update(h, x.detach().cpu().numpy())
    else:
        h.update(repr(x).encode())


def _world_state(h, w) -> None:
    for k, v in sorted(vars(w.table).items()):
        if isinstance(v, np.ndarray):
            h.update(k.encode())
            _update(h, v)
    _update(h, [w.tick, w.ego_vis, w.rsu_vis, w.active_rsu, w.lane_signal, w.inbox, w.last_events])


def gym_run(config: dict, ticks: int, agent: str | None = None, seed: int = 0, actions: str = "scripted") -> str:
    """Hash of ``ticks`` steps of ``gym.make("V2XIntersection-v0", **config)`` (reset after an
    episode ends), driven by a registered ``agent``, random actions or a scripted sine steer."""
    import gymnasium as gym

    import v2xbench  # noqa: F401  (registers the env)

    h = hashlib.sha256()
    env = gym.make("V2XIntersection-v0", **config)
    w = env.unwrapped.world
    rng = np.random.default_rng(seed)
    ag = None
    if agent is not None:
        import v2xbench.agents.expert  # noqa: F401  (registers the expert and the oracles)
        from v2xbench.agents.interface import load_agent

        ag = load_agent(agent)

    def start(s: int):
        obs, info = env.reset(seed=s)
        _update(h, [obs, info])
        if ag is not None:
            if hasattr(ag, "bind"):
                ag.bind(w)
            ag.reset({})
        return obs

    obs = start(seed)
    for i in range(ticks):
        if ag is not None:
            a = ag.act(obs)
        elif actions == "random":
            a = rng.uniform([0.0, -1.0, 0.0], [1.0, 1.0, 1.0]).astype(np.float32)
        else:
            a = np.array([0.5, 0.05 * np.sin(i / 10), 0.0], np.float32)
        obs, r, term, trunc, info = env.step(a)
        _update(h, [obs, r, term, trunc, info])
        _world_state(h, w)
        if term or trunc:
            obs = start(seed + i + 1)
    env.close()
    return h.hexdigest()[:16]


def torch_run(worlds: int, steps: int) -> str:
    """Hash of a ``V2XTorchEnv(num_worlds=worlds)`` rollout with random actions (seeded)."""
    import torch
    from v2xbench.envs.v2x_intersection import V2XTorchEnv

    torch.set_num_threads(1)
    env = V2XTorchEnv(num_worlds=worlds)
    env.set_seed(0)
    torch.manual_seed(0)
    td = env.rollout(steps, break_when_any_done=False)
    h = hashlib.sha256()
    _update(h, dict(td.flatten_keys().items()))
    return h.hexdigest()[:16]


#: name -> run; each takes a few seconds
CONFIGS: dict[str, Callable[[], str]] = {
    "test50/0 expert": lambda: gym_run(dict(suite="test50", route_index=0), 300, agent="expert"),
    "test50/12 expert": lambda: gym_run(dict(suite="test50", route_index=12), 300, agent="expert"),
    "test50/23 oracle_ego": lambda: gym_run(dict(suite="test50", route_index=23), 250, agent="oracle_ego"),
    "test50/31 oracle_v2x": lambda: gym_run(dict(suite="test50", route_index=31), 250, agent="oracle_v2x"),
    "test50/45 expert": lambda: gym_run(dict(suite="test50", route_index=45), 250, agent="expert"),
    "train/5 scripted": lambda: gym_run(dict(suite="train", route_index=5), 400),
    "Town01 random": lambda: gym_run(dict(town="Town01"), 400, actions="random"),
    "Town04 2 slots, latency 2, loss 0.2": lambda: gym_run(
        dict(town="Town04", rsu_slots=2, latency_ticks=2, loss_prob=0.2), 400),
    "Town03 60 vehicles": lambda: gym_run(dict(town="Town03", num_vehicles=60), 400, seed=3),
    "Town05 bev": lambda: gym_run(dict(town="Town05", obs_mode="bev"), 60),
    "torch 6 worlds": lambda: torch_run(6, 150),
}


def fingerprint(only: str | None = None, progress: bool = True) -> dict[str, str]:
    """``{configuration: hash}`` for the configurations whose name contains ``only``."""
    out = {}
    for name, run in CONFIGS.items():
        if only and only not in name:
            continue
        out[name] = run()
        if progress:
            print(f"{name:40s} {out[name]}", flush=True)
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--only", default=None, help="run the configurations whose name contains this")
    p.add_argument("--out", default=None, help="write the hashes to this JSON file")
    p.add_argument("--check", default=None, help="compare with hashes saved by --out; exit 1 on a difference")


#: key of the fingerprint file's platform record (not a configuration)
PLATFORM_KEY = "_platform"


def platform_record() -> dict:
    """What decides the last bits of NumPy's transcendental functions here
    (``platform_info.numpy_platform``: NumPy's version and its SIMD extensions on this CPU)."""
    return numpy_platform()


def run(args: argparse.Namespace) -> int:
    path = "NumPy" if os.environ.get("V2XBENCH_NO_JIT", "") not in ("", "0") else "numba"
    print(f"behaviour fingerprint ({path} path)")
    got = fingerprint(args.only)
    here = platform_record()
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(out, json.dumps({PLATFORM_KEY: here, **got}, indent=2) + "\n")
        print(f"wrote {out}")
    if args.check:
        want = json.loads(Path(args.check).read_text())
        saved = want.pop(PLATFORM_KEY, None)
        bad = [k for k in got if k in want and want[k] != got[k]]
        missing = [k for k in got if k not in want]
        for k in bad:
            print(f"DIFFERENT: {k}: {want[k]} -> {got[k]}", file=sys.stderr)
        if missing:
            print(f"not in {args.check}: {', '.join(missing)}", file=sys.stderr)
        if bad and saved is not None and saved != here:
            print(f"note: {args.check} was saved with NumPy {saved['numpy']} dispatching to {saved['simd']}, this run "
                  f"has NumPy {here['numpy']} with {here['simd']}: NumPy's arctan2, power, exp ... can differ in the "
                  "last bit between these, so compare code versions on one machine", file=sys.stderr)
        if bad:
            return 1
        print(f"same as {args.check} ({len(got) - len(missing)} configurations)")
    return 0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    raise SystemExit(run(p.parse_args()))


if __name__ == "__main__":
    main()
