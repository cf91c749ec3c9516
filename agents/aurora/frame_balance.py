"""Which training frames to keep when the ego stands: fewer of the frames where it stays, more of
the frames where it sets off (the inertia problem of imitation, Codevilla et al., ICCV 2019).

In the expert's data the ego stands (speed < :data:`REST_SPEED`) in about half of the frames, and
in almost all of them the expert plans to stay (about 30 frames in 31 on the 20-route LiDAR set):
at a light, behind a stopped car, parked before a gap. A planner that sees such a frame learns
that a standing car stays, and in closed loop a car that stopped for any reason stays for good
(`docs/baselines.md`, "Why the baselines run out of time"). :func:`balanced_frame_ids` thins the
frames where the standing ego stays (every ``rest_stride``-th) and thickens the frames where it
sets off (every ``start_stride``-th), the moving frames keeping the usual ``stride``:

=========  ====================================================  ===============
class      a frame of the class                                  kept every
=========  ====================================================  ===============
moving     ego speed >= ``REST_SPEED``                           ``stride``
resting    standing, the expert's last waypoint <= ``START_M``   ``rest_stride``
starting   standing, the expert's last waypoint > ``START_M``     ``start_stride``
=========  ====================================================  ===============

A stride of 0 means ``stride`` (the class is not rebalanced). Strides count the frame's index in
its episode, as the plain ``stride`` does, so the selection is a fixed subset, the same every run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Below this speed (m/s) the ego stands (the threshold of ``docs/results/standstill``).
REST_SPEED = 0.3
#: A standing ego whose expert's last waypoint (3 s ahead) is farther than this (m) sets off.
START_M = 1.0


def frame_classes(speed: np.ndarray, waypoints: np.ndarray) -> np.ndarray:
    """Per frame: 0 moving, 1 resting, 2 starting (module docstring), from the ego's ``(T,)``
    speed and the expert's ``(T, N, 2)`` ego-frame waypoints."""
    speed = np.asarray(speed, np.float64).reshape(-1)
    last = np.linalg.norm(np.asarray(waypoints, np.float64).reshape(len(speed), -1, 2)[:, -1],
                          axis=-1)
    rest = speed < REST_SPEED
    return np.where(rest, np.where(last > START_M, 2, 1), 0).astype(np.int8)


def keep_mask(classes: np.ndarray, stride: int, rest_stride: int = 0,
              start_stride: int = 0) -> np.ndarray:
    """Boolean mask over one episode's frames (index = tick in the episode)."""
    for name, v, lo in (("stride", stride, 1), ("rest_stride", rest_stride, 0),
                        ("start_stride", start_stride, 0)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < lo:
            raise ValueError(f"frame balance: {name}={v!r} must be an int >= {lo}")
    t = np.arange(len(classes))
    per_class = np.array([stride, rest_stride or stride, start_stride or stride])
    return t % per_class[np.asarray(classes, np.int64)] == 0


def split_classes(root: str | Path, split: str) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets, classes)`` of ``split`` of the data set at ``root``: the episodes' first global
    frame ids (and the total at the end, as :class:`~v2xbench.collectors.dataset.loader.V2XDataset`
    has them) and every frame's :func:`frame_classes` (read once)."""
    from v2xbench.collectors.dataset.loader import V2XDataset

    ds = V2XDataset(root, split, keys=["ego_speed", "expert_waypoints"])
    cls = [frame_classes(v, w) for v, w in zip(ds.columns("ego_speed"), ds.columns("expert_waypoints"))]
    return (np.asarray(ds.offsets, np.int64),
            np.concatenate(cls) if cls else np.zeros(0, np.int8))


def balanced_frame_ids(offsets: np.ndarray, classes: np.ndarray, stride: int,
                       rest_stride: int = 0, start_stride: int = 0) -> np.ndarray:
    """Sorted global frame ids kept by :func:`keep_mask`, episode by episode, of a split's
    :func:`split_classes`."""
    out = [offsets[e] + np.flatnonzero(keep_mask(classes[offsets[e]:offsets[e + 1]], stride,
                                                 rest_stride, start_stride))
           for e in range(len(offsets) - 1)]
    return np.concatenate(out).astype(np.int64) if out else np.zeros(0, np.int64)


def class_counts(classes: np.ndarray, frame_ids: np.ndarray) -> dict[str, int]:
    """How many of ``frame_ids`` are moving, resting and starting (for the run file)."""
    picked = np.asarray(classes)[np.asarray(frame_ids, np.int64)]
    return {name: int((picked == i).sum()) for i, name in enumerate(("moving", "resting",
                                                                        "starting"))}


__all__ = ["REST_SPEED", "START_M", "balanced_frame_ids", "class_counts", "frame_classes",
           "keep_mask", "split_classes"]
