"""Per-frame 3D box ground truth: ego-centric, roadside-centric and fused sets (paper).

Candidates: every active actor but the ego (vehicles, VRUs, and any cone / sign / obstacle actor
a scenario adds) and every non-building static box (traffic-light poles, stop-sign poles, other
static obstacles: ``world.static_boxes[j]`` for ``j >= len(world.town.buildings)``). Buildings are
scenery, not objects.

Each box (a row of a struct-of-arrays dict, world frame; :func:`boxes_in_frame` moves a set to
the ego or RSU frame):

====================  ===========  ==========================================================
key                   shape/dtype  meaning
====================  ===========  ==========================================================
``id``                (M,) int64   ``actor_id`` for actors, ``1_000_000 + j`` for static box j
``instance``          (M,) int64   instance id in images and points (:mod:`.semantics`)
``class``             (M,) int64   object class (``classes``)
``center``            (M, 3)       3D box centre (m): ground position, z = half the height
``size``              (M, 3)       length, width, height (m)
``yaw``               (M,)         heading (rad)
``velocity``          (M, 3)       (vx, vy, 0) (m/s)
``ego_lidar_points``  (M,) int64   ego LiDAR returns on the object
``rsu_lidar_points``  (M,) int64   RSU LiDAR returns on the object
``ego_pixels``        (M,) int64   pixels with its instance id, summed over the ego cameras
``rsu_pixels``        (M,) int64   same in the RSU camera
``ego_pixel_fraction``  (M,)       visible / unoccluded pixels in the ego cameras (0 if none;
                                   unoccluded = the pixels it would cover with every other box
                                   removed, :func:`.fan.unoccluded_pixels`)
``rsu_pixel_fraction``  (M,)       same for the RSU camera
``in_ego``, ``in_rsu``, ``joint``  (M,) bool  membership of the sets below
====================  ===========  ==========================================================

Visibility (precise definitions):

- **visible to the ego sensors**: at least :data:`MIN_LIDAR_POINTS` (1) ego LiDAR return on the
  object, or at least :data:`MIN_PIXELS` (4) pixels of it in the ego cameras together;
- **visible to the RSU**: the same with the RSU LiDAR and the RSU camera;
- **fused** = ego set union RSU set, one box per id (the candidate table has unique ids);
- **jointly visible** = at least :data:`JOINT_MIN_POINTS` (10) returns in the ego LiDAR *and*
  at least 10 in the RSU LiDAR (paper); a subset of both sets.

Sensors switched off in the rig contribute nothing (zero points / pixels).
"""

from __future__ import annotations

import numpy as np

from ..core.geometry import transform_points
from ..core.jit import HAVE_JIT
from .kernels import instance_counts_kernel
from .semantics import STATIC_INSTANCE_OFFSET, static_instance

MIN_LIDAR_POINTS = 1
MIN_PIXELS = 4
JOINT_MIN_POINTS = 10
SETS = ("ego", "rsu", "fused", "joint")


def candidate_boxes(world) -> dict[str, np.ndarray]:
    """The candidate table (module docstring), without the visibility columns."""
    t = world.table
    rows = np.flatnonzero(t.active)
    rows = rows[rows > 0]
    n_build = len(world.town.buildings)
    sb = world.static_boxes
    js = np.arange(n_build, len(sb))
    na, ns = len(rows), len(js)
    center, size = np.empty((na + ns, 3)), np.empty((na + ns, 3))
    h_a, h_s = t.height[rows], world.static_heights[js]
    center[:na, :2], center[:na, 2] = t.pos[rows], h_a / 2
    center[na:, :2], center[na:, 2] = sb[js, :2], h_s / 2
    size[:na, 0], size[:na, 1], size[:na, 2] = t.length[rows], t.width[rows], h_a
    size[na:, 0], size[na:, 1], size[na:, 2] = sb[js, 2], sb[js, 3], h_s
    velocity = np.zeros((na + ns, 3))
    velocity[:na, 0] = t.speed[rows] * np.cos(t.yaw[rows])
    velocity[:na, 1] = t.speed[rows] * np.sin(t.yaw[rows])
    return {
        "id": np.concatenate([t.actor_id[rows], static_instance(js)]).astype(np.int64),
        "instance": np.concatenate([rows + 1, static_instance(js)]).astype(np.int64),
        "class": np.concatenate([world.object_classes()[rows], world.static_kinds[js]]).astype(np.int64),
        "center": center,
        "size": size,
        "yaw": np.concatenate([t.yaw[rows], sb[js, 4]]),
        "velocity": velocity,
    }


def _count(instances: np.ndarray, values: np.ndarray) -> np.ndarray:
    """How often each of ``instances (M,)`` occurs in ``values`` (instance ids, any shape)."""
    v = np.asarray(values).ravel()
    out = np.zeros(len(instances), np.int64)
    if len(v) == 0 or len(instances) == 0:
        return out
    if HAVE_JIT:
        return instance_counts_kernel(np.asarray(instances, np.int64), v, STATIC_INSTANCE_OFFSET)
    is_static = v >= STATIC_INSTANCE_OFFSET
    for sel, vals, base in (
        (instances < STATIC_INSTANCE_OFFSET, v[~is_static], 0),
        (instances >= STATIC_INSTANCE_OFFSET, v[is_static], STATIC_INSTANCE_OFFSET),
    ):
        if sel.any() and len(vals):
            c = np.bincount((vals - base).astype(np.int64))
            k = instances[sel] - base
            out[sel] = np.where(k < len(c), c[np.minimum(k, len(c) - 1)], 0)
    return out


def ground_truth(world, lidar_instances: dict, cameras: list, unoccluded=None) -> dict:
    """The three box sets of the current frame.

    Args:
        world: the world the frame was captured from.
        lidar_instances: ``{"ego": (P,) ids, "rsu": (Q,) ids}``: instance column of each LiDAR's
            points (absent / empty when the LiDAR is off).
        cameras: ``[(group, instance_image), ...]`` with group ``"ego"`` or ``"rsu"``.
        unoccluded: ``f([instances of camera 0, ...]) -> [(M_i,) pixel counts, ...]``: the
            pixels each object would cover in each camera with every other box removed
            (:func:`.fan.unoccluded_pixels_many` bound to the cameras); ``None``: fractions 0.

    Returns:
        ``{"boxes": table with every candidate, "ego": ..., "rsu": ..., "fused": ...,
        "joint": ...}``; each value a dict of arrays with the keys of the module docstring.
    """
    b = candidate_boxes(world)
    inst = b["instance"]
    m = len(inst)
    counts = [_count(inst, image) for _, image in cameras]
    seen = [np.flatnonzero(c > 0) for c in counts]
    full_k = unoccluded([inst[s] for s in seen]) if unoccluded else [np.zeros(len(s)) for s in seen]
    for g in ("ego", "rsu"):
        b[f"{g}_lidar_points"] = _count(inst, lidar_instances.get(g, np.zeros(0)))
        vis = np.zeros(m, np.int64)
        full = np.zeros(m)
        for (group, _), c, s, f in zip(cameras, counts, seen, full_k):
            if group == g:
                vis += c
                full[s] += f
        b[f"{g}_pixels"] = vis
        with np.errstate(divide="ignore", invalid="ignore"):
            b[f"{g}_pixel_fraction"] = np.where(full > 0, np.minimum(vis / full, 1.0), 0.0)
    b["in_ego"] = (b["ego_lidar_points"] >= MIN_LIDAR_POINTS) | (b["ego_pixels"] >= MIN_PIXELS)
    b["in_rsu"] = (b["rsu_lidar_points"] >= MIN_LIDAR_POINTS) | (b["rsu_pixels"] >= MIN_PIXELS)
    b["joint"] = (b["ego_lidar_points"] >= JOINT_MIN_POINTS) & (
        b["rsu_lidar_points"] >= JOINT_MIN_POINTS
    )
    masks = {
        "ego": b["in_ego"],
        "rsu": b["in_rsu"],
        "fused": b["in_ego"] | b["in_rsu"],
        "joint": b["joint"],
    }
    out = {"boxes": b}
    for name, mask in masks.items():
        out[name] = {k: v[mask] for k, v in b.items()}
    return out


def boxes_in_frame(boxes: dict, t_frame_world: np.ndarray) -> dict:
    """A box set expressed in another frame (e.g. ``inv(T_world_ego)``): centres, yaw, velocity.

    Args:
        boxes: a set from :func:`ground_truth` (world frame).
        t_frame_world: ``(4, 4)`` world -> target frame.

    Returns:
        A copy with ``center``, ``yaw`` and ``velocity`` in the target frame (yaw assumes a frame
        with a vertical z axis; for a pitched frame it is the heading of the rotated x axis).
    """
    out = dict(boxes)
    r = t_frame_world[:3, :3]
    out["center"] = transform_points(t_frame_world, boxes["center"])
    out["velocity"] = boxes["velocity"] @ r.T
    hd = np.stack([np.cos(boxes["yaw"]), np.sin(boxes["yaw"]), np.zeros(len(boxes["yaw"]))], -1)
    hd = hd @ r.T
    out["yaw"] = np.arctan2(hd[:, 1], hd[:, 0])
    return out


__all__ = [
    "JOINT_MIN_POINTS",
    "MIN_LIDAR_POINTS",
    "MIN_PIXELS",
    "boxes_in_frame",
    "candidate_boxes",
    "ground_truth",
]
