"""Open-loop planning and perception metrics (for model work; closed loop is the headline).

Open-loop numbers (L2, collision rate of a predicted trajectory against logged futures) are weak
indicators of driving quality: a policy can score well open loop and still drive badly, because
it never faces the consequences of its own actions. Report closed-loop DS first (``metrics.py``).

- :func:`l2_at`: L2 distance between predicted and expert future ego positions at 1, 2, 3 s.
- :func:`collision_rate`: UniAD / ST-P3 style: an ego box of :data:`EGO_BOX_LENGTH` x
  :data:`EGO_BOX_WIDTH` (4.7 x 1.9 m, the simulator's ego, ``world.EGO_LENGTH/EGO_WIDTH``) is placed
  at every predicted waypoint, heading along the trajectory, and tested (separating axes) against
  the ground-truth boxes of the other actors at that future step.
- :func:`detection_metrics`: nuScenes-style detection per class group (``classes.GROUPS``: vehicle,
  VRU, traffic light, traffic sign). Predictions match ground truth of the same group in the same
  frame greedily by descending score to the nearest unmatched centre (bird's-eye-view distance)
  below the threshold. AP per threshold {0.5, 1, 2, 4} m: precision interpolated at 101 recall
  points (``np.interp``, 0 beyond the maximum recall), the bins at recall <= 0.1 dropped, 0.1
  subtracted from precision (clipped at 0) and the mean rescaled by 1 / 0.9 (nuScenes
  ``min_recall = min_precision = 0.1``). True-positive errors at the 2 m threshold, as cumulative
  means over the score-sorted matches, averaged over recall 0.1 .. maximum recall (1 when that is
  below 0.1): ATE (centre distance, m), ASE (1 - 3D IoU of the boxes aligned in centre and yaw),
  AOE (absolute yaw error wrapped to [0, pi], rad), AVE (velocity error norm, m/s; NaN for the
  static groups traffic light and traffic sign, as nuScenes does for cones and barriers).
  ``NDS = (5 mAP + sum over ATE, ASE, AOE, AVE of (1 - min(1, mean error))) / 9``: nuScenes has
  a fifth error (attributes) and divides by 10; we have no attributes, hence four errors and 9.
  A group without ground truth is NaN and left out of the means; a TP error that is NaN in every
  group is left out of NDS and the 9 becomes 8.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..core.classes import GROUPS
from ..core.geometry import box_corners_2d, wrap_angle

EGO_BOX_LENGTH, EGO_BOX_WIDTH = 4.7, 1.9  # m, the simulator's ego box (world.EGO_LENGTH/WIDTH)
DIST_THRESHOLDS = (0.5, 1.0, 2.0, 4.0)  # m, centre-distance matching thresholds for AP
TP_THRESHOLD = 2.0  # m, matching threshold for the true-positive errors
MIN_RECALL = 0.1
MIN_PRECISION = 0.1
RECALL_POINTS = 101
STATIC_GROUPS = ("traffic_light", "traffic_sign")  # no AVE
TP_ERRORS = ("ate", "ase", "aoe", "ave")


# ------------------------------------------------------------------------------------ open loop


def _horizon_steps(horizons: Sequence[float], dt: float, t: int) -> list[int]:
    steps = [int(round(h / dt)) for h in horizons]
    if any(k < 1 or k > t for k in steps):
        raise ValueError(f"horizons {tuple(horizons)} s need steps {steps} of {dt} s; have {t}")
    return steps


def l2_at(
    pred: np.ndarray,
    gt: np.ndarray,
    horizons: Sequence[float] = (1.0, 2.0, 3.0),
    dt: float = 0.5,
    average: bool = False,
) -> dict[str, float]:
    """L2 error (m) of predicted future ego positions.

    Args:
        pred, gt: ``(..., T, 2)`` future positions, waypoint ``k`` at time ``(k + 1) * dt`` s; NaN
            in ``gt`` marks an unavailable future step (ignored).
        horizons: seconds. dt: waypoint spacing (s).
        average: False: error at the horizon step; True: mean over steps up to it (ST-P3 / UniAD).

    Returns:
        ``{"l2_1s": ..., ...}`` averaged over the leading dimensions.
    """
    pred, gt = np.asarray(pred, np.float64), np.asarray(gt, np.float64)
    err = np.linalg.norm(pred - gt, axis=-1).reshape(-1, pred.shape[-2])  # (B, T)
    out = {}
    for h, k in zip(horizons, _horizon_steps(horizons, dt, err.shape[1])):
        e = err[:, :k].mean(1) if average else err[:, k - 1]
        out[f"l2_{h:g}s"] = float(np.nanmean(e))
    return out


def boxes_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Separating-axis test of oriented rectangles; ``a, b (..., 4, 2)`` corners -> ``(...)``
    bool (touching does not count)."""
    axes = np.concatenate([np.diff(a[..., :3, :], axis=-2), np.diff(b[..., :3, :], axis=-2)], -2)
    normals = np.stack([-axes[..., 1], axes[..., 0]], -1)  # (..., 4, 2)
    pa = np.einsum("...kd,...cd->...kc", normals, a)
    pb = np.einsum("...kd,...cd->...kc", normals, b)
    sep = (pa.max(-1) <= pb.min(-1)) | (pb.max(-1) <= pa.min(-1))
    return ~sep.any(-1)


def trajectory_collisions(
    pred: np.ndarray,
    boxes: np.ndarray,
    ego_yaw: np.ndarray | None = None,
    ego_size: tuple[float, float] = (EGO_BOX_LENGTH, EGO_BOX_WIDTH),
) -> np.ndarray:
    """Per-step collisions of one predicted trajectory.

    Args:
        pred: ``(T, 2)`` waypoints (m) in the frame of the boxes, the ego starting at the origin.
        boxes: ``(T, N, 5)`` others' ``(x, y, length, width, yaw)`` per future step; rows with a
            NaN are padding.
        ego_yaw: ``(T,)`` ego heading (rad); default: direction of travel from the previous
            waypoint (origin for the first), keeping the previous heading (0 at the start) when
            the ego moves less than 1 cm.

    Returns:
        ``(T,)`` bool: the ego box overlaps some box at that step.
    """
    pred = np.asarray(pred, np.float64)
    boxes = np.asarray(boxes, np.float64).reshape(len(pred), -1, 5)
    if ego_yaw is None:
        d = np.diff(np.concatenate([np.zeros((1, 2)), pred]), axis=0)
        ego_yaw = np.zeros(len(pred))
        last = 0.0
        for k, (dx, dy) in enumerate(d):
            last = float(np.arctan2(dy, dx)) if np.hypot(dx, dy) > 0.01 else last
            ego_yaw[k] = last
    ego = box_corners_2d(
        pred, np.full(len(pred), ego_size[0]), np.full(len(pred), ego_size[1]), ego_yaw
    )
    out = np.zeros(len(pred), bool)
    for k in range(len(pred)):
        b = boxes[k][np.isfinite(boxes[k]).all(1)]
        if len(b):
            other = box_corners_2d(b[:, :2], b[:, 2], b[:, 3], b[:, 4])
            out[k] = bool(boxes_overlap(np.broadcast_to(ego[k], other.shape), other).any())
    return out


def collision_rate(
    pred: np.ndarray,
    boxes: np.ndarray,
    horizons: Sequence[float] = (1.0, 2.0, 3.0),
    dt: float = 0.5,
    average: bool = True,
) -> dict[str, float]:
    """Collision rate of predicted trajectories against ground-truth future boxes.

    Args:
        pred: ``(B, T, 2)`` or ``(T, 2)`` waypoints (see :func:`trajectory_collisions`).
        boxes: ``(B, T, N, 5)`` or ``(T, N, 5)`` NaN-padded future boxes.
        average: True (ST-P3 / UniAD): mean over steps up to the horizon of the per-step collision
            rate; False: fraction of samples colliding at any step up to the horizon.

    Returns:
        ``{"collision_1s": ..., ...}`` as fractions in [0, 1].
    """
    pred = np.asarray(pred, np.float64)
    boxes = np.asarray(boxes, np.float64)
    if pred.ndim == 2:
        pred, boxes = pred[None], boxes[None]
    col = np.stack([trajectory_collisions(p, b) for p, b in zip(pred, boxes)])  # (B, T)
    out = {}
    for h, k in zip(horizons, _horizon_steps(horizons, dt, col.shape[1])):
        v = col[:, :k].mean() if average else col[:, :k].any(1).mean()
        out[f"collision_{h:g}s"] = float(v)
    return out


# ------------------------------------------------------------------------------------ detection


@dataclass
class DetBoxes:
    """``N`` 3D boxes (predictions or ground truth) over several frames.

    Attributes:
        frame: ``(N,)`` frame / sample id. cls: ``(N,)`` class id (``classes``).
        center: ``(N, 2)`` bird's-eye-view centre (m). size: ``(N, 3)`` length, width, height (m).
        yaw: ``(N,)`` (rad). velocity: ``(N, 2)`` (m/s; default 0).
        score: ``(N,)`` confidence in (0, 1] for predictions (default 1; ignored for ground truth).
    """

    frame: np.ndarray
    cls: np.ndarray
    center: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    velocity: np.ndarray | None = None
    score: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        self.frame = np.asarray(self.frame, np.int64).reshape(-1)
        n = len(self.frame)
        self.cls = np.asarray(self.cls, np.int64).reshape(n)
        self.center = np.asarray(self.center, np.float64).reshape(n, 2)
        self.size = np.asarray(self.size, np.float64).reshape(n, 3)
        self.yaw = np.asarray(self.yaw, np.float64).reshape(n)
        self.velocity = (
            np.zeros((n, 2))
            if self.velocity is None
            else np.asarray(self.velocity, np.float64).reshape(n, 2)
        )
        self.score = (
            np.ones(n) if self.score is None else np.asarray(self.score, np.float64).reshape(n)
        )

    def select(self, mask: np.ndarray) -> DetBoxes:
        """Subset by a boolean mask or index array."""
        return DetBoxes(
            self.frame[mask],
            self.cls[mask],
            self.center[mask],
            self.size[mask],
            self.yaw[mask],
            self.velocity[mask],
            self.score[mask],
        )


def scale_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3D IoU of boxes ``(..., 3)`` sizes aligned in centre and orientation."""
    inter = np.prod(np.minimum(a, b), -1)
    return inter / (np.prod(a, -1) + np.prod(b, -1) - inter)


def _match(pred: DetBoxes, gt: DetBoxes, th: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy nuScenes matching; returns sorted scores ``(P,)``, tp flags ``(P,)`` and the matched
    gt index per prediction (-1 for false positives)."""
    order = np.argsort(-pred.score, kind="stable")
    taken = np.zeros(len(gt.frame), bool)
    match = np.full(len(order), -1)
    by_gt = np.argsort(gt.frame, kind="stable")  # gt indices grouped by frame, ascending within
    frames, first = np.unique(gt.frame[by_gt], return_index=True)
    per_frame = dict(zip(frames.tolist(), np.split(by_gt, first[1:])))
    none = np.zeros(0, np.int64)
    for j, i in enumerate(order):
        cand = per_frame.get(int(pred.frame[i]), none)
        cand = cand[~taken[cand]]
        if len(cand):
            d = np.linalg.norm(gt.center[cand] - pred.center[i], axis=1)
            k = int(np.argmin(d))
            if d[k] < th:
                taken[cand[k]] = True
                match[j] = cand[k]
    return pred.score[order], match >= 0, match


def _pr_curve(pred: DetBoxes, gt: DetBoxes, th: float):
    """101-point precision, confidence and sorted match data at threshold ``th``."""
    conf, tp, match = _match(pred, gt, th)
    if not tp.any():
        return None
    ctp, cfp = np.cumsum(tp), np.cumsum(~tp)
    prec, rec = ctp / (ctp + cfp), ctp / len(gt.frame)
    r = np.linspace(0.0, 1.0, RECALL_POINTS)
    return (
        np.interp(r, rec, prec, right=0),
        np.interp(r, rec, np.maximum(conf, 1e-12), right=0),
        conf,
        tp,
        match,
    )


def average_precision(prec: np.ndarray | None) -> float:
    """nuScenes AP of a 101-point precision curve (0 for no true positive)."""
    if prec is None:
        return 0.0
    p = prec[round(100 * MIN_RECALL) + 1 :] - MIN_PRECISION
    return float(np.mean(np.clip(p, 0.0, None))) / (1.0 - MIN_PRECISION)


def _tp_errors(pred: DetBoxes, gt: DetBoxes, static: bool) -> dict[str, float]:
    curve = _pr_curve(pred, gt, TP_THRESHOLD)
    if curve is None:
        return {k: (np.nan if static and k == "ave" else 1.0) for k in TP_ERRORS}
    _, conf_i, conf, tp, match = curve
    order = np.argsort(-pred.score, kind="stable")[tp]
    g = match[tp]
    errs = {
        "ate": np.linalg.norm(pred.center[order] - gt.center[g], axis=1),
        "ase": 1.0 - scale_iou(pred.size[order], gt.size[g]),
        "aoe": np.abs(wrap_angle(pred.yaw[order] - gt.yaw[g])),
        "ave": np.linalg.norm(pred.velocity[order] - gt.velocity[g], axis=1),
    }
    mconf = conf[tp]
    nz = np.flatnonzero(conf_i)
    last, first = (int(nz[-1]) if len(nz) else 0), round(100 * MIN_RECALL) + 1
    out = {}
    for k, e in errs.items():
        if static and k == "ave":
            out[k] = float("nan")
            continue
        cm = np.cumsum(e) / np.arange(1, len(e) + 1)
        curve_e = np.interp(conf_i[::-1], mconf[::-1], cm[::-1])[::-1]
        out[k] = 1.0 if last < first else float(np.mean(curve_e[first : last + 1]))
    return out


def detection_metrics(
    preds: DetBoxes,
    gts: DetBoxes,
    groups: Mapping[str, Sequence[int]] = GROUPS,
    thresholds: Sequence[float] = DIST_THRESHOLDS,
) -> dict[str, float]:
    """nuScenes-style mAP / TP errors / NDS per class group (see the module docstring).

    Returns:
        ``mAP``, ``mATE``, ``mASE``, ``mAOE``, ``mAVE``, ``NDS`` and per group ``<g>/AP``,
        ``<g>/AP@<th>``, ``<g>/ATE`` ... ``<g>/AVE``.
    """
    out: dict[str, float] = {}
    aps, tps = [], {k: [] for k in TP_ERRORS}
    for g, classes in groups.items():
        p, t = preds.select(np.isin(preds.cls, classes)), gts.select(np.isin(gts.cls, classes))
        if len(t.frame) == 0:
            ap, errs = float("nan"), dict.fromkeys(TP_ERRORS, float("nan"))
        else:
            per = []
            for th in thresholds:
                curve = _pr_curve(p, t, th)
                per.append(average_precision(None if curve is None else curve[0]))
                out[f"{g}/AP@{th:g}"] = per[-1]
            ap, errs = float(np.mean(per)), _tp_errors(p, t, g in STATIC_GROUPS)
        out[f"{g}/AP"] = ap
        aps.append(ap)
        for k in TP_ERRORS:
            out[f"{g}/{k.upper()}"] = errs[k]
            tps[k].append(errs[k])
    m = {
        k: (float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")) for k, v in tps.items()
    }
    out["mAP"] = float(np.nanmean(aps)) if np.isfinite(aps).any() else float("nan")
    for k in TP_ERRORS:
        out[f"m{k.upper()}"] = m[k]
    terms = [1.0 - min(1.0, e) for e in m.values() if np.isfinite(e)]
    out["NDS"] = (5.0 * out["mAP"] + sum(terms)) / (5.0 + len(terms))
    return out
