"""Open-loop planning evaluation of a trained AURORA system on recorded frames.

``v2xbench aurora eval-planning --run RUN | --weights DIR --data DIR`` runs the system's planner
on every ``stride``-th frame of each episode of a split, through the closed-loop policy's model
(:class:`~.system.AuroraSystem` in eval mode, no gradients: the LM without its vocabulary head,
the VAE's present-distribution mean; :mod:`.policy`) on the samples of stages 4-5
(:class:`~.pairs.AuroraPairs`, planning prompt, no speed dropout). A fusion run gets the roadside
message its roadside branch makes from the frame's recorded roadside camera (rounded to the
wire's float16; no latency, so the message is of the same tick); a No Fusion run, and a frame
without a unit, gets none. Metrics, overall and per navigation command
(``town.model.COMMAND_NAMES``):

- ``l2_<h>s``: L2 error (m) between the predicted and the expert waypoint at ``h`` = 1, 2, 3 s
  (UniAD / VAD style: the error at that horizon's waypoint, not a mean over the steps;
  :func:`~v2xbench.envs.v2x_intersection.evaluation.metrics_perception.l2_at`), for the model and for a
  constant-velocity baseline (:func:`constant_velocity_plan`: the ego's current speed, straight
  ahead), so a reader sees whether the planner beats it.
- ``collision_<h>s``: share of frames where an ego box (4.7 x 1.9 m, heading along the
  trajectory) at some predicted waypoint up to ``h`` overlaps a ground-truth actor's box at that
  waypoint's time (:func:`~v2xbench.envs.v2x_intersection.evaluation.metrics_perception.
  trajectory_collisions`; the heading from consecutive waypoints, kept where a step is under
  0.25 m: :func:`plan_headings`). Actors: the frame's ``gt/fused`` boxes (ego frame, within
  the ego range: what the ego or the roadside unit sees) of the vehicle and VRU classes, moved at
  **constant velocity** from their recorded velocity (:func:`actor_futures`; their true futures
  are not in a frame). The same for the baseline and for the expert's own waypoints (the expert
  does not collide: its rate measures what the constant-velocity futures get wrong).
- ``start_from_rest``: on frames where the ego is slower than 0.5 m/s and the expert's 3 s
  waypoint is farther than 5 m: the mean predicted and expert speed ``|wp1 - wp0| / 0.5 s`` (the
  policy's target speed, :func:`~.policy.target_speed`) and over 3 s ``|wp_3s| / 3 s``;
  ``stay_at_rest``: the same where the ego stands and the expert stays (3 s waypoint within
  1.5 m), so that a planner which always drives off shows.
- ``per_reason``: per binding constraint of the expert's speed at the frame (``expert_reason``:
  free road, a leader, a red or yellow light, a stop sign, yielding, a conflict, ...;
  :data:`~v2xbench.collectors.dataset.record.REASONS`): the ego's speed and the expert's and the
  model's planned speed over 3 s, the share of frames whose plan "goes" (at least
  :data:`GO_SPEED` over 3 s; a small mean can be a few frames that go, and in closed loop one
  such frame sets a standing car off), and the L2 at 3 s; again on the frames where the ego
  moves and where it stands. A planner that drives on where the expert stops for a red light
  shows here, whatever its mean L2.

Files (:func:`evaluate_planning`, written atomically): ``metrics.json`` and ``metrics.md`` in
``--out`` (default ``RUN/eval_planning`` or ``DIR/eval_planning``).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch
from v2xbench.envs.v2x_intersection.core.classes import CLASS_NAMES, VEHICLE_CLASSES, VRU_CLASSES
from v2xbench.envs.v2x_intersection.evaluation.metrics_perception import (
    l2_at,
    trajectory_collisions,
)
from v2xbench.envs.v2x_intersection.town.model import COMMAND_NAMES

from v2xbench.files import atomic_write_json, atomic_write_text, json_safe
from v2xbench.locks import dir_lock

HORIZONS = (1.0, 2.0, 3.0)
#: Classes whose boxes count in the collision rate (vehicles, pedestrians, bicycles).
ACTOR_CLASSES = tuple(int(c) for c in np.concatenate([VEHICLE_CLASSES, VRU_CLASSES]))
START_SPEED = 0.5  # m/s: the ego stands below this
START_DIST = 5.0  # m: ... and the expert's 3 s waypoint is farther than this
STAY_DIST = 1.5  # m: the expert stays at rest (its 3 s waypoint within this)
GO_SPEED = 1.0  # m/s: a plan this fast over 3 s "goes" (per_reason's go shares)
HEADING_MIN_STEP = 0.25  # m between waypoints (0.5 m/s): shorter steps keep the last heading
PLANS = ("model", "constant_velocity", "expert")
OUT_DIR = "eval_planning"


# ---------------------------------------------------------------------- geometry
def constant_velocity_plan(speed: np.ndarray, steps: int, dt: float) -> np.ndarray:
    """``(B, steps, 2)`` ego-frame waypoints of driving straight on at ``speed`` ``(B,)`` m/s:
    waypoint ``k`` at ``(speed (k + 1) dt, 0)``."""
    t = np.arange(1, steps + 1, dtype=np.float64) * dt
    v = np.asarray(speed, np.float64).reshape(-1, 1)
    return np.stack([v * t, np.zeros((len(v), steps))], -1)


def actor_futures(boxes: np.ndarray, labels: np.ndarray, mask: np.ndarray, steps: int,
                  dt: float, classes: Sequence[int] = ACTOR_CLASSES) -> np.ndarray:
    """Actors' future boxes at constant velocity.

    Args:
        boxes: ``(B, M, 10)`` ego-frame boxes in part 1's layout (x, y, z, l, w, h, sin yaw,
            cos yaw, vx, vy). labels: ``(B, M)`` class ids. mask: ``(B, M)`` valid rows.
        steps, dt: waypoints and their spacing (s); step ``k`` is at ``(k + 1) dt``.
        classes: the class ids that count (default: vehicles and VRUs).

    Returns:
        ``(B, steps, M, 5)`` ``(x, y, length, width, yaw)``, NaN for rows that do not count
        (:func:`~v2xbench.envs.v2x_intersection.evaluation.metrics_perception.trajectory_collisions`).
    """
    b = np.asarray(boxes, np.float64)
    keep = np.asarray(mask, bool) & np.isin(np.asarray(labels), list(classes))
    t = np.arange(1, steps + 1, dtype=np.float64)[None, :, None, None] * dt
    centre = b[:, None, :, :2] + b[:, None, :, 8:10] * t  # (B, T, M, 2)
    yaw = np.arctan2(b[..., 6], b[..., 7])
    rest = np.stack([b[..., 3], b[..., 4], yaw], -1)[:, None].repeat(steps, 1)
    out = np.concatenate([centre, rest], -1)
    out[~np.broadcast_to(keep[:, None], out.shape[:3])] = np.nan
    return out


def plan_headings(plans: np.ndarray, min_step: float = HEADING_MIN_STEP) -> np.ndarray:
    """``(B, T)`` ego headings (rad) along ``(B, T, 2)`` waypoints: the direction from the
    previous waypoint (the origin for the first), keeping the previous heading (0, the ego's
    own, at the start) where the step is shorter than ``min_step`` m, so that a standing car's
    centimetre jitter does not turn its box sideways."""
    p = np.asarray(plans, np.float64)
    d = np.diff(np.concatenate([np.zeros_like(p[:, :1]), p], 1), axis=1)
    yaw = np.zeros(p.shape[:2])
    last = np.zeros(len(p))
    for k in range(p.shape[1]):
        moved = np.hypot(d[:, k, 0], d[:, k, 1]) >= min_step
        last = np.where(moved, np.arctan2(d[:, k, 1], d[:, k, 0]), last)
        yaw[:, k] = last
    return yaw


def collisions(plans: np.ndarray, futures: np.ndarray) -> np.ndarray:
    """``(B, T)`` bool per-waypoint collisions of ``(B, T, 2)`` plans (headings:
    :func:`plan_headings`) with ``(B, T, M, 5)`` futures (:func:`actor_futures`)."""
    yaw = plan_headings(plans)
    return np.stack([trajectory_collisions(p, f, y) for p, f, y in zip(plans, futures, yaw)])


# ---------------------------------------------------------------------- metrics
def _mean(x: np.ndarray) -> float | None:
    return float(np.mean(x)) if len(x) else None


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100.0 * x:.0f} %"


def group_metrics(rec: Mapping[str, np.ndarray], rows: np.ndarray, dt: float) -> dict:
    """Metrics of the frames ``rows`` (bool ``(N,)``) of the per-frame records ``rec``
    (:func:`evaluate_planning`: ``expert``, ``model``, ``constant_velocity`` ``(N, T, 2)``;
    ``col_<plan>`` ``(N, T)``; ``speed`` ``(N,)``)."""
    n = int(rows.sum())
    out: dict = {"frames": n}
    steps = [int(round(h / dt)) for h in HORIZONS]
    for plan in PLANS:
        m: dict = {}
        if plan != "expert":
            m.update(l2_at(rec[plan][rows], rec["expert"][rows], HORIZONS, dt) if n else
                     {f"l2_{h:g}s": None for h in HORIZONS})
        col = rec[f"col_{plan}"][rows]
        for h, k in zip(HORIZONS, steps):
            m[f"collision_{h:g}s"] = _mean(col[:, :k].any(1))
        out[plan] = m
    return out


def start_from_rest(rec: Mapping[str, np.ndarray], dt: float, stay: bool = False) -> dict:
    """Predicted vs expert speeds on the start-from-rest frames (module docstring); with
    ``stay``, on the frames where the ego stands and the expert stays (its 3 s waypoint within
    :data:`STAY_DIST`): the counterpart that shows a planner which always drives off."""
    k3 = int(round(3.0 / dt)) - 1
    far = np.linalg.norm(rec["expert"][:, k3], axis=-1)
    rows = (rec["speed"] < START_SPEED) & ((far < STAY_DIST) if stay else (far > START_DIST))
    out: dict = {"frames": int(rows.sum()), "ego_speed_below": START_SPEED}
    out.update({"expert_3s_within": STAY_DIST} if stay else
               {"expert_3s_farther_than": START_DIST})
    for plan in ("model", "expert"):
        w = rec[plan][rows]
        out[plan] = {"speed_wp0_wp1": _mean(np.linalg.norm(w[:, 1] - w[:, 0], axis=-1) / dt),
                     "speed_3s": _mean(np.linalg.norm(w[:, k3], axis=-1) / 3.0)}
    return out


def split_reasons(root: str | Path, split: str) -> np.ndarray | None:
    """Every frame's ``expert_reason`` of ``split`` of the data set at ``root``, indexed by the
    split's global frame id (``None`` for a data set without the field)."""
    from v2xbench.collectors.dataset.loader import V2XDataset

    try:
        cols = V2XDataset(root, split, keys=["expert_reason"]).columns("expert_reason")
    except KeyError:  # a data set recorded before the field
        return None
    return np.concatenate([c.astype(np.int64).reshape(-1) for c in cols]) if cols else np.zeros(0, np.int64)


def per_reason(rec: Mapping[str, np.ndarray], dt: float) -> dict:
    """Per ``expert_reason`` present (``rec["reason"]``): frames, the ego's mean speed, the
    expert's and the model's mean planned speed over 3 s (``|wp_3s| / 3 s``) and the model's L2
    at 3 s (module docstring); the same under ``moving`` and ``standing`` for the frames where
    the ego moves (>= :data:`START_SPEED`: approaching a red light, say) and where it stands (at
    the light: only the light, or the car ahead, says to stay)."""
    from v2xbench.collectors.dataset.record import REASONS

    k3 = int(round(3.0 / dt)) - 1

    def speeds(rows: np.ndarray) -> dict:
        m, ex = rec["model"][rows], rec["expert"][rows]
        vm, ve = np.linalg.norm(m[:, k3], axis=-1) / 3.0, np.linalg.norm(ex[:, k3], axis=-1) / 3.0
        return {"frames": int(rows.sum()), "ego_speed": _mean(rec["speed"][rows]),
                "expert_speed_3s": _mean(ve), "model_speed_3s": _mean(vm),
                "expert_go_share": _mean(ve >= GO_SPEED), "model_go_share": _mean(vm >= GO_SPEED),
                "model_l2_3s": _mean(np.linalg.norm(m[:, k3] - ex[:, k3], axis=-1))}

    out, moving = {}, rec["speed"] >= START_SPEED
    for r in sorted(set(int(v) for v in rec["reason"])):
        rows = rec["reason"] == r
        name = REASONS[r] if 0 <= r < len(REASONS) else f"reason_{r}"
        out[name] = {**speeds(rows), "moving": speeds(rows & moving),
                     "standing": speeds(rows & ~moving)}
    return out


def summarize(rec: Mapping[str, np.ndarray], dt: float) -> dict:
    """``overall``, ``per_command`` (commands present), ``start_from_rest`` / ``stay_at_rest``
    and, where ``rec`` has ``reason``, ``per_reason`` metrics."""
    every = np.ones(len(rec["speed"]), bool)
    per = {}
    for c in sorted(set(int(v) for v in rec["command"])):
        name = COMMAND_NAMES[c] if 0 <= c < len(COMMAND_NAMES) else f"command_{c}"
        per[name] = group_metrics(rec, rec["command"] == c, dt)
    return {"overall": group_metrics(rec, every, dt), "per_command": per,
            "start_from_rest": start_from_rest(rec, dt),
            "stay_at_rest": start_from_rest(rec, dt, stay=True),
            "per_reason": per_reason(rec, dt) if "reason" in rec else None}


# ---------------------------------------------------------------------- the model
def load_model(run: str | Path | None = None, weights: str | Path | None = None,
               stage: int | None = None, device: str = "cpu"):
    """``(system, tokenizer, info)`` of a run (:func:`~.system.load_system`) or of exported
    weights (:func:`~.export.load_export`); exactly one of ``run`` / ``weights``."""
    if (run is None) == (weights is None):
        raise ValueError("eval-planning: give exactly one of --run RUN and --weights DIR")
    if weights is not None:
        from .export import load_export

        if stage is not None:
            raise ValueError("eval-planning: --stage chooses a stage of a run; exported weights "
                             "hold one stage")
        if not Path(weights).is_dir():
            raise FileNotFoundError(f"eval-planning: weights folder {weights} does not exist "
                                    "(export one with `v2xbench aurora export`)")
        return load_export(weights, device)
    from .system import load_system

    return load_system(run, stage, device)


def output_dir(out: str | Path | None, run: str | Path | None, weights: str | Path | None,
               name: str) -> Path:
    """Where an evaluation of :func:`load_model`'s model writes: ``out`` if given, else
    ``RUN/name`` (a run folder holds its evaluations), else ``./name/<weights folder name>``
    (an export, maybe the shipped one, is not written into)."""
    if out is not None:
        return Path(out)
    return Path(run) / name if run is not None else Path(name) / Path(weights).name


@torch.no_grad()
def predict(system, batch: Mapping[str, torch.Tensor]) -> np.ndarray:
    """``(B, T, 2)`` planned waypoints of a :func:`~.pairs.collate_pairs` batch: the policy's
    inference pass (:class:`~.policy.AuroraPolicyNet`: eval mode, no gradients, the VAE's
    latent mean). The batch's labels (none on planning samples) are dropped; its tensors go to
    the system's device."""
    dev = next(system.parameters()).device
    inputs = {k: v.to(dev) for k, v in batch.items() if k != "labels"}
    out = system(inputs, plan=True)
    return out["plan"]["waypoints"].float().cpu().numpy().astype(np.float64)


def evaluate_planning(data: str | Path, *, run: str | Path | None = None,
                      weights: str | Path | None = None, stage: int | None = None,
                      split: str = "test", stride: int = 50, out: str | Path | None = None,
                      batch_size: int = 8, device: str = "cpu", progress: bool = True,
                      command: str | None = None) -> dict:
    """Run the planner over ``split`` of ``data`` and write ``metrics.json`` / ``metrics.md``.

    Args:
        data: data set folder (``v2xbench collect --out``). run / weights: the model (one of
            them; :func:`load_model`). stage: a run's stage (default: its latest of 3-5).
        split: ``train``, ``val``, ``test`` or ``all``. stride: every ``stride``-th frame of
            each episode. out: output folder (default ``RUN/eval_planning`` or
            ``DIR/eval_planning``). batch_size, device: inference settings.
        command: the command line to record (default: none).

    Returns:
        the metrics dict (also in ``metrics.json``) plus ``out`` and ``table`` (Markdown).

    Raises:
        FileNotFoundError: a missing run, weights or data folder. ValueError: bad arguments,
            an unknown split or one without frames in ``data``, or ``out`` locked by another
            process.
    """
    from tqdm import tqdm

    from .data import AuroraFrames
    from .pairs import AuroraPairs, make_pair_loader, planning_items

    check_settings("eval-planning", stride, batch_size)
    data = Path(data)
    if not data.is_dir():
        raise FileNotFoundError(f"eval-planning: data directory {data} does not exist (collect "
                                "one with `v2xbench collect --out DIR`)")
    if run is not None and not Path(run).is_dir():
        raise FileNotFoundError(f"eval-planning: run folder {run} does not exist")
    system, tok, info = load_model(run, weights, stage, device)
    cfg = system.cfg
    frames = AuroraFrames(data, split, "ego", cfg, images=False)
    items = planning_items(frames, stride)
    ds = AuroraPairs(data, split, cfg, tok, items, fusion=system.fusion)
    loader = make_pair_loader(ds, batch_size, shuffle=False)
    out = output_dir(out, run, weights, OUT_DIR)
    t_steps, dt = cfg.plan_waypoints, cfg.plan_dt
    parts = new_parts()
    t0 = time.perf_counter()
    with dir_lock(out, "aurora eval-planning"):
        for batch in tqdm(loader, desc="eval-planning", unit="batch", disable=not progress):
            add_batch(parts, batch, predict(system, batch), t_steps, dt)
        head = {"format": "v2xbench-aurora-eval-planning/1",
                "source": {"run": None if run is None else str(run),
                           "weights": None if weights is None else str(weights),
                           "stage": info.get("stage"), "checkpoint": info.get("checkpoint"),
                           "fusion": bool(system.fusion), "scale": cfg.scale,
                           "planner": cfg.planner},
                "data": str(data), "split": split, "stride": stride, "command": command}
        return write_result(out, parts, head, t_steps, dt, time.perf_counter() - t0, len(ds))


def check_settings(who: str, stride: int, batch_size: int) -> None:
    """``stride`` and ``batch_size`` each an int (not a bool) >= 1; ``ValueError`` naming
    ``who`` and the field otherwise."""
    for name, v in (("stride", stride), ("batch_size", batch_size)):
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise ValueError(f"{who}: {name}={v!r} must be an int >= 1")


def new_parts() -> dict[str, list]:
    """Empty per-batch records for :func:`add_batch`."""
    return {k: [] for k in ("frame_id", "command", "speed", "expert", "model", "has_rsu",
                            "futures")}


def add_batch(parts: dict[str, list], batch: Mapping[str, torch.Tensor], plans: np.ndarray,
              t_steps: int, dt: float) -> None:
    """Append one batch's planned waypoints ``plans`` ``(B, T, 2)`` and what the metrics need
    of the batch (expert waypoints, speed, command, frame ids, ``has_rsu``, the actors'
    constant-velocity futures) to ``parts`` (:func:`new_parts`)."""
    parts["model"].append(np.asarray(plans, np.float64)[:, :t_steps])
    parts["expert"].append(batch["expert_waypoints"][:, :t_steps].double().numpy())
    parts["speed"].append(batch["ego_speed"].double().numpy())
    parts["command"].append(batch["command"].numpy())
    parts["frame_id"].append(batch["frame_id"].numpy())
    parts["has_rsu"].append(batch["has_rsu"].numpy())
    parts["futures"].append(actor_futures(batch["det_boxes"].numpy(), batch["det_labels"].numpy(),
                                          batch["det_mask"].numpy(), t_steps, dt))


def write_result(out: Path, parts: dict[str, list], head: dict, t_steps: int, dt: float,
                 wall: float, samples: int) -> dict:
    """Score the records of :func:`add_batch` (frames without an expert future dropped;
    the constant-velocity line and every plan's collisions added), write ``metrics.json`` and
    ``metrics.md`` into ``out`` (atomically) and return the metrics with ``out`` and ``table``.
    ``head``: the evaluator's ``format``, ``source``, ``data``, ``split``, ``stride``,
    ``command`` (and a baseline's ``title``)."""
    rec = {k: np.concatenate(v) for k, v in parts.items()}
    reasons = split_reasons(head["data"], head["split"]) if head.get("data") else None
    if reasons is not None:
        rec["reason"] = reasons[rec["frame_id"]]
    bad = ~np.isfinite(rec["expert"]).all((1, 2))
    if bad.any():  # no expert future recorded: nothing to compare with
        rec = {k: v[~bad] for k, v in rec.items()}
    rec["constant_velocity"] = constant_velocity_plan(rec["speed"], t_steps, dt)
    for plan in PLANS:
        rec[f"col_{plan}"] = collisions(rec[plan], rec["futures"])
    result = json_safe({
        **head, "frames": int(len(rec["speed"])), "frames_without_expert_future": int(bad.sum()),
        "frames_with_roadside_unit": int(rec["has_rsu"].sum()),
        "horizons_s": list(HORIZONS), "dt_s": dt,
        "collision_actors": [CLASS_NAMES[c] for c in ACTOR_CLASSES],
        "actor_futures": "constant velocity from each gt/fused box's recorded velocity",
        "heading_min_step_m": HEADING_MIN_STEP,
        "wall_s": round(wall, 1), "ms_per_frame": round(1e3 * wall / max(samples, 1), 1),
        **summarize(rec, dt)})
    table = markdown(result)
    atomic_write_json(out / "metrics.json", result, indent=1)
    atomic_write_text(out / "metrics.md", table)
    return dict(result, out=str(out), table=table)


# ---------------------------------------------------------------------- report
def _f(v, digits: int = 2) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}"


def _pct(v) -> str:
    return "n/a" if v is None else f"{100 * v:.1f} %"


def _row(name: str, g: dict) -> str:
    m, cv, ex = g["model"], g["constant_velocity"], g["expert"]
    l2 = " / ".join(_f(m[f"l2_{h:g}s"]) for h in HORIZONS)
    l2cv = " / ".join(_f(cv[f"l2_{h:g}s"]) for h in HORIZONS)
    col = " / ".join(_pct(m[f"collision_{h:g}s"]) for h in HORIZONS)
    return (f"| {name} | {g['frames']} | {l2} | {l2cv} | {col} | "
            f"{_pct(cv['collision_3s'])} | {_pct(ex['collision_3s'])} |")


def markdown(result: Mapping) -> str:
    """The Markdown report of :func:`evaluate_planning`'s metrics (and of a baseline's:
    ``result["title"]`` names the method, AURORA when absent; no stage when it is ``None``)."""
    src = result["source"]
    what = f"run `{src['run']}`" if src["run"] else f"weights `{src['weights']}`"
    stage = "" if src["stage"] is None else f"stage {src['stage']}, "
    lines = [f"# {result.get('title', 'AURORA')} open-loop planning: {result['data']} "
             f"({result['split']})", "",
             f"{what}, {stage}fusion {src['fusion']}, {src['scale']} scale, "
             f"{src['planner']} planner; every {result['stride']}th frame of each episode: "
             f"{result['frames']} frames ({result['frames_with_roadside_unit']} with a roadside "
             f"unit); {result['ms_per_frame']} ms a frame.", ""]
    if result.get("command"):
        lines += [f"Command: `{result['command']}`", ""]
    if result.get("ego_speed_input", "frame") != "frame":
        lines += [f"**Probe**: the model was told an ego speed of {result['ego_speed_input']:g} "
                  "m/s on every frame instead of the frame's own.", ""]
    lines += ["L2 (m) at 1 / 2 / 3 s: the error at that horizon's waypoint. Constant velocity: "
              "the ego's current speed, straight ahead. Collision: share of frames where the "
              "ego box at a planned waypoint up to that time overlaps a vehicle / VRU box of "
              "`gt/fused` moved at constant velocity (the expert's own rate is what those "
              "futures get wrong).", "",
              "| frames | n | L2 model | L2 constant velocity | collision model (1/2/3 s) | "
              "collision CV 3 s | collision expert 3 s |",
              "|---|---|---|---|---|---|---|",
              _row("all", result["overall"])]
    lines += [_row(c, g) for c, g in result["per_command"].items()]
    s, r = result["start_from_rest"], result["stay_at_rest"]
    lines += ["", f"At rest (ego < {s['ego_speed_below']} m/s): start from rest = the expert's "
              f"3 s waypoint > {s['expert_3s_farther_than']} m ({s['frames']} frames); stay = "
              f"within {r['expert_3s_within']} m ({r['frames']} frames).", "",
              "| | start: speed wp0-wp1 (m/s) | start: speed over 3 s | stay: speed wp0-wp1 | "
              "stay: speed over 3 s |", "|---|---|---|---|---|"]
    for plan in ("model", "expert"):
        lines.append(f"| {plan} | {_f(s[plan]['speed_wp0_wp1'])} | {_f(s[plan]['speed_3s'])} | "
                     f"{_f(r[plan]['speed_wp0_wp1'])} | {_f(r[plan]['speed_3s'])} |")
    if result.get("per_reason"):
        lines += ["", "Per binding constraint of the expert's speed (`expert_reason`): speeds in "
                  "m/s, planned speed = distance to the 3 s waypoint / 3 s.", "",
                  "| expert's reason | n | ego speed | expert planned | model planned | "
                  "L2 3 s model | n moving | expert, moving | model, moving | n standing | "
                  "expert, standing | model, standing | goes, standing: expert / model |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for name, g in result["per_reason"].items():
            mv, st = g["moving"], g["standing"]
            lines.append(f"| {name} | {g['frames']} | {_f(g['ego_speed'])} | "
                         f"{_f(g['expert_speed_3s'])} | {_f(g['model_speed_3s'])} | "
                         f"{_f(g['model_l2_3s'])} | {mv['frames']} | "
                         f"{_f(mv['expert_speed_3s'])} | {_f(mv['model_speed_3s'])} | "
                         f"{st['frames']} | {_f(st['expert_speed_3s'])} | "
                         f"{_f(st['model_speed_3s'])} | {_pct(st.get('expert_go_share'))} / "
                         f"{_pct(st.get('model_go_share'))} |")
    return "\n".join(lines) + "\n"


__all__ = ["ACTOR_CLASSES", "GO_SPEED", "HEADING_MIN_STEP", "HORIZONS", "OUT_DIR", "START_DIST",
           "output_dir",
           "START_SPEED", "STAY_DIST", "actor_futures", "add_batch", "check_settings", "collisions",
           "constant_velocity_plan", "evaluate_planning", "group_metrics", "load_model",
           "markdown", "new_parts", "per_reason", "plan_headings", "predict", "split_reasons",
           "start_from_rest", "summarize",
           "write_result"]
