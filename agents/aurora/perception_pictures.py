"""Pictures of one evaluated frame: bird's-eye view and camera images with boxes.

Left: the branch's perception range from above (x forward up the page, y left to the left),
ground-truth boxes (green) and map polylines (thin: divider orange, boundary red, crosswalk
blue), predicted boxes (magenta, opacity by score) and map elements (dashed) whose score passes
``score_threshold``. Right: the branch's camera images with the same 3D boxes projected through
the sample's ``intrinsics`` and ``cam_to_frame`` (:func:`.calib.project_points`).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import torch

from v2xbench.files import atomic_write_bytes

from .calib import CAMERA_NAMES, project_points
from .config import AuroraConfig

MAP_COLOURS = ("orange", "red", "royalblue")
GT_COLOUR, PRED_COLOUR = "limegreen", "magenta"
#: corner pairs of a box's 12 edges (corners: bottom 0-3, top 4-7, counter-clockwise)
EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4),
         (0, 4), (1, 5), (2, 6), (3, 7))


def box_corners(boxes10: np.ndarray) -> np.ndarray:
    """``(M, 8, 3)`` corners of boxes ``(M, 10)`` ``x, y, z, l, w, h, sin, cos, ...`` (``z``
    the centre): bottom face, then top, each counter-clockwise from the front left (EDGES)."""
    b = np.asarray(boxes10, np.float64).reshape(-1, 10)
    yaw = np.arctan2(b[:, 6], b[:, 7])
    dx = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * 0.5
    dy = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * 0.5
    dz = np.array([-1, -1, -1, -1, 1, 1, 1, 1]) * 0.5
    lx, ly, lz = b[:, 3:4] * dx, b[:, 4:5] * dy, b[:, 5:6] * dz
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    return np.stack([b[:, 0:1] + c * lx - s * ly, b[:, 1:2] + s * lx + c * ly, b[:, 2:3] + lz], -1)


def _bev(ax, pts: np.ndarray, **kw) -> None:
    ax.plot(-pts[..., 1], pts[..., 0], **kw)


def _predictions(outputs: dict, top_k: int, score_threshold: float):
    prob = outputs["det_logits"].float().sigmoid()
    score, _ = prob.max(-1)
    order = torch.argsort(score, descending=True)[:top_k]
    order = order[score[order] >= score_threshold]
    mscore, _ = outputs["map_logits"].float().sigmoid().max(-1)
    mcls = outputs["map_logits"].argmax(-1)
    mkeep = mscore >= score_threshold
    return (outputs["det_boxes"][order].numpy(), score[order].numpy(),
            outputs["map_points"][mkeep].numpy(), mcls[mkeep].numpy())


def frame_picture(sample: dict, outputs: dict, cfg: AuroraConfig, branch: str,
                  path: str | Path, *, top_k: int = 50, score_threshold: float = 0.3) -> Path:
    """Draw one frame (module docstring) to ``path`` (PNG, written atomically).

    Args:
        sample: one sample of :class:`~.data.AuroraFrames` (no batch dimension).
        outputs: the branch's last-layer outputs for it: ``det_logits (Q, C)``,
            ``det_boxes (Q, 10)``, ``map_logits (Qm, 3)``, ``map_points (Qm, P, 2)``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = cfg.pc_range(branch)
    gt_boxes = sample["det_boxes"][sample["det_mask"]].numpy()
    gt_map = sample["map_points"][sample["map_mask"]].numpy()
    gt_map_cls = sample["map_labels"][sample["map_mask"]].numpy()
    gt_closed = sample["map_closed"][sample["map_mask"]].numpy()
    p_boxes, p_score, p_map, p_map_cls = _predictions(outputs, top_k, score_threshold)
    cams = CAMERA_NAMES[branch]
    ncol = 3 if len(cams) > 1 else 1
    nrow = (len(cams) + ncol - 1) // ncol
    fig = plt.figure(figsize=(5 + 3.2 * ncol, max(5.0, 1.9 * nrow + 1)), dpi=110)
    grid = fig.add_gridspec(nrow, ncol + 2)
    ax = fig.add_subplot(grid[:, :2])
    for pts, c, closed in zip(gt_map, gt_map_cls, gt_closed):
        pts = np.concatenate([pts, pts[:1]]) if closed else pts
        _bev(ax, pts, color=MAP_COLOURS[int(c)], lw=1.0)
    for pts, c in zip(p_map, p_map_cls):
        _bev(ax, pts, color=MAP_COLOURS[int(c)], lw=1.0, ls="--", alpha=0.8)
    for corners in box_corners(gt_boxes):
        _bev(ax, corners[[0, 1, 2, 3, 0]], color=GT_COLOUR, lw=1.2)
    for corners, sc in zip(box_corners(p_boxes), p_score):
        _bev(ax, corners[[0, 1, 2, 3, 0]], color=PRED_COLOUR, lw=1.0, alpha=float(sc))
    ax.plot([0], [0], marker="^" if branch == "ego" else "s", color="k")
    ax.set_xlim(-rng[4], -rng[1])
    ax.set_ylim(rng[0], rng[3])
    ax.set_aspect("equal")
    ax.set_title(f"{branch} frame {int(sample['frame_id'])}: GT (green) / predicted (magenta)",
                 fontsize=8)
    ax.set_xlabel("-y (m)", fontsize=7)
    ax.set_ylabel("x (m)", fontsize=7)
    ax.tick_params(labelsize=6)
    imgs = sample["images"].permute(0, 2, 3, 1).numpy()
    k, c2f = sample["intrinsics"].numpy(), sample["cam_to_frame"].numpy()
    for n, name in enumerate(cams):
        cax = fig.add_subplot(grid[n // ncol, 2 + n % ncol])
        h, w = imgs[n].shape[:2]
        cax.imshow(imgs[n], extent=(0, w, h, 0))
        for boxes, colour, alphas in ((gt_boxes, GT_COLOUR, None), (p_boxes, PRED_COLOUR, p_score)):
            corners = box_corners(boxes)
            for j, cb in enumerate(corners):
                uv, z = project_points(cb, k[n], c2f[n])
                if (z <= 0.1).any():
                    continue
                a = 1.0 if alphas is None else float(alphas[j])
                for e0, e1 in EDGES:
                    cax.plot(uv[[e0, e1], 0], uv[[e0, e1], 1], color=colour, lw=0.8, alpha=a)
        cax.set_xlim(0, w)
        cax.set_ylim(h, 0)
        cax.set_title(name, fontsize=7)
        cax.axis("off")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return atomic_write_bytes(Path(path), buf.getvalue())


__all__ = ["box_corners", "frame_picture"]
