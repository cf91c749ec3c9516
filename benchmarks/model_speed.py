"""AURORA model speed: training samples/s per stage and inference ms per frame per branch.

``v2xbench bench-model`` (or ``python -m v2xbench.benchmarks.model_speed``). For each scale
(``--scales``, default ``tiny,default``) and each stage (1: ego branch, 6 cameras; 2: roadside
branch, 1 camera) it builds the branch, its criterion and AdamW, and times on this machine:

- ``train``: optimizer steps (forward, set-prediction loss with Hungarian matching, backward,
  clipping, AdamW) on batches of the stage's batch size, in samples/s;
- ``infer``: one frame at a time (``eval``, ``no_grad``), in ms per frame.

Batches are synthetic but shaped like the data set's (images, the default rig's calibration,
10 boxes and ``num_map_queries / 2`` polylines per frame), so the model's cost is measured
apart from data loading. With ``--data DIR`` it also times loading samples from a collected
data set (:class:`~v2xbench.agents.aurora.data.AuroraFrames`, one process) and says, per stage,
whether loading or compute bounds a training step. Torch runs on ``--threads`` threads
(default 1). Prints a table, writes ``OUT/model_speed.json`` and ``.md`` atomically.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from datetime import datetime, timezone
from pathlib import Path

STAGES = {1: "ego", 2: "rsu"}


def synthetic_batch(cfg, branch: str, batch_size: int, seed: int = 0) -> dict:
    """A batch shaped like :class:`AuroraFrames`' (random pixels and targets, real geometry)."""
    import numpy as np
    import torch
    from v2xbench.agents.aurora.calib import camera_tensors, rsu_ground_pose
    from v2xbench.envs.v2x_intersection.core.geometry import pose_matrix
    from v2xbench.envs.v2x_intersection.sensors.camera import ego_camera_specs, rsu_camera_spec
    from v2xbench.envs.v2x_intersection.v2x.rsu import RSU_HEIGHT, RSU_PITCH, RSU_ROLL

    g = torch.Generator().manual_seed(seed)
    w, h = cfg.image_size(branch)
    if branch == "ego":
        specs = ego_camera_specs(w, h)
        t_ego_cam = np.stack([s.T_parent_optical() for s in specs])
        t_ego_frame = np.eye(4)
    else:
        specs = (rsu_camera_spec(w, h),)
        t_wr = pose_matrix(10.0, -6.0, RSU_HEIGHT, 2.5, RSU_PITCH, RSU_ROLL)
        t_ego_cam = t_wr @ specs[0].T_parent_optical()[None]
        t_ego_frame = rsu_ground_pose(t_wr)
    k, c2f = camera_tensors(np.stack([s.intrinsics for s in specs]), t_ego_cam, t_ego_frame,
                            (w, h))
    n, m, kq, p = len(specs), 96, cfg.num_map_queries, cfg.map_points
    lo = torch.tensor(cfg.pc_range(branch)[:3])
    span = torch.tensor(cfg.pc_range(branch)[3:]) - lo
    boxes = torch.zeros(batch_size, m, 10)
    boxes[..., :3] = lo + span * torch.rand(batch_size, m, 3, generator=g)
    boxes[..., 3:6] = torch.tensor([4.5, 1.9, 1.6])
    yaw = 6.28 * torch.rand(batch_size, m, generator=g)
    boxes[..., 6], boxes[..., 7] = yaw.sin(), yaw.cos()
    pts = lo[:2] + span[:2] * torch.rand(batch_size, kq, p, 2, generator=g)
    batch = {
        "images": torch.rand(batch_size, n, 3, h, w, generator=g),
        "intrinsics": k.expand(batch_size, -1, -1, -1).contiguous(),
        "cam_to_frame": c2f.expand(batch_size, -1, -1, -1).contiguous(),
        "det_boxes": boxes,
        "det_labels": torch.randint(0, cfg.num_classes, (batch_size, m), generator=g),
        "det_mask": torch.arange(m).expand(batch_size, -1) < 10,
        "map_points": pts,
        "map_labels": torch.randint(0, 3, (batch_size, kq), generator=g),
        "map_mask": torch.arange(kq).expand(batch_size, -1) < max(1, kq // 2),
        "map_closed": torch.zeros(batch_size, kq, dtype=torch.bool),
        "frame_id": torch.arange(batch_size),
    }
    if branch == "ego":
        batch["light"] = torch.randint(0, cfg.num_light_classes, (batch_size,), generator=g)
    return batch


def _train_speed(cfg, stage: int, steps: int, warmup: int) -> dict:
    import torch
    from v2xbench.agents.aurora.branch import PerceptionBranch
    from v2xbench.agents.aurora.losses import SetCriterion

    branch, hp = STAGES[stage], cfg.stage_hparams(stage)
    torch.manual_seed(0)
    model, crit = PerceptionBranch(cfg, branch), SetCriterion(cfg, branch)
    opt = torch.optim.AdamW(model.parameters(), lr=hp.lr, betas=hp.betas,
                            weight_decay=hp.weight_decay)
    batch = synthetic_batch(cfg, branch, hp.batch_size)
    times = []
    model.train()
    for i in range(warmup + steps):
        t0 = time.perf_counter()
        loss, _ = crit(model(batch), batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), max(hp.grad_clip, 1e-6))
        opt.step()
        if i >= warmup:
            times.append(time.perf_counter() - t0)
    step_s = sum(times) / len(times)
    return {"batch_size": hp.batch_size, "step_s": step_s, "samples_per_s": hp.batch_size / step_s,
            "params": sum(p.numel() for p in model.parameters())}


def _infer_speed(cfg, branch: str, frames: int, warmup: int) -> float:
    import torch
    from v2xbench.agents.aurora.branch import PerceptionBranch

    model = PerceptionBranch(cfg, branch).eval()
    batch = synthetic_batch(cfg, branch, 1)
    times = []
    with torch.no_grad():
        for i in range(warmup + frames):
            t0 = time.perf_counter()
            model(batch)
            if i >= warmup:
                times.append(time.perf_counter() - t0)
    return 1e3 * sum(times) / len(times)


def _load_speed(cfg, data: str, branch: str, samples: int, stride: int) -> float:
    from v2xbench.agents.aurora.data import AuroraFrames

    ds = AuroraFrames(data, "train", branch, cfg, stride=stride)
    idx = [int(i) for i in range(0, len(ds), max(1, len(ds) // samples))][:samples]
    t0 = time.perf_counter()
    for i in idx:
        ds[i]
    return 1e3 * (time.perf_counter() - t0) / len(idx)


def measure(scales: tuple[str, ...] = ("tiny", "default"), steps: int = 5, warmup: int = 2,
            frames: int = 10, data: str | None = None, load_samples: int = 40,
            threads: int = 1) -> dict:
    """Run the benchmark (module docstring); returns a JSON-able dict."""
    import torch
    from v2xbench.agents.aurora.config import AuroraConfig

    torch.set_num_threads(threads)
    rows = []
    for scale in scales:
        cfg = AuroraConfig.for_scale(scale)
        for stage, branch in STAGES.items():
            row = {"scale": scale, "stage": stage, "branch": branch,
                   **_train_speed(cfg, stage, steps, warmup),
                   "infer_ms_per_frame": _infer_speed(cfg, branch, frames, warmup)}
            if data is not None:
                stride = cfg.stage_hparams(stage).frame_stride
                row["load_ms_per_sample"] = _load_speed(cfg, data, branch, load_samples, stride)
                load_s = row["load_ms_per_sample"] * row["batch_size"] / 1e3
                row["bound_by"] = "data loading" if load_s > row["step_s"] else "compute"
                row["load_share"] = load_s / (load_s + row["step_s"])
            rows.append(row)
    return {"benchmark": "model_speed",
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "machine": f"{platform.machine()} {os.cpu_count()} cpus, python "
                       f"{platform.python_version()}, torch {torch.__version__}",
            "threads": threads, "steps": steps, "data": data, "rows": rows}


def table(res: dict) -> str:
    """Markdown table of :func:`measure`'s rows."""
    data = res["data"] is not None
    head = "| scale | stage (branch) | batch | train samples/s | infer ms/frame | params |"
    sep = "|---|---|---|---|---|---|"
    if data:
        head += " load ms/sample | step bound by |"
        sep += "---|---|"
    lines = [head, sep]
    for r in res["rows"]:
        line = (f"| {r['scale']} | {r['stage']} ({r['branch']}) | {r['batch_size']} | "
                f"{r['samples_per_s']:.2f} | {r['infer_ms_per_frame']:.1f} | "
                f"{r['params'] / 1e6:.2f} M |")
        if data:
            line += f" {r['load_ms_per_sample']:.1f} | {r['bound_by']} |"
        lines.append(line)
    return "\n".join(lines) + "\n"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scales", default="tiny,default", help="comma-separated AURORA scales")
    p.add_argument("--steps", type=int, default=5, help="timed training steps per stage")
    p.add_argument("--frames", type=int, default=10, help="timed inference frames per branch")
    p.add_argument("--data", default=None, help="data set folder: also time sample loading")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--quick", action="store_true", help="tiny scale, 1 step: a smoke test")
    p.add_argument("--out", default="benchmarks/results", help="folder for model_speed.json/.md")


def run(args: argparse.Namespace) -> int:
    from v2xbench.files import atomic_write_json, atomic_write_text

    scales = tuple(s.strip() for s in args.scales.split(",") if s.strip())
    if args.steps < 1 or args.frames < 1 or args.threads < 1:
        raise ValueError("bench-model: --steps, --frames and --threads must be >= 1")
    if args.data is not None and not Path(args.data).is_dir():
        raise FileNotFoundError(f"bench-model: data directory {args.data} does not exist")
    if args.quick:
        res = measure(("tiny",), 1, 1, 2, args.data, 4, args.threads)
    else:
        res = measure(scales, args.steps, 2, args.frames, args.data, 40, args.threads)
    md = table(res)
    out = Path(args.out)
    suffix = "_quick" if args.quick else ""
    atomic_write_json(out / f"model_speed{suffix}.json", res, indent=2)
    atomic_write_text(out / f"model_speed{suffix}.md",
                      f"AURORA model speed, {res['machine']}, {res['threads']} torch thread(s), "
                      f"{res['date']}\n\n{md}")
    print(md, end="")
    print(f"wrote {out / f'model_speed{suffix}.json'} and .md")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="v2xbench bench-model", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
