"""xcalib.data.crops: image and LiDAR crops."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.data.crops import (IMAGENET_MEAN, IMAGENET_STD, CropConfig, crop_images, crop_points,
                               prepare_frame, resample_points)


def test_image_crop_keeps_aspect_and_normalises():
    img = np.zeros((100, 200, 3), np.uint8)
    img[40:60, 50:150] = 255  # a 100x20 white bar
    crops, kept = crop_images(img, [[50, 40, 150, 60]], 20)
    assert kept.tolist() == [0] and crops.shape == (1, 3, 20, 20)
    white = (1 - IMAGENET_MEAN) / IMAGENET_STD
    black = -IMAGENET_MEAN / IMAGENET_STD
    col = crops[0, 0, :, 10]
    # the bar fills only the middle rows (aspect kept: 100x20 box -> 20x4 rows of the crop)
    assert np.allclose(col[8:12], white[0], atol=1e-4) and np.allclose(col[:6], black[0], atol=1e-4)


def test_image_crop_outside_parts_are_zero_and_bad_boxes_dropped():
    img = np.full((50, 50, 3), 255, np.uint8)
    boxes = [[-25, 0, 25, 50], [10, 10, 5, 20], [60, 0, 80, 10], [np.nan, 0, 5, 5], [0, 0, 10, 10]]
    crops, kept = crop_images(img, boxes, 10)
    assert kept.tolist() == [0, 4]
    assert np.allclose(crops[0, :, :, :5], 0.0, atol=1e-5)  # left half outside the image -> mean fill
    assert crops[0, :, :, 5:].min() > 1.0


def test_point_crops_are_yaw_aware_box_frame_and_not_padded_at_origin():
    rng = np.random.default_rng(0)
    # a thin box rotated by 45 degrees around z, centred at (10, 5, 0)
    yaw = np.pi / 4
    local = rng.uniform(-0.5, 0.5, size=(500, 3)) * [4.0, 0.5, 1.0]
    c, s = np.cos(yaw), np.sin(yaw)
    world = np.stack([c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1], local[:, 2]], 1) + [10, 5, 0]
    noise = rng.uniform(-20, 20, size=(2000, 3))
    pc = np.concatenate([world, noise]).astype(np.float32)
    box7 = np.array([[10, 5, 0, 4.0, 0.5, 1.0, yaw]])
    crops, b7, counts, kept = crop_points(pc, box7, 1024, expansion=1.0)
    assert kept.tolist() == [0] and counts[0] >= 500 and counts[0] < 520
    pts = crops[0]
    assert np.abs(pts[:, 0]).max() <= 2.0 + 1e-4 and np.abs(pts[:, 1]).max() <= 0.25 + 1e-4  # box frame
    assert not np.any(np.all(pts == 0, axis=1))  # padding repeats real points, never (0,0,0)
    assert len(np.unique(pts, axis=0)) == counts[0]  # every point used at least once


def test_resampling_is_seeded_and_subsamples_without_replacement():
    pts = np.arange(300 * 3, dtype=np.float32).reshape(300, 3)
    a = resample_points(pts, np.array([200, 100]), 150, np.random.default_rng(1))
    b = resample_points(pts, np.array([200, 100]), 150, np.random.default_rng(1))
    assert np.array_equal(a, b)
    assert len(np.unique(a[0], axis=0)) == 150  # 200 -> 150 without replacement
    assert np.all(a[0][:, 0] < 600) and np.all(a[1][:, 0] >= 600)  # groups never mix
    with pytest.raises(ValueError, match="counts"):
        resample_points(pts, np.array([0]), 4, np.random.default_rng(0))


def test_prepare_frame_drops_empty_and_degenerate_with_index_maps():
    img = np.zeros((480, 640, 3), np.uint8)
    pc = np.random.default_rng(0).uniform(-1, 1, size=(1000, 3)).astype(np.float32) + [10, 0, 0]
    b2 = np.array([[0, 0, 10, 10], [5, 5, 1, 1], [100, 100, 200, 200]], np.float32)
    b3 = np.array([[50, 50, 0, 1, 1, 1], [10, 0, 0, 2, 2, 2], [10, 0, 0, 0, 2, 2]], np.float32)
    fi = prepare_frame(img, pc, b2, b3, CropConfig(point_cloud_size=16))
    assert fi.kept_2d.tolist() == [0, 2] and fi.kept_3d.tolist() == [1]
    assert fi.crops_3d.shape == (1, 16, 3) and np.allclose(fi.boxes_2d, b2[[0, 2]])
    fi2 = prepare_frame(img, pc, b2, b3, CropConfig(point_cloud_size=16))
    assert np.array_equal(fi.crops_3d, fi2.crops_3d)  # deterministic by default
    empty = prepare_frame(img, pc, np.zeros((0, 4)), np.zeros((0, 6)))
    assert empty.empty and empty.crops_2d.shape[0] == 0 and empty.crops_3d.shape[0] == 0


def test_multi_camera_crops_use_each_boxes_camera():
    a = np.zeros((480, 640, 3), np.uint8)
    b = np.full((480, 640, 3), 255, np.uint8)
    pc = np.zeros((10, 3), np.float32)
    fi = prepare_frame(a, pc, [[0, 0, 50, 50], [0, 0, 50, 50], [0, 0, 50, 50]], np.zeros((0, 6)),
                       images={"A": a, "B": b}, camera_per_det=["B", "A", "C"])
    assert fi.kept_2d.tolist() == [0, 1]
    assert fi.crops_2d[0].mean() > fi.crops_2d[1].mean()
