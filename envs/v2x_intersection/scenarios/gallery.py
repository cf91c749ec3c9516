"""Scenario gallery: one short video per scenario, plus a markdown index linking them.

Each video shows, side by side, the top-down view around the ego and the view around the active
RSU (cyan rings: seen by the ego; magenta: seen by the RSU), while the observation-only route
follower drives through the scenario.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..render.topdown import render_topdown, save_video
from . import get_scenario
from .probe import hidden_seconds, probe


def _frames_for(name: str, seed: int, size: int, every: int = 3, lead_s: float = 4.0) -> tuple[list[np.ndarray], dict]:
    """Frames from ``lead_s`` seconds before the trigger until shortly after the ego passed."""
    frames: list[np.ndarray] = []

    def grab(world) -> None:
        sc = world.scenarios[0]
        if world.tick % every or sc.ego_s(world) < sc.trigger_s - lead_s * max(world.table.speed[0], 5.0):
            return
        ego = render_topdown(world, size, view_m=80.0)
        rsu = render_topdown(world, size, view_m=80.0, center="rsu", text=False)
        frames.append(np.concatenate([ego, rsu], axis=1))

    rec = probe(name, seed, max_ticks=500, stop_after_pass=2.0, on_tick=grab)
    info = {"hidden_s": hidden_seconds(rec) if len(rec.scenario.hazard_rows) else 0.0,
            "events": rec.events, "passed": rec.scenario.passed, "town": rec.world.town.name}
    return frames, info


def render_gallery(names: list[str], out: Path, seed: int = 0, size: int = 256, quiet: bool = False) -> Path:
    """Write ``<out>/<name>.gif`` for each scenario and ``<out>/README.md``; returns the index path."""
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Scenario gallery", "", "Made by `v2xbench scenarios render`. Left: around the ego; right: "
             "around the active RSU. Cyan rings: seen by the ego; magenta: seen by the RSU.", "",
             "| scenario | family | V2X | town | hazard hidden from ego, seen by RSU (s) | video |",
             "|---|---|---|---|---|---|"]
    for name in tqdm(names, desc="scenarios", disable=quiet):
        frames, info = _frames_for(name, seed, size)
        cls = get_scenario(name)
        path = save_video(frames, out / f"{name}.gif", fps=10 // 3)
        lines.append(f"| {name} | {cls.family} | {'yes' if cls.v2x else 'no'} | {info['town']} | "
                     f"{info['hidden_s']:.1f} | [{path.name}]({path.name}) |")
    index = out / "README.md"
    tmp = index.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(index)
    return index
