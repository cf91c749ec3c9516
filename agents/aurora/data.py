"""AURORA's training and evaluation samples from a collected data set (``v2xbench collect``).

:class:`AuroraFrames` is a torch ``Dataset`` over one split and one branch: it reads the shards'
memmaps in place through :class:`~v2xbench.collectors.dataset.loader.V2XDataset` (only the keys
the branch needs) and turns each frame into the batch sample of the perception branches
(``/work/notes/aurora_contract.md``, shapes without the leading ``B``):

==================  =====================  ==================================================
key                 shape, dtype           content
==================  =====================  ==================================================
``images``          (N, 3, H, W) float32   RGB in [0, 1]; N = 6 ego cameras or 1 roadside
``intrinsics``      (N, 3, 3) float32      pixel intrinsics at ``cfg.image_size(branch)``
``cam_to_frame``    (N, 4, 4) float32      camera optical frame -> branch frame (:mod:`.calib`)
``det_boxes``       (M, 10) float32        x, y, z, l, w, h, sin yaw, cos yaw, vx, vy
``det_labels``      (M,) int64             class ids; ``det_mask`` (M,) bool valid rows
``map_points``      (K, P, 2) float32      polylines in the branch frame (``town.map_vectors``)
``map_labels``      (K,) int64             0 divider, 1 boundary, 2 crosswalk; ``map_mask``,
                                           ``map_closed`` (K,) bool
``light``           () int64               ego only: ``light_state + 1`` (0 none .. 4 stop sign)
``frame_id``        () int64               global frame index in the split's ``V2XDataset``
==================  =====================  ==================================================

Targets: ``gt/ego`` for the ego branch, ``gt/rsu`` in the roadside unit's ground frame for the
roadside branch (frames without an active unit are skipped), both cut to the branch's
perception range (box centre inside ``cfg.pc_range``); ``M`` is the data set's box rows,
``K = cfg.num_map_queries`` (the nearest elements when a frame has more). Images are resized
(bilinear) when the recorded size differs from ``cfg.image_size(branch)``, with the intrinsics
scaled to match.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader, Dataset
from v2xbench.collectors.dataset.loader import V2XDataset
from v2xbench.envs.v2x_intersection.core.geometry import invert_transform
from v2xbench.envs.v2x_intersection.town import get_town
from v2xbench.envs.v2x_intersection.town.map_vectors import map_vectors

from .calib import CAMERA_NAMES, ego_frame_pose, frame_camera_tensors, world_frame_pose
from .calib import boxes_to_frame as _boxes_to_frame
from .config import AuroraConfig, check_branch

CALIB_KEYS = ("T_world_ego", "T_world_rsu", "T_ego_rsu", "rsu_unit", "cam_intrinsics",
              "T_ego_cam")
GT_SET = {"ego": "ego", "rsu": "rsu"}


def _keys(branch: str, images: bool = True) -> list:
    gt = GT_SET[branch]
    keys: list = [("calib", k) for k in CALIB_KEYS]
    keys += [("gt", gt, k) for k in ("boxes", "class", "mask")]
    if images:
        keys += [("cameras", c, "rgb") for c in CAMERA_NAMES[branch]]
    if branch == "ego":
        keys.append("light_state")
    return keys


def encode_targets(boxes: np.ndarray) -> np.ndarray:
    """``(M, 9)`` ``x, y, z, l, w, h, yaw, vx, vy`` -> ``(M, 10)`` with ``sin, cos`` of yaw."""
    b = np.asarray(boxes, np.float64).reshape(-1, 9)
    return np.c_[b[:, :6], np.sin(b[:, 6]), np.cos(b[:, 6]), b[:, 7:9]].astype(np.float32)


def model_images(rgb: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Camera images ``(N, H, W, 3)`` uint8 -> the model's ``(N, 3, h, w)`` float32 in [0, 1]
    at ``size = (w, h)`` (bilinear with antialiasing when the size differs): the one conversion
    of the data set's frames and of closed-loop observations."""
    images = rgb.permute(0, 3, 1, 2).float().div_(255.0)
    if (int(rgb.shape[2]), int(rgb.shape[1])) != tuple(size):
        w, h = size
        images = F.interpolate(images, size=(h, w), mode="bilinear", align_corners=False,
                               antialias=True).clamp_(0.0, 1.0)
    return images


def in_range(points: np.ndarray, pc_range: Sequence[float]) -> np.ndarray:
    """``(M,)`` bool: points ``(M, 3)`` inside ``(xmin, ymin, zmin, xmax, ymax, zmax)``."""
    p, r = np.asarray(points, np.float64).reshape(-1, 3), np.asarray(pc_range, np.float64)
    return ((p >= r[:3]) & (p <= r[3:])).all(1)


class AuroraFrames(Dataset):
    """Samples of one branch over one split of a data set (module docstring).

    Args:
        root: data set folder (``v2xbench collect --out``).
        split: ``train``, ``val``, ``test`` or ``all``.
        branch: ``"ego"`` or ``"rsu"``.
        cfg: model configuration (image size, range, map points and queries).
        stride: keep frames whose index in their episode is a multiple of ``stride``.
        images: read and return the camera images (``False``: targets and calibration only,
            e.g. when the branch's outputs come from a feature cache).

    Raises:
        FileNotFoundError: ``root`` does not exist or holds no data set.
        ValueError: a shard lacks a key the branch needs (e.g. recorded without cameras; the
            shard and the keys are named), an unknown branch or split, a bad stride, or no
            frame left (e.g. no roadside unit active in any frame of the split).
    """

    def __init__(self, root: str | Path, split: str, branch: str, cfg: AuroraConfig,
                 stride: int = 1, images: bool = True) -> None:
        self.branch, self.cfg = check_branch(branch), cfg
        self.images = bool(images)
        if not isinstance(stride, int) or isinstance(stride, bool) or stride < 1:
            raise ValueError(f"AuroraFrames: stride={stride!r} must be an int >= 1")
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"AuroraFrames: data directory {root} does not exist "
                                    "(collect one with `v2xbench collect --out DIR`)")
        self.ds = V2XDataset(root, split, keys=_keys(branch, self.images))
        self.pc_range = tuple(float(v) for v in cfg.pc_range(branch))
        self.image_size = tuple(cfg.image_size(branch))
        frames = []
        for e, sid in enumerate(self.ds.episodes):
            td = self._open(e, sid)
            t = np.arange(int(self.ds.offsets[e + 1] - self.ds.offsets[e]))
            keep = t % stride == 0
            if branch == "rsu":
                keep &= td["calib", "rsu_unit"].numpy() >= 0
            frames.append(self.ds.offsets[e] + t[keep])
        self.frame_ids = np.concatenate(frames).astype(np.int64)
        if not len(self.frame_ids):
            why = " with an active roadside unit" if branch == "rsu" else ""
            raise ValueError(f"AuroraFrames: no frame{why} in split {split!r} of {root}")

    def _open(self, e: int, sid: str):
        try:
            return self.ds.shard(e)
        except KeyError as err:
            need = ", ".join("/".join(k) if isinstance(k, tuple) else k for k in _keys(self.branch))
            raise ValueError(
                f"AuroraFrames: shard {sid} of {self.ds.root} lacks keys the {self.branch} "
                f"branch needs ({need}): {err}; collect with `--sensors rgb,...`") from None

    def __len__(self) -> int:
        return len(self.frame_ids)

    @property
    def recorded_size(self) -> tuple[int, int]:
        """``(width, height)`` of the branch's recorded camera images (the data set's schema)."""
        key = ("cameras", CAMERA_NAMES[self.branch][0], "rgb")
        if key not in self.ds.schema:
            raise ValueError(f"AuroraFrames: the data set {self.ds.root} has no camera images "
                             f"({'/'.join(key)}); collect with `--sensors rgb,...`")
        h, w = self.ds.schema[key][1][:2]
        return int(w), int(h)

    def town(self, frame_id: int) -> str:
        """Town name of a global frame index."""
        return str(self.ds.meta[self.ds.locate(int(frame_id))[0]]["town"])

    def index_of(self, frame_id: int) -> int:
        """Position in this dataset of a global frame index (``ValueError`` if not kept)."""
        i = int(np.searchsorted(self.frame_ids, frame_id))
        if i >= len(self.frame_ids) or self.frame_ids[i] != frame_id:
            raise ValueError(f"AuroraFrames: frame {frame_id} is not a sample of this dataset")
        return i

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        fid = int(self.frame_ids[index])
        td = self.ds[fid]
        calib = {k: td["calib", k].numpy() for k in CALIB_KEYS}
        return self.sample(td, calib, fid)

    # ------------------------------------------------------------------ one frame
    def sample(self, td, calib: dict, frame_id: int) -> dict[str, torch.Tensor]:
        """The sample of a frame's TensorDict ``td`` (keys of this branch) and its ``calib``."""
        branch, cfg = self.branch, self.cfg
        images = None
        if self.images:
            imgs = torch.stack([td["cameras", c, "rgb"] for c in CAMERA_NAMES[branch]])
            src = (int(imgs.shape[2]), int(imgs.shape[1]))  # (W, H)
            images = model_images(imgs, self.image_size)  # (N, 3, H, W)
        else:  # the recorded images' size, from the data set's schema
            src = self.recorded_size
        k, c2f = frame_camera_tensors(calib, branch, src, self.image_size)
        gt = GT_SET[branch]
        mask = td["gt", gt, "mask"].numpy().astype(bool)
        boxes = td["gt", gt, "boxes"].numpy()
        labels = td["gt", gt, "class"].numpy()
        if branch == "rsu":
            boxes = _boxes_to_frame(boxes, invert_transform(ego_frame_pose(calib, branch)))
        keep = mask & in_range(boxes[:, :3], self.pc_range)
        m = len(mask)
        det_boxes = np.zeros((m, 10), np.float32)
        det_boxes[:, 3:6], det_boxes[:, 7] = 1.0, 1.0  # harmless padding (1 m boxes, yaw 0)
        det_labels = np.zeros(m, np.int64)
        n = int(keep.sum())
        det_boxes[:n] = encode_targets(boxes[keep])
        det_labels[:n] = labels[keep]
        kq, p = cfg.num_map_queries, cfg.map_points
        town = get_town(self.town(frame_id))
        mv = map_vectors(town, world_frame_pose(calib, branch), self.pc_range, p, kq)
        map_points = np.zeros((kq, p, 2), np.float32)
        map_labels = np.zeros(kq, np.int64)
        map_closed = np.zeros(kq, bool)
        map_points[:len(mv)], map_labels[:len(mv)], map_closed[:len(mv)] = (
            mv.points, mv.labels, mv.closed)
        out = {
            "intrinsics": k,
            "cam_to_frame": c2f,
            "det_boxes": torch.from_numpy(det_boxes),
            "det_labels": torch.from_numpy(det_labels),
            "det_mask": torch.arange(m) < n,
            "map_points": torch.from_numpy(map_points),
            "map_labels": torch.from_numpy(map_labels),
            "map_mask": torch.arange(kq) < len(mv),
            "map_closed": torch.from_numpy(map_closed),
            "frame_id": torch.tensor(frame_id, dtype=torch.int64),
        }
        if images is not None:
            out["images"] = images
        if branch == "ego":
            out["light"] = (td["light_state"].to(torch.int64) + 1).reshape(())
        return out


def fused_targets(sample, pc_range: Sequence[float]) -> dict[str, torch.Tensor]:
    """A frame's ``gt/fused`` boxes (ego frame) cut to ``pc_range``, in part 1's target layout
    (``det_boxes`` (M, 10) encoded, padding rows 1 m boxes at yaw 0; ``det_labels``;
    ``det_mask``): the fused heads' targets of AURORA's stages and the baselines."""
    mask = sample["gt", "fused", "mask"].numpy().astype(bool)
    boxes = sample["gt", "fused", "boxes"].numpy()
    keep = mask & in_range(boxes[:, :3], pc_range)
    m, n = len(mask), int(keep.sum())
    det = np.zeros((m, 10), np.float32)
    det[:, 3:6], det[:, 7] = 1.0, 1.0  # padding rows: 1 m boxes, yaw 0
    det[:n] = encode_targets(boxes[keep])
    labels = np.zeros(m, np.int64)
    labels[:n] = sample["gt", "fused", "class"].numpy()[keep]
    return {"det_boxes": torch.from_numpy(det), "det_labels": torch.from_numpy(labels),
            "det_mask": torch.arange(m) < n}


def collate(samples: Sequence[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Stack samples into a batch (every key gains a leading ``B``)."""
    if not samples:
        raise ValueError("collate: no samples")
    keys = samples[0].keys()
    for s in samples[1:]:
        if s.keys() != keys:
            raise ValueError(f"collate: samples have different keys ({sorted(s.keys())} vs "
                             f"{sorted(keys)})")
    return {k: torch.stack([s[k] for s in samples]) for k in keys}


def make_loader(dataset: Dataset, batch_size: int, *, shuffle: bool = True, seed: int = 0,
                num_workers: int = 0, drop_last: bool = False) -> DataLoader:
    """A ``DataLoader`` of :func:`collate` batches; shuffling is seeded (repeatable order)."""
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"make_loader: batch_size={batch_size!r} must be an int >= 1")
    gen = torch.Generator().manual_seed(int(seed))
    return DataLoader(dataset, batch_size=batch_size, shuffle=shuffle, collate_fn=collate,
                      num_workers=num_workers, drop_last=drop_last, generator=gen,
                      persistent_workers=num_workers > 0)


__all__ = ["AuroraFrames", "collate", "encode_targets", "fused_targets", "in_range", "make_loader",
           "model_images"]
