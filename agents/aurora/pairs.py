"""Samples of stages 3-5: the ego frame, the roadside unit's frame and a question (or the
planning prompt), paired.

A sample is one frame of the data set and one text: a Chat-V2XBench QA item of that frame's
keyframe (``chat/qa.jsonl``, ``v2xbench qa build``: stage 3 and half of stage 5), or the planning
prompt ending with ``<wp>`` (stage 4 and the other half of stage 5). Keys (shapes without the
leading ``B``; ``M`` box rows, ``K`` map elements, ``T`` tokens):

=========================  ==========================================================
key                        content
=========================  ==========================================================
``ego/*``                  the ego branch's sample (:class:`~.data.AuroraFrames`):
                           ``images`` (unless a feature cache replaces them),
                           ``intrinsics``, ``cam_to_frame``, its targets (``gt/ego``)
``rsu/*``                  the roadside branch's sample (zeros without a unit)
``has_rsu``                () bool: a roadside unit serves the ego in this frame
``rsu_to_ego``             (4, 4) ``E_{r->e}`` (:func:`~.cqaf.rsu_to_ego`; identity
                           without a unit)
``det_boxes``, ...         ``gt/fused`` in the ego frame, cut to the ego range (CQAF's
                           fused heads' targets, part 1's layout)
``map_points``, ...        the map targets in the ego frame (the ego branch's)
``input_ids``, ``labels``  (T,) the prompt (:func:`~.prompt.build_prompt`: run-time
                           context only) and the answer's labels (``-100`` elsewhere)
``command``                () int64 navigation command
``route_points``           (K, 2) float32 the planner's route input: the K =
                           ``cfg.plan_route_points`` points ahead on the recorded
                           ``route``, ego frame (:func:`~.route_input.
                           planner_route_points`, as the policy at run time)
``route_path``             (N, 2) float32, route-frame planners only (``cfg.plan_frame
                           = "route"``): the route polyline the planner's ``(s, d)``
                           refer to (:func:`~.route_input.planner_route_path`)
``ego_speed``              () float32 the ego's speed (m/s; the planning loss's
                           start-from-rest weight reads it, whatever the prompt says)
``expert_waypoints``       (8, 2) the expert's future positions, ego frame, 0.5 s apart
``agent_future``           (M, T_plan, 2) ``gt/fused`` agents at constant velocity;
                           ``agent_future_mask`` (M, T_plan)
``plan_mask``              () bool: a planning sample (its prompt has ``<wp>``; never
                           with ``plan=False``: stage 3 without QA, :mod:`.stages`)
``feat/*``, ``msg/*``      cached branch outputs (:mod:`.feature_cache`), when given
``frame_id``               () int64 global frame index
=========================  ==========================================================

The prompt says "no message received" for frames without a unit and for a model without
fusion (``fusion=False``), as at run time. Speed dropout (training only, ``speed_dropout=p``):
a planning prompt says "Ego speed: unknown" for a share ``p`` of the planning samples, chosen
per sample by a generator seeded with ``(seed, index)`` (repeatable, and the same on resume);
QA prompts and the default ``p = 0`` (evaluation) always carry the speed.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset
from v2xbench.collectors.dataset.loader import V2XDataset

from .config import AuroraConfig
from .cqaf import rsu_to_ego
from .data import CALIB_KEYS, AuroraFrames, fused_targets
from .language import IGNORE, encode_qa
from .planner_losses import constant_velocity_futures
from .prompt import PLAN_QUESTION, build_prompt
from .route_input import PATH_KEY, ROUTE_KEY, planner_route_path, planner_route_points

QA_FILE = Path("chat") / "qa.jsonl"
EXTRA_KEYS = ("ego_speed", "command", "route", "expert_waypoints", ("gt", "fused", "boxes"),
              ("gt", "fused", "class"), ("gt", "fused", "mask"))
TEXT_KEYS = ("input_ids", "labels", "attention_mask")

#: One sample: ``(frame_id, question, answer)``; ``question is None``: the planning prompt.
Item = tuple[int, str | None, str | None]


# ---------------------------------------------------------------------- which samples
def planning_items(frames: AuroraFrames, stride: int) -> list[Item]:
    """Planning samples: every ``stride``-th frame of each episode of ``frames``' split."""
    ds = frames.ds
    out: list[Item] = []
    for e in range(len(ds.episodes)):
        n = int(ds.offsets[e + 1] - ds.offsets[e])
        out += [(int(ds.offsets[e] + t), None, None) for t in range(0, n, stride)]
    return out


def qa_items(root: str | Path, frames: AuroraFrames, stride: int) -> list[Item]:
    """QA samples: every ``stride``-th Chat-V2XBench item (file order) whose episode is in
    ``frames``' split, at its keyframe's frame.

    Raises:
        FileNotFoundError: no ``chat/qa.jsonl`` (run ``v2xbench qa build --data DIR``).
        ValueError: a malformed line or a tick outside its episode (file and line named).
    """
    path = Path(root) / QA_FILE
    if not path.is_file():
        raise FileNotFoundError(f"AURORA stages 3-5: {path} does not exist (build the QA "
                                f"items with `v2xbench qa build --data {root}`)")
    ds = frames.ds
    index = {sid: e for e, sid in enumerate(ds.episodes)}
    out: list[Item] = []
    kept = 0
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                it = json.loads(line)
                ep, tick, q, a = it["episode"], int(it["tick"]), it["question"], it["answer"]
            except (ValueError, KeyError, TypeError) as err:
                raise ValueError(f"{path}:{n}: not a QA item ({type(err).__name__}: {err})"
                                 ) from None
            e = index.get(ep)
            if e is None:
                continue
            if not 0 <= tick < int(ds.offsets[e + 1] - ds.offsets[e]):
                raise ValueError(f"{path}:{n}: tick {tick} is outside episode {ep}")
            if kept % stride == 0:
                out.append((int(ds.offsets[e] + tick), str(q), str(a)))
            kept += 1
    return out


# ---------------------------------------------------------------------- the data set
class AuroraPairs(Dataset):
    """Paired samples of stages 3-5 (module docstring).

    Args:
        root: data set folder. split: ``train``, ``val``, ``test`` or ``all``.
        cfg: model configuration. tokenizer: AURORA's tokenizer (:mod:`.tokenizer`).
        items: the samples (:func:`planning_items`, :func:`qa_items`).
        fusion: the model uses the roadside message (``False``: the prompt never has one).
        images: read the camera images (``False`` with a feature cache).
        cache: a :class:`~.feature_cache.FeatureCache` holding every item's frame.
        speed_dropout: training only: the share of planning prompts whose speed reads
            "unknown" (module docstring; 0: never). seed: seeds that choice.
        plan: ``False`` sets no ``plan_mask`` (the planner does not run on the samples).
        prompt_speed: probes only (:mod:`.speed_probe`): every planning prompt says this
            speed (m/s) instead of the frame's (``ego_speed`` keeps the frame's); ``None``: the
            frame's.
    """

    def __init__(self, root: str | Path, split: str, cfg: AuroraConfig, tokenizer,
                 items: Sequence[Item], *, fusion: bool = True, images: bool = True,
                 cache=None, speed_dropout: float = 0.0, seed: int = 0,
                 plan: bool = True, prompt_speed: float | None = None) -> None:
        if not items:
            raise ValueError(f"AuroraPairs: no samples in split {split!r} of {root}")
        if not 0 <= float(speed_dropout) <= 1:
            raise ValueError(f"AuroraPairs: speed_dropout={speed_dropout!r} must be in [0, 1]")
        self.speed_dropout, self.seed = float(speed_dropout), int(seed)
        if prompt_speed is not None and not (np.isfinite(prompt_speed) and prompt_speed >= 0):
            raise ValueError(f"AuroraPairs: prompt_speed={prompt_speed!r} must be a speed >= 0")
        self.prompt_speed = None if prompt_speed is None else float(prompt_speed)
        self.cfg, self.tok, self.items = cfg, tokenizer, list(items)
        self.fusion, self.cache, self.plan = bool(fusion), cache, bool(plan)
        self.ego = AuroraFrames(root, split, "ego", cfg, images=images)
        try:
            self.rsu: AuroraFrames | None = AuroraFrames(root, split, "rsu", cfg, images=images)
        except ValueError:  # no frame of the split has an active unit
            self.rsu = None
        self.extra = V2XDataset(root, split, keys=list(EXTRA_KEYS))
        self.range = tuple(float(v) for v in cfg.pc_range("ego"))
        if cache is not None:
            missing = sorted({fid for fid, _, _ in self.items} - set(cache.frames))
            if missing:
                raise ValueError(f"AuroraPairs: the feature cache lacks {len(missing)} frames "
                                 f"(e.g. {missing[:3]})")
        self._blank: dict[str, torch.Tensor] | None = None

    def __len__(self) -> int:
        return len(self.items)

    def frame_ids(self) -> list[int]:
        """The distinct frames of the samples, sorted."""
        return sorted({fid for fid, _, _ in self.items})

    def drops_speed(self, index: int) -> bool:
        """Whether sample ``index``'s prompt says "unknown" instead of the speed (a planning
        sample, with probability ``speed_dropout``; module docstring)."""
        if self.speed_dropout <= 0 or self.items[index][1] is not None:
            return False
        return bool(np.random.default_rng((self.seed, int(index))).random() < self.speed_dropout)

    def _rsu_sample(self, fid: int, calib: dict, like: dict) -> dict[str, torch.Tensor]:
        if self.rsu is not None and int(calib["rsu_unit"]) >= 0:
            return self.rsu.sample(self.rsu.ds[fid], calib, fid)
        if self._blank is None:  # zeros in the roadside sample's layout (identity matrices)
            w, h = self.cfg.image_size("rsu")
            blank = {k: torch.zeros_like(v) for k, v in like.items() if k != "images"}
            blank["intrinsics"] = torch.eye(3)[None]
            blank["cam_to_frame"] = torch.eye(4)[None]
            blank["det_boxes"][:, 3:6] = 1.0  # padding rows: 1 m boxes, yaw 0 (cos = 1)
            blank["det_boxes"][:, 7] = 1.0
            blank.pop("light", None)
            if "images" in like:
                blank["images"] = torch.zeros(1, 3, h, w)
            self._blank = blank
        return {k: v.clone() for k, v in self._blank.items()}

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        fid, question, answer = self.items[index]
        cfg = self.cfg
        td = self.ego.ds[fid]
        calib = {k: td["calib", k].numpy() for k in CALIB_KEYS}
        ego = self.ego.sample(td, calib, fid)
        has = self.rsu is not None and int(calib["rsu_unit"]) >= 0
        rsu = self._rsu_sample(fid, calib, ego)
        rsu.pop("frame_id", None)
        e = rsu_to_ego(calib["T_world_ego"], calib["T_world_rsu"]) if has else torch.eye(4)
        x = self.extra[fid]
        speed, command = float(x["ego_speed"]), int(x["command"])
        said = None if self.drops_speed(index) else speed
        if said is not None and question is None and self.prompt_speed is not None:
            said = self.prompt_speed
        prompt = build_prompt(said, command, e if (has and self.fusion) else None,
                              question or PLAN_QUESTION, num_det=cfg.num_det_queries,
                              num_map=cfg.num_map_queries, waypoint=question is None)
        ids, labels = encode_qa(self.tok, prompt, answer, cfg.lm_max_len)
        out = {f"ego/{k}": v for k, v in ego.items() if k != "frame_id"}
        out.update({f"rsu/{k}": v for k, v in rsu.items()})
        out.update(fused_targets(x, self.range))
        out.update({k: ego[k] for k in ("map_points", "map_labels", "map_mask", "map_closed")})
        fut, fmask = constant_velocity_futures(out["det_boxes"][None], out["det_mask"][None],
                                               cfg.plan_waypoints, cfg.plan_dt)
        out.update(
            has_rsu=torch.tensor(has), rsu_to_ego=e.float(),
            input_ids=torch.tensor(ids, dtype=torch.long),
            labels=torch.tensor(labels, dtype=torch.long),
            command=torch.tensor(command, dtype=torch.long),
            **{ROUTE_KEY: planner_route_points(x["route"], cfg)},
            ego_speed=torch.tensor(speed, dtype=torch.float32),
            expert_waypoints=x["expert_waypoints"].float(),
            agent_future=fut[0], agent_future_mask=fmask[0],
            plan_mask=torch.tensor(question is None and self.plan), frame_id=torch.tensor(fid))
        if cfg.plan_frame == "route":
            out[PATH_KEY] = planner_route_path(x["route"], cfg)
        if self.cache is not None:
            out.update(self.cache.row(fid))
        return out


def collate_pairs(samples: Sequence[dict[str, torch.Tensor]], pad_id: int
                  ) -> dict[str, torch.Tensor]:
    """Stack samples; ``input_ids`` / ``labels`` are right-padded (``pad_id`` / ``-100``) and
    ``attention_mask`` marks the real tokens."""
    if not samples:
        raise ValueError("collate_pairs: no samples")
    keys = samples[0].keys()
    for s in samples[1:]:
        if s.keys() != keys:
            raise ValueError(f"collate_pairs: samples have different keys "
                             f"({sorted(set(s) ^ set(keys))})")
    out = {k: torch.stack([s[k] for s in samples]) for k in keys if k not in TEXT_KEYS}
    t = max(len(s["input_ids"]) for s in samples)
    ids = torch.full((len(samples), t), pad_id, dtype=torch.long)
    labels = torch.full((len(samples), t), IGNORE, dtype=torch.long)
    mask = torch.zeros(len(samples), t, dtype=torch.long)
    for i, s in enumerate(samples):
        n = len(s["input_ids"])
        ids[i, :n], labels[i, :n], mask[i, :n] = s["input_ids"], s["labels"], 1
    out.update(input_ids=ids, labels=labels, attention_mask=mask)
    return out


def make_pair_loader(ds: AuroraPairs, batch_size: int, *, shuffle: bool = True, seed: int = 0,
                     num_workers: int = 0) -> DataLoader:
    """A seeded ``DataLoader`` of :func:`collate_pairs` batches."""
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"make_pair_loader: batch_size={batch_size!r} must be an int >= 1")
    collate = functools.partial(collate_pairs, pad_id=int(ds.tok.pad_token_id))
    return DataLoader(ds, batch_size=batch_size, shuffle=shuffle, collate_fn=collate,
                      num_workers=num_workers, generator=torch.Generator().manual_seed(seed),
                      persistent_workers=num_workers > 0)


__all__ = ["EXTRA_KEYS", "QA_FILE", "AuroraPairs", "Item", "collate_pairs", "make_pair_loader",
           "planning_items", "qa_items"]
