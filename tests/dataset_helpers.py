"""A tiny collected data set shared by the dataset and Chat-V2XBench tests."""

from __future__ import annotations

from pathlib import Path

from v2xbench.collectors.dataset.collect import CollectConfig

#: two training routes kept apart from the shipped suites (a suite rebuild does not change what
#: the tests collect): ControlLoss on Town02, SignalizedJunctionRightTurn on Town03
TINY_SUITE = str(Path(__file__).parent / "fixtures" / "tiny_suite.json")
#: 2 train routes x 40 ticks, small cameras and LiDARs (about 5 s to collect)
TINY = CollectConfig(suite=TINY_SUITE, max_routes=2, max_ticks=40, camera_size=(32, 16), lidar_scale=0.5,
                     val_fraction=0.5)
