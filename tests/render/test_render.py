"""Top-down renderer and video writer: pixels that must be there, and files that must read back.

All renders use ``view_m / size = 120 / 512`` m per pixel (the default scale) on one small town,
so the static map is built once for the whole module.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from v2xbench.envs.v2x_intersection.core.classes import PEDESTRIAN
from v2xbench.envs.v2x_intersection.render import video
from v2xbench.envs.v2x_intersection.render.topdown import (
    EGO_COLOR,
    EGO_SEEN_COLOR,
    LIGHT_COLORS,
    RSU_SEEN_COLOR,
    make_view,
    render_legend,
    render_topdown,
    save_video,
)
from v2xbench.envs.v2x_intersection.sim.config import make_config
from v2xbench.envs.v2x_intersection.sim.world import World
from v2xbench.envs.v2x_intersection.traffic.signals import GREEN, RED

SIZE, VIEW_M = 256, 60.0  # 0.234 m per pixel, as the 512 px / 120 m default


@pytest.fixture(scope="module")
def world() -> World:
    w = World(make_config(town="Town05", num_vehicles=12, num_pedestrians=6, num_bicycles=2))
    w.reset(seed=0)
    for _ in range(20):
        w.step(np.array([0.4, 0.0, 0.0]), w.default_rsu_message())
    return w


def _has_color(img: np.ndarray, color: tuple, center: np.ndarray, radius: int) -> int:
    """Number of pixels exactly ``color`` within ``radius`` pixels of ``center`` (col, row)."""
    c, r = np.round(center).astype(int)
    patch = img[max(r - radius, 0) : r + radius + 1, max(c - radius, 0) : c + radius + 1]
    return int(np.all(patch == np.array(color, np.uint8), axis=-1).sum())


def test_shape_dtype_and_ego_at_centre(world: World) -> None:
    img = render_topdown(world, size=SIZE, view_m=VIEW_M)
    assert img.shape == (SIZE, SIZE, 3) and img.dtype == np.uint8
    view, _ = make_view(world, SIZE, VIEW_M)
    ego_px = view.to_pixel(world.table.pos[0])
    assert np.all(np.abs(ego_px - (SIZE - 1) / 2) <= 0.51)  # the view is centred on the ego
    c = SIZE // 2
    block = img[c - 1 : c + 2, c - 1 : c + 2].reshape(-1, 3)
    assert np.all(block == np.array(EGO_COLOR, np.uint8))
    # the picture is not blank: road, buildings, markings give many distinct colours
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 30


def test_other_sizes_centres_and_legend(world: World) -> None:
    assert render_topdown(world, size=128, view_m=30.0).shape == (128, 128, 3)
    whole = render_topdown(world, size=160, center="map", text=False)
    assert whole.shape == (160, 160, 3)
    assert render_topdown(world, size=SIZE, view_m=VIEW_M, center="rsu").shape == (SIZE, SIZE, 3)
    with_key = render_topdown(world, size=SIZE, view_m=VIEW_M, legend=True)
    strip = render_legend(SIZE)
    assert with_key.shape == (SIZE + strip.shape[0], SIZE, 3)
    assert np.array_equal(with_key[SIZE:], strip)
    with pytest.raises(ValueError, match="center"):
        render_topdown(world, size=SIZE, view_m=VIEW_M, center="nowhere")


def test_traffic_light_pole_takes_its_lane_colour(world: World) -> None:
    lights = world.town.lights
    assert len(lights) > 0
    x, y, _, lane = lights[0]
    saved = world.lane_signal.copy()
    try:
        counts = {}
        for state in (RED, GREEN):
            world.lane_signal = saved.copy()
            world.lane_signal[int(lane)] = state
            img = render_topdown(world, size=SIZE, view_m=VIEW_M, center=(x, y), text=False)
            view, _ = make_view(world, SIZE, VIEW_M, center=(x, y))
            pole = view.to_pixel(np.array([x, y]))
            counts[state] = {
                s: _has_color(img, LIGHT_COLORS[s], pole, radius=3) for s in (RED, GREEN)
            }
    finally:
        world.lane_signal = saved
    assert counts[RED][RED] >= 9 and counts[RED][GREEN] == 0
    assert counts[GREEN][GREEN] >= 9 and counts[GREEN][RED] == 0


def test_visibility_outlines(world: World) -> None:
    t = world.table
    # a vehicle-sized box (not a pedestrian disc), as far as possible from every other actor
    cand = np.flatnonzero(t.active & (t.kind != PEDESTRIAN))
    cand = cand[cand > 0]
    gaps = [np.sort(np.linalg.norm(t.pos[t.active] - t.pos[i], axis=1))[1] for i in cand]
    i = int(cand[int(np.argmax(gaps))])
    saved_ego, saved_rsu = world.ego_vis.copy(), world.rsu_vis.copy()
    centre = tuple(t.pos[i])
    found = {}
    try:
        for ego_v, rsu_v in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)):
            world.ego_vis = np.zeros_like(saved_ego)
            world.rsu_vis = np.zeros_like(saved_rsu)
            world.ego_vis[i], world.rsu_vis[0, i] = ego_v, rsu_v
            img = render_topdown(world, size=SIZE, view_m=VIEW_M, center=centre, text=False)
            px = (SIZE - 1) / 2 * np.ones(2)
            found[(ego_v, rsu_v)] = (
                _has_color(img, EGO_SEEN_COLOR, px, radius=18),
                _has_color(img, RSU_SEEN_COLOR, px, radius=18),
            )
    finally:
        world.ego_vis, world.rsu_vis = saved_ego, saved_rsu
    assert found[(0.0, 0.0)] == (0, 0)
    assert found[(1.0, 0.0)][0] > 10 and found[(1.0, 0.0)][1] == 0
    assert found[(0.0, 1.0)][0] == 0 and found[(0.0, 1.0)][1] > 10
    assert found[(1.0, 1.0)][0] > 10 and found[(1.0, 1.0)][1] > 10


def test_save_gif_round_trip(tmp_path) -> None:
    frames = [np.full((32, 48, 3), 40 * k, np.uint8) for k in range(5)]
    for k, f in enumerate(frames):
        f[k : k + 4, 10:20] = (255, 0, 0)  # make each frame distinct
    out = save_video(frames, tmp_path / "sub" / "clip.gif", fps=10)
    assert out == tmp_path / "sub" / "clip.gif"
    assert [p.name for p in out.parent.iterdir()] == ["clip.gif"]  # no temporary file left
    with Image.open(out) as im:
        assert im.n_frames == 5
        assert im.size == (48, 32)
        assert im.info["duration"] == 100
        im.seek(3)
        assert np.array(im.convert("RGB"))[4, 12].tolist() == [255, 0, 0]


def test_save_video_errors(tmp_path, monkeypatch) -> None:
    frames = [np.zeros((8, 8, 3), np.uint8)] * 2
    monkeypatch.setattr(video, "_have_ffmpeg", lambda: False)
    with pytest.raises(RuntimeError, match=r"\.gif"):
        save_video(frames, tmp_path / "clip.mp4")
    with pytest.raises(ValueError, match="no frames"):
        save_video([], tmp_path / "clip.gif")
    with pytest.raises(ValueError, match="frame 1"):
        save_video([frames[0], np.zeros((9, 8, 3), np.uint8)], tmp_path / "clip.gif")
    with pytest.raises(ValueError, match=".gif or .mp4"):
        save_video(frames, tmp_path / "clip.avi")
    assert list(tmp_path.iterdir()) == []
