"""Probe: the shipped CoDriving in closed loop, logging every tick its planned target speed, its
first waypoints, its speed and its control, then a summary of where it stands for good.

    PROBE_OUT=probe.jsonl v2xbench eval --agent docs/results/standstill/probe_agent.py:ProbeCoDriving \\
        --suite test50 --routes test50_000 --set max_steps=600 --out /tmp/probe
    python docs/results/standstill/probe_agent.py probe.jsonl [--out FILE]

Numbers in docs/baselines.md ("Why the baselines run out of time"): test50_000 (600 ticks) and
test50_002 (the whole route), seed 0.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
from v2xbench.agents.baselines.codriving.agent import CoDrivingAgent
from v2xbench.agents.baselines.common.policy import SPEED


class ProbeCoDriving(CoDrivingAgent):
    """The registered ``codriving`` agent (shipped weights) writing one JSON line a tick."""

    def __init__(self) -> None:
        super().__init__()
        self._log = open(os.environ.get("PROBE_OUT", "probe.jsonl"), "a")  # noqa: SIM115

    def act(self, obs: dict) -> np.ndarray:
        t0 = time.perf_counter()
        wps, speed = self.driver.plan(obs)
        self.infer_s += time.perf_counter() - t0
        self.ticks += 1
        a = self.controller.control(wps, float(obs["ego"][SPEED]), speed)
        self._log.write(json.dumps({"t": self.ticks, "v": float(obs["ego"][SPEED]),
                                    "target": float(speed), "wp": np.round(wps[:3], 2).tolist(),
                                    "a": np.round(a, 3).tolist()}) + "\n")
        self._log.flush()
        return a


# the base class finds its policy and train modules next to the class's module
ProbeCoDriving.__module__ = CoDrivingAgent.__module__


def summarize(path: Path) -> dict:
    """Where the probed run stands for good and what it plans from there."""
    from standstill import stands_from  # the script's folder (run as a script; not as an agent)

    rows = [json.loads(line) for line in path.read_text().splitlines()]
    start = stands_from(np.array([r["v"] for r in rows]))
    tail = rows[start:]
    target = np.array([r["target"] for r in tail])
    reach = np.array([np.hypot(*r["wp"][-1]) for r in tail])
    return {"ticks": len(rows), "stands_from_tick": start, "standing_ticks": len(tail),
            "target_speed_mean": float(target.mean()) if len(tail) else None,
            "target_speed_max": float(target.max()) if len(tail) else None,
            "third_waypoint_distance_max_m": float(reach.max()) if len(tail) else None,
            "braking_share": float(np.mean([r["a"][2] > 0.5 for r in tail])) if tail else None}


def main() -> None:
    ap = argparse.ArgumentParser(description="summarize a probe log")
    ap.add_argument("log", type=Path)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    s = summarize(args.log)
    print(json.dumps(s, indent=1))
    if args.out is not None:
        from standstill import write_json

        write_json(s, args.out)


if __name__ == "__main__":
    main()
