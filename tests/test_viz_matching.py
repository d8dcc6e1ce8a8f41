"""Matching overlay: layout, BEV orientation (not mirrored), score colours, unmatched and wrong pairs."""

from __future__ import annotations

import numpy as np
import pytest

import xcalib
from xcalib.types import MatchResult
from xcalib.viz.matching import _HEADER, _PAD, bev_view, draw_matching_overlay, score_colors


def _scene():
    image = np.full((300, 400, 3), 60, np.uint8)
    b2 = np.array([[40, 100, 120, 200], [250, 80, 330, 180], [150, 20, 180, 60]], np.float32)
    # box7: (x, y, z, l, w, h, yaw); two boxes ahead (+x), one left (+y), one right (-y)
    b7 = np.array([[20, 6, 0, 4.5, 1.8, 1.5, 0.0], [20, -6, 0, 4.5, 1.8, 1.5, 0.3],
                   [35, 0, 0, 4.5, 1.8, 1.5, 0.0]], np.float32)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0, 50, 3000), rng.uniform(-20, 20, 3000), rng.uniform(-2, 0, 3000)])
    return image, pts.astype(np.float32), b2, b7


def _pane(out, height):
    left_w = int(round(400 * height / 300))
    x0 = _PAD + left_w + _PAD
    return out[_HEADER:_HEADER + height, x0:], out[_HEADER:_HEADER + height, _PAD:_PAD + left_w]


def test_bev_axes_are_not_mirrored():
    v = bev_view(np.zeros((0, 2)), np.array([[0.0, -10.0], [40.0, 10.0]]), 400, 400)
    px = v.to_pixels(np.array([[20.0, 5.0], [20.0, -5.0], [30.0, 0.0], [10.0, 0.0]]))
    assert px[0, 0] < px[1, 0]  # +y (left in a right-handed top view) is drawn to the left
    assert px[2, 1] < px[3, 1]  # +x is drawn upward
    assert v.scale == pytest.approx(min(400 / (v.x_max - v.x_min), 400 / (v.y_max - v.y_min)))


def test_layout_and_lazy_export():
    image, pts, b2, b7 = _scene()
    out = xcalib.draw_matching_overlay(image, pts, b2, b7, [(0, 0, 0.9)], output_height=300)
    assert out.dtype == np.uint8 and out.ndim == 3 and out.shape[2] == 3
    assert out.shape[0] > 300
    _, left = _pane(out, 300)
    assert np.all(left[150, 200:240] == 60) or np.all(left[250, 200:240] == 60)  # the image itself is shown


def test_matched_box_takes_score_colour_and_lands_on_the_correct_side():
    image, _, b2, b7 = _scene()
    # C0 <-> L0 (y=+6: must be drawn left of the pane centre), score 1 -> green
    out = draw_matching_overlay(image, None, b2, b7, [(0, 0, 1.0)], output_height=300)
    pane, left = _pane(out, 300)
    green = tuple(score_colors(np.array([1.0]))[0])
    mask = np.all(pane == green, axis=2)
    cols = np.nonzero(mask)[1]
    assert len(cols) > 20 and cols.mean() < pane.shape[1] / 2
    # the matched 2D box outline is green on the image pane too
    assert np.all(left == green, axis=2).sum() > 50
    # a low score is drawn red-ish instead
    out_low = draw_matching_overlay(image, None, b2, b7, [(0, 0, 0.0)], output_height=300)
    red = tuple(score_colors(np.array([0.0]))[0])
    assert np.all(_pane(out_low, 300)[0] == red, axis=2).sum() > 20
    assert np.all(_pane(out_low, 300)[0] == green, axis=2).sum() == 0


def test_wrong_pairs_are_marked_only_when_wrong():
    image, pts, b2, b7 = _scene()
    truth = np.zeros((3, 3), bool)
    truth[0, 0] = truth[1, 1] = True
    wrong_red = np.array([255, 60, 60])
    ok = draw_matching_overlay(image, pts, b2, b7, [(0, 0, 0.9), (1, 1, 0.8)], match_matrix=truth)
    bad = draw_matching_overlay(image, pts, b2, b7, [(0, 1, 0.9), (1, 0, 0.8)], match_matrix=truth)
    body = slice(_HEADER, -40)
    assert np.all(ok[body] == wrong_red, axis=2).sum() == 0
    assert np.all(bad[body] == wrong_red, axis=2).sum() > 40


def test_accepts_match_result_protocol_boxes_and_threshold():
    image, pts, b2, b7 = _scene()
    b6 = np.hstack([b7[:, :3] - b7[:, 3:6] / 2, b7[:, :3] + b7[:, 3:6] / 2])  # extents convention
    mr = MatchResult(similarity=np.eye(3, dtype=np.float32), top_indices=np.arange(3), matches=[(0, 0, 0.9), (2, 2, 0.1)],
                     kept_2d_indices=np.arange(3), kept_3d_indices=np.arange(3))
    a = draw_matching_overlay(image, pts, b2, b6, mr)
    b = draw_matching_overlay(image, pts, b2, b6, mr, match_threshold=0.5)
    assert a.shape == b.shape and not np.array_equal(a, b)  # the 0.1 pair is dropped


def test_bad_inputs_name_the_argument():
    image, pts, b2, b7 = _scene()
    with pytest.raises(ValueError, match="matches"):
        draw_matching_overlay(image, pts, b2, b7, [(5, 0, 1.0)])
    with pytest.raises(ValueError, match="match_matrix"):
        draw_matching_overlay(image, pts, b2, b7, [(0, 0, 1.0)], match_matrix=np.zeros((2, 2), bool))
    with pytest.raises(ValueError, match="image"):
        draw_matching_overlay(image[..., 0], pts, b2, b7)
    with pytest.raises(ValueError, match="bev_range"):
        draw_matching_overlay(image, pts, b2, b7, bev_range=(10, 0, 0, 5))


def test_camera_wedge_is_drawn():
    image, pts, b2, b7 = _scene()
    intr = xcalib.CameraIntrinsics(300.0, 300.0, 200.0, 150.0)
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]  # LiDAR x forward -> camera z
    a = draw_matching_overlay(image, None, b2, b7, camera=(intr, T), bev_range=(-5, 45, -20, 20))
    b = draw_matching_overlay(image, None, b2, b7, bev_range=(-5, 45, -20, 20))
    amber = np.array([255, 200, 0])
    assert np.all(a == amber, axis=2).sum() > 30 and np.all(b == amber, axis=2).sum() == 0
