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


def _fit_all_poses(batch, R, t, fs, active, max_iter):
    """``poses_refine._fit`` as it was: every step solves, projects and differentiates all H poses."""
    from xcalib.calib.poses_refine import COST_TOL, STEP_TOL, _exp, _robust

    R, t = R.copy(), t.copy()
    r, raw, proj = batch.residuals(R, t)
    cost, wts = _robust(r, fs)
    lam = np.full(len(R), 1e-3)
    live = active.copy()
    J = batch.jacobian(t, raw, proj)
    eye = np.eye(6)
    for _ in range(max_iter):
        if not live.any():
            break
        Jf = J.reshape(len(R), -1, 6)
        sf = wts.reshape(len(R), -1)
        Jt = Jf.transpose(0, 2, 1)
        A = (Jt * sf[:, None, :] ** -3) @ Jf
        g = (Jt @ (r.reshape(len(R), -1) / sf)[..., None])[..., 0]
        dA = np.maximum(np.diagonal(A, axis1=1, axis2=2), 1e-12)
        M = A + lam[:, None, None] * (eye * dA[:, None, :])
        M[~live] = eye
        dx = -np.linalg.solve(M, np.where(live[:, None], g, 0.0)[..., None])[..., 0]
        Rn = _exp(dx[:, :3]) @ R
        tn = t + dx[:, 3:]
        rn, rawn, projn = batch.residuals(Rn, tn)
        cn, wn = _robust(rn, fs)
        better = live & (cn <= cost)
        step = np.linalg.norm(dx[:, :3], axis=1) + np.linalg.norm(dx[:, 3:], axis=1) / 100.0
        settled = better & ((step < STEP_TOL) | (cost - cn <= COST_TOL * np.maximum(cost, 1e-12)))
        if better.any():
            R[better], t[better] = Rn[better], tn[better]
            r[better], raw[better], wts[better], cost[better] = rn[better], rawn[better], wn[better], cn[better]
            J[better] = batch.jacobian(tn, rawn, projn)[better]
        lam = np.where(better, np.maximum(lam / 3.0, 1e-9), lam * 4.0)
        live &= ~settled & (lam < 1e8)
    return R, t, r


def test_poses_fit_live_only_same_as_all_poses():
    """The consensus's batched fit stepping only the live poses gives the poses and residuals of
    stepping all of them, to the bit (seeded frame, 6 rough starts, one of them inactive)."""
    from xcalib.calib.cost import Occlusion, edge_sigma
    from xcalib.calib.pose import Pose
    from xcalib.calib.poses_refine import _Batch, _fit
    from xcalib.calib.refine import DEFAULT_NOISE

    frames, T = _junction(5, 12, 1)
    cfs, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    fr = cfs[0]
    poses = _poses(T, np.random.default_rng(5), 5)
    R = np.stack([p[0] for p in poses])
    t = np.stack([p[1] for p in poses])
    pairs, _ = match_poses(fr, intr, R, t, 0.1, 1.0)
    assert all(len(p) >= 3 for p in pairs)
    sig = [edge_sigma(fr.boxes2d[p[:, 0]], fr.corners[p[:, 1]], intr, Pose(R[h], t[h]), DEFAULT_NOISE, np.zeros(len(p)))
           for h, p in enumerate(pairs)]
    batch = _Batch(fr, pairs, sig, intr, Occlusion())
    active = np.ones(len(R), bool)
    active[2] = False
    fs = np.full(len(R), 2.0)
    for max_iter in (1, 4, 15):
        got = _fit(batch, R, t, fs, active, max_iter)
        ref = _fit_all_poses(batch, R, t, fs, active, max_iter)
        for a, b in zip(got, ref):
            np.testing.assert_array_equal(a, b)
    assert not np.array_equal(got[0], R)  # the fit moved the poses
