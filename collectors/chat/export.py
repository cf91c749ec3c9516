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

Inputs are checked and every error names its file and line: a keyframe line that is not a
JSON object or whose image paths leave its shard's ``images`` folder, a QA item without the
fields of our schema (:data:`ITEM_FIELDS`) or with a duplicated id.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

from v2xbench.files import atomic_write, atomic_write_json, remove_stale_tmp

from ..dataset.shards import load_manifest, shards_dir
from .generate import CAMERA_ORDER, LEVELS, keyframe_qa
from .scoring import CLOSED_SLOT

#: fields of a QA item (our schema) and their JSON types; ``label`` is any JSON value
ITEM_FIELDS = {"id": str, "keyframe": str, "episode": str, "route_id": str, "town": str,
               "scenarios": list, "tick": int, "level": str, "type": str, "kind": str,
               "question": str, "answer": str, "context": str, "images": list}
KINDS = ("closed", "coordinate", "descriptive")
STALE_TMP_S = 600.0  # a temporary export file untouched this long was left by a killed build

CAMERA_LABELS = {"cam_front": "FRONT", "cam_front_right": "FRONT_RIGHT", "cam_back_right": "BACK_RIGHT",
                 "cam_back": "BACK", "cam_back_left": "BACK_LEFT", "cam_front_left": "FRONT_LEFT",
                 "rsu_cam": "ROADSIDE"}


def _plain_image(p, sid: str) -> bool:
    prefix = f"shards/{sid}/images/"
    return (isinstance(p, str) and p.startswith(prefix) and "\\" not in p
            and all(q not in ("", ".", "..") for q in p[len(prefix):].split("/")))


def _jsonl(path: Path) -> Iterator[tuple[str, object]]:
    """``("<path>:<line>", parsed JSON)`` of every non-blank line; bad JSON raises naming both."""
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            if line.strip():
                try:
                    yield f"{path}:{n}", json.loads(line)
                except ValueError as e:
                    raise ValueError(f"{path}:{n}: not valid JSON: {e}") from None


def keyframe_lines(root: str | Path) -> Iterator[tuple[str, dict]]:
    """``("<file>:<line>", facts)`` of every keyframe of every manifest shard, in order.

    Raises:
        FileNotFoundError: a shard's ``keyframes.jsonl`` is missing. ValueError: a line is not
            a JSON object, or an image path leaves its shard's ``images`` folder (named).
    """
    root = Path(root)
    man = load_manifest(root)
    for sid in sorted(man.get("shards", {})):
        path = shards_dir(root) / sid / "keyframes.jsonl"
        if not path.is_file():
            raise FileNotFoundError(f"shard {sid}: {path} is missing (v2xbench data validate)")
        for where, facts in _jsonl(path):
            if not isinstance(facts, dict):
                raise ValueError(f"{where}: a keyframe must be a JSON object")
            images = facts.get("images", {})
            if not isinstance(images, dict):
                raise ValueError(f"{where}: images must be a JSON object {{camera: path}}")
            for cam, p in images.items():
                if not _plain_image(p, sid):
                    raise ValueError(f"{where}: image {cam!r} path {p!r} is not a file under "
                                     f"shards/{sid}/images/ (refused)")
            yield where, facts


def iter_keyframes(root: str | Path) -> Iterator[dict]:
    """Keyframe facts of every shard listed in the manifest, in order (:func:`keyframe_lines`)."""
    for _, facts in keyframe_lines(root):
        yield facts


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
    n = 0
    with atomic_write(path) as f:
        for r in rows:
            f.write(json.dumps(r, sort_keys=True) + "\n")
            n += 1
    return n


def _keyframe_qa(where: str, facts: dict, seed: int) -> list[dict]:
    try:
        return keyframe_qa(facts, seed)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        raise ValueError(f"{where}: keyframe facts are malformed "
                         f"({type(e).__name__}: {e})") from None


def build(root: str | Path, seed: int = 0, out: str | Path | None = None) -> dict:
    """Generate and write Chat-V2XBench for the data set at ``root`` (module docstring).

    Returns:
        ``{"qa": path, "llava": path, "stats": stats dict}``.
    """
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise ValueError(f"qa build: seed={seed!r} must be an int in [0, 2**63)")
    root = Path(root)
    out = Path(out) if out is not None else root / "chat"
    if out.exists() and not out.is_dir():
        raise ValueError(f"qa build: output {out} is a file, not a folder")
    per_kf = [_keyframe_qa(where, f, seed) for where, f in keyframe_lines(root)]
    items = [it for kf in per_kf for it in kf]
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_tmp(out, older_than_s=STALE_TMP_S)
    _write_lines(out / "qa.jsonl", items)
    _write_lines(out / "llava.jsonl", (llava_record(kf) for kf in per_kf if kf))
    st = stats(items)
    atomic_write_json(out / "stats.json", st, indent=1, sort_keys=True)
    return {"qa": str(out / "qa.jsonl"), "llava": str(out / "llava.jsonl"), "stats": st}


def check_item(it, where: str) -> dict:
    """``it`` when it is a QA item of our schema (:data:`ITEM_FIELDS`, a known ``kind``, a
    closed type the scorer knows, a 3-number coordinate label, plain image paths).

    Raises:
        ValueError: naming ``where`` and the field.
    """
    if not isinstance(it, dict):
        raise ValueError(f"{where}: a QA item must be a JSON object")
    for name, kind in ITEM_FIELDS.items():
        v = it.get(name)
        if not isinstance(v, kind) or (kind is int and isinstance(v, bool)):
            raise ValueError(f"{where}: field {name!r} must be a {kind.__name__}, got {v!r}")
    if "label" not in it:
        raise ValueError(f"{where}: field 'label' is missing")
    if it["kind"] not in KINDS:
        raise ValueError(f"{where}: kind {it['kind']!r} is not one of {KINDS}")
    if it["kind"] == "closed" and it["type"] not in CLOSED_SLOT:
        raise ValueError(f"{where}: closed type {it['type']!r} is not one of {sorted(CLOSED_SLOT)}")
    lab = it["label"]
    if it["kind"] == "coordinate" and not (
            isinstance(lab, list) and len(lab) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in lab)):
        raise ValueError(f"{where}: a coordinate label must be 3 numbers, got {lab!r}")
    if not all(isinstance(p, str) and not p.startswith("/") and ".." not in p.split("/")
               for p in it["images"]):
        raise ValueError(f"{where}: images {it['images']!r} must be relative paths in the data set")
    return it


def load_items(path: str | Path) -> list[dict]:
    """QA items from a ``qa.jsonl`` file or from a data set root (its ``chat/qa.jsonl``),
    each checked (:func:`check_item`; ids unique).

    Raises:
        FileNotFoundError: no such file. ValueError: naming the file, line and field.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "chat" / "qa.jsonl"
    if not p.is_file():
        raise FileNotFoundError(f"{p} not found (run `v2xbench qa build DATA` first)")
    items, seen = [], {}
    for where, it in _jsonl(p):
        check_item(it, where)
        if it["id"] in seen:
            raise ValueError(f"{where}: id {it['id']!r} repeats {seen[it['id']]}")
        seen[it["id"]] = where
        items.append(it)
    return items


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


__all__ = ["ITEM_FIELDS", "KINDS", "build", "check_item", "iter_keyframes", "keyframe_lines",
           "llava_record", "load_items", "stats", "stats_text"]
