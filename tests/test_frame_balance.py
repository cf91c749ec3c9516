"""Rebalanced training frames (agents/aurora/frame_balance.py): which frames are moving, resting
and starting, which of them each stride keeps, the plain stride unchanged when nothing is
rebalanced, and a baseline's run file recording the balance (a run resumes only with the same)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from v2xbench.agents.aurora.frame_balance import (
    REST_SPEED,
    START_M,
    balanced_frame_ids,
    class_counts,
    frame_classes,
    keep_mask,
    split_classes,
)
from v2xbench.collectors.dataset.loader import V2XDataset

torch.set_num_threads(1)


def _waypoints(last: list[float]) -> np.ndarray:
    """(T, 6, 2) straight-ahead waypoints whose last one is ``last[t]`` m ahead."""
    return np.stack([np.c_[np.linspace(0, d, 6), np.zeros(6)] for d in last])


def test_classes_follow_speed_and_the_experts_last_waypoint():
    speed = np.array([5.0, 0.0, 0.0, REST_SPEED - 0.01, REST_SPEED])
    wp = _waypoints([10.0, 0.2, START_M + 0.5, START_M - 0.1, 0.0])
    assert frame_classes(speed, wp).tolist() == [0, 1, 2, 1, 0]


def test_each_class_keeps_its_own_stride_and_zero_means_the_plain_stride():
    cls = np.array([0] * 8 + [1] * 8 + [2] * 8)
    t = np.arange(24)
    assert np.array_equal(keep_mask(cls, 4), t % 4 == 0)
    assert np.array_equal(keep_mask(cls, 4, 0, 0), t % 4 == 0)
    m = keep_mask(cls, 4, rest_stride=8, start_stride=1)
    assert np.flatnonzero(m).tolist() == [0, 4, 8, *range(16, 24)]
    for bad in (dict(stride=0), dict(stride=2, rest_stride=-1), dict(stride=2, start_stride=1.5),
                dict(stride=True)):
        with pytest.raises(ValueError, match="frame balance"):
            keep_mask(cls, **{"rest_stride": 0, "start_stride": 0, **bad})


def test_on_a_collected_set_the_plain_stride_is_unchanged_and_start_frames_all_kept(tiny_dataset):
    ds = V2XDataset(tiny_dataset, "all", keys=["ego_speed", "expert_waypoints"])
    plain = np.concatenate([ds.offsets[e] + np.arange(n)[np.arange(n) % 3 == 0] for e, n in
                            enumerate(np.diff(ds.offsets))])
    offsets, classes = split_classes(tiny_dataset, "all")
    assert np.array_equal(offsets, ds.offsets)
    assert np.array_equal(balanced_frame_ids(offsets, classes, 3), plain)
    every = balanced_frame_ids(offsets, classes, 1)
    total = class_counts(classes, every)
    # every episode starts at rest with the expert setting off
    assert sum(total.values()) == len(every) == ds.offsets[-1] and total["starting"] >= 2
    kept = class_counts(classes, balanced_frame_ids(offsets, classes, 3, 1000, 1))
    assert kept["starting"] == total["starting"]  # every starting frame
    assert kept["moving"] == class_counts(classes, plain)["moving"]
    assert kept["resting"] <= total["resting"]


def test_a_baseline_run_records_its_balance_and_resumes_only_with_it(tiny_dataset, tmp_path):
    from v2xbench.agents.baselines.univ2x.train import train

    run = tmp_path / "run"
    s = train(tiny_dataset, run, scale="tiny", max_steps=1, stride=2, rest_stride=6,
              start_stride=1, progress=False)
    info = __import__("json").loads((run / "univ2x.json").read_text())
    offsets, classes = split_classes(tiny_dataset, "train")
    keep = balanced_frame_ids(offsets, classes, 2, 6, 1)
    assert info["frame_balance"]["rest_stride"] == 6 and s["frames"] == info["frames"] == len(keep)
    assert info["frame_balance"]["classes"] == class_counts(classes, keep)
    with pytest.raises(ValueError, match="frame_balance"):
        train(tiny_dataset, run, scale="tiny", max_steps=2, stride=2, rest_stride=5,
              start_stride=1, progress=False)
