"""Several poses of one frame refined at once (``xcalib.calib.poses_refine``, the consensus
matcher's refinement): the same optimum and matches as ``refine.refine_pose`` pose by pose."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.calib.context import RefineOptions
from xcalib.calib.hypotheses import kabsch, kabsch_triangles
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.poses_refine import match_poses, refine_poses
from xcalib.calib.refine import match_frame, refine_pose
from xcalib.data.synth import generate_frames, sample_site
from xcalib.geometry.rotations import rotation_angle, so3_exp

OPTS = RefineOptions(gates=((0.1, 1.0), (0.2, 0.5), (0.3, 0.0)), max_nfev=15, max_outer=3)


@pytest.fixture(scope="module")
def frame():
    site = sample_site(3)
    f = generate_frames(site, 1, seed=5, render_images=False, lidar=False, box_noise_px=1.0)[0]
    cfs, intr, _ = prepare_frames([f], f.intrinsics)
    return cfs[0], intr, site.T_cam_lidar


def _starts(T, n=4, seed=0):
    rng = np.random.default_rng(seed)
    R = np.stack([so3_exp(rng.normal(size=3) * np.radians(1.5)) @ T[:3, :3] for _ in range(n)])
    t = T[:3, 3] + rng.normal(size=(n, 3)) * 0.3
    return R, t


def test_refine_poses_reaches_refine_pose_optimum(frame):
    fr, intr, T = frame
    R0, t0 = _starts(T)
    fit = refine_poses(fr, intr, R0, t0, OPTS)
    for h in range(len(R0)):
        one = refine_pose([fr], intr, R0[h], t0[h], options=OPTS)
        pairs, ious, _ = match_frame(fr, intr, one.R, one.t, gate_iou=0.3)
        assert sorted(map(tuple, fit.pairs[h].tolist())) == sorted(map(tuple, pairs.tolist()))
        assert rotation_angle(fit.R[h], one.R) < 0.05 and np.linalg.norm(fit.t[h] - one.t) < 0.05
        assert fit.score[h] == pytest.approx(float(ious.sum()), abs=0.05)
        assert rotation_angle(fit.R[h], T[:3, :3]) < 3.0  # one frame: near the truth, not at it


def test_match_poses_is_match_frame_at_each_pose(frame):
    fr, intr, T = frame
    R0, t0 = _starts(T, 3, seed=1)
    pairs, iou = match_poses(fr, intr, R0, t0, 0.2, 0.5)
    assert iou.shape == (3, fr.n2, fr.n3)
    for h in range(3):
        p, _, _ = match_frame(fr, intr, R0[h], t0[h], gate_iou=0.2, gate_dist=0.5)
        assert p.tolist() == pairs[h].tolist()


def test_kabsch_triangles_is_kabsch():
    rng = np.random.default_rng(4)
    A = rng.normal(size=(500, 3, 3)) * 4.0
    R = np.stack([so3_exp(w) for w in rng.normal(size=(500, 3))])
    B = A @ R.transpose(0, 2, 1) + rng.normal(size=(500, 1, 3)) + rng.normal(size=(500, 3, 3)) * 0.5
    B[:50] = -B[:50]  # mirrored triangles: the determinant correction
    R1, t1 = kabsch(A, B)
    R2, t2 = kabsch_triangles(A, B)
    np.testing.assert_allclose(R2, R1, atol=1e-9)
    np.testing.assert_allclose(t2, t1, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R2), 1.0, atol=1e-12)
