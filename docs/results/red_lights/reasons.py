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


def _cells(pr: dict, key: str) -> str:
    return " | ".join(f"{pr[r]['moving'][key]:.2f} | {standing(pr[r])[key]:.2f}" for r in REASONS)


def table(runs: dict[str, dict]) -> str:
    """The Markdown table of ``runs`` (name -> metrics): the expert's row once per data set (its
    frames' counts after it), then each run's."""
    head = ["| who (data set) | " + " | ".join(f"{r}, moving | {r}, standing" for r in REASONS)
            + " |", "|---|" + "---|---|" * len(REASONS)]
    rows, seen, notes = [], set(), []
    for name, m in runs.items():
        data, pr = Path(m["data"]).name, m["per_reason"]
        if data not in seen:
            seen.add(data)
            rows.append(f"| expert ({data}) | {_cells(pr, 'expert_speed_3s')} |")
            counts = ", ".join(f"{r} {pr[r]['moving']['frames']} / {standing(pr[r])['frames']}"
                               for r in REASONS)
            notes.append(f"{data}: frames (moving / standing) {counts}.")
        rows.append(f"| {name} ({data}) | {_cells(pr, 'model_speed_3s')} |")
    return "\n".join(head + rows) + "\n\n" + "\n".join(notes) + "\n"


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
