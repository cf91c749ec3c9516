"""What asking for fewer camera images saves: ``obs_mode="sensors"`` steps by ``camera_images``.

Prints one row per image set (all four, ``rgb``, ``depth``, ``semantic``, none): thread CPU time
per ``step`` of the Gymnasium env and of a one-world ``V2XTorchEnv`` (``info=False``), and the
speed-up against all four images. Run: ``python -m benchmarks.sensor_images`` (``--quick`` for a
smoke run).

Setup: Town01, default population, default 128 x 64 cameras and LiDARs (``--camera-size``
changes the cameras), a constant action, the same seed for every set. Thread CPU time
(``time.thread_time``) rather than wall time, so that other load on a shared machine does not
count; each set is measured ``--reps`` times in turns, ``--steps`` steps each after a warm-up, and
the best repetition is reported (the closest to the uncontended cost). Single thread.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import time  # noqa: E402

#: the image sets measured (``EnvConfig.camera_images``)
SETS = {"all": ("rgb", "depth", "semantic", "instance"), "rgb": ("rgb",), "depth": ("depth",),
        "semantic": ("semantic",), "none": ()}


def measure(steps: int = 40, reps: int = 9, camera_size: tuple[int, int] = (128, 64),
            seed: int = 3) -> dict[str, dict[str, float]]:
    """``{set: {"gym_ms": ..., "torchrl_ms": ...}}``: the best repetition's CPU ms per step."""
    import numpy as np
    import torch
    from v2xbench.envs.v2x_intersection import V2XIntersectionEnv
    from v2xbench.envs.v2x_intersection.api.torchrl_env import V2XTorchEnv

    torch.set_num_threads(1)
    action = np.array([0.4, 0.0, 0.0], np.float32)
    gym_envs = {k: V2XIntersectionEnv(obs_mode="sensors", camera_images=v, camera_size=camera_size)
                for k, v in SETS.items()}
    rl_envs = {k: V2XTorchEnv(num_worlds=1, info=False, obs_mode="sensors", camera_images=v,
                              camera_size=camera_size) for k, v in SETS.items()}
    best = {k: {"gym_ms": float("inf"), "torchrl_ms": float("inf")} for k in SETS}

    def gym_run(env) -> float:
        env.reset(seed=seed)
        env.step(action)  # warm-up
        t = time.thread_time()
        for _ in range(steps):
            env.step(action)
        return (time.thread_time() - t) / steps * 1e3

    def rl_run(env) -> float:
        env.set_seed(seed)
        td = env.reset()
        td["action"] = torch.tensor(action[None])
        env.step(td)  # warm-up
        t = time.thread_time()
        for _ in range(steps):
            env.step(td)
        return (time.thread_time() - t) / steps * 1e3

    for _ in range(reps):
        for k in SETS:
            best[k]["gym_ms"] = min(best[k]["gym_ms"], gym_run(gym_envs[k]))
            best[k]["torchrl_ms"] = min(best[k]["torchrl_ms"], rl_run(rl_envs[k]))
    return best


def main(argv: list[str] | None = None) -> int:
    """Print the table (module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--reps", type=int, default=9)
    p.add_argument("--camera-size", default="128x64", help="WxH of the cameras")
    p.add_argument("--quick", action="store_true", help="3 steps x 1 repetition")
    args = p.parse_args(argv)
    w, h = (int(v) for v in args.camera_size.lower().split("x"))
    steps, reps = (3, 1) if args.quick else (args.steps, args.reps)
    res = measure(steps, reps, (w, h))
    base = res["all"]
    print(f"camera_images  gym ms/step  speed-up  torchrl ms/step  speed-up   ({w} x {h} cameras)")
    for k, r in res.items():
        print(f"{k:13s}  {r['gym_ms']:11.2f}  {base['gym_ms'] / r['gym_ms']:7.2f}x  "
              f"{r['torchrl_ms']:15.2f}  {base['torchrl_ms'] / r['torchrl_ms']:7.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
