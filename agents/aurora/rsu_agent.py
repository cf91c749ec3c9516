"""The roadside unit as a learned agent: its branch perceives, its action is the message.

:class:`AuroraRoadside` is AURORA's roadside policy (``agents/interface.py``, "Roadside
policy"; ``collectors/roadside.py``). Every tick a unit serves the ego, the harness calls
:meth:`AuroraRoadside.act` with the unit's observation (the PettingZoo ``rsu`` agent's, in
``sensors`` mode: its ``camera`` image and ``calibration``); the roadside branch
(:class:`~.branch.PerceptionBranch` ``"rsu"``) runs on the camera, and the message
(:func:`~.cqaf.rsu_message`: the top ``cfg.cqaf_det_topk`` detection queries with reference
points and scores, the top ``cfg.cqaf_map_topk`` map queries with polylines and scores, all in
the unit's ground frame) is returned as a raw payload of floats (:func:`serialize_message`).
The V2X channel serializes it (float16 by default: 2 bytes a float after its 16-byte header),
counts its bytes in the run's BPS, delays it ``latency_ticks``, loses it with ``loss_prob``;
the ego reads it from ``v2x_payload`` (:func:`deserialize_message`) and the unit's pose from
``v2x_info`` (:func:`received_pose`: ``E_{r->e}``, the ground frame -> ego frame, as the
channel gives the sender's pose relative to the ego when the message arrives).

Payload layout (``F`` = :func:`message_floats`; every value float16-representable):

====================  =====================================================================
floats                content
====================  =====================================================================
6                     header: :data:`MAGIC`, :data:`VERSION`, ``K``, ``Km``, ``D``, ``P``
``K * (4 + D)``       per detection query: reference ``x, y, z`` (m), score, query (``D``)
``Km * (1 + 2P + D)`` per map query: score, polyline ``(P, 2)`` (m), query (``D``)
====================  =====================================================================

At the default scale ``F = 6 + 32 * 132 + 10 * 145 = 5680`` floats (11,376 bytes on air, about
0.91 Mbit/s at 10 Hz), above the env's default ``max_payload_floats`` (320): evaluate with
``max_payload_floats=F`` (:func:`message_floats`; the config's bound is 65,535 floats), which the
``aurora`` agent declares as its ``channel`` so that ``eval`` sets it.
A message longer than the limit is an error that fails the route, never cut.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch
from v2xbench.agents.devices import run_on_module
from v2xbench.envs.v2x_intersection.api.observations import V2X_INFO_FEATURES
from v2xbench.envs.v2x_intersection.core.geometry import pose_matrix
from v2xbench.envs.v2x_intersection.v2x.wire import FORMAT_RAW, PAYLOAD_LIMIT

from .calib import frame_camera_tensors, spec_calib
from .config import AuroraConfig
from .cqaf import rsu_message
from .data import model_images

MAGIC = 1717.0  # an integer float16 holds exactly
VERSION = 1.0
HEADER_FLOATS = 6
_INFO = {name: i for i, name in enumerate(V2X_INFO_FEATURES)}


def message_floats(cfg: AuroraConfig) -> int:
    """Floats of the roadside message at ``cfg``'s sizes (what ``max_payload_floats`` must hold)."""
    k = min(cfg.cqaf_det_topk, cfg.num_det_queries)
    km = min(cfg.cqaf_map_topk, cfg.num_map_queries)
    d, p = cfg.dec_width, cfg.map_points
    return HEADER_FLOATS + k * (4 + d) + km * (1 + 2 * p + d)


def to_wire(msg: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The message's float tensors rounded to float16 (what the channel delivers with its
    default encoding; the cast passes gradients), clipped to ``+-PAYLOAD_LIMIT``."""
    out = {}
    for k, v in msg.items():
        if v.dtype.is_floating_point and k != "rsu_to_ego":
            v = v.clamp(-PAYLOAD_LIMIT, PAYLOAD_LIMIT).to(torch.float16).to(v.dtype)
        out[k] = v
    return out


def serialize_message(msg: Mapping[str, torch.Tensor]) -> np.ndarray:
    """A one-sample message (:func:`~.cqaf.rsu_message` with batch 1) as a raw payload: a 1-D
    float32 array of float16-representable values (module docstring). Values beyond
    ``+-PAYLOAD_LIMIT`` (1e4, the channel's bound) are clipped."""
    q, ref, sc = msg["det_queries"], msg["det_ref"], msg["det_scores"]
    mq, mp, ms = msg["map_queries"], msg["map_points"], msg["map_scores"]
    if q.dim() != 3 or q.shape[0] != 1:
        raise ValueError(f"serialize_message: det_queries has shape {tuple(q.shape)}; expected "
                         "(1, K, D) (one roadside unit's message)")
    k, d = q.shape[1:]
    km, p = mq.shape[1], mp.shape[2]
    det = torch.cat([ref[0], sc[0, :, None], q[0]], -1).reshape(-1)
    mpp = torch.cat([ms[0, :, None], mp[0].reshape(km, 2 * p), mq[0]], -1).reshape(-1)
    head = torch.tensor([MAGIC, VERSION, k, km, d, p], dtype=torch.float32)
    flat = torch.cat([head, det.detach().float().cpu(), mpp.detach().float().cpu()]).numpy()
    flat = np.clip(flat, -PAYLOAD_LIMIT, PAYLOAD_LIMIT)
    return flat.astype(np.float16).astype(np.float32)


def deserialize_message(payload: np.ndarray, cfg: AuroraConfig) -> dict[str, torch.Tensor]:
    """The message tensors (batch 1; :data:`~.cqaf.MESSAGE_KEYS` but ``rsu_to_ego``, which the
    receiver adds: :func:`received_pose`) of a payload made by :func:`serialize_message`.

    Raises:
        ValueError: not an AURORA message (magic, version), sizes other than ``cfg``'s (``D``,
            ``P``, more queries than the config sends), or a length that disagrees with them.
    """
    x = np.asarray(payload, np.float32).reshape(-1)
    if x.shape[0] < HEADER_FLOATS or x[0] != MAGIC or x[1] != VERSION:
        head = x[:2].tolist()
        raise ValueError(f"deserialize_message: not an AURORA roadside message (header {head}, "
                         f"expected [{MAGIC}, {VERSION}])")
    k, km, d, p = (int(v) for v in x[2:6])
    kk = min(cfg.cqaf_det_topk, cfg.num_det_queries)
    kkm = min(cfg.cqaf_map_topk, cfg.num_map_queries)
    if d != cfg.dec_width or p != cfg.map_points or k > kk or km > kkm:
        raise ValueError(f"deserialize_message: the message has K={k}, Km={km}, D={d}, P={p}; "
                         f"this model takes K<={kk}, Km<={kkm}, D={cfg.dec_width}, "
                         f"P={cfg.map_points}")
    n_det, n_map = k * (4 + d), km * (1 + 2 * p + d)
    if x.shape[0] != HEADER_FLOATS + n_det + n_map:
        raise ValueError(f"deserialize_message: {x.shape[0]} floats; a message with K={k}, "
                         f"Km={km} has {HEADER_FLOATS + n_det + n_map}")
    det = torch.from_numpy(x[HEADER_FLOATS:HEADER_FLOATS + n_det].copy()).view(k, 4 + d)
    mpp = torch.from_numpy(x[HEADER_FLOATS + n_det:].copy()).view(km, 1 + 2 * p + d)
    return {
        "det_ref": det[None, :, :3], "det_scores": det[None, :, 3],
        "det_queries": det[None, :, 4:], "det_mask": torch.ones(1, k, dtype=torch.bool),
        "map_scores": mpp[None, :, 0], "map_points": mpp[None, :, 1:1 + 2 * p].view(1, km, p, 2),
        "map_queries": mpp[None, :, 1 + 2 * p:], "map_mask": torch.ones(1, km, dtype=torch.bool),
    }


def received_payload(obs: Mapping[str, np.ndarray]) -> np.ndarray | None:
    """The raw payload the ego holds (``v2x_payload[:payload_length]``), or ``None`` when no
    message is held or it is not a raw payload (e.g. an object list)."""
    info = np.asarray(obs["v2x_info"], np.float64)
    if info[_INFO["received"]] < 0.5 or int(info[_INFO["payload_format"]]) != FORMAT_RAW:
        return None
    n = int(info[_INFO["payload_length"]])
    return np.asarray(obs["v2x_payload"][:n], np.float32) if n > 0 else None


def received_pose(v2x_info: np.ndarray) -> torch.Tensor:
    """``E_{r->e}`` ``(4, 4)``: the sender's ground frame -> ego frame, from ``v2x_info``
    (``rsu_x``, ``rsu_y``, ``rsu_yaw``: the unit's pose in the ego frame when the message is
    read; the same matrix as :func:`~.cqaf.rsu_to_ego` of the calibration)."""
    info = np.asarray(v2x_info, np.float64)
    e = pose_matrix(info[_INFO["rsu_x"]], info[_INFO["rsu_y"]], 0.0, info[_INFO["rsu_yaw"]])
    return torch.from_numpy(np.asarray(e, np.float32))


class AuroraRoadside:
    """AURORA's roadside policy: the roadside branch on the unit's camera, the message as the
    action (module docstring).

    Args:
        branch: the trained roadside :class:`~.branch.PerceptionBranch` (``"rsu"``).
        cfg: its configuration.
        camera_size: the env's ``(width, height)`` of the unit's camera (``camera_size``).
        checkpoint: the weight files it was loaded from (hashed into the run's fingerprint).
    """

    def __init__(self, branch: torch.nn.Module, cfg: AuroraConfig,
                 camera_size: tuple[int, int] = (128, 64),
                 checkpoint: str | list[str] | None = None) -> None:
        if getattr(branch, "branch", None) != "rsu":
            raise ValueError("AuroraRoadside: needs the roadside PerceptionBranch ('rsu')")
        self.branch, self.cfg = branch.eval(), cfg
        self.camera_size = tuple(int(v) for v in camera_size)
        if checkpoint is not None:
            self.checkpoint = checkpoint
        self._cams: tuple[np.ndarray, torch.Tensor, torch.Tensor] | None = None
        self.messages = 0  # messages produced since the last reset
        self.infer_s = 0.0  # seconds spent in the branch since the last reset

    def reset(self, route_info: dict) -> None:
        """A new route: forget the cached camera calibration and the counters."""
        self._cams, self.messages, self.infer_s = None, 0, 0.0

    def camera(self, t_world_rsu: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """``(intrinsics (1, 1, 3, 3), cam_to_frame (1, 1, 4, 4))`` of the unit's camera at
        ``t_world_rsu`` (:func:`~.calib.spec_calib`; cached while the unit stays)."""
        key = np.asarray(t_world_rsu, np.float64)
        if self._cams is None or not np.array_equal(self._cams[0], key):
            cal = spec_calib(self.camera_size, t_world_rsu, 0)
            k, c2f = frame_camera_tensors(cal, "rsu", self.camera_size,
                                          self.cfg.image_size("rsu"))
            self._cams = (key, k[None], c2f[None])
        return self._cams[1], self._cams[2]

    def inputs(self, rsu_obs: Mapping) -> dict[str, torch.Tensor]:
        """The branch's batch-1 inputs (``images``, ``intrinsics``, ``cam_to_frame``) of one
        observation (its camera ``rgb`` image and ``calibration[0]``); ``ValueError`` naming a
        missing or misshapen image."""
        cam = rsu_obs.get("camera")
        if not isinstance(cam, Mapping) or "rgb" not in cam:
            raise ValueError("AuroraRoadside: the roadside observation has no camera rgb image "
                             "(evaluate with obs_mode='sensors' and camera_images including rgb)")
        rgb = torch.as_tensor(np.asarray(cam["rgb"]))
        if tuple(rgb.shape) != (self.camera_size[1], self.camera_size[0], 3):
            raise ValueError(f"AuroraRoadside: the camera image has shape {tuple(rgb.shape)}; "
                             f"expected {(self.camera_size[1], self.camera_size[0], 3)} "
                             "(camera_size)")
        k, c2f = self.camera(np.asarray(rsu_obs["calibration"][0], np.float64))
        images = model_images(rgb[None], self.cfg.image_size("rsu"))[None]
        return {"images": images, "intrinsics": k, "cam_to_frame": c2f}

    @torch.no_grad()
    def message(self, rsu_obs: Mapping) -> dict[str, torch.Tensor]:
        """The message tensors (:func:`~.cqaf.rsu_message`, batch 1) of one observation."""
        import time

        t0 = time.perf_counter()
        out = run_on_module(self.branch, self.inputs(rsu_obs))
        msg = rsu_message(out, self.cfg, torch.eye(4)[None])
        self.infer_s += time.perf_counter() - t0
        return msg

    def act(self, rsu_obs: Mapping) -> np.ndarray:
        """The message of this tick as a raw payload (:func:`serialize_message`)."""
        payload = serialize_message(self.message(rsu_obs))
        self.messages += 1
        return payload


def load_roadside(run: str | Path, camera_size: tuple[int, int] = (128, 64)) -> AuroraRoadside:
    """The roadside policy of a trained run: the roadside branch of the run's latest stage
    (:func:`~.system.latest_stage`; stage 2 for a run without stages 3-5)."""
    from .system import load_branch_of_run

    branch, cfg, ckpt = load_branch_of_run(run, "rsu")
    return AuroraRoadside(branch, cfg, camera_size, checkpoint=[str(ckpt)])


__all__ = ["HEADER_FLOATS", "MAGIC", "VERSION", "AuroraRoadside", "deserialize_message",
           "load_roadside", "message_floats", "received_payload", "received_pose",
           "serialize_message", "to_wire"]
