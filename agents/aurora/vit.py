"""A plain ViT image encoder (Dosovitskiy et al.), written in the shape of timm's blocks.

``PatchEmbed`` -> learned 2D patch position + per-camera embedding + the branch's 3D position
embedding (:mod:`.position`) -> ``depth`` pre-norm transformer ``Block`` s -> ``LayerNorm``.
Attention runs within each camera image (as a ViT backbone in PETR / ORION); the decoders attend
across all cameras. Everything trains from scratch.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

#: Fixed input normalization of images in [0, 1].
IMAGE_MEAN = 0.5
IMAGE_STD = 0.25


class PatchEmbed(nn.Module):
    """``patch x patch`` patches -> ``width`` channels.

    ``stem="linear"``: ViT's patchify (one ``patch``-strided conv). ``stem="conv"``: the
    convolutional stem of Xiao et al. ("Early convolutions help transformers see better",
    2021): ``log2(patch)`` stride-2 3x3 conv + BatchNorm + ReLU layers (channels ``width/2^n``
    doubling to ``width/2``, at least 8) and a 1x1 projection; the same token grid, steadier
    training from scratch.
    """

    def __init__(self, patch: int, width: int, in_chans: int = 3, stem: str = "linear") -> None:
        super().__init__()
        if stem == "linear":
            self.proj = nn.Conv2d(in_chans, width, kernel_size=patch, stride=patch)
            return
        n = patch.bit_length() - 1
        if stem != "conv" or 2**n != patch:
            raise ValueError(f"PatchEmbed: stem={stem!r} must be 'linear' or 'conv' (conv needs "
                             f"a power-of-two patch, got {patch})")
        layers: list[nn.Module] = []
        c_in = in_chans
        for k in range(n):
            c = max(width // 2 ** (n - k), 8)  # width/2^n, ..., width/2
            layers += [nn.Conv2d(c_in, c, 3, stride=2, padding=1, bias=False),
                       nn.BatchNorm2d(c), nn.ReLU(inplace=True)]
            c_in = c
        layers.append(nn.Conv2d(c_in, width, kernel_size=1))
        self.proj = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, 3, H, W)`` -> ``(B, H/p * W/p, width)`` tokens in row-major patch order."""
        return self.proj(x).flatten(2).transpose(1, 2)


class Mlp(nn.Module):
    """Two linear layers with GELU."""

    def __init__(self, width: int, hidden: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.fc1 = nn.Linear(width, hidden)
        self.fc2 = nn.Linear(hidden, width)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.drop(self.fc2(self.drop(F.gelu(self.fc1(x)))))


class Attention(nn.Module):
    """Multi-head self-attention (``scaled_dot_product_attention``)."""

    def __init__(self, width: int, heads: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(width, 3 * width)
        self.proj = nn.Linear(width, width)
        self.dropout = dropout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, t, d = x.shape
        q, k, v = self.qkv(x).view(b, t, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        p = self.dropout if self.training else 0.0
        y = F.scaled_dot_product_attention(q, k, v, dropout_p=p)  # (B, heads, T, d/heads)
        return self.proj(y.transpose(1, 2).reshape(b, t, d))


class Block(nn.Module):
    """Pre-norm transformer block: ``x + attn(norm(x))``, ``x + mlp(norm(x))``."""

    def __init__(self, width: int, heads: int, mlp_ratio: float, dropout: float = 0.0) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(width)
        self.attn = Attention(width, heads, dropout)
        self.norm2 = nn.LayerNorm(width)
        self.mlp = Mlp(width, int(width * mlp_ratio), dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class ViTEncoder(nn.Module):
    """ViT over each camera image of one branch.

    Args:
        image_size: ``(width, height)`` of the images (pixels).
        patch: patch size (pixels).
        width, depth, heads, mlp_ratio: transformer sizes.
        num_cameras: cameras of the branch (one learned embedding each).
        dropout: dropout in attention and MLPs.
        stem: patch embedding, ``"linear"`` or ``"conv"`` (:class:`PatchEmbed`).
    """

    def __init__(self, image_size: tuple[int, int], patch: int, width: int, depth: int,
                 heads: int, mlp_ratio: float, num_cameras: int, dropout: float = 0.0,
                 stem: str = "linear") -> None:
        super().__init__()
        self.image_size = tuple(image_size)
        self.patch = patch
        w, h = image_size
        self.grid = (h // patch, w // patch)  # (rows, cols) of patches
        self.num_patches = self.grid[0] * self.grid[1]
        self.patch_embed = PatchEmbed(patch, width, stem=stem)
        self.pos2d = nn.Parameter(torch.randn(1, self.num_patches, width) * 0.02)
        self.cam_embed = nn.Parameter(torch.randn(num_cameras, 1, width) * 0.02)
        self.blocks = nn.ModuleList(Block(width, heads, mlp_ratio, dropout) for _ in range(depth))
        self.norm = nn.LayerNorm(width)

    def forward(self, images: torch.Tensor, pos3d: torch.Tensor | None = None) -> torch.Tensor:
        """Encode ``images`` ``(B, N, 3, H, W)`` in [0, 1].

        Args:
            images: camera images, ``N`` = the branch's cameras.
            pos3d: ``(B, N, T, width)`` 3D position embedding added to the patch tokens.

        Returns:
            ``(B, N, T, width)`` tokens, ``T = H/p * W/p`` in row-major patch order.
        """
        b, n = images.shape[:2]
        x = self.patch_embed((images.flatten(0, 1) - IMAGE_MEAN) / IMAGE_STD)  # (B*N, T, D)
        x = x.view(b, n, self.num_patches, -1) + self.pos2d + self.cam_embed[:n]
        if pos3d is not None:
            x = x + pos3d
        x = x.flatten(0, 1)
        for blk in self.blocks:
            x = blk(x)
        return self.norm(x).view(b, n, self.num_patches, -1)
