"""Detector-like 2D boxes (xcalib.data.synth.detector, realism ``detector_*`` conditions): deterministic,
and each habit produces what it claims."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.data.synth.detector import OUTLINE_SHRINK, DetectorStyle
from xcalib.data.synth.realism import REALISM_CONDITIONS, make_realism_case

SEED = 0  # an identifiable roadside site
W, H = 1920, 1200


def _cat(case, key):
    return np.concatenate([np.asarray(f.meta[key]) for f in case.frames])


def test_detector_conditions_are_registered_and_deterministic():
    names = [n for n in REALISM_CONDITIONS if n.startswith("detector_")]
    assert set(names) >= {"detector_outline", "detector_truncation", "detector_merge", "detector_misses",
                          "detector_scores", "detector_all"}
    a, b = make_realism_case("detector_all", SEED, 4), make_realism_case("detector_all", SEED, 4)
    for fa, fb in zip(a.frames, b.frames):
        assert np.array_equal(fa.bboxes_2d, fb.bboxes_2d)
        assert fa.detections.scores_2d == fb.detections.scores_2d
    clean = make_realism_case("clean", SEED, 4)
    assert not all(np.array_equal(fa.bboxes_2d, fc.bboxes_2d) for fa, fc in zip(a.frames, clean.frames))
    with pytest.raises(ValueError):
        DetectorStyle(merge_prob=1.5)


def test_outline_is_narrower_and_lower_than_the_corner_box_for_vehicles():
    case = make_realism_case("detector_outline", SEED, 10)
    b, cb = np.concatenate([f.bboxes_2d for f in case.frames]).astype(float), _cat(case, "boxes_2d_corner")
    cls = np.array(sum((list(f.meta["classes_2d"]) for f in case.frames), []))
    inner = np.isfinite(cb[:, 0]) & (cb[:, 0] > 1) & (cb[:, 2] < W - 1) & (cb[:, 1] > 1) & (cb[:, 3] < H - 1)
    car = inner & (cls == "car")
    assert car.sum() >= 10
    rw = (b[car, 2] - b[car, 0]) / (cb[car, 2] - cb[car, 0])
    rh = (b[car, 3] - b[car, 1]) / (cb[car, 3] - cb[car, 1])
    sw, st, sb = OUTLINE_SHRINK["car"]
    # per-object shapes vary (sd 0.025) and a few cars dominate: the median within 2 object sd
    assert np.median(rw) == pytest.approx(1 - sw, abs=0.05) and np.median(rh) == pytest.approx(1 - st - sb, abs=0.05)
    assert np.mean(rw < 1) > 0.9 and np.mean(rh < 1) > 0.9
    ped = inner & (cls == "pedestrian")
    if ped.any():  # persons' boxes include what they carry: wider
        assert np.median((b[ped, 2] - b[ped, 0]) / (cb[ped, 2] - cb[ped, 0])) > 1.0


def test_truncated_boxes_end_at_the_border_inside_the_image():
    base = make_realism_case("detector_outline", SEED, 20)
    trunc = make_realism_case("detector_truncation", SEED, 20)
    b = np.concatenate([f.bboxes_2d for f in trunc.frames]).astype(float)
    assert np.all(b[:, 0] >= 0) and np.all(b[:, 2] <= W) and np.all(b[:, 1] >= 0) and np.all(b[:, 3] <= H)
    assert np.all(b[:, 2] > b[:, 0]) and np.all(b[:, 3] > b[:, 1])
    at_border = lambda c: int(sum(np.sum((f.bboxes_2d[:, 0] <= 0) | (f.bboxes_2d[:, 2] >= W)) for f in c.frames))
    assert at_border(trunc) > at_border(base)  # more objects cut by the border are detected


def test_merges_draw_one_box_around_two_overlapping_objects():
    merged = make_realism_case("detector_merge", SEED, 20)
    ids = _cat(merged, "ids_2d")
    base = make_realism_case("clean", SEED, 20)
    n_true = int(sum(np.sum(np.asarray(f.meta["ids_2d"]) >= 0) for f in base.frames))
    assert 0 < n_true - int(np.sum(ids >= 0)) < 0.5 * n_true  # some boxes merged, not most
    cb = _cat(merged, "boxes_2d_corner")
    assert np.all(np.isfinite(cb[ids >= 0]))


def test_misses_depend_on_the_class_and_false_boxes_appear():
    case = make_realism_case("detector_misses", SEED, 20)
    ids = _cat(case, "ids_2d")
    cls = np.array(sum((list(f.meta["classes_2d"]) for f in case.frames), []))
    assert np.sum(ids < 0) > 0  # part boxes / duplicates / generic false boxes
    assert all(len(f.detections.classes_2d) == f.num_2d for f in case.frames)
    assert set(cls) <= set(OUTLINE_SHRINK)


def test_scores_lower_noise_higher_for_small_boxes():
    case = make_realism_case("detector_scores", SEED, 20)
    b = np.concatenate([f.bboxes_2d for f in case.frames]).astype(float)
    cb, ids = _cat(case, "boxes_2d_corner"), _cat(case, "ids_2d")
    s = np.concatenate([f.detections.scores_2d for f in case.frames])
    assert np.all((s >= 0.3) & (s <= 1))
    ok = ids >= 0
    err = np.abs(b[ok] - cb[ok]).mean(1)
    lo = s[ok] < np.median(s[ok])
    assert err[lo].mean() > err[~lo].mean()  # low-score boxes are noisier
