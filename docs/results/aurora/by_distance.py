"""AURORA detection AP by distance from the sensor frame's origin (the numbers in by_distance.json).

Usage: python docs/results/aurora/by_distance.py RUN DATA SPLIT STRIDE OUT.json
e.g. RUN=runs/aurora DATA=data/v2x-test SPLIT=all STRIDE=25 (test) or DATA=data/v2x SPLIT=train
STRIDE=60. Predictions and ground truth are both cut to a radius before matching.
"""

import json
import sys

import numpy as np
import torch
from v2xbench.agents.aurora.data import AuroraFrames
from v2xbench.agents.aurora.eval_perception import load_branch, predict
from v2xbench.envs.v2x_intersection.core.classes import VEHICLE_CLASSES
from v2xbench.envs.v2x_intersection.evaluation.metrics_perception import detection_metrics


def main(run: str, data: str, split: str, stride: int, out_path: str) -> None:
    torch.set_num_threads(1)
    out = {}
    for branch, stage in (("ego", 1), ("rsu", 2)):
        model, cfg = load_branch(f"{run}/stage{stage}")
        res = predict(model, AuroraFrames(data, split, branch, cfg, stride=stride), top_k=50)
        p, g = res["preds"], res["gts"]
        for r in (10, 20, 30, float("inf")):
            pm, gm = np.linalg.norm(p.center, axis=1) < r, np.linalg.norm(g.center, axis=1) < r
            m = detection_metrics(p.select(pm), g.select(gm))
            row = {"vehicle": round(m["vehicle/AP"], 3), "vru": round(m["vru/AP"], 3),
                   "mAP": round(m["mAP"], 3), "NDS": round(m["NDS"], 3),
                   "n_gt_vehicle": int(np.isin(g.select(gm).cls, VEHICLE_CLASSES).sum())}
            out[f"{branch} r<{r:g}"] = row
            print(branch, r, row, flush=True)
    with open(out_path, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5])
