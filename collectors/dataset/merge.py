"""One data set from several: ``v2xbench data merge A B --out C`` (DAgger's aggregation).

A learned driver's collection (``collect --driver``, :mod:`.driver`) is trained on together with
the expert's. The merged data set is an ordinary one (every loader, ``qa build`` and training
command reads it as it is): its shards are the sources' shards, hard-linked file by file (no bytes
copied where the file system allows; copied where it does not), its manifest lists them all and
records every source's manifest under ``merged_from``.

The sources must have the same record schema (sensors, camera size, LiDAR scale, boxes, payload
size: the message names what differs) and no shard name in common (collect the driven set with
``--first-seed K`` so its episodes are ``<route>_sK...``, other seeds of the same routes). The
merge is written into a temporary folder and renamed into place, so ``OUT`` is whole or absent.
``collect`` refuses to resume into a merged data set (it has no single config to resume).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from v2xbench.files import atomic_write_json

from .shards import MANIFEST_FORMAT, dataset_schema, load_manifest, shards_dir


def _link_tree(src: Path, dst: Path) -> None:
    """``dst`` as a copy of ``src`` whose files are hard links (copies across file systems)."""
    for dirpath, _, files in os.walk(src):
        here = dst / Path(dirpath).relative_to(src)
        here.mkdir(parents=True, exist_ok=True)
        for name in files:
            a, b = Path(dirpath) / name, here / name
            try:
                os.link(a, b)
            except OSError:
                shutil.copy2(a, b)


def _schema_difference(a: dict, b: dict) -> list[str]:
    keys = sorted(set(a) | set(b), key=str)
    return ["/".join(k) if isinstance(k, tuple) else str(k) for k in keys if a.get(k) != b.get(k)]


def merge(sources: list[str | Path], out: str | Path) -> dict:
    """Merge the data sets ``sources`` into a new data set at ``out``; returns its manifest.

    Raises:
        ValueError: fewer than two sources, ``out`` exists, a source is incomplete or differs in
            schema from the first (naming the keys), shard names shared by two sources.
        FileNotFoundError: a source without a manifest.
    """
    roots = [Path(s) for s in sources]
    out = Path(out)
    if len(roots) < 2:
        raise ValueError("data merge: give at least two data sets")
    if out.exists():
        raise ValueError(f"data merge: {out} exists; give a new --out")
    mans = [load_manifest(r) for r in roots]
    schema = dataset_schema(roots[0], mans[0])
    owner: dict[str, Path] = {}
    for root, man in zip(roots, mans):
        if not man.get("complete"):
            raise ValueError(f"data merge: {root} is not complete (run `v2xbench collect` on it "
                             "again to finish it)")
        diff = _schema_difference(schema, dataset_schema(root, man))
        if diff:
            raise ValueError(f"data merge: {root} records other data than {roots[0]} "
                             f"(keys {diff[:6]}); merge data sets of the same --sensors, "
                             "--camera-size, --lidar-scale and --set")
        if man.get("sensor_config") != mans[0].get("sensor_config"):
            raise ValueError(f"data merge: {root} has another sensor_config than {roots[0]}")
        shared = sorted(set(man["shards"]) & set(owner))
        if shared:
            raise ValueError(f"data merge: shards {shared[:5]} are in both {owner[shared[0]]} and "
                             f"{root}; collect one of them with --first-seed K (other seeds)")
        owner.update({sid: root for sid in man["shards"]})
    tmp = out.with_name(out.name + ".merging")
    shutil.rmtree(tmp, ignore_errors=True)
    for sid, root in owner.items():
        _link_tree(shards_dir(root) / sid, shards_dir(tmp) / sid)
    manifest = {
        "format": MANIFEST_FORMAT, "config": mans[0]["config"],
        "sensor_config": mans[0].get("sensor_config"),
        "episodes": [e for man in mans for e in man["episodes"]],
        "shards": {sid: s for man in mans for sid, s in man["shards"].items()},
        "failed": {}, "complete": True,
        "merged_from": [{"root": str(r.resolve()), **{k: m.get(k) for k in ("config", "driver")}}
                        for r, m in zip(roots, mans)],
    }
    atomic_write_json(tmp / "manifest.json", manifest, indent=1, sort_keys=True)
    tmp.rename(out)
    return manifest


__all__ = ["merge"]
