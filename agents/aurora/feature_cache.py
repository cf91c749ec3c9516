"""Frozen perception branches' outputs, computed once and kept on disk (memmap).

While the perception branches are frozen (stages 4 and 5; stage 3 where the scale freezes them)
their outputs are a function of the frame alone, so running them every epoch repeats the same
work. :func:`ensure_cache` runs them once per frame (eval mode, no gradient) and stores, per
frame, the ego branch's :data:`~.system.EGO_FEATURES` (last decoder layer) and the roadside
message's :data:`~.system.MSG_FEATURES` (rounded to the wire's float16, zeros for frames without
a unit) as ``.npy`` memmaps; :class:`AuroraPairs <.pairs.AuroraPairs>` then reads rows
(``feat/*``, ``msg/*``) instead of images.

Layout: ``RUN/cache/<digest>/`` where ``digest`` hashes the branches' weights and the
configuration (other weights: another folder), with ``meta.json`` (parts, shapes, build
seconds) and one folder per part (``part-000/``: ``frames.npy`` and one ``<stream>.<key>.npy``
per tensor). A later stage that needs frames the cache lacks adds a part for them only.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from v2xbench.files import atomic_write_json
from v2xbench.locks import dir_lock

from .config import AuroraConfig
from .cqaf import rsu_message
from .data import CALIB_KEYS, AuroraFrames
from .rsu_agent import to_wire
from .system import EGO_FEATURES, MSG_FEATURES, AuroraSystem, ego_features, message_features

FORMAT = "v2xbench-aurora-feature-cache/1"
META = "meta.json"
INPUT_KEYS = ("images", "intrinsics", "cam_to_frame")


def weights_digest(system: AuroraSystem) -> str:
    """SHA-256 (hex, 16 characters) of the branches' weights and buffers and the config."""
    conf = system.cfg.to_dict()
    # the planner's output and its prompt do not change the branches' outputs: a run that
    # differs only in them shares the cache (caches from before plan_speed_dropout was ignored
    # are rebuilt once)
    for key in ("plan_frame", "plan_route_step", "plan_speed_dropout"):
        conf.pop(key)
    h = hashlib.sha256(json.dumps(conf, sort_keys=True).encode())
    for name, t in sorted({**system.ego.state_dict(prefix="ego."),
                           **system.rsu.state_dict(prefix="rsu.")}.items()):
        h.update(name.encode())
        h.update(t.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()[:16]


class _Inputs(Dataset):
    """The branches' camera inputs of a list of frames (roadside zeros without a unit)."""

    def __init__(self, ego: AuroraFrames, rsu: AuroraFrames | None, frames: Sequence[int]):
        self.ego, self.rsu, self.frames = ego, rsu, list(frames)

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        fid = self.frames[i]
        td = self.ego.ds[fid]
        calib = {k: td["calib", k].numpy() for k in CALIB_KEYS}
        s = self.ego.sample(td, calib, fid)
        out = {f"ego/{k}": s[k] for k in INPUT_KEYS}
        has = self.rsu is not None and int(calib["rsu_unit"]) >= 0
        if has:
            r = self.rsu.sample(self.rsu.ds[fid], calib, fid)
            out.update({f"rsu/{k}": r[k] for k in INPUT_KEYS})
        else:
            w, h = self.ego.cfg.image_size("rsu")
            out.update({"rsu/images": torch.zeros(1, 3, h, w),
                        "rsu/intrinsics": torch.eye(3)[None],
                        "rsu/cam_to_frame": torch.eye(4)[None]})
        out["has_rsu"] = torch.tensor(has)
        return out


def _shapes(cfg: AuroraConfig) -> dict[str, tuple[int, ...]]:
    q, qm, d, p = cfg.num_det_queries, cfg.num_map_queries, cfg.dec_width, cfg.map_points
    k, km, w = min(cfg.cqaf_det_topk, q), min(cfg.cqaf_map_topk, qm), cfg.lm_width
    ego = {"q_det": (q, d), "det_ref": (q, 3), "det_logits": (q, cfg.num_classes),
           "q_map": (qm, d), "map_points": (qm, p, 2), "t_det": (q, w), "t_map": (qm, w)}
    msg = {"det_queries": (k, d), "det_ref": (k, 3), "det_scores": (k,),
           "map_queries": (km, d), "map_points": (km, p, 2), "map_scores": (km,)}
    return {**{f"feat/{n}": ego[n] for n in EGO_FEATURES},
            **{f"msg/{n}": msg[n] for n in MSG_FEATURES}}


class FeatureCache:
    """A built cache folder (module docstring): ``row(frame_id)`` gives a frame's tensors."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        meta_path = self.folder / META
        if not meta_path.is_file():
            raise FileNotFoundError(f"FeatureCache: {meta_path} does not exist")
        self.meta = json.loads(meta_path.read_text())
        if self.meta.get("format") != FORMAT:
            raise ValueError(f"FeatureCache: {meta_path} has format {self.meta.get('format')!r}"
                             f"; expected {FORMAT!r}")
        self.shapes = {k: tuple(v) for k, v in self.meta["shapes"].items()}
        self._where: dict[int, tuple[int, int]] = {}
        self._parts: list[dict[str, np.ndarray] | None] = []
        for j, part in enumerate(self.meta["parts"]):
            frames = np.load(self.folder / part["dir"] / "frames.npy")
            self._where.update({int(f): (j, i) for i, f in enumerate(frames)})
            self._parts.append(None)  # opened lazily (once per process)

    @property
    def frames(self) -> list[int]:
        """Every cached frame id."""
        return list(self._where)

    def _part(self, j: int) -> dict[str, np.ndarray]:
        if self._parts[j] is None:
            d = self.folder / self.meta["parts"][j]["dir"]
            self._parts[j] = {k: np.load(d / f"{k.replace('/', '.')}.npy", mmap_mode="r")
                              for k in self.shapes}
        return self._parts[j]

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_parts"] = [None] * len(self._parts)  # workers map the files themselves
        return state

    def row(self, frame_id: int) -> dict[str, torch.Tensor]:
        """``feat/*`` and ``msg/*`` tensors of one frame (``KeyError`` if not cached)."""
        j, i = self._where[int(frame_id)]
        part = self._part(j)
        return {k: torch.from_numpy(np.array(part[k][i])) for k in self.shapes}


@torch.no_grad()
def _build_part(system: AuroraSystem, inputs: _Inputs, out_dir: Path, batch_size: int,
                num_workers: int, device: str, progress: bool) -> float:
    """Run the branches over ``inputs`` and write one part into ``out_dir``; seconds taken."""
    from .data import collate

    cfg = system.cfg
    shapes = _shapes(cfg)
    n = len(inputs)
    tmp = out_dir.with_name(out_dir.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    arrays = {k: np.lib.format.open_memmap(tmp / f"{k.replace('/', '.')}.npy", mode="w+",
                                           dtype=np.float32, shape=(n, *s))
              for k, s in shapes.items()}
    loader = DataLoader(inputs, batch_size=batch_size, shuffle=False, collate_fn=collate,
                        num_workers=num_workers)
    ego, rsu = system.ego.eval().to(device), system.rsu.eval().to(device)
    t0 = time.perf_counter()
    i = 0
    for batch in tqdm(loader, disable=not progress, desc="feature cache", dynamic_ncols=True):
        batch = {k: v.to(device) for k, v in batch.items()}
        b = batch["has_rsu"].shape[0]
        feat = ego_features(ego({k[4:]: batch[k] for k in batch if k.startswith("ego/")}))
        for k, v in feat.items():
            arrays[f"feat/{k}"][i:i + b] = v.float().cpu().numpy()
        rows = batch["has_rsu"].nonzero()[:, 0]
        for k in MSG_FEATURES:
            arrays[f"msg/{k}"][i:i + b] = 0.0
        if len(rows):
            rin = {k[4:]: batch[k][rows] for k in batch if k.startswith("rsu/")}
            eye = torch.eye(4, device=device).expand(len(rows), 4, 4)
            msg = message_features(to_wire(rsu_message(rsu(rin), cfg, eye)))
            idx = (i + rows).cpu().numpy()
            for k, v in msg.items():
                arrays[f"msg/{k}"][idx] = v.float().cpu().numpy()
        i += b
    for a in arrays.values():
        a.flush()
    np.save(tmp / "frames.npy", np.asarray(inputs.frames, np.int64))
    seconds = time.perf_counter() - t0
    del arrays
    shutil.rmtree(out_dir, ignore_errors=True)
    os.replace(tmp, out_dir)
    return seconds


def ensure_cache(system: AuroraSystem, root: str | Path, split: str, frames: Sequence[int],
                 cache_root: str | Path, *, batch_size: int = 8, num_workers: int = 0,
                 device: str = "cpu", progress: bool = True) -> tuple[FeatureCache, dict]:
    """The cache of ``system``'s branches holding every frame of ``frames`` (built or extended).

    Returns ``(cache, stats)``: ``stats`` has ``digest``, ``frames`` (asked), ``built``
    (frames computed now), ``build_s`` (seconds now), ``ms_per_frame`` (of the branches and
    loading, over every part ever built) and ``folder``.
    """
    cfg = system.cfg
    digest = weights_digest(system)
    folder = Path(cache_root) / digest
    folder.mkdir(parents=True, exist_ok=True)
    with dir_lock(folder, "aurora feature cache"):
        meta_path = folder / META
        meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {
            "format": FORMAT, "digest": digest, "config": cfg.to_dict(), "data": str(root),
            "split": split, "shapes": {k: list(v) for k, v in _shapes(cfg).items()},
            "parts": []}
        have: set[int] = set()
        for part in meta["parts"]:
            have.update(int(f) for f in np.load(folder / part["dir"] / "frames.npy"))
        need = sorted(set(int(f) for f in frames) - have)
        build_s = 0.0
        if need:
            ego = AuroraFrames(root, split, "ego", cfg)
            try:
                rsu: AuroraFrames | None = AuroraFrames(root, split, "rsu", cfg)
            except ValueError:
                rsu = None
            name = f"part-{len(meta['parts']):03d}"
            build_s = _build_part(system, _Inputs(ego, rsu, need), folder / name, batch_size,
                                  num_workers, device, progress)
            meta["parts"].append({"dir": name, "frames": len(need), "build_s": build_s})
            atomic_write_json(meta_path, meta, indent=1)
    total_frames = sum(p["frames"] for p in meta["parts"])
    total_s = sum(p["build_s"] for p in meta["parts"])
    stats = {"digest": digest, "frames": len(set(frames)), "built": len(need),
             "build_s": build_s, "ms_per_frame": 1e3 * total_s / max(total_frames, 1),
             "folder": str(folder)}
    return FeatureCache(folder), stats


__all__ = ["FORMAT", "FeatureCache", "ensure_cache", "weights_digest"]
