"""Build Chat-V2XBench from a collected data set: our JSONL schema, LLaVA JSONL and statistics.

``build(root)`` reads every shard's ``keyframes.jsonl`` (in manifest order), generates the QA
items (:mod:`.generate`) and writes, atomically:

- ``<root>/chat/qa.jsonl``: one QA item per line (our schema, :mod:`.generate`);
- ``<root>/chat/llava.jsonl``: one conversation per keyframe in the LLaVA format
  (``{"id", "image": [7 paths], "conversations": [{"from": "human", "value"}, {"from": "gpt",
  "value"}, ...]}``); the first human turn carries one ``<image>`` token per camera (6 ego
  cameras then the roadside camera, labelled), the context and the first question. Image paths
  are relative to ``root`` (use it as LLaVA's ``image_folder``);
- ``<root>/chat/stats.json``: :func:`stats`.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from pathlib import Path

from ..dataset.shards import load_manifest, shards_dir
from .generate import CAMERA_ORDER, LEVELS, keyframe_qa

CAMERA_LABELS = {"cam_front": "FRONT", "cam_front_right": "FRONT_RIGHT", "cam_back_right": "BACK_RIGHT",
                 "cam_back": "BACK", "cam_back_left": "BACK_LEFT", "cam_front_left": "FRONT_LEFT",
                 "rsu_cam": "ROADSIDE"}


def iter_keyframes(root: str | Path):
    """Keyframe facts of every shard listed in the manifest, in order."""
    root = Path(root)
    man = load_manifest(root)
    for sid in sorted(man.get("shards", {})):
        path = shards_dir(root) / sid / "keyframes.jsonl"
        if not path.exists():
            raise FileNotFoundError(f"shard {sid}: {path} is missing (v2xbench data validate)")
        with open(path) as f:
            for line in f:
                if line.strip():
                    yield json.loads(line)


def llava_record(items: list[dict]) -> dict:
    """One keyframe's QA items as a LLaVA multi-turn conversation."""
    first = items[0]
    tokens = "\n".join(f"{CAMERA_LABELS[c]}: <image>" for c in CAMERA_ORDER[: len(first["images"])])
    conv = []
    for k, it in enumerate(items):
        q = f"{tokens}\n{it['context']}\n{it['question']}" if k == 0 else it["question"]
        conv += [{"from": "human", "value": q}, {"from": "gpt", "value": it["answer"]}]
    return {"id": first["keyframe"], "image": first["images"], "conversations": conv}


def _write_lines(path: Path, rows) -> int:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    n = 0
    with open(tmp, "w") as f:
        for r in rows:
            f.write(json.dumps(r, sort_keys=True) + "\n")
            n += 1
    os.replace(tmp, path)
    return n


def build(root: str | Path, seed: int = 0, out: str | Path | None = None) -> dict:
    """Generate and write Chat-V2XBench for the data set at ``root`` (module docstring).

    Returns:
        ``{"qa": path, "llava": path, "stats": stats dict}``.
    """
    root = Path(root)
    out = Path(out) if out is not None else root / "chat"
    out.mkdir(parents=True, exist_ok=True)
    per_kf = [keyframe_qa(f, seed) for f in iter_keyframes(root)]
    items = [it for kf in per_kf for it in kf]
    _write_lines(out / "qa.jsonl", items)
    _write_lines(out / "llava.jsonl", (llava_record(kf) for kf in per_kf if kf))
    st = stats(items)
    tmp = out / f".stats.json.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(st, indent=1, sort_keys=True))
    os.replace(tmp, out / "stats.json")
    return {"qa": str(out / "qa.jsonl"), "llava": str(out / "llava.jsonl"), "stats": st}


def load_items(path: str | Path) -> list[dict]:
    """QA items from a ``qa.jsonl`` file or from a data set root (its ``chat/qa.jsonl``)."""
    p = Path(path)
    if p.is_dir():
        p = p / "chat" / "qa.jsonl"
    if not p.exists():
        raise FileNotFoundError(f"{p} not found (run `v2xbench qa build DATA` first)")
    with open(p) as f:
        return [json.loads(line) for line in f if line.strip()]


def stats(items: list[dict]) -> dict:
    """Counts per level, per question type and per scenario type (a keyframe counts for every
    scenario of its route), plus keyframes and episodes."""
    scen: Counter = Counter()
    for it in items:
        for s in it["scenarios"] or ["(none)"]:
            scen[s] += 1
    return {"qa_pairs": len(items), "keyframes": len({it["keyframe"] for it in items}),
            "episodes": len({it["episode"] for it in items}),
            "per_level": {lv: sum(it["level"] == lv for it in items) for lv in LEVELS},
            "per_type": dict(sorted(Counter(it["type"] for it in items).items())),
            "per_scenario": dict(sorted(scen.items()))}


def stats_text(st: dict) -> str:
    """A printable table of :func:`stats`."""
    lines = [f"QA pairs: {st['qa_pairs']}  keyframes: {st['keyframes']}  episodes: {st['episodes']}", "",
             "per level:"]
    lines += [f"  {k:<22} {v:>7}" for k, v in st["per_level"].items()]
    lines += ["", "per question type:"] + [f"  {k:<22} {v:>7}" for k, v in st["per_type"].items()]
    lines += ["", "per scenario:"] + [f"  {k:<40} {v:>7}" for k, v in st["per_scenario"].items()]
    return "\n".join(lines)


__all__ = ["build", "iter_keyframes", "llava_record", "load_items", "stats", "stats_text"]
