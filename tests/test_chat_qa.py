"""Chat-V2XBench: exact answers against logged state, paraphrases, exports and scoring."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from v2xbench.agents.aurora.cqaf import rsu_to_ego
from v2xbench.agents.aurora.prompt import context_from_record, runtime_context
from v2xbench.agents.expert import Expert
from v2xbench.collectors.chat import templates
from v2xbench.collectors.chat.export import build, is_hint_free, load_items, split_items, stats
from v2xbench.collectors.chat.facts import TREND_EPS, keyframe_facts
from v2xbench.collectors.chat.generate import keyframe_id, keyframe_qa
from v2xbench.collectors.chat.scoring import closed_label, coordinates, score, slots
from v2xbench.collectors.dataset.collect import _rig
from v2xbench.collectors.dataset.record import light_info
from v2xbench.collectors.dataset.shards import load_shard, shards_dir
from v2xbench.envs.v2x_intersection.core.geometry import (
    invert_transform,
    relative_transform,
    transform_points,
)
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached
from v2xbench.envs.v2x_intersection.town.model import COMMAND_NAMES
from v2xbench.envs.v2x_intersection.traffic.signals import GREEN, RED, YELLOW

from tests.dataset_helpers import TINY
from v2xbench.cli import main


@pytest.fixture(scope="module")
def qa(tiny_dataset):
    build(tiny_dataset, seed=0)
    return load_items(tiny_dataset)


def _shard(root, episode):
    return load_shard(root, episode)


def test_four_levels_and_stats(qa, tiny_dataset, capsys):
    st = stats(qa)
    assert st["keyframes"] == 10 and st["episodes"] == 2
    assert all(st["per_level"][lv] > 0 for lv in ("scene", "perception", "alignment", "planning"))
    assert st["per_type"]["traffic_light"] == st["per_type"]["speed_trend"] == 10
    assert set(st["per_scenario"]) == {"ControlLoss", "SignalizedJunctionRightTurn"}
    assert main(["qa", "stats", str(tiny_dataset)]) == 0
    out = capsys.readouterr().out
    assert "alignment" in out and "speed_trend" in out and "ControlLoss" in out
    for it in qa:  # the GT object hints are an annotation; the context is the run-time one
        assert "Nearby objects (ground truth, ego frame" in it["hints"]
        assert "Roadside camera" in it["hints"]
        assert it["context"].startswith("Ego speed: ") and "ground truth" not in it["context"]
        assert "Roadside unit" in it["context"] and it["split"] in ("train", "val")
    assert {it["split"] for it in qa} == {"train", "val"}  # TINY holds out one of its 2 routes


def test_spatial_alignment_transforms_back_within_1cm(qa, tiny_dataset):
    items = [it for it in qa if it["type"] == "rsu_to_ego"]
    assert items
    facts = {(json.loads(line)["episode"], json.loads(line)["tick"]): json.loads(line)
             for sid in ("train_000_s0", "train_001_s0")
             for line in (shards_dir(tiny_dataset) / sid / "keyframes.jsonl").read_text().splitlines()}
    for it in items:
        f = facts[(it["episode"], it["tick"])]
        td = _shard(tiny_dataset, it["episode"])[it["tick"]]
        # the transform in the facts is the logged calibration's rigid transform
        t_ego_cam = relative_transform(td["calib", "T_world_ego"].numpy(), td["calib", "T_world_cam"][6].numpy())
        assert np.allclose(np.array(f["T_ego_rsu_cam"]).reshape(4, 4), t_ego_cam, atol=1e-8)
        q_cam = coordinates(it["question"])
        a_ego = coordinates(it["answer"])
        back = transform_points(invert_transform(t_ego_cam), a_ego)
        assert np.linalg.norm(back - q_cam) < 0.01
        assert np.allclose(a_ego, it["label"])
        # the object is jointly visible (>= 10 LiDAR points from both) and its GT box is there
        g = td["gt", "fused"]
        near = np.linalg.norm(g["boxes"][:, :3].numpy() - a_ego, axis=1)
        k = int(np.argmin(np.where(g["mask"].numpy(), near, np.inf)))
        assert near[k] < 0.02 and bool(g["joint"][k])
        assert (g["lidar_points"][k] >= 10).all()


def test_traffic_light_answers_match_the_logged_signal(qa, tiny_dataset):
    for it in (it for it in qa if it["type"] == "traffic_light"):
        td = _shard(tiny_dataset, it["episode"])[it["tick"]]
        state, affects = int(td["light_state"]), bool(td["light_affects_ego"])
        want = ("green", "yellow", "red")[state] if affects else "no"
        assert it["label"] == want == closed_label("traffic_light", it["answer"])


def test_traffic_light_answer_for_each_colour():
    """Drive toward a signal until it affects the ego; force each colour; the answer follows."""
    spec = next(r for r in load_suite_cached("train") if r.scenarios[0].type == "SignalizedJunctionRightTurn")
    world = World(make_config(town=spec.town, num_vehicles=0, num_pedestrians=0, num_parked=0,
                              num_bicycles=0))
    world.reset(seed=spec.seed, spec=spec)
    expert = Expert()
    expert.bind(world)
    expert.reset({})
    for _ in range(600):
        world.step(expert.act(None), world.default_rsu_message())
        if light_info(world)[1]:
            break
    assert light_info(world)[1], "the route never came within 40 m of a signal"
    expert.act(None)
    cfg = TINY
    frame = _rig(cfg).capture(world)
    lane = int(world.route.lane_ids[world.monitor.progress])
    hist = {"speed": {world.tick: 0.0}, "command": {}}
    for state, name in ((RED, "red"), (YELLOW, "yellow"), (GREEN, "green")):
        world.lane_signal[lane] = state
        f = keyframe_facts(world, frame, expert, hist, {}, {"episode": "x", "route_id": spec.id,
                                                             "town": spec.town, "scenarios": []})
        light = next(q for q in keyframe_qa(f) if q["type"] == "traffic_light")
        assert light["label"] == name and name in light["answer"] and light["answer"].startswith("Yes")
        scene = next(q for q in keyframe_qa(f) if q["type"] == "scene_description")
        assert ("light", name) in slots(scene["answer"])


def test_speed_trend_and_previous_command_match_the_log(qa, tiny_dataset):
    seen = set()
    for it in qa:
        if it["type"] not in ("speed_trend", "previous_command") or it["tick"] == 0:
            continue
        td = _shard(tiny_dataset, it["episode"])
        if it["type"] == "speed_trend":
            dv = float(td["ego_speed"][it["tick"]] - td["ego_speed"][it["tick"] - 10])
            want = "accelerating" if dv > TREND_EPS else ("decelerating" if dv < -TREND_EPS else "unchanged")
            assert it["label"] == want == closed_label("speed_trend", it["answer"])
            seen.add(want)
        else:
            want = COMMAND_NAMES[int(td["command"][it["tick"] - 1])]
            assert it["label"] == want == closed_label("previous_command", it["answer"])
    assert "accelerating" in seen  # the expert starts from rest


def test_descriptive_answers_agree_with_the_facts(qa, tiny_dataset):
    for it in qa:
        if it["type"] == "scene_description":
            found = slots(it["answer"])
            lab = it["label"]
            assert ("weather", lab["weather"]) in found and ("time_of_day", lab["time_of_day"]) in found
            assert ("density", lab["density"]) in found
        elif it["type"] == "behavior":
            assert closed_label("speed_decision", it["answer"]) == it["label"]["speed_decision"]
            assert ("reason", it["label"]["reason"]) in slots(it["answer"])
            if it["label"]["speed_decision"] in ("accelerate", "keep"):  # never "... because it is red"
                assert it["label"]["reason"] in ("free", "follow", "clear_until", "other")
        elif it["type"] == "critical_objects":
            for o in it["label"]["objects"]:
                assert f"#{o['id']}" in it["answer"] and f"({o['x']:.1f}, {o['y']:.1f})" in it["answer"]
        elif it["type"] == "speed_decision":  # matches the expert's planned speeds in the log
            td = _shard(tiny_dataset, it["episode"])[it["tick"]]
            sp, v = td["expert_speeds"].numpy(), float(td["ego_speed"])
            want = "stop" if sp[2] < 0.3 else ("accelerate" if sp[1] - v > 0.5 else
                                                ("decelerate" if sp[1] - v < -0.5 else "keep"))
            assert it["label"] == want


def test_paraphrases_vary_with_the_seed_but_not_the_labels(tiny_dataset):
    lines = (shards_dir(tiny_dataset) / "train_001_s0" / "keyframes.jsonl").read_text().splitlines()
    facts = [json.loads(line) for line in lines]
    a = [q for f in facts for q in keyframe_qa(f, seed=0)]
    b = [q for f in facts for q in keyframe_qa(f, seed=1)]
    assert a == [q for f in facts for q in keyframe_qa(f, seed=0)]  # reproducible
    assert [q["label"] for q in a if q["type"] != "rsu_to_ego"] == [q["label"] for q in b if q["type"] != "rsu_to_ego"]
    assert sum(x["question"] != y["question"] or x["answer"] != y["answer"] for x, y in zip(a, b)) > len(a) // 3


def test_llava_export(qa, tiny_dataset):
    rows = [json.loads(line) for line in (tiny_dataset / "chat" / "llava.jsonl").read_text().splitlines()]
    assert len(rows) == 10
    for r in rows:
        assert len(r["image"]) == 7 and r["image"][-1].endswith("rsu_cam.png")
        assert all((tiny_dataset / p).exists() for p in r["image"])
        conv = r["conversations"]
        assert [c["from"] for c in conv] == ["human", "gpt"] * (len(conv) // 2)
        assert conv[0]["value"].count("<image>") == 7 and "ROADSIDE: <image>" in conv[0]["value"]
        assert all("<image>" not in c["value"] for c in conv[1:])


def test_default_llava_prompts_hold_no_ground_truth_object(qa, tiny_dataset, tmp_path):
    facts = {keyframe_id(f): f for sid in ("train_000_s0", "train_001_s0")
             for f in map(json.loads, (shards_dir(tiny_dataset) / sid / "keyframes.jsonl")
                          .read_text().splitlines())}
    by_kf: dict = {}
    for it in qa:
        by_kf.setdefault(it["keyframe"], []).append(it)
    llava = (tiny_dataset / "chat" / "llava.jsonl").read_text().splitlines()
    rows = [json.loads(line) for line in llava]
    objects = 0
    for r in rows:
        f, items = facts[r["id"]], by_kf[r["id"]]
        humans = [c["value"] for c in r["conversations"] if c["from"] == "human"]
        assert items[0]["context"] in humans[0]
        # what the prompts carry besides the questions: camera tokens and the run-time context
        rest = "\n".join(h.replace(it["question"], "") for h, it in zip(humans, items, strict=True))
        low = rest.lower()
        assert "ground truth" not in low and "#" not in rest and "objects" not in low
        for o in f["objects"]:
            objects += 1
            for v in (f"{o['x']:.2f}", f"{o['y']:.2f}", f"{o['x']:.1f}, {o['y']:.1f}",
                      f"#{o['id']}"):
                assert v not in rest, (v, rest)
            assert templates.CLASS.get(o["class"], o["class"]) not in low and o["class"] not in low
            # ... but the annotation beside the conversation keeps them
            assert f"#{o['id']} at ({o['x']:.2f}, {o['y']:.2f})" in r["hints"]
        assert r["hints"] == items[0]["hints"]
    assert objects > 0
    # the context is the run-time prompt's, rebuilt from the recorded frame
    it = qa[0]
    td = _shard(tiny_dataset, it["episode"])[it["tick"]]
    assert it["context"] == context_from_record(td)
    e = rsu_to_ego(td["calib", "T_world_ego"].numpy(), td["calib", "T_world_rsu"].numpy())
    assert it["context"] == runtime_context(float(td["ego_speed"]), int(td["command"]),
                                            e if int(td["calib", "rsu_unit"]) >= 0 else None)
    # the labelling form puts the hints in the prompt; qa.jsonl is the same either way
    res = build(tiny_dataset, seed=0, out=tmp_path / "hinted", hints_in_prompt=True)
    first = json.loads(Path(res["llava"]).read_text().splitlines()[0])
    assert "Nearby objects (ground truth" in first["conversations"][0]["value"]
    assert Path(res["qa"]).read_text() == (tiny_dataset / "chat" / "qa.jsonl").read_text()


def test_files_without_hints_still_load(qa, tmp_path, capsys):
    old = [{k: v for k, v in it.items() if k not in ("hints", "split")} for it in qa]
    path = tmp_path / "qa.jsonl"
    path.write_text("".join(json.dumps(it) + "\n" for it in old))
    items = load_items(path)
    assert len(items) == len(qa) and not is_hint_free(items) and is_hint_free(qa)
    assert split_items(items, "all") == items
    with pytest.raises(ValueError, match="no 'split' field"):
        split_items(items, "train")
    with pytest.raises(ValueError, match=r"no QA item of split 'test'.*\['train', 'val'\]"):
        split_items(qa, "test")
    path.write_text(json.dumps(dict(qa[0], hints=3)) + "\n")
    assert main(["qa", "stats", str(path)]) == 2
    assert "field 'hints' must be a str, got 3" in capsys.readouterr().err


def test_scoring(qa, tiny_dataset, tmp_path, capsys):
    perfect = score(qa, {it["id"]: it["answer"] for it in qa})
    assert perfect["closed"]["accuracy"] == 1.0 and perfect["descriptive"]["f1"] == 1.0
    assert perfect["coordinate"]["mean_error_m"] < 1e-9
    wrong = {}
    for it in qa:
        if it["kind"] == "coordinate":
            x, y, z = it["label"]
            wrong[it["id"]] = f"({x + 3:.2f}, {y - 4:.2f}, {z:.2f})"
        elif it["type"] == "speed_trend":
            wrong[it["id"]] = "Decelerating." if it["label"] != "decelerating" else "Accelerating."
        else:
            wrong[it["id"]] = it["answer"]
    empty = score(qa, {it["id"]: " " for it in qa})  # an empty answer scores 0, even where the
    assert empty["descriptive"]["f1"] == 0.0  # reference has no slots ("no critical object")
    s = score(qa, wrong)
    assert abs(s["coordinate"]["mean_error_m"] - 5.0) < 0.01 and s["coordinate"]["within_0.5m"] == 0.0
    assert s["closed"]["per_type"]["speed_trend"] == 0.0 and s["closed"]["per_type"]["traffic_light"] == 1.0
    assert closed_label("traffic_light", "No, there is none.") == "no"
    assert closed_label("traffic_light", "Yes, it shows amber.") == "yellow"
    ref = "It is night with foggy weather. There is heavy traffic."
    assert slots(ref) == {("time_of_day", "night"), ("weather", "fog"), ("density", "heavy")}
    pred = tmp_path / "pred.jsonl"
    pred.write_text("".join(json.dumps({"id": it["id"], "answer": it["answer"]}) + "\n" for it in qa[:5]))
    capsys.readouterr()
    assert main(["qa", "score", str(tiny_dataset), str(pred)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["missing"] == len(qa) - 5
    assert set(out["per_level"]) == {"scene", "perception", "alignment", "planning"}
    assert sum(v["n"] for v in out["per_level"].values()) == len(qa)
    # per level: the same groups over the level's items
    lv = perfect["per_level"]
    assert lv["alignment"]["coordinate"]["n"] == perfect["coordinate"]["n"]
    assert lv["alignment"]["closed"]["n"] == 0 and lv["scene"]["closed"]["accuracy"] == 1.0
    assert s["per_level"]["planning"]["closed"]["accuracy"] < 1.0  # speed_trend is wrong
    val = [it for it in qa if it["split"] == "val"]
    pred.write_text("".join(json.dumps({"id": it["id"], "answer": it["answer"]}) + "\n"
                            for it in val))
    assert main(["qa", "score", str(tiny_dataset), str(pred), "--split", "val"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["missing"] == 0 and out["answered"] == len(val) < len(qa)
    assert out["closed"]["accuracy"] == 1.0


def test_show_keyframe(qa, tiny_dataset, tmp_path, capsys):
    from PIL import Image

    out = tmp_path / "kf.png"
    assert main(["qa", "show", str(tiny_dataset), "--out", str(out), "--scale", "2"]) == 0
    md = capsys.readouterr().out
    assert "| alignment | rsu_to_ego |" in md and "Prompt context" in md
    w, h = Image.open(out).size
    assert w > 3 * 64 and h > 3 * 32


def test_bad_predictions_are_named_by_file_and_line(qa, tiny_dataset, tmp_path, capsys):
    pred = tmp_path / "pred.jsonl"
    good = json.dumps({"id": qa[0]["id"], "answer": "Yes."})
    for line, needle in ((json.dumps({"answer": "x"}), "'id' must be a string, got missing"),
                         (json.dumps({"id": qa[1]["id"], "answer": 3}),
                          "'answer' must be a string, got int 3"),
                         ("{oops", "not valid JSON"), ("[1, 2]", "expected a JSON object"),
                         (good, "repeats line 1")):
        pred.write_text(good + "\n\n" + line + "\n")
        capsys.readouterr()
        assert main(["qa", "score", str(tiny_dataset), str(pred)]) == 2
        err = capsys.readouterr().err
        assert f"{pred}:3: " in err and needle in err, err
    with pytest.raises(ValueError, match="answer for .* is float 3.0, not a string"):
        score(qa, {qa[0]["id"]: 3.0})


def test_bad_reference_items_and_keyframes_are_named(qa, tiny_dataset, tmp_path, capsys):
    ref = tmp_path / "qa.jsonl"
    closed = next(it for it in qa if it["kind"] == "closed")
    coord = next(it for it in qa if it["kind"] == "coordinate")
    cases = (("{oops", "not valid JSON"),
             (json.dumps({k: v for k, v in qa[1].items() if k != "kind"}),
              "field 'kind' must be a str, got None"),
             (json.dumps(dict(closed, type="colour")), "closed type 'colour'"),
             (json.dumps(dict(coord, label=[1, 2])), "coordinate label must be 3 numbers"),
             (json.dumps(dict(qa[1], images=["../../etc/x.png"])), "must be relative paths"),
             (json.dumps(qa[0]), f"id {qa[0]['id']!r} repeats {ref}:1"))
    for line, needle in cases:
        ref.write_text(json.dumps(qa[0]) + "\n" + line + "\n")
        capsys.readouterr()
        assert main(["qa", "stats", str(ref)]) == 2
        err = capsys.readouterr().err
        assert f"{ref}:2: " in err and needle in err, err
    root = tmp_path / "ds"
    shutil.copytree(tiny_dataset, root, ignore=shutil.ignore_patterns("chat"))
    kf = shards_dir(root) / "train_001_s0" / "keyframes.jsonl"
    kf.chmod(0o644)
    lines = kf.read_text().splitlines()
    facts = json.loads(lines[2])
    escape = dict(facts, images=dict(facts["images"],
                                     rsu_cam="shards/train_001_s0/images/../../../../secret.png"))
    for bad, needle in ((json.dumps(escape), "image 'rsu_cam' path"), ("{oops", "not valid JSON"),
                        (json.dumps({k: v for k, v in facts.items() if k != "plan"}),
                         "keyframe facts are malformed (KeyError")):
        kf.write_text("\n".join(lines[:2] + [bad] + lines[3:]) + "\n")
        capsys.readouterr()
        assert main(["qa", "build", str(root)]) == 2
        err = capsys.readouterr().err
        assert f"{kf}:3: " in err and needle in err, err
    assert not (root / "chat" / "qa.jsonl").exists()  # nothing half-built
