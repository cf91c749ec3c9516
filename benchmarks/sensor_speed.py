"""Sensor-rig speed: full-rig ticks per second and the cost of every sensor.

Prints a table and writes JSON (``--out``, atomically). Run: ``python benchmarks/sensor_speed.py``
(``--quick`` for a tiny CI smoke run).

Setup: ``World`` on ``--town`` (default Town01) with the default population (30 NPC vehicles,
10 parked, 12 pedestrians, 3 bicycles), a constant action, and the default :class:`SensorRig`
(6 ego cameras + 1 RSU camera at 128 x 64, ego LiDAR 32 x 360, RSU LiDAR 64 x 240, BEV 128 x 128,
calibration and the three ground-truth box sets). Each measured tick steps the world (not timed
as sensor time), then captures the full rig once (``full_rig``), then times every part alone on
the same state. Single thread (BLAS pools pinned to 1). Both wall time and process CPU time are
reported, mean and best (minimum) per part: on a shared machine the mean includes waiting for the
CPU and cache contention; the best tick is the closest to the uncontended cost.
Goal (later issue): 100 full-rig ticks/s on one core.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

from .settle import settle  # noqa: E402

GOAL_TICKS_PER_S = 100.0


def _timed(fn) -> tuple[float, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    return (time.perf_counter() - w0) * 1e3, (time.process_time() - c0) * 1e3


def _jobs(rig, world) -> list:
    """``(name, callable)`` of the full capture, then of every part on the same state."""
    frame: dict = {}
    jobs = [("full_rig", lambda: frame.update(rig.capture(world)))]
    scene = rig.scene(world)
    jobs.append(("scene", lambda: rig.scene(world)))
    for spec in rig.ego_cameras:
        jobs.append((spec.name, lambda s=spec: rig.capture_camera(world, s.name, scene)))
    jobs += [
        ("ego_cameras_batched", lambda: rig.capture_ego_cameras(world, scene)),
        ("rsu_cam", lambda: rig.capture_rsu_camera(world, scene)),
        ("lidar", lambda: rig.capture_ego_lidar(world, scene)),
        ("rsu_lidar", lambda: rig.capture_rsu_lidar(world, scene)),
        ("bev", lambda: rig.capture_bev(world)),
        ("calibration", lambda: rig.calibration(world)),
        ("groundtruth", lambda: rig.groundtruth(world, frame, scene)),
    ]
    return jobs


def measure(
    town: str,
    ticks: int,
    warmup: int,
    seed: int,
    quick: bool,
    camera_size=None,
    rsu_camera_size=None,
) -> dict:
    """Run the benchmark; returns a JSON-able dict (camera sizes ``(W, H)``; None: defaults)."""
    import numpy as np
    from v2xbench.envs.v2x_intersection.sensors import SensorConfig, SensorRig
    from v2xbench.envs.v2x_intersection.sensors.lidar import ego_lidar_spec, rsu_lidar_spec
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    cfg = SensorConfig(
        camera_size=camera_size or SensorConfig.camera_size,
        rsu_camera_size=rsu_camera_size or camera_size or SensorConfig.rsu_camera_size,
    )
    if quick:  # tiny sensors: a smoke test of the code path, not a measurement
        cfg = SensorConfig(
            camera_size=(32, 16),
            rsu_camera_size=(32, 16),
            ego_lidar=ego_lidar_spec(8, 90),
            rsu_lidar=rsu_lidar_spec(16, 60),
        )
    rig = SensorRig(cfg)
    world = World(make_config(town=town))
    world.reset(seed=seed)
    control = np.array([0.35, 0.0, 0.0])
    rig.capture(world)  # builds the town's ground raster and caches
    for _ in range(warmup):
        world.step(control)
    parts: dict[str, list[tuple[float, float]]] = {}

    def add(name: str, fn) -> None:
        parts.setdefault(name, []).append(_timed(fn))

    step_ms = []
    settle()
    for _ in range(ticks):
        if world.ended:
            world.reset(seed=seed + 1)
        step_ms.append(_timed(lambda: world.step(control, world.default_rsu_message())))
        for name, fn in _jobs(rig, world):
            add(name, fn)
    rows = {}
    for name, vals in parts.items():
        a = np.array(vals)
        rows[name] = {
            "wall_ms": float(a[:, 0].mean()),
            "wall_ms_min": float(a[:, 0].min()),
            "cpu_ms": float(a[:, 1].mean()),
            "cpu_ms_min": float(a[:, 1].min()),
        }
    full = rows["full_rig"]
    st = np.array(step_ms)
    return {
        "benchmark": "sensor_speed",
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": f"{platform.machine()} {os.cpu_count()} cpus, {platform.python_implementation()} "
        f"{platform.python_version()}, numpy {np.__version__}",
        "town": town,
        "ticks": ticks,
        "quick": quick,
        "config": {
            "camera_size": list(cfg.camera_size),
            "rsu_camera_size": list(cfg.rsu_camera_size or ()),
            "ego_lidar": [cfg.ego_lidar.channels, cfg.ego_lidar.azimuth_steps],
            "rsu_lidar": [cfg.rsu_lidar.channels, cfg.rsu_lidar.azimuth_steps],
            "bev": [cfg.bev.size, cfg.bev.mpp],
            "actors": int(world.table.active.sum()),
        },
        "parts": rows,
        "full_rig_ticks_per_s": 1e3 / full["wall_ms"],
        "full_rig_ticks_per_s_cpu": 1e3 / full["cpu_ms"],
        "full_rig_ticks_per_s_best": 1e3 / full["wall_ms_min"],
        "env_step_ms": float(st[:, 0].mean()),
        "env_plus_rig_ticks_per_s": 1e3 / (full["wall_ms"] + float(st[:, 0].mean())),
        "goal_ticks_per_s": GOAL_TICKS_PER_S,
    }


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--town", default="Town01")
    p.add_argument("--ticks", type=int, default=40)
    p.add_argument("--warmup", type=int, default=20, help="world steps before measuring")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="tiny run for CI smoke tests")
    p.add_argument("--camera-size", default=None, help="ego (and RSU) camera WxH, e.g. 96x48")
    p.add_argument(
        "--rsu-camera-size", default=None, help="RSU camera WxH (default: --camera-size)"
    )
    p.add_argument("--out", default="benchmarks/results")
    args = p.parse_args()

    def size(v: str | None) -> tuple[int, int] | None:
        return None if v is None else tuple(int(x) for x in v.lower().split("x"))

    res = measure(
        args.town,
        3 if args.quick else args.ticks,
        2 if args.quick else args.warmup,
        args.seed,
        args.quick,
        size(args.camera_size),
        size(args.rsu_camera_size),
    )
    full = res["parts"]["full_rig"]["wall_ms"]
    print(
        f"sensor rig on {res['town']}, {res['ticks']} ticks, {res['config']['actors']} actors ({res['machine']})"
    )
    print(f"{'part':22s} {'wall ms':>8s} {'best ms':>8s} {'cpu ms':>8s} {'share':>6s}")
    for name, r in res["parts"].items():
        share = "" if name == "full_rig" else f"{100 * r['wall_ms'] / full:5.0f}%"
        print(
            f"{name:22s} {r['wall_ms']:8.2f} {r['wall_ms_min']:8.2f} {r['cpu_ms']:8.2f} {share:>6s}"
        )
    print(
        f"full rig: {res['full_rig_ticks_per_s']:.1f} ticks/s (mean wall), "
        f"{res['full_rig_ticks_per_s_cpu']:.1f} (mean CPU), {res['full_rig_ticks_per_s_best']:.1f} (best "
        f"tick); goal {GOAL_TICKS_PER_S:.0f}. env step {res['env_step_ms']:.2f} ms; env + rig "
        f"{res['env_plus_rig_ticks_per_s']:.1f} ticks/s"
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    suffix = "_quick" if args.quick else ""
    if args.camera_size and not args.quick:
        suffix = f"_{args.camera_size.lower()}"
    path = out / f"sensor_speed{suffix}.json"
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(res, indent=2))
    tmp.replace(path)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
