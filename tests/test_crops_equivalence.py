"""The vectorised crops and the grid points-in-boxes reproduce the 0.3.1 preprocessing bit for bit
(``_legacy_preprocess``, frozen), so ``Matcher.match`` outputs are what they were: random frames
with edge cases (boxes across borders, on pixel edges, NaN, float and non-contiguous images,
points on box faces, yawed boxes) and, when present, the 16 real A9 frames end to end."""

from __future__ import annotations

import numpy as np
import pytest

import _legacy_preprocess as legacy
from _matching_frames import TINY
from conftest import shared_path
from xcalib.data.crops import CropConfig, crop_images, crop_points, gather_box_points, prepare_frame
from xcalib.engine.matcher import Matcher
from xcalib.geometry.boxes import as_box7, box_point_pairs, points_in_boxes


def _random_boxes2d(r: np.random.Generator) -> np.ndarray:
    K = int(r.integers(0, 14))
    xy = r.uniform(-100, 450, (K, 2))
    wh = r.uniform(-5, 300, (K, 2)) * r.random((K, 1)) ** 2
    b = np.hstack([xy, xy + wh])
    if r.random() < 0.3:
        b = np.round(b) + (r.random(b.shape) < 0.3) * 0.5  # on pixel edges and half pixels
    if K and r.random() < 0.2:
        b[0, r.integers(0, 4)] = np.nan
    return b


@pytest.mark.parametrize("seed", range(40))
def test_crop_images_equal_legacy(seed):
    r = np.random.default_rng(seed)
    img = r.integers(0, 255, (300, 400, 3), dtype=np.uint8)
    image = [img, img[:, ::-1], img.astype(np.float32) / 255][seed % 3]
    b = _random_boxes2d(r)
    for S, keep_aspect, normalize in ((32, True, True), (7, False, seed % 2 == 0)):
        want, kept_want = legacy.crop_images(image, b, S, keep_aspect=keep_aspect, normalize=normalize)
        got, kept = crop_images(image, b, S, keep_aspect=keep_aspect, normalize=normalize)
        np.testing.assert_array_equal(kept, kept_want)
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(40))
def test_points_in_boxes_equal_legacy(seed):
    r = np.random.default_rng(seed)
    pts = r.uniform(-20, 20, size=(int(r.integers(0, 4000)), 3 + seed % 2)).astype(np.float32)
    m = int(r.integers(0, 16))
    b7 = np.hstack([r.uniform(-18, 18, (m, 3)), r.uniform(0.5, 8, (m, 3)),
                    r.uniform(-np.pi, np.pi, (m, 1)) * (seed % 2)])
    if seed % 3 == 0:  # points and boxes on a 0.1 m lattice: many points exactly on faces
        pts, b7 = np.round(pts, 1), np.round(b7, 1)
    for expansion in (1.0, 1.25):
        want = legacy.points_in_boxes(pts, b7, expansion=expansion)
        got = points_in_boxes(pts, b7, expansion=expansion)
        assert got.shape == want.shape
        np.testing.assert_array_equal(got, want)
        mi, pi = box_point_pairs(pts, b7, expansion=expansion)
        np.testing.assert_array_equal(np.stack([mi, pi]), np.stack(np.nonzero(want)))
        g_pts, g_counts = gather_box_points(pts, b7, expansion)
        w_pts, w_counts = legacy.gather_box_points(pts, b7, expansion)
        np.testing.assert_array_equal(g_counts, w_counts)
        np.testing.assert_array_equal(g_pts, w_pts)


def test_points_far_outside_the_boxes_and_protocol_boxes():
    pts = np.array([[1e6, 0, 0], [-1e6, 5, 1], [1, 1, 1], [1.0, 1.0, 2.0], [np.nan, 1, 1]], dtype=np.float32)
    ext = np.array([[0, 0, 0, 2, 2, 2], [0.5, 0.5, 0.5, 1.5, 1.5, 1.5]], dtype=float)
    want = legacy.points_in_boxes(pts[:4], ext)
    np.testing.assert_array_equal(points_in_boxes(pts[:4], ext), want)
    np.testing.assert_array_equal(points_in_boxes(pts[:4], ext), [[0, 0, 1, 1], [0, 0, 1, 0]])
    with np.errstate(invalid="ignore"):
        assert not points_in_boxes(pts, ext)[:, 4].any()  # a NaN point is in no box


def _frames():
    from xcalib.io.frames import read_frames

    root = shared_path("a9_sample")
    return [read_frames(root / f"frame_{i:04d}")[0] for i in range(16)]


@pytest.mark.shared_data
def test_a9_match_outputs_equal_legacy():
    """Every A9 frame: the model inputs equal the 0.3.1 preprocessing, hence the matches."""
    m = Matcher.from_pretrained("fastmatch", site="synthetic", device="cpu")
    cfg: CropConfig = m.crop_config
    for f in _frames():
        inp = prepare_frame(f.image, f.point_cloud, f.bboxes_2d, f.bboxes_3d, cfg)
        c2, k2 = legacy.crop_images(f.image, f.bboxes_2d, cfg.crop_size)
        c3, b7, counts, k3 = legacy.crop_points(f.point_cloud, f.bboxes_3d, cfg.point_cloud_size,
                                                expansion=cfg.bbox_expansion, rng=np.random.default_rng(cfg.seed))
        for got, want in ((inp.crops_2d, c2), (inp.kept_2d, k2), (inp.crops_3d, c3), (inp.boxes_3d, b7),
                          (inp.point_counts, counts), (inp.kept_3d, k3)):
            np.testing.assert_array_equal(got, want)
        old = legacy_inputs(f, cfg)
        np.testing.assert_array_equal(m.match(*f.inputs(), validate="off", geometry="off").similarity,
                                      m.similarity(old))


def legacy_inputs(f, cfg: CropConfig):
    """FrameInputs of one frame made by the frozen 0.3.1 preprocessing."""
    from xcalib.data.crops import FrameInputs

    c2, k2 = legacy.crop_images(f.image, f.bboxes_2d, cfg.crop_size, keep_aspect=cfg.keep_aspect,
                                normalize=cfg.normalize)
    c3, b7, counts, k3 = legacy.crop_points(f.point_cloud, f.bboxes_3d, cfg.point_cloud_size,
                                            expansion=cfg.bbox_expansion, rng=np.random.default_rng(cfg.seed))
    b2 = np.asarray(f.bboxes_2d, dtype=np.float64).reshape(-1, 4)
    return FrameInputs(c2, c3, b2[k2].astype(np.float32), b7, counts, (f.image.shape[1], f.image.shape[0]), k2, k3)


def test_tiny_frames_crop_points_equal_legacy():
    from _matching_frames import make_frame

    for seed in range(6):
        f = make_frame(seed, n_obj=5)
        for n in (TINY["fastmatch"]["point_cloud_size"], 7):
            got = crop_points(f.point_cloud, f.bboxes_3d, n, rng=np.random.default_rng(seed))
            want = legacy.crop_points(f.point_cloud, f.bboxes_3d, n, rng=np.random.default_rng(seed))
            for g, w in zip(got, want):
                np.testing.assert_array_equal(g, w)
        np.testing.assert_array_equal(as_box7(f.bboxes_3d)[:, 6], 0.0)


def test_non_finite_boxes_hold_no_points():
    pts = np.array([[1, 1, 1], [5, 5, 5]], dtype=np.float32)
    b7 = np.array([[1, 1, 1, 2, 2, 2, 0], [np.nan, 1, 1, 2, 2, 2, 0], [5, 5, 5, 1, 1, 1, np.inf]])
    with np.errstate(invalid="ignore"):
        np.testing.assert_array_equal(points_in_boxes(pts, b7), [[1, 0], [0, 0], [0, 0]])
