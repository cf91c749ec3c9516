"""``v2xbench aurora``: train AURORA's perception branches and measure them (issue #32)."""

from __future__ import annotations

import argparse

from v2xbench.cli.data import _int_in


def _threads(n: int | None) -> None:
    if n is not None:
        import torch

        torch.set_num_threads(n)


def _train(args: argparse.Namespace) -> int:
    from v2xbench.agents.aurora.cli import format_summary, train_stage

    _threads(args.threads)
    s = train_stage(args.data, args.out, args.stage, scale=args.scale, device=args.device,
                    max_steps=args.max_steps, stride=args.stride, seed=args.seed,
                    progress=not args.quiet, num_workers=args.workers)
    print(format_summary(s))
    return 0


def _eval(args: argparse.Namespace) -> int:
    from v2xbench.agents.aurora.eval_perception import evaluate_run

    _threads(args.threads)
    r = evaluate_run(args.run, args.data, args.split, args.out, device=args.device,
                     top_k=args.top_k, batch_size=args.batch_size, stride=args.stride,
                     pictures=args.pictures, progress=not args.quiet)
    print(r["table"], end="")
    print(f"written: {r['out']}/perception.json, perception.md, pictures/")
    return 0


def register(sub) -> None:
    """Add ``aurora`` (``train``, ``eval-perception``) to the ``v2xbench`` parser."""
    p = sub.add_parser("aurora", help="AURORA perception: train the ego / roadside branches, "
                       "evaluate them", description=__doc__)
    asub = p.add_subparsers(dest="aurora_command", required=True)
    t = asub.add_parser("train", help="train stage 1 (ego branch) or 2 (roadside branch)",
                        description="Train one AURORA perception stage on the train split of a "
                        "data set (resumes RUN/stage<N> when present).")
    t.add_argument("--stage", type=int, required=True, help="1: ego branch, 2: roadside branch")
    t.add_argument("--data", required=True, help="data set folder (v2xbench collect --out)")
    t.add_argument("--out", required=True, help="run folder RUN (the stage trains in RUN/stage<N>)")
    t.add_argument("--scale", default="default", help="tiny | default | paper (default: default)")
    t.add_argument("--device", default="cpu", help="torch device (default: cpu)")
    t.add_argument("--max-steps", type=_int_in(1), default=None,
                   help="stop after N optimizer steps in total (the same command resumes)")
    t.add_argument("--stride", type=_int_in(1), default=None,
                   help="use every K-th frame (default: the scale's frame stride)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--workers", type=_int_in(0), default=None,
                   help="data-loader worker processes (default: the scale's)")
    t.add_argument("--threads", type=_int_in(1), default=None,
                   help="torch threads (default: torch's, one per core)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=_train)
    e = asub.add_parser("eval-perception", help="detection metrics (paper's perception table) "
                        "and pictures of a trained run",
                        description="Evaluate every trained branch of RUN on a split: avg mAP, "
                        "NDS, mAP per class group; JSON, Markdown and pictures.")
    e.add_argument("--run", required=True, help="run folder (v2xbench aurora train --out)")
    e.add_argument("--data", required=True, help="data set folder (e.g. the test50 collection)")
    e.add_argument("--split", default="test", help="train | val | test | all (default: test)")
    e.add_argument("--out", default=None, help="output folder (default: RUN/eval_<split>)")
    e.add_argument("--device", default="cpu")
    e.add_argument("--top-k", type=_int_in(1), default=50, help="queries kept per frame")
    e.add_argument("--batch-size", type=_int_in(1), default=4)
    e.add_argument("--stride", type=_int_in(1), default=1, help="every K-th frame")
    e.add_argument("--pictures", type=_int_in(0), default=4, help="pictures per branch")
    e.add_argument("--threads", type=_int_in(1), default=None, help="torch threads")
    e.add_argument("--quiet", action="store_true")
    e.set_defaults(func=_eval)
