"""Build Chat-V2XBench from a collected data set: our JSONL schema, LLaVA JSONL and statistics.

``build(root)`` reads every shard's ``keyframes.jsonl`` (in manifest order), generates the QA
items (:mod:`.generate`) and writes, atomically:

- ``<root>/chat/qa.jsonl``: one QA item per line (our schema, :mod:`.generate`), with the
  keyframe's hint-free ``context`` (:func:`runtime_contexts`: the ego's speed, its navigation
  command and the active roadside unit's pose relative to the ego, the text
  ``agents/aurora/prompt.py`` builds at run time from the recorded frame), the ground-truth
  ``hints`` annotation (objects, exact camera pose; what auto-labelled the answers) and the
  episode's ``split`` (from the manifest);
- ``<root>/chat/llava.jsonl``: one conversation per keyframe in the LLaVA format
  (``{"id", "image": [7 paths], "conversations": [{"from": "human", "value"}, {"from": "gpt",
  "value"}, ...], "hints"}``); the first human turn carries one ``<image>`` token per camera (6
  ego cameras then the roadside camera, labelled), the hint-free context and the first
  question; ``hints`` is the keyframe's annotation, outside the conversation. With
  ``hints_in_prompt=True`` (``qa build --with-hints``) the first turn carries the hints instead
  of the context, the paper's auto-labelling prompt: for labelling, not for training a model
  that drives. Image paths are relative to ``root`` (use it as LLaVA's ``image_folder``);
- ``<root>/chat/stats.json``: :func:`stats`.

Files written before the hint-free export (no ``hints`` field; their ``context`` holds the
ground-truth hints) still load with :func:`load_items`; :func:`is_hint_free` tells them apart.

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
#: optional fields (absent from files written before the hint-free export) and their types
OPTIONAL_FIELDS = {"hints": str, "split": str}
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


def llava_record(items: list[dict], hints_in_prompt: bool = False) -> dict:
    """One keyframe's QA items as a LLaVA multi-turn conversation (module docstring): the first
    turn carries the hint-free ``context``, or the ``hints`` with ``hints_in_prompt``."""
    first = items[0]
    tokens = "\n".join(f"{CAMERA_LABELS[c]}: <image>" for c in CAMERA_ORDER[: len(first["images"])])
    ctx = first["hints"] if hints_in_prompt else first["context"]
    conv = []
    for k, it in enumerate(items):
        q = f"{tokens}\n{ctx}\n{it['question']}" if k == 0 else it["question"]
        conv += [{"from": "human", "value": q}, {"from": "gpt", "value": it["answer"]}]
    rec = {"id": first["keyframe"], "image": first["images"], "conversations": conv}
    if "hints" in first:
        rec["hints"] = first["hints"]
    return rec


def runtime_contexts(root: str | Path, keyframes: list[tuple[str, dict]]) -> list[str]:
    """The hint-free context of every ``(where, facts)`` keyframe: ``agents.aurora.prompt.
    context_from_record`` of the shard's recorded frame at the keyframe's tick (it reads only
    the speed, the navigation command and the calibration, ``prompt.RUNTIME_KEYS``).

    Raises:
        ValueError: a keyframe whose episode has no shard or whose tick is not recorded (named).
    """
    from v2xbench.agents.aurora.prompt import RUNTIME_KEYS, context_from_record

    from ..dataset.shards import load_shard

    root = Path(root)
    shards: dict[str, object] = {}
    out = []
    for where, facts in keyframes:
        ep, tick = facts.get("episode"), facts.get("tick")
        if ep not in shards:
            try:
                shards[ep] = load_shard(root, ep).select(*RUNTIME_KEYS)
            except (ValueError, FileNotFoundError, TypeError) as e:
                raise ValueError(f"{where}: episode {ep!r}: no readable shard ({e})") from None
        td = shards[ep]
        if isinstance(tick, bool) or not isinstance(tick, int) or not 0 <= tick < td.batch_size[0]:
            raise ValueError(f"{where}: tick {tick!r} is not a recorded frame of {ep!r} "
                             f"({td.batch_size[0]} frames)")
        out.append(context_from_record(td[tick]))
    return out


def is_hint_free(items: list[dict]) -> bool:
    """Whether ``items`` come from the hint-free export (every item has ``hints``, so its
    ``context`` is the run-time context); older files put the hints in ``context``."""
    return bool(items) and all("hints" in it for it in items)


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


def build(root: str | Path, seed: int = 0, out: str | Path | None = None,
          hints_in_prompt: bool = False) -> dict:
    """Generate and write Chat-V2XBench for the data set at ``root`` (module docstring);
    ``hints_in_prompt``: the LLaVA prompts carry the ground-truth hints (labelling form).

    Returns:
        ``{"qa": path, "llava": path, "stats": stats dict}``.
    """
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise ValueError(f"qa build: seed={seed!r} must be an int in [0, 2**63)")
    root = Path(root)
    out = Path(out) if out is not None else root / "chat"
    if out.exists() and not out.is_dir():
        raise ValueError(f"qa build: output {out} is a file, not a folder")
    lines = list(keyframe_lines(root))
    per_kf = [_keyframe_qa(where, f, seed) for where, f in lines]
    splits = {sid: sh.get("split") for sid, sh in load_manifest(root).get("shards", {}).items()}
    for (_, facts), ctx, kf in zip(lines, runtime_contexts(root, lines), per_kf):
        for it in kf:
            it.update(context=ctx, split=str(splits.get(facts["episode"])))
    items = [it for kf in per_kf for it in kf]
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_tmp(out, older_than_s=STALE_TMP_S)
    _write_lines(out / "qa.jsonl", items)
    _write_lines(out / "llava.jsonl", (llava_record(kf, hints_in_prompt) for kf in per_kf if kf))
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
    for name, kind in OPTIONAL_FIELDS.items():
        if name in it and not isinstance(it[name], kind):
            raise ValueError(f"{where}: field {name!r} must be a {kind.__name__}, "
                             f"got {it[name]!r}")
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


def split_items(items: list[dict], split: str, where: str = "qa") -> list[dict]:
    """The items whose episode is in ``split`` (their ``split`` field; ``"all"``: every item).

    Raises:
        ValueError: an item without a ``split`` field (a file written before the hint-free
            export: build it again), or no item in the split (the splits present named).
    """
    if split == "all":
        return list(items)
    if any("split" not in it for it in items):
        raise ValueError(f"{where}: the QA items have no 'split' field (built before the "
                         "hint-free export); build them again with `v2xbench qa build DATA`")
    out = [it for it in items if it["split"] == split]
    if not out:
        have = sorted({it["split"] for it in items})
        raise ValueError(f"{where}: no QA item of split {split!r}; the items have splits "
                         f"{have} (or use 'all')")
    return out


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


__all__ = ["ITEM_FIELDS", "KINDS", "OPTIONAL_FIELDS", "build", "check_item", "is_hint_free",
           "iter_keyframes", "keyframe_lines", "llava_record", "load_items", "runtime_contexts",
           "split_items", "stats", "stats_text"]
