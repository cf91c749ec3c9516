"""PETR-style depth-aware 3D position embedding of image patches (Liu et al., ECCV 2022).

For every patch of every camera, ``D`` points along the ray through the patch's pixel centre,
at depths ``d_0 < ... < d_{D-1}`` from ``near`` to ``far`` (linear-increasing discretization,
LID: the bins widen with distance), are back-projected with ``K^-1`` and ``cam_to_frame`` into
the branch frame (ego frame or the roadside unit's frame), normalized by the branch's perception
range to ``[-1, 1]`` (points outside give values beyond), and an MLP maps the ``3 D`` numbers to
the token width. Pixel coordinates are continuous: the image spans ``[0, W] x [0, H]`` and patch
``(i, j)`` (row, column) covers ``[j p, (j + 1) p] x [i p, (i + 1) p]``.
"""

from __future__ import annotations

import torch
from torch import nn


def lid_depths(bins: int, near: float, far: float) -> torch.Tensor:
    """``(bins,)`` depths (m), linear-increasing discretization from ``near`` to ``far``.

    ``d_i = near + (far - near) * i (i + 1) / ((D - 1) D)``, so ``d_0 = near``, ``d_{D-1} = far``.
    """
    if bins == 1:
        return torch.tensor([near])
    i = torch.arange(bins, dtype=torch.float64)
    return (near + (far - near) * i * (i + 1) / ((bins - 1) * bins)).float()


def patch_centres(image_size: tuple[int, int], patch: int) -> torch.Tensor:
    """``(T, 2)`` pixel centres ``(u, v)`` of the patches, row-major (``T = H/p * W/p``)."""
    w, h = image_size
    v, u = torch.meshgrid(torch.arange(h // patch), torch.arange(w // patch), indexing="ij")
    return torch.stack([(u.flatten() + 0.5) * patch, (v.flatten() + 0.5) * patch], -1).float()


def ray_points(intrinsics: torch.Tensor, cam_to_frame: torch.Tensor, pixels: torch.Tensor,
               depths: torch.Tensor) -> torch.Tensor:
    """Back-project pixels at depths into the branch frame.

    Args:
        intrinsics: ``(B, N, 3, 3)`` pixel intrinsics.
        cam_to_frame: ``(B, N, 4, 4)`` camera optical frame (x right, y down, z forward) ->
            branch frame.
        pixels: ``(T, 2)`` pixel coordinates ``(u, v)``.
        depths: ``(D,)`` depths along the optical axis (m).

    Returns:
        ``(B, N, T, D, 3)`` points in the branch frame (m).
    """
    t, d = pixels.shape[0], depths.shape[0]
    pix = torch.cat([pixels, torch.ones(t, 1, dtype=pixels.dtype, device=pixels.device)], -1)
    rays = torch.einsum("bnij,tj->bnti", torch.linalg.inv(intrinsics), pix)  # (B, N, T, 3), z=1
    cam = rays[..., None, :] * depths.view(1, 1, 1, d, 1)  # (B, N, T, D, 3)
    rot, trans = cam_to_frame[..., :3, :3], cam_to_frame[..., :3, 3]
    return torch.einsum("bnij,bntdj->bntdi", rot, cam) + trans[:, :, None, None, :]


class DepthAwarePE(nn.Module):
    """3D position embedding of every patch of a branch's cameras (module docstring).

    Args:
        image_size: ``(width, height)`` of the images.
        patch: patch size (pixels).
        depth_bins, near, far: the ray discretization.
        pc_range: ``(xmin, ymin, zmin, xmax, ymax, zmax)`` of the branch (m).
        width: output embedding width.
    """

    def __init__(self, image_size: tuple[int, int], patch: int, depth_bins: int, near: float,
                 far: float, pc_range: tuple[float, ...], width: int) -> None:
        super().__init__()
        self.register_buffer("pixels", patch_centres(image_size, patch), persistent=False)
        self.register_buffer("depths", lid_depths(depth_bins, near, far), persistent=False)
        lo = torch.tensor(pc_range[:3], dtype=torch.float32)
        hi = torch.tensor(pc_range[3:], dtype=torch.float32)
        self.register_buffer("lo", lo, persistent=False)
        self.register_buffer("span", hi - lo, persistent=False)
        self.mlp = nn.Sequential(nn.Linear(3 * depth_bins, 4 * width), nn.ReLU(),
                                 nn.Linear(4 * width, width))

    def points(self, intrinsics: torch.Tensor, cam_to_frame: torch.Tensor) -> torch.Tensor:
        """``(B, N, T, D, 3)`` ray points of every patch in the branch frame (m)."""
        return ray_points(intrinsics.float(), cam_to_frame.float(), self.pixels, self.depths)

    def forward(self, intrinsics: torch.Tensor, cam_to_frame: torch.Tensor) -> torch.Tensor:
        """``(B, N, T, width)`` embedding from the cameras' calibration."""
        pts = self.points(intrinsics, cam_to_frame)
        norm = 2.0 * (pts - self.lo) / self.span - 1.0  # [-1, 1] inside the range
        return self.mlp(norm.flatten(-2))
