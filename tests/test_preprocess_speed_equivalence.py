"""The 0.5 preprocessing speed-ups give the same bits as the frozen 0.3.1 code
(tests/_legacy_preprocess.py): uint8 crops normalised through a table, the occupancy of few
vs many boxes, NaN / huge coordinates on the grid border, row gathers, one-chunk graph calls."""

from __future__ import annotations

import numpy as np
import pytest

import _legacy_preprocess as legacy
from xcalib.data.crops import crop_images, gather_box_points, resample_points
from xcalib.deploy.chunking import run_chunked
from xcalib.geometry.boxes import box_point_pairs, take_rows


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(np.uint32)


@pytest.mark.parametrize("seed", range(12))
def test_uint8_crops_bitwise_equal_legacy(seed):
    r = np.random.default_rng([seed, 5])
    img = r.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    n = int(r.integers(1, 12))
    xy = r.uniform(-40, 170, (n, 2))
    wh = r.uniform(1, 90, (n, 2))
    b = np.hstack([xy, xy + wh])  # many boxes cross the borders: partial crops filled with the mean
    image = img if seed % 2 else img[::-1]  # also a view with negative strides
    for S, keep_aspect, normalize in ((32, True, True), (9, False, False), (16, True, False)):
        want, kw = legacy.crop_images(image, b, S, keep_aspect=keep_aspect, normalize=normalize)
        got, k = crop_images(image, b, S, keep_aspect=keep_aspect, normalize=normalize)
        np.testing.assert_array_equal(k, kw)
        assert got.dtype == np.float32 and got.shape == want.shape and got.flags.c_contiguous
        np.testing.assert_array_equal(_bits(got), _bits(want))  # bit for bit, signs of zeros included


@pytest.mark.parametrize("m", [3, 31, 32, 33, 70])
def test_points_in_boxes_few_and_many_boxes_with_bad_points(m):
    r = np.random.default_rng(m)
    pts = r.uniform([-30, -30, -3], [30, 30, 3], (6000, 3)).astype(np.float32)
    pts[:4] = [[np.nan, 0, 0], [np.inf, 1, 1], [-np.inf, 0, 0], [1e30, -1e30, 0]]
    b7 = np.hstack([r.uniform([-25, -25, -2], [25, 25, 2], (m, 3)), r.uniform(0.5, 9, (m, 3)),
                    r.uniform(-np.pi, np.pi, (m, 1))])
    want = legacy.points_in_boxes(pts[4:], b7, expansion=1.25)  # (0.3.1 loses every pair with an inf point)
    with np.errstate(invalid="ignore"):
        mi, pi = box_point_pairs(pts, b7, expansion=1.25)
    assert want.sum() > 20 and pi.min() >= 4  # NaN, inf and 1e30 points are in no box
    np.testing.assert_array_equal(np.stack([mi, pi - 4]), np.stack(np.nonzero(want)))
    g, c = gather_box_points(pts[4:], b7, 1.25)
    w, wc = legacy.gather_box_points(pts[4:], b7, 1.25)
    np.testing.assert_array_equal(c, wc)
    np.testing.assert_array_equal(_bits(g), _bits(w))


def test_take_rows_equals_fancy_indexing():
    r = np.random.default_rng(0)
    a = r.normal(size=(50, 3)).astype(np.float32)
    for idx in (r.integers(0, 50, 200), r.integers(0, 50, (4, 7)), np.zeros(0, np.int64)):
        got = take_rows(a, idx)
        assert got.shape == a[idx].shape and got.dtype == a.dtype
        np.testing.assert_array_equal(got, a[idx])
    strided = r.normal(size=(50, 4))[:, :3]  # not C-contiguous: plain indexing
    np.testing.assert_array_equal(take_rows(strided, [3, 1, 3]), strided[[3, 1, 3]])


def test_resample_points_same_stream_as_legacy():
    r = np.random.default_rng(3)
    counts = np.array([1, 5, 64, 200, 7])
    pts = r.normal(size=(counts.sum(), 3)).astype(np.float32)
    got = resample_points(pts, counts, 64, np.random.default_rng(9))
    want = legacy.resample_points(pts, counts, 64, np.random.default_rng(9))
    np.testing.assert_array_equal(_bits(got), _bits(want))


def test_run_chunked_one_call_and_chunks_agree():
    feeds = {"a": np.arange(10.0), "b": np.arange(10.0) * 2}
    calls = []

    def fn(f):
        calls.append(len(f["a"]))
        return {"s": f["a"] + f["b"]}

    one = run_chunked(fn, feeds, None)
    chunked = run_chunked(fn, feeds, 3)
    np.testing.assert_array_equal(one["s"], chunked["s"])
    assert calls == [10, 3, 3, 3, 1]
    with pytest.raises(ValueError):
        run_chunked(fn, {"a": np.zeros(2), "b": np.zeros(3)}, None)
