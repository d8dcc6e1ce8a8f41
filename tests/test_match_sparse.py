"""Matching on the candidate pairs only (issue 29, dense scenes) gives the pairs of the full arrays.

``refine._match_frames`` switches to ``match_sparse.match_candidates`` from ``sparse_above`` padded
IoU entries on; both paths are forced here on seeded busy-junction frames, at the truth and at
rough poses, with the IoU gate alone and with the centre-distance gate, and compared pair by pair
(and with the unpruned full-matrix reference of ``test_match_pruning``).
"""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.calib.inputs import prepare_frames
from xcalib.calib.match_sparse import _ranks, explained_iou, match_candidates
from xcalib.calib.refine import _match_frames, project_frames

from test_match_pruning import GATES, _junction, _poses, _reference


@pytest.mark.parametrize("seed,per_side", [(0, 60), (1, 15)])
def test_sparse_same_pairs_as_full_arrays(seed, per_side):
    frames, T = _junction(seed, per_side, 4)
    cfs, intr, problem = prepare_frames(frames, frames[0].intrinsics)
    assert not problem
    n_pairs = n_assigned = 0
    for R, t in _poses(T, np.random.default_rng(seed), 4):
        proj = project_frames(cfs, intr, R, t)
        for gi, gd in GATES + ((0.05, 2.0),):
            full = _match_frames(cfs, proj, gi, gd, sparse_above=10 ** 12)
            sparse = _match_frames(cfs, proj, gi, gd, sparse_above=0)
            for fr, a, b in zip(cfs, full, sparse):
                assert a.dtype == b.dtype == np.int64
                np.testing.assert_array_equal(a, b)
                np.testing.assert_array_equal(b, _reference(fr, intr, R, t, gi, gd))
                n_pairs += len(b)
                n_assigned += int(len(np.unique(b[:, 0])) < len(b) or len(b) > 1)
    assert n_pairs > 100 and n_assigned > 0


def test_sparse_declines_without_an_iou_gate():
    """gate_iou 0 allows every pair: no candidates to prune, the full arrays decide."""
    rects = np.array([[[0.0, 0.0, 10.0, 10.0]]])
    boxes = np.array([[[100.0, 100.0, 110.0, 110.0]]])
    assert match_candidates(rects, [1], boxes, [1], 0.0, 0.0) is None
    got = match_candidates(rects, [1], boxes, [1], 0.3, 0.0)
    assert len(got) == 1 and got[0].shape == (0, 2)
    # the centre-distance gate reaches a box whose rectangle does not overlap it
    got = match_candidates(rects, [1], boxes, [1], 0.3, 10.0)
    np.testing.assert_array_equal(got[0], [[0, 0]])


def test_ranks_is_unique_with_inverse():
    a = np.random.default_rng(0).integers(0, 50, 200)
    vals, inv = _ranks(a, 60)
    ref_vals, ref_inv = np.unique(a, return_inverse=True)
    np.testing.assert_array_equal(vals, ref_vals)
    np.testing.assert_array_equal(inv, ref_inv)


def test_explained_iou_is_the_full_arrays_maxima():
    """``score_poses``' maxima from the overlapping pairs only equal those of ``iou_batched``'s full
    [H,K,M] array, to the bit: rough poses of a seeded junction frame (many rectangles NaN or
    outside every box), with boxes touching and exactly sharing edges."""
    from xcalib.calib.boxproj import iou_batched, project_rects

    frames, T = _junction(2, 40, 1)
    cfs, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    fr = cfs[0]
    poses = _poses(T, np.random.default_rng(7), 30)
    R = np.stack([p[0] for p in poses])
    t = np.stack([p[1] for p in poses])
    rects, valid = project_rects(fr.box_corners, R, t, intr, fr.size)
    assert (~valid).any() and valid.any()
    boxes = np.concatenate([fr.boxes2d, rects[0][valid[0]][:3], rects[0][valid[0]][:3] + [5.0, 0.0, 5.0, 0.0]])
    for b in (fr.boxes2d, boxes):
        iou = iou_batched(rects, b)
        best, col = explained_iou(rects, b)
        np.testing.assert_array_equal(best, iou.max(2))
        np.testing.assert_array_equal(col, iou.max(1))
        assert (best > 0).any()


def _angular_step_balanced(points, n_sample=500, k=48, min_range_m=3.0, seed=0):
    """``boxshape.lidar_angular_step`` as it was (a median-balanced k-d tree)."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)[:, :3]
    p = p[np.linalg.norm(p, axis=1) > min_range_m]
    ang = np.column_stack([np.arctan2(p[:, 1], p[:, 0]), np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))])
    s = ang[np.random.default_rng(seed).choice(len(ang), size=min(n_sample, len(ang)), replace=False)]
    return cKDTree(ang).query(s, k=min(k, len(ang)))


def test_angular_step_tree_same_neighbours():
    """The scan step's unbalanced k-d tree finds the same neighbours (distances and rows) as the
    balanced one it replaced, on a seeded ring scan, so the same step."""
    from scipy.spatial import cKDTree

    from xcalib.calib.boxshape import lidar_angular_step

    rng = np.random.default_rng(3)
    az = np.arange(-np.pi, np.pi, np.radians(0.2))
    el = np.radians(np.arange(-25.0, 5.0, 0.7))
    A, E = np.meshgrid(az, el)
    r = rng.uniform(4.0, 60.0, A.shape)
    pts = np.stack([r * np.cos(E) * np.cos(A), r * np.cos(E) * np.sin(A), r * np.sin(E)], -1).reshape(-1, 3)
    pts += rng.normal(0.0, 0.01, pts.shape)
    dist, idx = _angular_step_balanced(pts)
    p = pts[np.linalg.norm(pts, axis=1) > 3.0]
    ang = np.column_stack([np.arctan2(p[:, 1], p[:, 0]), np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))])
    s = ang[np.random.default_rng(0).choice(len(ang), size=500, replace=False)]
    d2, i2 = cKDTree(ang, balanced_tree=False).query(s, k=48)
    np.testing.assert_array_equal(dist, d2)
    np.testing.assert_array_equal(idx, i2)
    step = lidar_angular_step(pts)
    assert step is not None
    np.testing.assert_allclose(step, np.radians([0.2, 0.7]), rtol=0.1)
