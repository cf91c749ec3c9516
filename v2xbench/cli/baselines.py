"""``v2xbench baselines``: train the paper's cooperative baselines (issue #34) and measure their
perception. Each method trains with AURORA's loop (resume, logs, plots) and drives through
``v2xbench eval --agent NAME --agent-config FILE`` with ``{"run": RUN}``."""

from __future__ import annotations

import argparse

from v2xbench.cli.data import _int_in

#: Methods with a command here (name -> what it is). Each one's module (``BASELINES[name]`` in
#: :mod:`v2xbench.agents.baselines`) has a ``train`` submodule with ``train(data, out, **kw)``,
#: ``format_summary(summary)``, ``evaluate_perception(run, data, split, **kw)`` and
#: ``evaluate_planning(run, data, split, **kw)``.
METHODS = {"codriving": "CoDriving (Liu et al., IEEE TPAMI 2025): LiDAR pillars, driving-oriented "
           "sparse BEV cells (route request x roadside confidence), max fusion, native PID",
           "univ2x": "UniV2X (Yu et al., AAAI 2025): camera, sparse agent queries + dense "
           "occupancy, query planner",
           "unimm_v2x": "UniMM-V2X (Song et al., AAAI 2026): camera, MoE BEV and motion decoder, "
           "perception + prediction queries shared, query planner",
           "v2x_vit": "V2X-ViT (Xu et al., ECCV 2022): LiDAR pillars, roadside BEV features "
           "(1x1 bottleneck), HMSA + multi-scale window attention, delay encoding"}


def _train_module(method: str):
    """The ``train`` module of a baseline (imported on use: torch loads only then)."""
    import importlib

    from v2xbench.agents.baselines import BASELINES

    return importlib.import_module(BASELINES[method] + ".train")


def _threads(n: int | None) -> None:
    import torch

    torch.set_num_threads(n if n is not None else 1)


def _train(args: argparse.Namespace) -> int:
    m = _train_module(args.method)
    _threads(args.threads)
    s = m.train(args.data, args.out, scale=args.scale, device=args.device,
                     max_steps=args.max_steps, stride=args.stride, seed=args.seed,
                     progress=not args.quiet, num_workers=args.workers,
                     overrides=_overrides(args), rest_stride=args.rest_stride,
                     start_stride=args.start_stride)
    print(m.format_summary(s))
    return 0


def _overrides(args: argparse.Namespace) -> dict | None:
    """The configuration fields the train command's switches set (``None``: the scale's)."""
    out = {**({} if args.ego_speed is None else {"plan_ego_speed": args.ego_speed}),
           **({} if args.plan_frame is None else {"plan_frame": args.plan_frame}),
           **({} if args.msg_latency_ticks is None
              else {"msg_latency_ticks": args.msg_latency_ticks})}
    return out or None


def _eval_perception(args: argparse.Namespace) -> int:
    m = _train_module(args.method)
    _threads(args.threads)
    r = m.evaluate_perception(args.run, args.data, args.split, out=args.out, stride=args.stride,
                            top_k=args.top_k, batch_size=args.batch_size, device=args.device,
                            progress=not args.quiet)
    print(r["markdown"], end="")
    print(f"message: {r['message_floats']:,d} floats = {r['message_bytes']:,d} bytes on air; "
          f"written: {r['out']}/perception.json, perception.md")
    return 0


def _eval_planning(args: argparse.Namespace) -> int:
    import shlex

    m = _train_module(args.method)
    _threads(args.threads)
    opt = [] if args.out is None else ["--out", str(args.out)]
    opt += [] if args.ego_speed is None else ["--ego-speed", f"{args.ego_speed:g}"]
    cmd = shlex.join(["v2xbench", "baselines", "eval-planning", args.method, "--run",
                      str(args.run), *opt, "--data", str(args.data), "--split", args.split,
                      "--stride", str(args.stride)])
    r = m.evaluate_planning(args.run, args.data, args.split, out=args.out, stride=args.stride,
                            batch_size=args.batch_size, device=args.device,
                            progress=not args.quiet, command=cmd, ego_speed=args.ego_speed)
    print(r["table"], end="")
    print(f"written: {r['out']}/metrics.json, metrics.md")
    return 0


def _export(args: argparse.Namespace) -> int:
    import shlex

    from v2xbench.agents.baselines.common.export import export_dir, export_run

    cmd = shlex.join(["v2xbench", "baselines", "export", args.method, "--run", str(args.run),
                      *([] if args.out is None else ["--out", str(args.out)])])
    m = export_run(args.method, args.run, args.out, command=cmd)
    size = sum(f["bytes"] for f in m["files"].values())
    print(f"exported {args.method} ({m['scale']}, {m['parameters']:,d} parameters, plan_frame "
          f"{m['plan_frame']!r}, told the speed: {m['plan_ego_speed']}) of {args.run} into "
          f"{export_dir(args.method, args.out)} ({size / 1e6:.1f} MB)")
    return 0


def register(sub) -> None:
    """Add ``baselines train``, ``export``, ``eval-perception`` and ``eval-planning`` to the
    ``v2xbench`` parser."""
    p = sub.add_parser("baselines", help="the paper's cooperative baselines: train, export, "
                       "evaluate perception and open-loop planning (drive them with `v2xbench "
                       "eval --agent NAME`)",
                       description=__doc__)
    bsub = p.add_subparsers(dest="baselines_command", required=True)
    t = bsub.add_parser("train", help="train a baseline on the train split of a data set",
                        description="Train a baseline end to end (both the roadside and the ego "
                        "half) with AURORA's loop: checkpoints every epoch and when stopped; the "
                        "same command on the same --out resumes. Methods: " + "; ".join(
                            f"{k}: {v}" for k, v in METHODS.items()))
    t.add_argument("method", choices=sorted(METHODS), help="the baseline")
    t.add_argument("--data", required=True, help="data set folder (v2xbench collect --out)")
    t.add_argument("--out", required=True, help="run folder RUN")
    t.add_argument("--scale", default="default", choices=("tiny", "default", "paper"),
                   help="model size and training settings (default: default)")
    t.add_argument("--max-steps", type=_int_in(1), default=None,
                   help="stop after N optimizer steps in total (run again to go on)")
    t.add_argument("--stride", type=_int_in(1), default=None,
                   help="every K-th frame of each episode (default: the scale's)")
    t.add_argument("--rest-stride", type=_int_in(0), default=None,
                   help="every K-th frame where the ego stands and the expert stays (0: "
                   "--stride; default: the scale's); fewer of these teach a standing car to "
                   "stay less (agents/aurora/frame_balance.py)")
    t.add_argument("--start-stride", type=_int_in(0), default=None,
                   help="every K-th frame where the standing ego sets off (0: --stride; "
                   "default: the scale's)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--device", default="cpu", help="torch device (default: cpu)")
    t.add_argument("--workers", type=_int_in(0), default=None,
                   help="data-loader worker processes (default: the scale's)")
    t.add_argument("--threads", type=_int_in(1), default=None,
                   help="torch threads (default: 1)")
    t.add_argument("--ego-speed", action=argparse.BooleanOptionalAction, default=None,
                   help="whether the planner is told the ego's speed (config plan_ego_speed; "
                   "default: no, in training and closed loop alike)")
    frame = t.add_mutually_exclusive_group()
    frame.add_argument("--route-frame", dest="plan_frame", action="store_const", const="route",
                       help="the planner plans along the observed route, AURORA's "
                       "route-relative output (config plan_frame='route'; the default)")
    frame.add_argument("--ego-frame", dest="plan_frame", action="store_const", const="ego",
                       help="the published planners' ego-frame x, y steps (config "
                       "plan_frame='ego')")
    t.add_argument("--msg-latency-ticks", type=_int_in(0), default=None, metavar="N",
                   help="training samples pair the ego's tick with the roadside's of N "
                   "ticks earlier, none before the first message arrives (default 1: the "
                   "channel's latency; 0: UniV2X / UniMM-V2X runs trained before the second, "
                   "V2X-ViT / CoDriving runs before the third stop of 2026-11-28; V2X-ViT / "
                   "CoDriving draw older ages up to train_max_delay too)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=_train)
    e = bsub.add_parser("eval-perception", help="detection metrics of a trained baseline on a "
                        "split (AURORA's metrics code)", description="Run the trained model over "
                        "every K-th frame of a split and score its fused detections against "
                        "gt/fused (ego range) with the nuScenes-style metrics AURORA uses; writes "
                        "perception.json and perception.md.")
    x = bsub.add_parser("export", help="write a trained run's weights as shipped weights "
                        "(SHA-256 manifest)", description="Copy what the registered agent needs "
                        "of a trained run (weights, run file) into a folder with a SHA-256 "
                        "manifest; `v2xbench eval --agent NAME` without --agent-config loads "
                        "agents/baselines/weights/NAME, the default --out.")
    x.add_argument("method", choices=sorted(METHODS), help="the baseline")
    x.add_argument("--run", required=True, help="trained run folder")
    x.add_argument("--out", default=None,
                   help="output folder (default: agents/baselines/weights/METHOD)")
    x.set_defaults(func=_export)
    _eval_arguments(e, stride=5, out="RUN/eval_<split>")
    e.add_argument("--top-k", type=_int_in(1), default=50, help="predictions per frame")
    e.set_defaults(func=_eval_perception)
    e = bsub.add_parser("eval-planning", help="open-loop planning of a trained baseline on a "
                        "split (AURORA's metrics: L2 at 1/2/3 s, collision rate)",
                        description="Run the trained model (both halves: the roadside message "
                        "from the frame's recorded roadside sensors) over every K-th frame of "
                        "each episode of a split and score its waypoints against the expert's "
                        "with the metrics of `v2xbench aurora eval-planning` (the same frames for "
                        "the same --split and --stride); writes metrics.json and metrics.md.")
    _eval_arguments(e, stride=50, out="RUN/eval_planning")
    e.add_argument("--ego-speed", type=float, default=None, metavar="M",
                   help="tell the model this speed (m/s) on every frame instead of the frame's "
                   "own: how much its plans lean on the ego's speed")
    e.set_defaults(func=_eval_planning)


def _eval_arguments(e: argparse.ArgumentParser, stride: int, out: str) -> None:
    """The arguments the two evaluation commands share (``stride`` and ``out``: defaults)."""
    e.add_argument("method", choices=sorted(METHODS), help="the baseline")
    e.add_argument("--run", required=True, help="trained run folder")
    e.add_argument("--data", required=True, help="data set folder")
    e.add_argument("--split", default="test", help="train | val | test | all (default: test)")
    e.add_argument("--stride", type=_int_in(1), default=stride,
                   help=f"every K-th frame of each episode (default: {stride})")
    e.add_argument("--batch-size", type=_int_in(1), default=4)
    e.add_argument("--out", default=None, help=f"output folder (default: {out})")
    e.add_argument("--device", default="cpu")
    e.add_argument("--threads", type=_int_in(1), default=None, help="torch threads (default: 1)")
    e.add_argument("--quiet", action="store_true")
