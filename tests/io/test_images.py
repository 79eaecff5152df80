"""PNG writers, depth colour mapping, render-vs-input panels and plots."""

from __future__ import annotations

import cv2
import matplotlib
import numpy as np
import pytest

from gsjax.io.images import (
    COLOR_ERROR_RANGE,
    DEPTH_ERROR_RANGE_M,
    LABEL_HEIGHT,
    colorize_depth,
    colorize_error,
    render_panel,
    save_color_png,
    save_depth_png,
    to_uint8,
)
from gsjax.io.plots import plot_errors_over_time, plot_trajectory_top_view, top_view_axes


def test_colour_png_round_trips_in_rgb_order(tmp_path):
    rng = np.random.default_rng(0)
    color = rng.random((9, 13, 3))
    color[0, 0] = [1.0, 0.0, 0.0]  # pure red stays red (no BGR mix-up)
    color[0, 1] = [1.7, -0.2, np.nan]  # clipped, NaN -> 0
    save_color_png(tmp_path / "c.png", color)
    back = cv2.cvtColor(cv2.imread(str(tmp_path / "c.png"), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(back, to_uint8(color))
    assert back[0, 0].tolist() == [255, 0, 0] and back[0, 1].tolist() == [255, 0, 0]
    assert np.abs(back[1:].astype(float) / 255 - color[1:]).max() <= 0.5 / 255 + 1e-12


def test_depth_png_stores_scaled_16_bit_depth_with_zero_for_invalid(tmp_path):
    depth = np.array([[1.2345, 0.0], [np.nan, 4.0]])
    save_depth_png(tmp_path / "d.png", depth, scale=5000.0)
    back = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16
    assert back.tolist() == [[6172, 0], [0, 20000]]
    with pytest.raises(ValueError, match="does not fit"):
        save_depth_png(tmp_path / "far.png", np.array([[14.0]]), scale=5000.0)


def test_colorize_depth_maps_the_range_through_the_colormap_and_blacks_out_invalid():
    depth = np.array([[1.0, 2.0, 3.0, 0.0]])
    rgb = colorize_depth(depth, vmin=1.0, vmax=3.0, cmap="viridis")
    cmap = matplotlib.colormaps["viridis"]
    assert rgb[0, 0].tolist() == to_uint8(np.array([[cmap(0.0)[:3]]]))[0, 0].tolist()
    assert rgb[0, 2].tolist() == to_uint8(np.array([[cmap(1.0)[:3]]]))[0, 0].tolist()
    assert rgb[0, 3].tolist() == [0, 0, 0]


def test_render_panel_lays_out_labelled_render_input_and_error_tiles_enlarged_to_the_minimum_width():
    h, w, gap = 5, 7, 2
    render, inp = np.full((h, w, 3), 0.2), np.full((h, w, 3), 0.8)
    inp[0, 0] = 0.2  # one pixel without colour error
    depth_gt = np.linspace(1, 2, h * w).reshape(h, w)
    depth_gt[4, 6] = 0.0  # invalid input depth: black in the depth error map
    depth = depth_gt + 0.05
    panel = render_panel(render, inp, depth, depth_gt, min_width=20, gap=gap)
    zoom = 3  # the smallest integer factor making 7 px at least 20 px wide
    th, tw = LABEL_HEIGHT + zoom * h, zoom * w  # a tile with its label strip
    assert panel.shape == (2 * th + gap, 3 * tw + 2 * gap, 3)

    def tile(row, col):
        top, left = row * (th + gap) + LABEL_HEIGHT, col * (tw + gap)
        return panel[top : top + zoom * h : zoom, left : left + tw : zoom]  # back to one pixel per input pixel

    def strip(row, col):
        top, left = row * (th + gap), col * (tw + gap)
        return panel[top : top + LABEL_HEIGHT, left : left + tw]

    lo, hi = np.percentile(depth_gt[depth_gt > 0], [1, 99])
    assert (tile(0, 0) == to_uint8(render)).all() and (tile(0, 1) == to_uint8(inp)).all()
    color_error = np.abs(render - inp).mean(axis=-1)
    assert (tile(0, 2) == colorize_error(color_error, COLOR_ERROR_RANGE)).all()
    assert tile(0, 2)[0, 0].tolist() == colorize_error(np.zeros((1, 1)), 1.0)[0, 0].tolist()
    assert (tile(1, 0) == colorize_depth(depth, lo, hi)).all()
    assert (tile(1, 1) == colorize_depth(depth_gt, lo, hi)).all()
    assert (tile(1, 2) == colorize_error(np.abs(depth - depth_gt), DEPTH_ERROR_RANGE_M, depth_gt > 0)).all()
    assert tile(1, 2)[4, 6].tolist() == [0, 0, 0]
    for row in range(2):
        for col in range(3):  # white strips with dark label text
            assert (strip(row, col) < 128).any() and np.mean(strip(row, col) == 255) > 0.6
    assert (panel[th : th + gap] == 255).all() and (panel[:, tw : tw + gap] == 255).all()
    assert render_panel(render, inp, min_width=20, gap=gap).shape == (th, 3 * tw + 2 * gap, 3)
    with pytest.raises(ValueError, match="give both"):
        render_panel(render, inp, depth)


def test_colorize_error_clips_at_the_range_and_blacks_out_invalid_pixels():
    error = np.array([[0.0, 0.05, 0.2, np.nan]])
    rgb = colorize_error(error, 0.1, valid=np.array([[True, True, True, True]]), cmap="viridis")
    cmap = matplotlib.colormaps["viridis"]
    assert rgb[0, 1].tolist() == to_uint8(np.array([[cmap(0.5)[:3]]]))[0, 0].tolist()
    assert rgb[0, 2].tolist() == to_uint8(np.array([[cmap(1.0)[:3]]]))[0, 0].tolist()
    assert rgb[0, 3].tolist() == [0, 0, 0]


def _read_png(path):
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert image is not None, f"{path} is not a readable PNG"
    return image


def test_trajectory_plot_and_error_plot_write_png_images(tmp_path):
    s = np.linspace(0, 2 * np.pi, 50)
    gt = np.stack([np.cos(s), 0.05 * np.sin(5 * s), np.sin(s)], 1)
    est = gt + 0.02
    top = _read_png(plot_trajectory_top_view(tmp_path / "top.png", est, gt, title="ATE 2 cm"))
    assert top.shape[0] > 200 and top.shape[1] > 200 and top.std() > 5  # a picture, not a blank canvas
    err = _read_png(plot_errors_over_time(tmp_path / "err.png", s, {"ATE (cm)": np.full(50, 2.0)}))
    assert err.shape[1] > 300
    with pytest.raises(ValueError, match="plane"):
        plot_trajectory_top_view(tmp_path / "x.png", est, gt, plane="xx")


def test_top_view_uses_the_two_widest_axes():
    points = np.array([[0.0, 0.0, 0.0], [3.0, 0.1, -2.0], [1.0, -0.1, 1.0]])
    assert top_view_axes(points) == (0, 2)
