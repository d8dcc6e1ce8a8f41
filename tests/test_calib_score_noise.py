"""Detector scores in the noise model (issue 25, uncertainty): a detector's less confident boxes are
noisier, and how much is measured on the run's own residuals (``refine.estimate_noise``).

Small, seeded box-level scenes (``test_calib_support``), matches taken from the truth, no search:
when low-score boxes are noisier the score term is found, the weighted fit is more accurate and its
sigma covers the error; when scores are absent or all equal nothing changes (bit for bit).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from test_calib_support import sim_frames

from xcalib.calib.diagnostics import CalibDiagnostics, NoiseModel
from xcalib.calib.inputs import box_scores, input_scores, prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import DEFAULT_NOISE, FitContext, estimate_noise, lsq, pair_scores
from xcalib.calib.uncertainty import pose_covariance


def _truth_pairs(frames, cframes):
    out = []
    for fr, cf in zip(frames, cframes):
        i2 = {int(k): r for r, k in enumerate(cf.idx2d)}
        i3 = {int(k): r for r, k in enumerate(cf.idx3d)}
        ij = [(i2[a], i3[b]) for a, b in np.argwhere(fr.match_matrix) if a in i2 and b in i3]
        out.append(np.asarray(ij, dtype=np.int64).reshape(-1, 2))
    return out


def _scene(seed: int, scores: str = "informative", rel: float = 0.25):
    """6 frames whose 2D boxes carry 0.5 px noise plus ``rel`` x size x (1 - score) for a score drawn
    per box; ``scores``: "informative" (the drawn scores given), "equal" (all 0.7 given), "none"."""
    frames, T = sim_frames(seed=seed, n_frames=6, noise_px=0.0, miss=0.0, false_pos=0.0, extra_3d=0)
    rng = np.random.default_rng([seed, 99])
    out = []
    for f in frames:
        b = np.asarray(f.bboxes_2d, dtype=np.float64)
        s = np.sqrt((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]))
        q = rng.uniform(0.2, 0.95, len(b))
        b = b + rng.normal(0.0, 1.0, b.shape) * (0.5 + rel * s * (1 - q))[:, None]
        meta = dict(f.meta or {})
        if scores == "informative":
            meta["detections"] = {"scores_2d": q.tolist()}
        elif scores == "equal":
            meta["scores_2d"] = np.full(len(b), 0.7)
        out.append(dataclasses.replace(f, bboxes_2d=b.astype(np.float32), meta=meta))
    return out, T


def _fit(frames, T):
    cframes, intr, _ = prepare_frames(frames, frames[0].intrinsics, scores=True)
    pairs = _truth_pairs(frames, cframes)
    pose0 = Pose(T[:3, :3], T[:3, 3])
    noise = DEFAULT_NOISE
    R, t = pose0.R, pose0.t
    for _ in range(2):  # fit, re-fit the noise model at the fitted pose, fit again (as refine_pose)
        R, t, _, _, _ = lsq(FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0), 60)
        noise = estimate_noise(cframes, pairs, intr, R, t)
    R, t, _, _, _ = lsq(FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0), 60)
    rs, ts, _ = pose_covariance(cframes, pairs, intr, R, t, noise=noise)
    err = Pose(R, t).delta(pose0)
    return noise, err, np.concatenate([rs, ts]), cframes, pairs


def test_scores_reach_the_calib_frames():
    frames, _ = _scene(0)
    off, _, _ = prepare_frames(frames, frames[0].intrinsics)  # CalibConfig.detector_scores is off by default
    assert all(cf.scores2d_input is None for cf in off)
    cframes, _, _ = prepare_frames(frames, frames[0].intrinsics, scores=True)
    for f, cf in zip(frames, cframes):
        q = np.asarray(f.detections.scores_2d)  # the earlier meta["detections"] dict fills the typed field
        assert np.array_equal(box_scores(cf), q[cf.idx2d])
    # a score list of another length than the boxes is not used, and says so
    with pytest.warns(UserWarning, match="3 scores for 5 2D boxes"):
        assert input_scores({"scores_2d": [0.5, 0.6, 0.7]}, 5, 2) is None
    with pytest.warns(UserWarning, match="NaN"):
        assert input_scores({"scores_2d": [0.5, np.nan]}, 2) is None
    assert input_scores({}, 3) is None and input_scores({"detections": {"source": "x"}}, 3) is None


def test_low_score_boxes_noisier_weighted_and_covered():
    """Over seeded scenes: the score term is found, the weighted pose is closer to the truth than the
    one that ignores the scores, and the sigma of the weighted fit still covers its error."""
    err_w, err_u, z_w = [], [], []
    for seed in range(10):
        frames, T = _scene(seed)
        noise, e_w, sd_w, cframes, pairs = _fit(frames, T)
        assert noise.sigma_score > 0.05 and 0.9 <= noise.score_ref <= 0.95
        assert pair_scores(cframes, pairs) is not None
        bare = [dataclasses.replace(f, detections=None) for f in frames]
        noise_u, e_u, _, _, _ = _fit(bare, T)
        assert noise_u.sigma_score == 0.0
        err_w.append(e_w ** 2)
        err_u.append(e_u ** 2)
        z_w.extend(np.abs(e_w) / sd_w)
    mse_w, mse_u = np.mean(err_w, axis=0), np.mean(err_u, axis=0)  # per axis over the scenes
    assert mse_w[:3].sum() < 0.8 * mse_u[:3].sum() and mse_w[3:].sum() < 0.8 * mse_u[3:].sum()
    assert 0.9 <= np.mean(np.asarray(z_w) <= 1.96) <= 0.99
    assert 0.5 <= np.median(z_w) <= 0.85  # the sigma neither too large nor too small (0.674 when right)


def test_equal_or_absent_scores_change_nothing():
    frames, T = _scene(3, scores="equal")
    bare = [dataclasses.replace(f, meta={k: v for k, v in f.meta.items() if k != "scores_2d"}) for f in frames]
    n_eq, e_eq, sd_eq, _, _ = _fit(frames, T)
    n_no, e_no, sd_no, _, _ = _fit(bare, T)
    assert n_eq == n_no and n_eq.sigma_score == 0.0
    assert np.array_equal(e_eq, e_no) and np.array_equal(sd_eq, sd_no)


def test_noise_model_record_unchanged_without_scores():
    d = CalibDiagnostics().to_dict()
    assert set(d["noise_model"]) == {"sigma_px", "sigma_3d_m", "sigma_size"}
    d = CalibDiagnostics(noise_model=NoiseModel(1.0, 0.03, 0.01, 0.2, 0.9)).to_dict()
    assert d["noise_model"]["sigma_score"] == 0.2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert CalibDiagnostics.from_dict(d).noise_model == NoiseModel(1.0, 0.03, 0.01, 0.2, 0.9)
