"""Animated GIF / MP4 writing for rendered frames (atomic: ``v2xbench.files.atomic_write``)."""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from v2xbench.files import atomic_write, atomic_write_bytes


def _have_ffmpeg() -> bool:
    return importlib.util.find_spec("imageio_ffmpeg") is not None


def save_video(frames: Sequence[np.ndarray], path: str | Path, fps: int = 10) -> Path:
    """Write frames to an animated GIF (or MP4 when imageio-ffmpeg is installed), atomically.

    The file is written next to ``path`` under a temporary name, fsynced and renamed into place
    (``v2xbench.files.atomic_write``), so a reader never sees a half-written video.

    Args:
        frames: ``(H, W, 3)`` uint8 RGB frames, all the same shape (e.g. from
            :func:`render_topdown`).
        path: destination ending in ``.gif`` or ``.mp4``.
        fps: frames per second (the simulator's 10 Hz plays in real time at 10).

    Returns:
        The written path.

    Raises:
        ValueError: no frames, frames of different shapes or dtypes, bad ``fps`` or suffix.
        RuntimeError: ``.mp4`` asked but no ffmpeg backend (imageio-ffmpeg) is installed.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"save_video: {path.name!r} must end in .gif or .mp4")
    if not isinstance(fps, (int, float)) or not fps > 0:
        raise ValueError(f"save_video: fps={fps!r} must be positive")
    if len(frames) == 0:
        raise ValueError("save_video: no frames to write")
    shape = np.shape(frames[0])
    for i, f in enumerate(frames):
        f = np.asarray(f)
        if f.shape != shape or f.ndim != 3 or f.shape[2] != 3 or f.dtype != np.uint8:
            raise ValueError(
                f"save_video: frame {i} is {f.dtype} {f.shape}; all frames must be "
                f"uint8 (H, W, 3) like frame 0 {shape}"
            )
    if suffix == ".mp4" and not _have_ffmpeg():
        raise RuntimeError(
            f"save_video: writing {path.name!r} needs an ffmpeg backend (pip install "
            "imageio-ffmpeg), which is not installed; save as .gif instead"
        )
    if suffix == ".gif":
        images = [Image.fromarray(np.asarray(f)) for f in frames]
        with atomic_write(path, "wb") as fh:
            images[0].save(
                fh,
                format="GIF",
                save_all=True,
                append_images=images[1:],
                duration=int(round(1000.0 / fps)),
                loop=0,
                optimize=False,
                disposal=1,
            )
    else:  # ffmpeg writes a named .mp4 file: encode in a scratch folder, then write atomically
        import tempfile

        import imageio.v2 as imageio

        with tempfile.TemporaryDirectory(prefix="v2xbench-video-") as scratch:
            scratch_path = Path(scratch) / "video.mp4"
            imageio.mimwrite(
                scratch_path, [np.asarray(f) for f in frames], fps=fps, format="FFMPEG",
                macro_block_size=1
            )
            atomic_write_bytes(path, scratch_path.read_bytes())
    return path


__all__ = ["save_video"]
