"""The data set records the ego's objects-mode observation (issue #30 item 11)."""

import dataclasses
import json

import numpy as np
from v2xbench.collectors.dataset.collect import CollectConfig, collect
from v2xbench.collectors.dataset.loader import V2XDataset
from v2xbench.collectors.dataset.record import OBS_KEYS
from v2xbench.envs.v2x_intersection.api.observations import EGO_FEATURES, ego_space
from v2xbench.envs.v2x_intersection.sim.config import make_config

from tests.dataset_helpers import TINY


def test_frames_hold_the_objects_observation_inside_its_space(tiny_dataset):
    ds = V2XDataset(tiny_dataset, "all")
    space = ego_space(make_config(obs_mode="objects"))
    speed = EGO_FEATURES.index("speed")
    received = 0
    for i in range(0, len(ds), 7):
        f = ds[i]
        obs = {k: f["obs", k].numpy() for k in OBS_KEYS}
        assert space.contains(obs), i
        assert np.isclose(obs["ego"][speed], float(f["ego_speed"]), atol=1e-5)
        received += int(obs["v2x_info"][0] > 0)
    assert received > 0  # the received message is part of it


def test_data_sets_without_the_observation_still_load(tmp_path):
    cfg = dataclasses.replace(TINY, max_routes=1, max_ticks=5, objects_obs=False)
    collect(cfg, tmp_path, workers=1, progress=False)
    man = tmp_path / "manifest.json"
    d = json.loads(man.read_text())
    del d["config"]["objects_obs"]  # as written before the field existed
    man.chmod(0o644)
    man.write_text(json.dumps(d))
    assert CollectConfig.from_json(d["config"]).objects_obs is False
    f = V2XDataset(tmp_path, "all")[0]
    assert "obs" not in f.keys()
