"""DAgger-style collection: a learned driver drives, the expert labels every frame
(``collectors/dataset/driver.py``)."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest
import torch
from v2xbench.agents.route_follower import RouteFollower
from v2xbench.collectors.dataset.collect import collect
from v2xbench.collectors.dataset.shards import load_manifest, load_shard, validate

from tests.dataset_helpers import TINY

ONE = dataclasses.replace(TINY, max_routes=1)

SENSOR_AGENT = '''
import numpy as np

class Blind:
    """Drives straight at a fixed throttle from its camera and LiDAR observation."""
    obs_mode = "sensors"
    sensors = {"camera_size": [32, 16], "camera_images": ["rgb"]}
    CHANNEL

    def reset(self, route_info):
        self.seen = 0

    def act(self, obs):
        assert "cameras" in obs and "lidar" in obs and "objects" not in obs
        self.seen += 1
        return np.array([0.4, 0.0, 0.0])
'''


def _arrays(root, sid):
    td = load_shard(root, sid)
    return {k: td.get(k).clone() for k in td.keys(include_nested=True, leaves_only=True)}


def test_expert_share_one_records_the_expert_collection(tiny_dataset, tmp_path):
    """With every tick the expert's, a driven collection is the expert's, frame for frame."""
    root = tmp_path / "driven"
    cfg = dataclasses.replace(TINY, driver="route_follower", expert_share=1.0)
    man = collect(cfg, root, progress=False)
    assert man["complete"] and man["driver"]["spec"] == "route_follower"
    for sid in man["episodes"]:
        a, b = _arrays(root, sid), _arrays(tiny_dataset, sid)
        assert a.keys() == b.keys()
        for k in a:
            assert torch.equal(a[k], b[k]), k


def test_driver_drives_and_the_expert_labels(tiny_dataset, tmp_path):
    root = tmp_path / "driven"
    cfg = dataclasses.replace(ONE, driver="route_follower", perturb=False)
    collect(cfg, root, progress=False)
    assert validate(root)["ok"]
    td, expert = load_shard(root, "train_000_s0"), load_shard(tiny_dataset, "train_000_s0")
    # the executed controls are the route follower's on the recorded (objects-mode) observations
    agent = RouteFollower()
    agent.reset({})
    for t in range(td.batch_size[0]):
        obs = {k: td["obs", k][t].numpy() for k in td["obs"].keys()}
        np.testing.assert_allclose(td["control"][t].numpy(), agent.act(obs), atol=1e-5)
    # ... which are not the expert's: the drive differs, and each frame carries the expert's plan
    assert not torch.equal(td["control"], td["expert_control"])
    assert not torch.equal(td["ego_pose"], expert["ego_pose"])
    assert td["expert_waypoints"].abs().sum() > 0


def test_sensor_mode_driver_keeps_the_collection_schema(tmp_path):
    (tmp_path / "blind.py").write_text(SENSOR_AGENT.replace("CHANNEL", ""))
    spec = f"{tmp_path / 'blind.py'}:Blind"
    root = tmp_path / "driven"
    cfg = dataclasses.replace(ONE, driver=spec, perturb=False)
    man = collect(cfg, root, progress=False)
    assert man["complete"], man["failed"]
    td = load_shard(root, "train_000_s0")
    assert validate(root)["ok"]
    assert torch.allclose(td["control"], torch.tensor([0.4, 0.0, 0.0]))
    assert td["obs", "objects"].shape[0] == td.batch_size[0]  # obs/* stays the objects mode
    assert float(td["ego_speed"][-1]) > 1.0


def test_bad_drivers_are_refused_up_front(tiny_dataset, tmp_path):
    (tmp_path / "talker.py").write_text(
        SENSOR_AGENT.replace("CHANNEL", "channel = {'max_payload_floats': 640}"))
    talker = f"{tmp_path / 'talker.py'}:Blind"
    with pytest.raises(ValueError, match="--set max_payload_floats=640"):
        collect(dataclasses.replace(ONE, driver=talker), tmp_path / "a", progress=False)
    assert not (tmp_path / "a" / "shards").exists()
    with pytest.raises(ValueError, match="privileged"):
        collect(dataclasses.replace(ONE, driver="expert"), tmp_path / "b", progress=False)
    with pytest.raises(ValueError, match="expert_share"):
        dataclasses.replace(ONE, driver="route_follower", expert_share=1.5)
    with pytest.raises(ValueError, match="expert_share without a driver"):
        dataclasses.replace(ONE, expert_share=0.5)
    with pytest.raises(ValueError, match="driver_config without a driver"):
        dataclasses.replace(ONE, driver_config={"use_v2x": False})
    with pytest.raises(ValueError, match="town"):
        dataclasses.replace(ONE, env={"town": "Town01"})


def test_resume_needs_the_same_driver(tiny_dataset, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(tiny_dataset, root)
    with pytest.raises(ValueError, match="other settings"):  # the expert's set, driven now
        collect(dataclasses.replace(TINY, driver="route_follower"), root, progress=False)
    driven = tmp_path / "driven"
    cfg = dataclasses.replace(ONE, driver="route_follower", perturb=False)
    collect(cfg, driven, progress=False)
    man = json.loads((driven / "manifest.json").read_text())
    man["driver"]["checkpoint"] = {"weights.safetensors": "0" * 64}  # as if other weights drove
    (driven / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(ValueError, match="another driver or other weights"):
        collect(cfg, driven, progress=False)


def test_manifest_written_before_the_driver_fields_still_resumes(tiny_dataset, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(tiny_dataset, root)
    man = json.loads((root / "manifest.json").read_text())
    for k in ("driver", "driver_config", "expert_share"):
        man["config"].pop(k)
    (root / "manifest.json").write_text(json.dumps(man))
    again = collect(TINY, root, progress=False)
    assert again["complete"] and load_manifest(root)["config"]["driver"] is None


def test_first_seed_and_merge_aggregate_a_driven_set(tiny_dataset, tmp_path):
    """DAgger's aggregation: the expert's set and a driven one on other seeds, merged."""
    from v2xbench.collectors.dataset.loader import V2XDataset
    from v2xbench.collectors.dataset.merge import merge

    driven = tmp_path / "driven"
    cfg = dataclasses.replace(ONE, driver="route_follower", perturb=False, first_seed=1)
    man = collect(cfg, driven, progress=False)
    assert man["episodes"] == ["train_000_s1"]  # another world seed of the same route
    out = tmp_path / "merged"
    merged = merge([tiny_dataset, driven], out)
    assert validate(out)["ok"] and set(merged["shards"]) == {"train_000_s0", "train_001_s0",
                                                             "train_000_s1"}
    assert [m["driver"] for m in merged["merged_from"]][0] is None
    ds = V2XDataset(out, "all", keys=["control"])
    assert len(ds) == sum(s["frames"] for s in merged["shards"].values())
    assert torch.equal(load_shard(out, "train_000_s1")["control"],
                       load_shard(driven, "train_000_s1")["control"])
    with pytest.raises(ValueError, match="merged data set"):
        collect(TINY, out, progress=False)
    with pytest.raises(ValueError, match="in both"):  # shard names must not clash
        merge([tiny_dataset, tiny_dataset], tmp_path / "twice")
    other = tmp_path / "other"
    collect(dataclasses.replace(ONE, first_seed=2, camera_size=(16, 8)), other, progress=False)
    with pytest.raises(ValueError, match="records other data"):
        merge([tiny_dataset, other], tmp_path / "mixed")
    with pytest.raises(ValueError, match="exists"):
        merge([tiny_dataset, driven], out)
    assert not (tmp_path / "mixed").exists() and not (tmp_path / "twice").exists()
