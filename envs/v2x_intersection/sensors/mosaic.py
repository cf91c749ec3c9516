"""One picture of a captured frame, for videos: cameras, RSU view, BEV and LiDAR from above.

Layout (three columns, each as wide as a camera tile; camera tiles are the images scaled up by
an integer factor to about 256 pixels wide)::

    front-left      front           front-right
    back-left       back            back-right
    RSU camera      BEV             LiDAR top view
    RSU semantic

The BEV is drawn in colour (map in greys, vehicles blue, VRUs pink, the ego orange, signals on
their stop lines); the LiDAR view is north = ego forward, ego object returns coloured by semantic id,
ego ground returns in grey by intensity (lane paint is bright), RSU points (moved into the ego
frame with the calibration) in magenta, the active RSU a white square. Use :func:`..render.save_video` to write a list of mosaics to GIF/MP4.
"""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw

from ..render.topdown import font as _font
from .bev import BEV_CHANNELS
from .camera import EGO_CAMERA_NAMES
from .semantics import NUM_CLASSES, SEMANTIC_COLORS

_GRID = (
    ("cam_front_left", "cam_front", "cam_front_right"),
    ("cam_back_left", "cam_back", "cam_back_right"),
)
_BEV_COLORS = {
    "drivable": (92, 94, 100),
    "parking": (118, 112, 104),
    "sidewalk": (170, 160, 142),
    "crosswalk": (206, 206, 206),
    "lane_marking": (245, 245, 245),
    "lane_centerline": (86, 140, 220),
    "obstacle": (58, 58, 66),
    "light_green": (40, 220, 90),
    "light_yellow": (255, 205, 0),
    "light_red": (240, 30, 30),
    "stop_sign": (190, 0, 40),
    "vehicle": (60, 120, 255),
    "vru": (255, 60, 150),
    "ego": (255, 140, 0),
}
_LIDAR_RANGE = 45.0  # m from the ego to the edge of the LiDAR view


def _label(img: Image.Image, text: str, xy: tuple[int, int]) -> None:
    d = ImageDraw.Draw(img)
    font = _font(11)
    w = d.textlength(text, font=font)
    d.rectangle((xy[0], xy[1], xy[0] + w + 6, xy[1] + 14), fill=(0, 0, 0))
    d.text((xy[0] + 3, xy[1] + 1), text, fill=(255, 255, 255), font=font)


def _scale(img: np.ndarray, tw: int, th: int) -> np.ndarray:
    return np.asarray(Image.fromarray(img).resize((tw, th), Image.Resampling.NEAREST))


def bev_image(bev: np.ndarray) -> np.ndarray:
    """Colour picture ``(H, W, 3)`` uint8 of a BEV stack ``(C, H, W)``."""
    out = np.full(bev.shape[1:] + (3,), 34, np.uint8)
    for name, col in _BEV_COLORS.items():
        out[bev[BEV_CHANNELS.index(name)] > 0] = col
    return out


def lidar_image(frame: dict, size: int) -> np.ndarray:
    """Top view ``(size, size, 3)`` uint8 of the ego (and RSU) LiDAR points, ego forward up."""
    img = np.full((size, size, 3), 16, np.uint8)
    mpp = 2 * _LIDAR_RANGE / size
    cal = frame.get("calibration", {})

    def plot(pts: np.ndarray, t_ego_sensor: np.ndarray, colors: np.ndarray) -> None:
        p = pts[:, :3] @ t_ego_sensor[:3, :3].T + t_ego_sensor[:3, 3]
        r = (size / 2 - p[:, 0] / mpp).astype(np.int64)
        c = (size / 2 - p[:, 1] / mpp).astype(np.int64)
        ok = (r >= 0) & (r < size) & (c >= 0) & (c < size)
        order = np.argsort(pts[ok, 4] < NUM_CLASSES, kind="stable")  # objects drawn last
        img[r[ok][order], c[ok][order]] = colors[ok][order]

    lid = frame.get("lidars", {})
    if "rsu_lidar" in lid and "rsu_lidar" in cal and frame.get("rsu_unit", -1) >= 0:
        pts = lid["rsu_lidar"]["points"]
        obj = pts[:, 4] < NUM_CLASSES
        col = np.where(obj[:, None], np.array([255, 70, 255]), np.array([96, 36, 100])).astype(
            np.uint8
        )
        plot(pts, cal["rsu_lidar"]["T_ego_sensor"], col)
    if "lidar" in lid and "lidar" in cal:
        pts = lid["lidar"]["points"]
        sem = pts[:, 4].astype(np.int64)
        col = SEMANTIC_COLORS[sem].astype(np.float32)
        grey = 70.0 + 250.0 * np.sqrt(pts[:, 3])  # ground: grey by intensity (paint is bright)
        col[sem >= NUM_CLASSES] = np.minimum(grey, 255.0)[sem >= NUM_CLASSES, None] * (
            0.55,
            0.65,
            0.6,
        )
        plot(pts, cal["lidar"]["T_ego_sensor"], col.astype(np.uint8))
    pil = Image.fromarray(img)
    d = ImageDraw.Draw(pil)
    hl, hw = 2.35 / mpp, 0.95 / mpp
    d.rectangle((size / 2 - hw, size / 2 - hl, size / 2 + hw, size / 2 + hl), outline=(255, 140, 0))
    if "T_ego_rsu" in cal and frame.get("rsu_unit", -1) >= 0:
        x, y = cal["T_ego_rsu"][:2, 3]
        cx, cy = size / 2 - y / mpp, size / 2 - x / mpp
        d.rectangle((cx - 3, cy - 3, cx + 3, cy + 3), fill=(255, 255, 255), outline=(255, 0, 255))
    return np.asarray(pil)


def mosaic(frame: dict, tile_width: int = 256) -> np.ndarray:
    """Lay out a frame from :meth:`.rig.SensorRig.capture` as one RGB image.

    Args:
        frame: a captured frame (missing sensors leave grey tiles).
        tile_width: target width of a camera tile (pixels; the actual width is the camera
            width times the nearest integer scale).

    Returns:
        ``(H, 3 * tile, 3)`` uint8 RGB image.
    """
    cams = frame.get("cameras", {})
    ref = next((c["rgb"] for n, c in cams.items() if n in EGO_CAMERA_NAMES), None)
    ch, cw = ref.shape[:2] if ref is not None else (64, 128)
    s = max(1, int(round(tile_width / cw)))
    tw, th = cw * s, ch * s
    canvas = Image.new("RGB", (3 * tw, 2 * th + 2 * th), (60, 60, 60))
    for r, row in enumerate(_GRID):
        for c, name in enumerate(row):
            if name in cams:
                canvas.paste(Image.fromarray(_scale(cams[name]["rgb"], tw, th)), (c * tw, r * th))
            _label(canvas, name.replace("cam_", ""), (c * tw + 3, r * th + 3))
    y0 = 2 * th
    if "rsu_cam" in cams:
        rc = cams["rsu_cam"]
        canvas.paste(Image.fromarray(_scale(rc["rgb"], tw, th)), (0, y0))
        canvas.paste(Image.fromarray(_scale(SEMANTIC_COLORS[rc["semantic"]], tw, th)), (0, y0 + th))
        unit = frame.get("rsu_unit", -1)
        _label(canvas, f"RSU {unit}" if unit >= 0 else "no RSU", (3, y0 + 3))
        _label(canvas, "RSU semantic", (3, y0 + th + 3))
    side = min(tw, 2 * th)
    if "bev" in frame:
        b = bev_image(frame["bev"])
        canvas.paste(Image.fromarray(_scale(b, side, side)), (tw + (tw - side) // 2, y0))
        _label(canvas, "BEV", (tw + 3, y0 + 3))
    if frame.get("lidars"):
        canvas.paste(Image.fromarray(lidar_image(frame, side)), (2 * tw + (tw - side) // 2, y0))
        _label(canvas, "LiDAR ego + RSU", (2 * tw + 3, y0 + 3))
    return np.asarray(canvas, dtype=np.uint8)


__all__ = ["bev_image", "lidar_image", "mosaic"]
