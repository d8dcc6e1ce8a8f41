"""The pruned matching (issue 29, dense scenes) gives the same matches as the full one.

``refine.match_all`` / ``match_frame`` / ``poses_refine.match_poses`` drop the 3D boxes that do not
project into the image before the IoU arrays, and the rows and columns without an allowed pair
before the assignment. The reference below is the unpruned computation as it was before (IoU of
every 2D box with every 3D box, Hungarian on the whole matrix with forbidden entries at 1e6);
seeded synthetic frames, a busy junction (a 360-degree LiDAR: most of its boxes behind the
camera) and rough poses with the centre-distance gate must give the same pairs.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from xcalib.calib.boxproj import iou_batched, project_rects
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.poses_refine import match_poses
from xcalib.calib.refine import match_all, match_frame
from xcalib.data.synth import generate_frames, sample_site
from xcalib.geometry.boxes import box2d_centers


def _reference(fr, intr, R, t, gate_iou, gate_dist):
    """The full matrix: every 3D box, every 2D box, forbidden entries at 1e6."""
    rects, valid = project_rects(fr.corners, R, t, intr, fr.size)
    if fr.n2 == 0 or fr.n3 == 0 or not np.any(valid):
        return np.zeros((0, 2), np.int64)
    iou = iou_batched(rects[None], fr.boxes2d)[0]
    c_obs = box2d_centers(fr.boxes2d)
    c_pred = np.stack([(rects[:, 0] + rects[:, 2]) / 2, (rects[:, 1] + rects[:, 3]) / 2], 1)
    diag = np.hypot(fr.boxes2d[:, 2] - fr.boxes2d[:, 0], fr.boxes2d[:, 3] - fr.boxes2d[:, 1])
    dist = np.linalg.norm(c_obs[:, None] - c_pred[None], axis=2) / diag[:, None]
    dist = np.where(valid[None], dist, np.inf)
    allowed = (iou >= gate_iou) if gate_dist <= 0 else ((iou >= gate_iou) | (dist <= gate_dist))
    allowed &= valid[None]
    if not np.any(allowed):
        return np.zeros((0, 2), np.int64)
    cost = np.where(allowed, (1 - iou) + np.minimum(dist, 10.0), 1e6)
    r, c = linear_sum_assignment(cost)
    keep = allowed[r, c]
    return np.column_stack([r[keep], c[keep]]).astype(np.int64)


def _junction(seed: int, per_side: int, n_frames: int):
    """A busy junction (as ``benchmarks/bench_calibration_memory.junction_frames``, smaller)."""
    n = int(round(1.1 * per_side))
    site = sample_site(seed, preset="roadside", n_objects=(n, n), lanes_per_direction=4, min_visible_fraction=0.05,
                       min_box_px=4.0, width=3840, height=2160, hfov_deg=(100.0, 100.0), camera_height=(8.0, 12.0))
    frames = generate_frames(site, n_frames, seed=seed, render_images=False, lidar=False, miss_rate_2d=0.1,
                             false_positive_rate_2d=0.05, box_noise_px=1.0)
    return frames, site.T_cam_lidar


def _poses(T, rng, n):
    """The truth and ``n`` poses around it (up to ~3 deg, 0.5 m: the refinement's rough starts)."""
    out = [(T[:3, :3], T[:3, 3])]
    for _ in range(n):
        dR = Rotation.from_rotvec(rng.normal(0, np.radians(1.5), 3)).as_matrix()
        out.append((dR @ T[:3, :3], T[:3, 3] + rng.normal(0, 0.25, 3)))
    return out


GATES = ((0.3, 0.0), (0.1, 1.0), (0.2, 0.5), (0.5, 0.0))


@pytest.mark.parametrize("seed,per_side", [(0, 20), (1, 60), (2, 5)])
def test_match_all_same_pairs_as_full_matrix(seed, per_side):
    frames, T = _junction(seed, per_side, 4)
    cfs, intr, problem = prepare_frames(frames, frames[0].intrinsics)
    assert not problem
    rng = np.random.default_rng(seed)
    n_pairs = 0
    n_pruned = 0
    for R, t in _poses(T, rng, 4):
        for gi, gd in GATES:
            got = match_all(cfs, intr, R, t, gate_iou=gi, gate_dist=gd)
            for fr, p in zip(cfs, got):
                ref = _reference(fr, intr, R, t, gi, gd)
                np.testing.assert_array_equal(p, ref)
                n_pairs += len(p)
                n_pruned += int(np.count_nonzero(~project_rects(fr.corners, R, t, intr, fr.size)[1]))
            one = match_frame(cfs[0], intr, R, t, gate_iou=gi, gate_dist=gd)[0]
            np.testing.assert_array_equal(one, got[0])
    assert n_pairs > 0 and n_pruned > 0  # the frames have matches, and boxes that cannot project


def test_match_poses_same_pairs_as_full_matrix():
    frames, T = _junction(3, 30, 2)
    cfs, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    rng = np.random.default_rng(3)
    poses = _poses(T, rng, 6)
    R = np.stack([p[0] for p in poses])
    t = np.stack([p[1] for p in poses])
    for fr in cfs:
        for gi, gd in GATES:
            got, _ = match_poses(fr, intr, R, t, gi, gd)
            for h in range(len(R)):
                np.testing.assert_array_equal(got[h], _reference(fr, intr, R[h], t[h], gi, gd))


def test_match_all_frames_without_valid_boxes():
    """A pose that puts every 3D box behind the camera: no pairs, as before."""
    frames, T = _junction(4, 10, 2)
    cfs, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    flip = Rotation.from_euler("y", 180, degrees=True).as_matrix()
    R, t = flip @ T[:3, :3], flip @ T[:3, 3]
    got = match_all(cfs, intr, R, t, gate_iou=0.3)
    for fr, p in zip(cfs, got):
        np.testing.assert_array_equal(p, _reference(fr, intr, R, t, 0.3, 0.0))
