"""``v2xbench aurora``: train AURORA (stages 0-5, or all in one pipeline), export its weights,
measure its perception and planning, and ask it Chat-V2XBench questions."""

from __future__ import annotations

import argparse

from v2xbench.cli.data import _int_in


def _threads(n: int | None) -> None:
    if n is not None:
        import torch

        torch.set_num_threads(n)


def _train(args: argparse.Namespace) -> int:
    from v2xbench.agents.aurora.cli import check_stage, format_summary, train_stage

    _threads(args.threads)
    if check_stage(args.stage) == 0:  # stage 0: agents/aurora/stage0.py
        return _train_stage0(args)
    if args.stage >= 3:  # stages 3-5: agents/aurora/stages.py
        from v2xbench.agents.aurora.stages import format_late_summary, train_late_stage

        s = train_late_stage(args.data, args.out, args.stage, scale=args.scale,
                             device=args.device, max_steps=args.max_steps, stride=args.stride,
                             seed=args.seed, progress=not args.quiet, num_workers=args.workers,
                             lm=args.lm, fusion=not args.no_fusion, cache=not args.no_cache,
                             route_points=args.plan_route_points, qa=not args.no_qa,
                             speed_dropout=args.speed_dropout)
        print(format_late_summary(s))
        return 0
    _refuse_late_stage_options(args)
    s = train_stage(args.data, args.out, args.stage, scale=args.scale or "default",
                    device=args.device, max_steps=args.max_steps, stride=args.stride,
                    seed=args.seed, progress=not args.quiet, num_workers=args.workers)
    print(format_summary(s))
    return 0


def _refuse_late_stage_options(args: argparse.Namespace, note: str = "") -> None:
    """``ValueError`` when an option of stages 3-5 is given to stage 0, 1 or 2."""
    if args.lm is not None or args.no_fusion or args.no_cache or args.no_qa \
            or args.plan_route_points is not None or args.speed_dropout is not None:
        raise ValueError("--lm, --no-fusion, --no-qa, --no-cache, --plan-route-points and "
                         f"--speed-dropout apply to stages 3-5{note}")


def _train_stage0(args: argparse.Namespace) -> int:
    from v2xbench.agents.aurora.stage0 import format_stage0_summary, train_stage0

    _refuse_late_stage_options(args, " (--lm replaces stage 0's model)")
    s = train_stage0(args.data, args.out, scale=args.scale or "default", chat=args.chat,
                     device=args.device, max_steps=args.max_steps, stride=args.stride,
                     seed=args.seed, progress=not args.quiet)
    print(format_stage0_summary(s))
    return 0


def _pipeline(args: argparse.Namespace) -> int:
    from v2xbench.agents.aurora.pipeline import SUMMARY, format_pipeline_summary, run_pipeline

    _threads(args.threads)
    s = run_pipeline(args.data, args.out, scale=args.scale, fusion=not args.no_fusion,
                     lm=args.lm, device=args.device, max_steps=args.max_steps,
                     stride=args.stride, seed=args.seed, progress=not args.quiet,
                     qa=not args.no_qa)
    print(format_pipeline_summary(s), end="")
    print(f"written: {args.out}/{SUMMARY}.json, {SUMMARY}.md")
    return 0


def _export(args: argparse.Namespace) -> int:
    import shlex

    from v2xbench.agents.aurora.export import export_run

    stage = [] if args.stage is None else ["--stage", str(args.stage)]
    cmd = shlex.join(["v2xbench", "aurora", "export", "--run", str(args.run), *stage, "--out",
                      str(args.out), "--dtype", args.dtype])
    m = export_run(args.run, args.stage, args.out, dtype=args.dtype, command=cmd)
    total = sum(f["bytes"] for f in m["files"].values())
    for rel, f in m["files"].items():
        print(f"{f['bytes']:>11,d}  {f['sha256'][:16]}  {rel}")
    print(f"exported stage {m['stage']} of {args.run} ({m['scale']}, fusion {m['fusion']}, "
          f"{m['parameters']:,d} parameters, {m['dtype']}): {total / 1e6:.2f} MB in {args.out} "
          f"(manifest.json: SHA-256 of every file, commit {m['git_commit']})")
    return 0


def _ask(args: argparse.Namespace) -> int:
    from v2xbench.agents.aurora.answer import ask

    _threads(args.threads)
    r = ask(args.run, args.data, args.keyframe, args.question, lm=args.lm,
            max_new_tokens=args.max_new_tokens, device=args.device, stage=args.stage,
            weights=args.weights)
    print(r["note"])
    print(f"prompt:\n{r['prompt']}")
    print(f"answer: {r['answer']}")
    return 0


def _answer(args: argparse.Namespace) -> int:
    from v2xbench.agents.aurora.answer import answer_split

    _threads(args.threads)
    r = answer_split(args.run, args.data, args.split, args.out, chat=args.chat, lm=args.lm,
                     max_new_tokens=args.max_new_tokens, batch_size=args.batch_size,
                     device=args.device, progress=not args.quiet, stage=args.stage,
                     weights=args.weights, stride=args.stride)
    print(r["note"])
    print(f"answered {r['items']} items of split {args.split!r} in {r['wall_s']:.0f} s "
          f"({r['items_per_s']:.1f}/s) -> {r['out']}")
    if r["empty"]:
        print(f"warning: {r['empty']} of {r['items']} answers are empty (they score 0)")
    print(f"score: v2xbench qa score {r['qa']} {r['out']} --split {args.split}")
    return 0


def _eval(args: argparse.Namespace) -> int:
    from v2xbench.agents.aurora.eval_perception import evaluate_run

    _threads(args.threads)
    if args.fused:
        from v2xbench.agents.aurora.eval_fused import evaluate_fused

        r = evaluate_fused(args.run, args.data, args.split, args.out, stage=args.stage,
                           device=args.device, top_k=args.top_k, batch_size=args.batch_size,
                           stride=args.stride, progress=not args.quiet)
        print(r["markdown"], end="")
        print(f"written: {r['out']}/perception.json, perception.md")
        return 0
    if args.stage is not None:
        raise ValueError("--stage chooses the stage of --fused (the fused heads of stages 3-5); "
                         "without --fused the branches of stages 1-2 are evaluated")
    r = evaluate_run(args.run, args.data, args.split, args.out, device=args.device,
                     top_k=args.top_k, batch_size=args.batch_size, stride=args.stride,
                     pictures=args.pictures, progress=not args.quiet)
    print(r["table"], end="")
    print(f"written: {r['out']}/perception.json, perception.md, pictures/")
    return 0


def register(sub) -> None:
    """Add ``aurora`` and its sub-commands to the ``v2xbench`` parser."""
    p = sub.add_parser("aurora", help="AURORA: train (stages 0-5, pipeline), export, evaluate "
                       "perception and planning, ask / answer", description=__doc__)
    asub = p.add_subparsers(dest="aurora_command", required=True)
    t = asub.add_parser("train", help="train one stage (1 ego branch, 2 roadside branch, "
                        "3 fusion + QA, 4 planning, 5 joint)",
                        description="Train one AURORA stage on the train split of a data set "
                        "(resumes RUN/stage<N> when present). Stages 3-5 need stages 1-2 in RUN "
                        "and the data set's QA items (v2xbench qa build).")
    t.add_argument("--chat", default=None,
                   help="stage 0: folder (or file) of the hint-free qa.jsonl (default DATA/chat; "
                   "v2xbench qa build DATA --out DIR)")
    t.add_argument("--stage", type=int, required=True,
                   help="0: language-model pre-training, 1: ego branch, 2: roadside branch, "
                   "3: fusion + QA (CQAF, LoRA), 4: planning, 5: joint QA + planning")
    t.add_argument("--data", required=True, help="data set folder (v2xbench collect --out)")
    t.add_argument("--out", required=True, help="run folder RUN (the stage trains in RUN/stage<N>)")
    t.add_argument("--scale", default=None,
                   help="tiny | default | paper (default: default; stages 3-5: the run's)")
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
    t.add_argument("--lm", default=None, help="stage 3: a local Hugging Face causal-LM folder "
                   "as the base LM (default: RUN/stage0, else a freshly built LM)")
    t.add_argument("--no-fusion", action="store_true", help="stages 3-5: train the No Fusion "
                   "model (roadside messages dropped)")
    t.add_argument("--no-qa", action="store_true", help="stages 3-5: drop the Chat-V2XBench "
                   "(QA) loss, the VQA ablation (stage 3 trains CQAF's fused heads on planning "
                   "frames; stage 5 on planning samples only)")
    t.add_argument("--no-cache", action="store_true", help="stages 3-5: run the frozen "
                   "branches every step instead of caching their outputs")
    t.add_argument("--plan-route-points", type=_int_in(0), default=None, metavar="K",
                   help="stages 3-4: the planner's route input, K route points ahead (0: none, "
                   "the paper's inputs; default: the run's, else the scale's); stage 5 keeps "
                   "stage 4's")
    t.add_argument("--speed-dropout", type=float, default=None, metavar="P",
                   help="stage 4: share of planning prompts whose ego speed reads 'unknown' "
                   "(default: the scale's, 0.15; 1: the planner never reads the speed and the "
                   "agent never says it: docs/aurora.md, 'A sixth run', on the planner copying the "
                   "speed it is told); stage 5 keeps stage 4's")
    t.set_defaults(func=_train)
    _register_pipeline(asub)
    x = asub.add_parser("export", help="write what inference needs of a trained stage (weights "
                        "+ manifest with SHA-256)", description="Export one stage of a run for "
                        "inference: weights.safetensors (float16 by default), the base LM's "
                        "config and tokenizer, the run file and manifest.json (SHA-256 and size "
                        "of every file, source, command, git commit, date). The aurora and "
                        "no_fusion agents load agents/aurora/weights/<name> when no run is given.")
    x.add_argument("--run", required=True, help="the trained run folder")
    x.add_argument("--stage", type=int, choices=(3, 4, 5), default=None,
                   help="stage to export (default: the run's latest of 3-5)")
    x.add_argument("--out", required=True, help="output folder, e.g. agents/aurora/weights/aurora")
    x.add_argument("--dtype", default="float16", choices=("float16", "bfloat16", "float32"),
                   help="storage type of floating tensors (default: float16)")
    x.set_defaults(func=_export)
    e = asub.add_parser("eval-perception", help="detection metrics (paper's perception table) "
                        "and pictures of a trained run",
                        description="Evaluate every trained branch of RUN on a split: avg mAP, "
                        "NDS, mAP per class group; JSON, Markdown and pictures. With --fused: "
                        "the fused heads of a fusion run's stage 3-5 (CQAF with the roadside "
                        "unit's float16 message) against gt/fused and gt/ego, beside the same "
                        "checkpoint's ego branch on the same frames.")
    e.add_argument("--run", required=True, help="run folder (v2xbench aurora train --out)")
    e.add_argument("--data", required=True, help="data set folder (e.g. the test50 collection)")
    e.add_argument("--split", default="test", help="train | val | test | all (default: test)")
    e.add_argument("--out", default=None, help="output folder (default: RUN/eval_<split>)")
    e.add_argument("--device", default="cpu")
    e.add_argument("--top-k", type=_int_in(1), default=50, help="queries kept per frame")
    e.add_argument("--batch-size", type=_int_in(1), default=4)
    e.add_argument("--stride", type=_int_in(1), default=1, help="every K-th frame")
    e.add_argument("--pictures", type=_int_in(0), default=4, help="pictures per branch")
    e.add_argument("--fused", action="store_true", help="evaluate the fused heads of a fusion "
                   "run (refused for a No Fusion run; default out: RUN/eval_fused_<split>)")
    e.add_argument("--stage", type=int, choices=(3, 4, 5), default=None,
                   help="with --fused: the stage (default: the run's latest)")
    e.add_argument("--threads", type=_int_in(1), default=None, help="torch threads")
    e.add_argument("--quiet", action="store_true")
    e.set_defaults(func=_eval)
    _register_answering(asub)
    _register_planning(asub)


def _eval_planning(args: argparse.Namespace) -> int:
    import shlex

    from v2xbench.agents.aurora.eval_planning import evaluate_planning

    _threads(args.threads)
    src = ["--run", str(args.run)] if args.run is not None else ["--weights", str(args.weights)]
    opt = [] if args.stage is None else ["--stage", str(args.stage)]
    opt += [] if args.out is None else ["--out", str(args.out)]
    opt += [] if args.threads is None else ["--threads", str(args.threads)]
    cmd = shlex.join(["v2xbench", "aurora", "eval-planning", *src, *opt, "--data",
                      str(args.data), "--split", args.split, "--stride", str(args.stride)])
    r = evaluate_planning(args.data, run=args.run, weights=args.weights, stage=args.stage,
                          split=args.split, stride=args.stride, out=args.out,
                          batch_size=args.batch_size, device=args.device,
                          progress=not args.quiet, command=cmd)
    print(r["table"], end="")
    print(f"written: {r['out']}/metrics.json, metrics.md")
    return 0


def _register_planning(asub) -> None:
    """``aurora eval-planning`` (:mod:`v2xbench.agents.aurora.eval_planning`)."""
    g = asub.add_parser("eval-planning", help="open-loop planning metrics on recorded frames "
                        "(L2 at 1/2/3 s vs a constant-velocity baseline, collision rate, start "
                        "from rest)", description="Run the trained planner (the closed-loop "
                        "policy's inference pass; fusion runs get the roadside message of the "
                        "recorded roadside camera) on every K-th frame of a split and report, "
                        "overall and per navigation command, L2 to the expert's waypoints at 1, "
                        "2, 3 s, the same for driving straight on at the current speed, the "
                        "collision rate against gt/fused actors moved at constant velocity, and "
                        "the predicted vs expert speed when starting from rest. Writes "
                        "metrics.json and metrics.md.")
    _planner_eval_args(g, (3, 4, 5), "test", 50, "eval_planning",
                       split_note="; a test50 collection made before route_split labels its "
                       "routes train/val: use all")
    g.set_defaults(func=_eval_planning)
    _register_speed_probe(asub)


def _speed_probe(args: argparse.Namespace) -> int:
    from v2xbench.agents.aurora.speed_probe import probe_speed

    _threads(args.threads)
    r = probe_speed(args.data, run=args.run, weights=args.weights, stage=args.stage,
                    split=args.split, stride=args.stride, out=args.out,
                    batch_size=args.batch_size, device=args.device, progress=not args.quiet)
    print(r["table"], end="")
    print(f"written: {r['out']}/metrics.json, metrics.md")
    return 0


def _register_speed_probe(asub) -> None:
    """``aurora speed-probe`` (:mod:`v2xbench.agents.aurora.speed_probe`)."""
    g = asub.add_parser("speed-probe", help="how much the planned speed follows the speed the "
                        "prompt says (inertia)", description="Run the trained planner over "
                        "every K-th planning frame of a split five times, the prompt saying the "
                        "frame's speed, 0, 1 and 3 m/s, and 'unknown', and tabulate the planned "
                        "speed (waypoints 0-1) by the ego's true speed and what the expert does "
                        "next (speeds up / slows / steady). Writes metrics.json and metrics.md.")
    _planner_eval_args(g, (4, 5), "val", 3, "speed_probe")
    g.set_defaults(func=_speed_probe)


def _planner_eval_args(g, stages: tuple[int, ...], split: str, stride: int, out: str,
                       split_note: str = "") -> None:
    """The options of a command that runs a trained planner over recorded frames: the model
    (``--run`` [``--stage``] or ``--weights``), the frames, the output folder, inference."""
    src = g.add_mutually_exclusive_group(required=True)
    src.add_argument("--run", default=None, help=f"trained run folder (stages "
                     f"{stages[0]}-{stages[-1]})")
    src.add_argument("--weights", default=None, help="exported weights folder (v2xbench aurora "
                     "export), e.g. agents/aurora/weights/aurora")
    g.add_argument("--stage", type=int, choices=stages, default=None,
                   help="with --run: the stage (default: the run's latest)")
    g.add_argument("--data", required=True, help="data set folder (v2xbench collect --out)")
    g.add_argument("--split", default=split,
                   help=f"train | val | test | all (default: {split}{split_note})")
    g.add_argument("--stride", type=_int_in(1), default=stride,
                   help=f"every K-th frame of each episode (default: {stride})")
    g.add_argument("--out", default=None, help=f"output folder (default: RUN/{out}, or "
                   f"./{out}/NAME for --weights DIR)")
    g.add_argument("--batch-size", type=_int_in(1), default=8)
    g.add_argument("--device", default="cpu")
    g.add_argument("--threads", type=_int_in(1), default=None, help="torch threads")
    g.add_argument("--quiet", action="store_true", help="no progress output")


def _register_pipeline(asub) -> None:
    """``aurora pipeline`` (:mod:`v2xbench.agents.aurora.pipeline`)."""
    p = asub.add_parser("pipeline", help="train stages 0-5 in order (resume, skip complete "
                        "stages, summary)", description="Run stages 0 (language model), 1 (ego "
                        "branch), 2 (roadside branch), 3 (fusion + QA), 4 (planning) and 5 "
                        "(joint) into RUN, as `aurora train --stage N` does each: a complete stage "
                        "is skipped, an incomplete one resumed. Writes RUN/pipeline_summary.json "
                        "and .md (final losses, steps, time per stage). Needs the data set's QA "
                        "items (v2xbench qa build).")
    p.add_argument("--data", required=True, help="data set folder (v2xbench collect --out)")
    p.add_argument("--out", required=True, help="run folder RUN")
    p.add_argument("--scale", default="default", help="tiny | default | paper (default: default)")
    p.add_argument("--no-fusion", action="store_true", help="stages 3-5: the No Fusion model")
    p.add_argument("--no-qa", action="store_true", help="stages 3-5 without the Chat-V2XBench "
                   "(QA) loss: the VQA ablation")
    p.add_argument("--lm", default=None, help="a local Hugging Face causal-LM folder as the base "
                   "LM (stage 0 is then not run)")
    p.add_argument("--device", default="cpu", help="torch device (default: cpu)")
    p.add_argument("--max-steps", type=_int_in(1), default=None,
                   help="stop each stage after N optimizer steps; the pipeline stops after a "
                   "stage left incomplete (the same command goes on)")
    p.add_argument("--stride", type=_int_in(1), default=None,
                   help="every K-th frame / QA item in every stage (default: each stage's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=_int_in(1), default=None, help="torch threads")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_pipeline)


def _model_args(p) -> None:
    """``--stage`` / ``--weights``: answer with the whole stage-3+ system instead of stage 0."""
    p.add_argument("--stage", type=int, choices=(3, 4, 5), default=None,
                   help="answer with the whole system of RUN/stage<N> (cameras, roadside "
                   "message, CQAF, fused tokens, LoRA LM); default: RUN/stage0 on the text alone")
    p.add_argument("--weights", default=None, help="answer with the whole system of exported "
                   "weights (v2xbench aurora export), instead of --run/--stage")


def _register_answering(asub) -> None:
    """``aurora ask`` and ``aurora answer`` (:mod:`v2xbench.agents.aurora.answer`)."""
    a = asub.add_parser("ask", help="answer a question about a recorded frame with the run's "
                        "language model", description="Generate an answer (greedy) from the "
                        "run-time prompt of one recorded frame: speed, navigation command, the "
                        "roadside unit's pose and the question; never ground-truth objects. The "
                        "model is RUN/stage0 (or --lm) on the text prompt alone, or with --stage "
                        "/ --weights the whole system on the frame's cameras.")
    _model_args(a)
    a.add_argument("question", help="the question, e.g. \"Should the ego stop?\"")
    a.add_argument("--run", default=None, help="run folder (v2xbench aurora train --out)")
    a.add_argument("--data", required=True, help="data set folder holding the frame")
    a.add_argument("--keyframe", required=True,
                   help="<episode>_t<tick>, e.g. train_000_s0_t00120 (any recorded tick)")
    a.add_argument("--lm", default=None,
                   help="a local Hugging Face causal-LM folder instead of RUN/stage0")
    a.add_argument("--max-new-tokens", type=_int_in(1), default=192)
    a.add_argument("--device", default="cpu")
    a.add_argument("--threads", type=_int_in(1), default=None, help="torch threads")
    a.set_defaults(func=_ask)
    w = asub.add_parser("answer", help="answer every Chat-V2XBench item of a split (JSONL for "
                        "`v2xbench qa score`)", description="Answer the hint-free QA items of a "
                        "split with the run's language model; writes {id, answer} lines to score "
                        "with `v2xbench qa score QA PRED --split SPLIT` (per kind, type, level).")
    _model_args(w)
    w.add_argument("--stride", type=_int_in(1), default=1, help="every K-th item of the split "
                   "(K > 1 also writes OUT.ref.jsonl, the answered items' reference to score)")
    w.add_argument("--run", default=None, help="run folder (v2xbench aurora train --out)")
    w.add_argument("--data", required=True, help="data set folder (its chat/qa.jsonl)")
    w.add_argument("--chat", default=None, help="folder or file of qa.jsonl (default DATA/chat)")
    w.add_argument("--split", default="test", help="train | val | test | all (default: test)")
    w.add_argument("--out", required=True, help="predictions file (JSONL)")
    w.add_argument("--lm", default=None,
                   help="a local Hugging Face causal-LM folder instead of RUN/stage0")
    w.add_argument("--batch-size", type=_int_in(1), default=32)
    w.add_argument("--max-new-tokens", type=_int_in(1), default=192)
    w.add_argument("--device", default="cpu")
    w.add_argument("--threads", type=_int_in(1), default=None, help="torch threads")
    w.add_argument("--quiet", action="store_true", help="no progress bar")
    w.set_defaults(func=_answer)
