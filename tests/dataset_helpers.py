"""A tiny collected data set shared by the dataset and Chat-V2XBench tests."""

from __future__ import annotations

from v2xbench.collectors.dataset.collect import CollectConfig

#: 2 train routes x 40 ticks, small cameras and LiDARs (about 5 s to collect)
TINY = CollectConfig(max_routes=2, max_ticks=40, camera_size=(32, 16), lidar_scale=0.5,
                     val_fraction=0.5)
