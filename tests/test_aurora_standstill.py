"""The "stopped stays stopped" fixes (issue #33): start-from-rest samples weighted up in the
planning loss, speed dropout in training prompts only, the policy's target speed."""

from __future__ import annotations

import itertools

import pytest
import torch
from v2xbench.agents.aurora.config import AuroraConfig
from v2xbench.agents.aurora.planner_losses import (
    PlanningCriterion,
    start_from_rest,
    start_weights,
)
from v2xbench.agents.aurora.policy import target_speed
from v2xbench.agents.aurora.prompt import PLAN_QUESTION, UNKNOWN_SPEED, build_prompt

CFG = AuroraConfig.for_scale("tiny", planner="mlp")
T = CFG.plan_waypoints


def _line(v: float) -> torch.Tensor:
    """8 waypoints 0.5 s apart at ``v`` m/s straight ahead (the data's layout)."""
    t = torch.arange(1, 9, dtype=torch.float32) * 0.5
    return torch.stack([v * t, torch.zeros(8)], -1)


def _batch(speeds, expert_v) -> dict:
    b = len(speeds)
    return {"ego_speed": torch.tensor(speeds, dtype=torch.float32),
            "expert_waypoints": torch.stack([_line(v) for v in expert_v]),
            "agent_future": torch.zeros(b, 0, T, 2),
            "agent_future_mask": torch.zeros(b, 0, T, dtype=torch.bool),
            "map_points": torch.zeros(b, 1, CFG.map_points, 2),
            "map_labels": torch.zeros(b, 1, dtype=torch.long),
            "map_mask": torch.zeros(b, 1, dtype=torch.bool),
            "map_closed": torch.zeros(b, 1, dtype=torch.bool)}


def test_start_from_rest_samples_alone_are_weighted_up():
    # rows: starts from rest | stands and stays | drives on | slow but the expert creeps < 1 m
    batch = _batch([0.0, 0.1, 5.0, 0.2], [2.0, 0.0, 5.0, 0.3])
    assert start_from_rest(batch["ego_speed"], batch["expert_waypoints"], CFG).tolist() == \
        [True, False, False, False]
    w = CFG.plan_start_weight
    assert w > 1  # on by default
    assert start_weights(batch, CFG).tolist() == [w, 1.0, 1.0, 1.0]
    pred = torch.zeros(4, T, 2)  # "stay where you are" for every row
    per = (pred - batch["expert_waypoints"][:, :T]).abs().mean((1, 2))
    _, parts = PlanningCriterion(CFG)({"waypoints": pred}, batch)
    weights = torch.tensor([w, 1.0, 1.0, 1.0])
    assert parts["plan_l1"] == pytest.approx(float((per * weights).sum() / weights.sum()))
    off = AuroraConfig.for_scale("tiny", planner="mlp", plan_start_weight=1.0)
    _, plain = PlanningCriterion(off)({"waypoints": pred}, batch)
    assert plain["plan_l1"] == pytest.approx(float(per.mean()))
    assert parts["plan_l1"] > plain["plan_l1"]  # the start row's error counts more
    # plan_mask still removes rows (stage 5's QA samples), weights or not
    masked = {**batch, "plan_mask": torch.tensor([False, True, True, True])}
    _, m = PlanningCriterion(CFG)({"waypoints": pred}, masked)
    assert m["plan_l1"] == pytest.approx(float(per[1:].mean()))
    with pytest.raises(ValueError, match="ego_speed"):
        PlanningCriterion(CFG)({"waypoints": pred},
                               {k: v for k, v in batch.items() if k != "ego_speed"})
    with pytest.raises(ValueError, match="plan_speed_dropout"):
        AuroraConfig.for_scale("tiny", plan_speed_dropout=1.5)
    with pytest.raises(ValueError, match="plan_start_weight"):
        AuroraConfig.for_scale("tiny", plan_start_weight=-1.0)


def test_unknown_speed_prompt():
    text = build_prompt(None, 0, None, PLAN_QUESTION, num_det=1, num_map=1, waypoint=True)
    assert f"Ego speed: {UNKNOWN_SPEED};" in text and "m/s" not in text
    assert "Ego speed: 0.0 m/s;" in build_prompt(0.0, 0, None, PLAN_QUESTION, num_det=1,
                                                  num_map=1)


def test_speed_dropout_rate_training_only(tiny_dataset):
    from v2xbench.agents.aurora.data import AuroraFrames
    from v2xbench.agents.aurora.pairs import AuroraPairs, planning_items
    from v2xbench.agents.aurora.prompt import template_texts
    from v2xbench.agents.aurora.tokenizer import train_tokenizer

    tok = train_tokenizer(template_texts() + [PLAN_QUESTION], CFG.lm_vocab)
    frames = AuroraFrames(tiny_dataset, "all", "ego", CFG, images=False)
    plan = planning_items(frames, 1)
    fid = plan[0][0]
    qa = [(fid, "What is the traffic light state?", "green")]
    items = list(itertools.islice(itertools.cycle(plan), 3000)) + qa * 200
    p = 0.3
    ds = AuroraPairs(tiny_dataset, "all", CFG, tok, items, images=False, speed_dropout=p, seed=7)
    drops = [ds.drops_speed(i) for i in range(len(items))]
    rate = sum(drops[:3000]) / 3000
    assert abs(rate - p) < 0.035, rate  # binomial sd ~0.008
    assert not any(drops[3000:])  # QA prompts always carry the speed
    again = AuroraPairs(tiny_dataset, "all", CFG, tok, items, images=False, speed_dropout=p,
                        seed=7)
    assert [again.drops_speed(i) for i in range(3000)] == drops[:3000]  # repeatable (resume)
    i_drop, i_keep = drops.index(True), drops.index(False)
    said = {i: tok.decode(ds[i]["input_ids"]) for i in (i_drop, i_keep)}
    assert f"Ego speed: {UNKNOWN_SPEED};" in said[i_drop] and "m/s" not in said[i_drop]
    assert "m/s" in said[i_keep] and UNKNOWN_SPEED not in said[i_keep]
    assert float(ds[i_drop]["ego_speed"]) == float(ds[i_drop]["ego_speed"])  # real speed kept
    evaluation = AuroraPairs(tiny_dataset, "all", CFG, tok, items[:500], images=False)
    assert not any(evaluation.drops_speed(i) for i in range(500))  # default: never
    with pytest.raises(ValueError, match="speed_dropout"):
        AuroraPairs(tiny_dataset, "all", CFG, tok, items[:5], images=False, speed_dropout=2.0)


def test_target_speed_reads_the_second_segment():
    start = torch.tensor([[[0.4, 0.0], [1.1, 0.0], [2.2, 0.0]]])  # driving off from rest
    assert float(target_speed(start, 0.5)) == pytest.approx(1.4)
    cruise = _line(6.0)[None]
    assert float(target_speed(cruise, 0.5)) == pytest.approx(6.0)
    with pytest.raises(ValueError, match="expected"):
        target_speed(torch.zeros(1, 1, 2), 0.5)
