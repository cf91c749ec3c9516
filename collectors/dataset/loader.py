"""Loading a collected data set: a torch ``Dataset`` of frames and a TorchRL ``ReplayBuffer`` view.

Both read the shards' memmaps in place (nothing is copied into memory up front). Shards are
opened with :func:`.shards.open_shard`: each file is checked against ``shard.json`` and the record
schema of the data set's settings before it is mapped, nothing is unpickled, and the mapping is
copy-on-write, so an in-place op on a frame or on :meth:`V2XDataset.shard` never changes the
files (a data set from someone else is safe to load; ``v2xbench data validate`` also checks the
CRCs). A frame is a
``TensorDict`` with batch size ``[]`` and the keys of :mod:`.record` (``keys`` selects a subset,
e.g. ``["ego_speed", "expert_waypoints", ("cameras", "cam_front", "rgb")]``), plus ``episode``
(int64 index into :attr:`V2XDataset.episodes`) and, with ``unpack_bev=True``, ``bev`` (14, S, S).

Splits are by route (never by frame): every shard has the split of its route
(``collect.route_split``: routes of a ``val`` suite are ``val``; train-suite routes are held out
by a hash of their id), so no route contributes frames to both.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from .record import unpack_bev
from .shards import dataset_schema, load_manifest, load_shard_meta, open_shard, shards_dir

SPLITS = ("train", "val", "test", "all")


class V2XDataset(Dataset):
    """Frames of a data set's shards of one split.

    Args:
        root: data set folder (``v2xbench collect --out``).
        split: ``train``, ``val``, ``test`` or ``all``.
        keys: keys to load (nested keys as tuples); ``None``: all.
        unpack_bev: also return ``bev`` unpacked from ``bev_bits``.

    Raises:
        FileNotFoundError: no manifest at ``root``, or a listed shard is missing.
        ValueError: unknown split, no shard in it, a malformed manifest or ``shard.json``
            (named); ``ShardDataError`` (a ValueError) when a shard's data is opened and does
            not match its metadata and the schema.
    """

    def __init__(self, root: str | Path, split: str = "train", keys: Sequence | None = None,
                 unpack_bev: bool = False) -> None:
        if split not in SPLITS:
            raise ValueError(f"V2XDataset: split={split!r} must be one of {SPLITS}")
        self.root = Path(root)
        man = load_manifest(self.root)
        self.schema = dataset_schema(self.root, man)
        self.episodes: list[str] = []
        self.meta: list[dict] = []
        for sid in sorted(man.get("shards", {})):
            folder = shards_dir(self.root) / sid
            if not folder.is_dir() or folder.is_symlink():
                raise FileNotFoundError(f"V2XDataset: shard {sid} of {root} is missing "
                                        "(v2xbench data validate)")
            meta = load_shard_meta(folder)
            if split == "all" or meta["split"] == split:
                self.episodes.append(sid)
                self.meta.append(meta)
        if not self.episodes:
            raise ValueError(f"V2XDataset: no shard of split {split!r} in {root}")
        lengths = np.array([m["frames"] for m in self.meta], np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(lengths)])
        self.keys = [tuple(k) if isinstance(k, (list, tuple)) else k for k in keys] if keys else None
        self.unpack_bev = unpack_bev
        self._tds: dict[int, object] = {}

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_tds"] = {}  # DataLoader workers re-open the mappings instead of copying them
        return state

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def locate(self, index: int) -> tuple[int, int]:
        """``(episode index, frame index in its shard)`` of a global frame index."""
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"V2XDataset: index {index} out of range for {n} frames")
        index %= n
        e = int(np.searchsorted(self.offsets, index, side="right") - 1)
        return e, int(index - self.offsets[e])

    def shard(self, e: int):
        """The memmap TensorDict of episode ``e`` (opened and checked lazily, once per process;
        copy-on-write: in-place ops on it stay in this process)."""
        if e not in self._tds:
            td = open_shard(shards_dir(self.root) / self.episodes[e], self.schema, self.meta[e])
            self._tds[e] = td.select(*self.keys, strict=True) if self.keys else td
        return self._tds[e]

    def columns(self, key: str | tuple) -> list[np.ndarray]:
        """``key`` of every episode as one NumPy array each (episode order, frames on axis 0):
        a per-frame column read without building frames. ``KeyError`` if the shards lack it."""
        return [np.asarray(self.shard(e)[key]) for e in range(len(self.episodes))]

    def __getitem__(self, index: int):
        e, t = self.locate(int(index))
        td = self.shard(e)[t].clone()
        td["episode"] = torch.tensor(e, dtype=torch.int64)
        if self.unpack_bev and "bev_bits" in td.keys():
            td["bev"] = torch.from_numpy(unpack_bev(td["bev_bits"].numpy()))
        return td

    def collate(self, indices: Sequence[int]):
        """Stack the frames at ``indices`` into a TensorDict of batch size ``[len(indices)]``."""
        return torch.stack([self[int(i)] for i in indices])


def replay_buffer(root: str | Path, split: str = "train", batch_size: int = 32,
                  keys: Sequence | None = None):
    """A TorchRL ``ReplayBuffer`` sampling frames of a split (a view over the shards).

    Its storage holds frame indices (``ListStorage``); ``collate_fn`` reads the sampled frames
    from the memmaps, so ``rb.sample()`` returns a TensorDict of batch size ``[batch_size]``
    (sampling draws from torch's global generator: ``torch.manual_seed`` makes it reproducible).
    """
    from torchrl.data import ListStorage, ReplayBuffer
    from torchrl.data.replay_buffers.samplers import RandomSampler

    ds = V2XDataset(root, split, keys)
    rb = ReplayBuffer(storage=ListStorage(max_size=len(ds)), sampler=RandomSampler(),
                      collate_fn=ds.collate, batch_size=batch_size)
    rb.extend(list(range(len(ds))))
    return rb


__all__ = ["SPLITS", "V2XDataset", "replay_buffer"]
