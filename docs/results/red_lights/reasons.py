"""Planned speed by the expert's binding constraint, every method: the table of docs/baselines.md,
"Red lights". Reads the ``metrics.json`` of ``v2xbench baselines eval-planning`` /
``v2xbench aurora eval-planning`` runs (copied beside this file) and prints, per method, the
expert's and the model's mean planned speed over 3 s (m/s) on the frames where the ego moves and
where it stands, per ``expert_reason``. A metrics file written before ``standing`` existed gets it
from the all-frames and moving means (exact: means weighted by their frame counts).

    python docs/results/red_lights/reasons.py NAME=metrics.json ... [--out table.md]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

REASONS = ("free", "leader", "red", "stop_sign", "yield", "conflict")


def standing(g: dict) -> dict:
    """The ``standing`` group of a per-reason entry, derived when absent."""
    if "standing" in g:
        return g["standing"]
    n, mv = g["frames"], g["moving"]
    k = n - mv["frames"]
    out = {"frames": k}
    for key in ("expert_speed_3s", "model_speed_3s", "ego_speed"):
        out[key] = None if not k else (n * g[key] - mv["frames"] * (mv[key] or 0.0)) / k
    return out


def table(runs: dict[str, dict]) -> str:
    """The Markdown table of ``runs`` (name -> metrics)."""
    first = next(iter(runs.values()))["per_reason"]
    head = ["| who | " + " | ".join(f"{r}, moving | {r}, standing" for r in REASONS) + " |",
            "|---|" + "---|---|" * len(REASONS)]
    rows = []
    for who, key in (("expert", "expert_speed_3s"),):
        rows.append(f"| {who} | " + " | ".join(
            f"{first[r]['moving'][key]:.2f} | {standing(first[r])[key]:.2f}" for r in REASONS) + " |")
    for name, m in runs.items():
        pr = m["per_reason"]
        rows.append(f"| {name} | " + " | ".join(
            f"{pr[r]['moving']['model_speed_3s']:.2f} | {standing(pr[r])['model_speed_3s']:.2f}"
            for r in REASONS) + " |")
    counts = ", ".join(f"{r} {first[r]['moving']['frames']} / {standing(first[r])['frames']}"
                       for r in REASONS)
    return "\n".join(head + rows) + f"\n\nFrames (moving / standing) of the first run: {counts}.\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="NAME=path/to/metrics.json")
    ap.add_argument("--out")
    a = ap.parse_args()
    runs = {}
    for arg in a.runs:
        name, path = arg.split("=", 1)
        runs[name] = json.loads(Path(path).read_text())
    text = table(runs)
    print(text)
    if a.out:
        Path(a.out).write_text(text)


if __name__ == "__main__":
    main()
