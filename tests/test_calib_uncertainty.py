"""Uncertainty (issue 12 item 4): the sigma clustered by object and the box-model floor.

Small, seeded box-level scenes (``test_calib_support``), matches taken from the truth, no search:
the same objects seen in many frames with one error each must widen the sigma (frames that
repeat them add no information), independent objects must not, and the box-model shift is
zero when every outline is its box.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_calib_support import sim_frames

from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import FitContext, lsq
from xcalib.calib.uncertainty import box_model_shift, combine, object_groups, object_sandwich, pose_covariance
from xcalib.types import Frame


def _truth_pairs(frames, cframes):
    """Per CalibFrame, the true (2D row, 3D row) pairs from each Frame's match matrix."""
    out = []
    for fr, cf in zip(frames, cframes):
        i2 = {int(k): r for r, k in enumerate(cf.idx2d)}
        i3 = {int(k): r for r, k in enumerate(cf.idx3d)}
        ij = [(i2[a], i3[b]) for a, b in np.argwhere(fr.match_matrix) if a in i2 and b in i3]
        out.append(np.asarray(ij, dtype=np.int64).reshape(-1, 2))
    return out


def _repeated_scene(seed: int, n_frames: int, bias_px: float):
    """One frame's objects seen again in ``n_frames`` frames: fresh 1 px box noise per frame plus
    an error per object (its 2D box shifted by the same ``bias_px``-scale offset in every frame)."""
    base, T = sim_frames(seed=seed, n_frames=1, noise_px=0.0, miss=0.0, false_pos=0.0, extra_3d=0)
    rng = np.random.default_rng(seed)
    f0 = base[0]
    bias = rng.normal(0, bias_px, (len(f0.bboxes_2d), 4))
    frames = [Frame(**{**f0.__dict__, "frame_key": f"{k:04d}",
                       "bboxes_2d": f0.bboxes_2d + bias + rng.normal(0, 1.0, f0.bboxes_2d.shape)})
              for k in range(n_frames)]
    return frames, T


def _fit(frames, T):
    cframes, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    pairs = _truth_pairs(frames, cframes)
    R, t, _, _, _ = lsq(FitContext(cframes, pairs, intr, Pose(T[:3, :3], T[:3, 3]), f_scale=2.0), 60)
    return cframes, pairs, intr, Pose(R, t)


def test_objects_repeated_over_frames_widen_the_sigma():
    frames, T = _repeated_scene(seed=1, n_frames=8, bias_px=4.0)
    cframes, pairs, intr, pose = _fit(frames, T)
    groups = object_groups(cframes, pairs)
    n_objects = len(pairs[0])
    assert int(groups.max()) + 1 == n_objects  # each object's 8 views are one cluster
    rot, tr, _ = pose_covariance(cframes, pairs, intr, pose.R, pose.t)
    clus = object_sandwich(FitContext(cframes, pairs, intr, pose), groups)
    # 8 views of one error count once: about sqrt(8) wider than counting every pair
    assert np.linalg.norm(clus[:3]) > 1.8 * np.linalg.norm(rot)
    assert np.linalg.norm(clus[3:]) > 1.8 * np.linalg.norm(tr)
    # and the combined 2 sigma covers the actual error of the pose (the per-pair sigma does not)
    err_deg, err_m = pose.error(Pose.parse(T))
    r, t = combine(np.concatenate([rot, tr]), None, np.zeros(6), np.concatenate([rot, tr]), clusters=clus)
    assert err_deg <= 2 * np.linalg.norm(r) and err_m <= 2 * np.linalg.norm(t)


def test_independent_objects_keep_the_pair_sigma():
    frames, T = sim_frames(seed=2, n_frames=6, miss=0.0, false_pos=0.0, extra_3d=0)
    cframes, pairs, intr, pose = _fit(frames, T)
    groups = object_groups(cframes, pairs, radius_m=0.05)  # every object is new in every frame
    rot, _, _ = pose_covariance(cframes, pairs, intr, pose.R, pose.t)
    clus = object_sandwich(FitContext(cframes, pairs, intr, pose), groups)
    assert int(groups.max()) + 1 == sum(len(p) for p in pairs)
    assert 0.5 < np.linalg.norm(clus[:3]) / np.linalg.norm(rot) < 1.6


def test_object_sandwich_needs_four_objects_and_each_object_must_not_fix_the_pose_alone():
    frames, T = _repeated_scene(seed=1, n_frames=4, bias_px=1.0)
    cframes, pairs, intr, pose = _fit(frames, T)
    three = [p[:3] for p in pairs]
    assert object_sandwich(FitContext(cframes, three, intr, pose), object_groups(cframes, three)) is None
    four = [p[:4] for p in pairs]
    assert np.all(np.isfinite(object_sandwich(FitContext(cframes, four, intr, pose), object_groups(cframes, four))))
    # one frame of 4 objects: without any one of them 3 boxes remain -> still determined (finite)
    one = [p[:4] if k == 0 else p[:0] for k, p in enumerate(pairs)]
    assert np.all(np.isfinite(object_sandwich(FitContext(cframes, one, intr, pose), object_groups(cframes, one))))


def test_box_model_shift_is_zero_for_box_outlines_and_seen_otherwise():
    frames, T = sim_frames(seed=3, n_frames=3, miss=0.0, false_pos=0.0, extra_3d=0)
    cframes, pairs, intr, pose = _fit(frames, T)
    assert box_model_shift(cframes, pairs, intr, pose) is None  # outlines are the box corners
    # a point-hull outline that sits lower than the box (as a LiDAR sees the near, lower side)
    lowered = [dataclasses.replace(f, corners=f.box_corners - np.array([0.0, 0.0, 0.3])) for f in cframes]
    R, t, _, _, _ = lsq(FitContext(lowered, pairs, intr, pose, f_scale=2.0), 60)
    fitted = Pose(R, t)  # fitted to the lowered outlines: the box corners pull it back towards the truth
    shift = box_model_shift(lowered, pairs, intr, fitted)
    assert shift is not None and np.linalg.norm(shift[3:]) > 0.05
    np.testing.assert_allclose(shift, pose.delta(fitted), atol=0.02)


def test_verdict_refuses_a_determined_pose_whose_reported_bound_is_too_wide():
    from xcalib.calib.config import CalibConfig
    from xcalib.calib.decision import Evidence, verdict

    def ev(total_deg, total_m):
        return Evidence(n_pairs=80, n_2d=100, most_per_frame=6, places=10, places_off_line=5, halves_available=True,
                        best_score=50.0, runner_up_score=0.0, rot_sd=np.full(3, 0.1), tr_sd=np.full(3, 0.05),
                        rot_sd_total=np.full(3, total_deg), tr_sd_total=np.full(3, total_m))

    cfg = CalibConfig()
    # 95 % bound of three equal axes: 2.80 sigma (2 |sigma| would be 3.46 sigma)
    assert verdict(ev(0.7, 0.4), cfg) is None  # 1.96 deg / 1.12 m: within 2 deg / 1.2 m
    wide = verdict(ev(0.8, 0.3), cfg)  # 2.24 deg
    assert wide is not None and wide.code == "uncertain" and "counting each object once" in wide.message
    assert "95 % bound" in wide.message
    assert verdict(ev(np.inf, 0.1), cfg).code == "uncertain"
    assert verdict(ev(0.8, 0.3), cfg.replace(max_rot_bound_deg=3.0)) is None
    # the frame-level sigma still judges whether the pose is determined at all
    loose = Evidence(**{**ev(0.1, 0.05).__dict__, "rot_sd": np.full(3, 0.4)})
    assert verdict(loose, cfg).code == "poorly_constrained"


def test_a_bound_the_objects_own_scatter_fails_is_refused_as_too_few_objects():
    """Issue 25 (A9, 416 px detections: 19 objects): when the objects' scatter alone -- no box or
    outline model -- exceeds the bound, the refusal's code and message say too few objects, with
    roughly how many would do; when the box model is what widens the bound it stays ``uncertain``."""
    from xcalib.calib.config import CalibConfig
    from xcalib.calib.decision import Evidence, verdict
    from xcalib.calib.diagnostics import UncertaintyParts
    from xcalib.calib.uncertainty import statistical_sd

    def ev(total_deg, total_m, objects_deg, objects_m):
        return Evidence(n_pairs=82, n_2d=107, most_per_frame=6, places=10, places_off_line=5, halves_available=True,
                        best_score=50.0, runner_up_score=0.0, rot_sd=np.full(3, 0.1), tr_sd=np.full(3, 0.05),
                        rot_sd_total=np.asarray(total_deg, float), tr_sd_total=np.asarray(total_m, float),
                        n_objects=19, rot_sd_objects=np.asarray(objects_deg, float),
                        tr_sd_objects=np.asarray(objects_m, float))

    cfg = CalibConfig()
    # A9 416 px: reported [1.13 0.79 0.63] deg / [0.57 0.77 0.27] m, objects alone [1.07 0.53 0.57] / [0.28 0.54 0.18]
    few = verdict(ev([1.13, 0.79, 0.63], [0.57, 0.77, 0.27], [1.07, 0.53, 0.57], [0.28, 0.54, 0.18]), cfg)
    assert few is not None and few.code == "too_few_objects"
    assert few.message.startswith("too few distinct objects") and "19 distinct objects" in few.message
    need = int(few.message.split("roughly ")[1].split()[0])
    assert 19 < need < 40
    # the same bound, but the objects alone are within the limits: the box model widens it
    box = verdict(ev([1.13, 0.79, 0.63], [0.57, 0.77, 0.27], [0.3, 0.2, 0.2], [0.1, 0.1, 0.1]), cfg)
    assert box is not None and box.code == "uncertain"
    assert verdict(ev([0.3, 0.3, 0.3], [0.1, 0.1, 0.1], [0.3, 0.3, 0.3], [0.1, 0.1, 0.1]), cfg) is None
    # the object-level part: per axis the largest of the Jacobian, clusters, bootstrap, own outlines
    parts = UncertaintyParts(jacobian=[0.2] * 6, clusters=[1.0, 0.1, 0.1, 0.3, 0.1, 0.1],
                             object_outline=[0.1, 0.5, 0.1, 0.1, 0.1, 0.1], outline=[9.0] * 6, floor=[9.0] * 6)
    np.testing.assert_allclose(statistical_sd(parts), [1.0, 0.5, 0.2, 0.3, 0.2, 0.2])
    assert statistical_sd(UncertaintyParts(jacobian=[0.2] * 6)) is None  # objects not counted


def test_exact_refits_replace_the_largest_linearised_moves():
    frames, T = _repeated_scene(seed=1, n_frames=8, bias_px=4.0)
    cframes, pairs, intr, pose = _fit(frames, T)
    groups = object_groups(cframes, pairs)
    lin = object_sandwich(FitContext(cframes, pairs, intr, pose), groups, exact=0, kind="jackknife")
    ref = object_sandwich(FitContext(cframes, pairs, intr, pose), groups, exact=3, kind="jackknife")
    assert np.all(np.isfinite(ref)) and not np.allclose(lin, ref)
    # a benign scene (no pair dominates): the refits agree with the linearisation within a factor 1.5
    assert 1 / 1.5 < np.linalg.norm(ref[:3]) / np.linalg.norm(lin[:3]) < 1.5


def test_frame_jackknife_grows_with_the_noise_and_needs_four_frames():
    from xcalib.calib.uncertainty import frame_jackknife

    spread = []
    for noise_px in (0.5, 4.0):
        frames, T = sim_frames(seed=2, n_frames=6, noise_px=noise_px, miss=0.0, false_pos=0.0, extra_3d=0)
        cframes, pairs, intr, pose = _fit(frames, T)
        assert frame_jackknife(FitContext(cframes, [p if k < 3 else p[:0] for k, p in enumerate(pairs)], intr, pose)) is None
        sd = frame_jackknife(FitContext(cframes, pairs, intr, pose))
        assert sd is not None and sd.shape == (6,) and np.all(np.isfinite(sd))
        spread.append(np.linalg.norm(sd[:3]))
    assert spread[1] > 3 * spread[0]  # 8x the box noise: the frames disagree more


def test_calibrate_reports_the_frame_jackknife_it_judged_by():
    import xcalib

    frames, T = sim_frames(seed=2, n_frames=6)
    res = xcalib.calibrate(frames, frames[0].intrinsics)
    parts = res.diagnostics.uncertainty
    assert parts.frames is not None and len(parts.frames) == 6 and np.all(np.isfinite(parts.frames))


def test_bound95_is_the_95_percent_radius_of_the_per_axis_sigma():
    from xcalib.calib.uncertainty import bound95

    assert bound95([1.0, 0.0, 0.0]) == pytest.approx(1.96, abs=0.01)
    assert bound95([1.0, 1.0, 1.0]) == pytest.approx(2.80, abs=0.01)  # sqrt(chi2_3(0.95)), not 2 sqrt(3)
    assert bound95([1.0, np.inf, 0.0]) == np.inf
    rng = np.random.default_rng(0)
    sd = np.array([0.3, 0.1, 0.2])
    e = np.linalg.norm(rng.normal(0, 1, (20000, 3)) * sd, axis=1)
    assert np.mean(e <= bound95(sd)) == pytest.approx(0.95, abs=0.01)


def test_combine_counts_the_frame_halves_once_and_the_outline_shift():
    jac, occ = np.full(6, 0.1), np.zeros(6)
    halves, clus = np.full(6, 1.0), np.full(6, 0.2)
    r, t = combine(jac, halves, occ, clusters=clus)  # the objects' spread contains the frames'
    assert np.allclose(r, 0.2) and np.allclose(t, 0.2)
    r, _ = combine(jac, halves, occ)  # without the object jackknife the halves judge
    assert np.allclose(r, 0.5)
    r, _ = combine(jac, None, np.full(6, 0.3), clusters=clus, outline=np.full(6, -0.4))  # the larger shift, once
    assert np.allclose(r, np.hypot(0.2, 0.4))


def test_sigma_coverage_on_seeded_scenes():
    """On seeded box-level scenes with independent objects (truth pairs, fitted pose) the reported
    1-sigma is neither grossly too large nor too small: about 95 % of the axes within 2 sigma and an
    RMS of |error| / sigma near 1 (a sigma 3x too large gives RMS 0.33 and 100 %, 3x too small
    RMS 3 and ~50 %)."""
    from xcalib.calib.cost import Occlusion
    from xcalib.calib.diagnostics import NoiseModel
    from xcalib.calib.uncertainty import estimate

    z = []
    for seed in range(8):
        frames, T = sim_frames(seed=seed, n_frames=5, noise_px=2.0, miss=0.0, false_pos=0.0, extra_3d=0)
        cframes, pairs, intr, pose = _fit(frames, T)
        unc = estimate(FitContext(cframes, pairs, intr, pose, NoiseModel(sigma_px=2.0), 2.0, Occlusion()))
        sd = np.concatenate([unc.rot_sd, unc.tr_sd])
        z.append(np.abs(pose.delta(Pose(T[:3, :3], T[:3, 3]))) / sd)
    z = np.asarray(z)
    assert 0.8 <= np.mean(z <= 2) <= 1.0
    assert 0.5 <= np.sqrt(np.mean(z ** 2)) <= 1.6


def _outline_and_noise(frames, T, shrink: float = 0.0):
    """(outline shift, its sampling-noise sigma, |pose error| [6]) on ``frames`` whose 2D boxes are
    shrunk by ``shrink`` of their size about the centre (a detector's tight outline: a common bias)."""
    from xcalib.calib.cost import Occlusion
    from xcalib.calib.diagnostics import NoiseModel
    from xcalib.calib.uncertainty import _outline_fit, _pose_spread, _shift_noises

    if shrink:
        def tight(b):
            c, s = (b[:, :2] + b[:, 2:]) / 2, (b[:, 2:] - b[:, :2]) * (1 - shrink) / 2
            return np.column_stack([c - s, c + s])
        frames = [dataclasses.replace(f, bboxes_2d=tight(np.asarray(f.bboxes_2d, float))) for f in frames]
    cframes, pairs, intr, pose = _fit(frames, T)
    ctx = FitContext(cframes, pairs, intr, pose, NoiseModel(sigma_px=1.0), 2.0, Occlusion())
    fitted = _outline_fit(cframes, pairs, intr, pose, ctx.noise, f_scale=2.0, occlusion=ctx.occlusion)
    _, free = _pose_spread(ctx)
    _, noise = _shift_noises(ctx, free, fitted, object_groups(cframes, pairs))
    return fitted[1].pose.delta(pose), noise


def test_a_shift_that_is_only_noise_adds_nothing_and_a_common_bias_is_kept():
    """The outline shift's own sampling noise (``shift_noise_sd``) has the scale of the shifts that
    exact boxes with 1 px noise give (|shift| / noise sd: median near 0.67, the half-normal's), so
    ``excess`` drops most of them; 2D boxes 12 % tighter than the 3D outline (one bias shared by all
    objects) shift the pose far beyond that noise, and the excess keeps almost all of it."""
    from xcalib.calib.uncertainty import excess

    z, kept_noise, kept_bias = [], [], []
    for seed in range(4):
        frames, T = sim_frames(seed=seed, n_frames=4, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
        shift, noise = _outline_and_noise(frames, T)
        z.append(np.abs(shift) / noise)
        kept_noise.append(np.linalg.norm(excess(shift, noise)) / np.linalg.norm(shift))
        shift_b, noise_b = _outline_and_noise(frames, T, shrink=0.12)
        kept_bias.append(np.linalg.norm(excess(shift_b, noise_b)) / np.linalg.norm(shift_b))
    assert 0.35 <= np.median(z) <= 1.3  # the noise estimate has the shifts' scale
    assert np.median(kept_noise) <= 0.6  # pure noise: most of the shift is dropped
    assert min(kept_bias) >= 0.9  # a real common bias: kept


def test_excess_and_shift_noise_sd_on_known_influences():
    """``excess`` is sqrt(max(d^2 - sd^2, 0)) per axis (the whole shift without a noise estimate);
    ``shift_noise_sd`` sums the pairs' influence differences per object and spreads them over objects."""
    from xcalib.calib.uncertainty import excess, shift_noise_sd

    assert np.allclose(excess([3.0, -1.0, 0.5], [4.0, 0.0, 0.3]), [0.0, 1.0, 0.4])
    assert np.allclose(excess([-2.0], None), [2.0])
    rng = np.random.default_rng(0)
    a, b = rng.normal(0, 1e-3, (400, 6)), np.zeros((400, 6))
    per_pair = shift_noise_sd(a, b)
    assert np.allclose(per_pair[3:], np.sqrt(400) * 1e-3, rtol=0.15)  # metres: sqrt(n) x the pair's spread
    assert np.allclose(per_pair[:3], np.degrees(np.sqrt(400) * 1e-3), rtol=0.15)  # radians reported in degrees
    same = np.repeat(np.arange(100), 4)  # 4 pairs per object with the same influence: objects, not pairs
    a4 = np.repeat(rng.normal(0, 1e-3, (100, 6)), 4, axis=0)
    assert np.allclose(shift_noise_sd(a4, b, same)[3:], 4 * np.sqrt(100) * 1e-3, rtol=0.2)
    assert shift_noise_sd(a[:2], b[:2]) is None and shift_noise_sd(a, None) is None


def _clustered_regression(rng, G: int):
    """A linear least-squares problem with G clusters of rows (6 parameters), each cluster with its own
    mean regressor (uneven leverage): (rows per cluster, X blocks, A = (X^T X)^-1)."""
    sizes = rng.integers(4, 16, G)
    X = [(rng.normal(size=(n, 6)) + rng.normal(size=6)) * rng.uniform(0.3, 3, size=6) for n in sizes]
    J = np.vstack(X)
    return sizes, X, np.linalg.inv(J.T @ J)


def test_cr2_covariance_is_the_bias_reduced_sandwich_with_bell_mccaffrey_dof():
    from scipy.linalg import sqrtm

    from xcalib.calib.uncertainty import cr2_covariance

    rng = np.random.default_rng(0)
    sizes, X, A = _clustered_regression(rng, 6)
    J = np.vstack(X)
    offs = np.cumsum([0, *sizes])
    r = rng.normal(size=len(J))
    r = r - J @ (A @ (J.T @ r))  # residuals at the least-squares optimum
    g = np.stack([X[c].T @ r[offs[c]:offs[c + 1]] for c in range(6)])
    M = np.stack([x.T @ x for x in X])
    cov, nu = cr2_covariance(A, g, M)
    # brute force in the residual space: (I - H_cc)^-1/2 per cluster, G = (I - H)_{.,c} (I - H_cc)^-1/2 J_c A e_k
    IH = np.eye(len(J)) - J @ A @ J.T
    adj = [np.real(np.linalg.inv(sqrtm(IH[offs[c]:offs[c + 1], offs[c]:offs[c + 1]]))) for c in range(6)]
    meat = sum(np.outer(X[c].T @ adj[c] @ r[offs[c]:offs[c + 1]], X[c].T @ adj[c] @ r[offs[c]:offs[c + 1]])
               for c in range(6))
    np.testing.assert_allclose(cov, A @ meat @ A, rtol=1e-8, atol=1e-14)
    for k in range(6):
        Gm = np.stack([IH[:, offs[c]:offs[c + 1]] @ adj[c] @ X[c] @ A[:, k] for c in range(6)], 1)
        lam = np.linalg.eigvalsh(Gm.T @ Gm)
        assert nu[k] == pytest.approx(lam.sum() ** 2 / np.sum(lam ** 2), rel=1e-8)
        assert 1.0 <= nu[k] <= 5.0  # at most G - 1


def test_cr2_with_bell_mccaffrey_t_covers_95_percent_where_the_jackknife_overstates_the_variance():
    from scipy.special import stdtrit

    from xcalib.calib.uncertainty import cr2_covariance

    rng = np.random.default_rng(1)
    G = 6
    sizes, X, A = _clustered_regression(rng, G)
    J = np.vstack(X)
    offs = np.cumsum([0, *sizes])
    M = np.stack([x.T @ x for x in X])
    info = J.T @ J
    covered, ratio = [], []
    for _ in range(400):  # errors shared within a cluster (one object's box error) plus per-row noise
        e = np.concatenate([rng.normal() + 0.5 * rng.normal(size=n) for n in sizes])
        b = A @ (J.T @ e)  # the estimate's error (truth 0)
        r = e - J @ b
        g = np.stack([X[c].T @ r[offs[c]:offs[c + 1]] for c in range(G)])
        cov, nu = cr2_covariance(A, g, M)
        sd = np.sqrt(np.diag(cov))
        covered.append(np.abs(b) <= stdtrit(nu, 0.975) * sd)
        d = np.stack([np.linalg.solve(info - M[c], g[c]) for c in range(G)])  # leave-one-cluster-out moves
        jack = np.sqrt(np.diag((G - 1) / G * (d - d.mean(0)).T @ (d - d.mean(0))))
        ratio.append(jack / sd)
    assert 0.92 <= np.mean(covered) <= 0.985
    assert np.median(ratio) > 1.1  # the jackknife (CR3) is wider than the unbiased CR2 before any t factor


def test_a_shift_counts_only_beyond_the_95_percent_point_of_its_noise():
    """``estimate`` counts of a model shift (occlusion, outline) only the part beyond ``SHIFT_NOISE_Z``
    of its own noise sigmas: where the shift is only noise, the plain positive part (z = 1) adds
    E[(chi2_1 - 1)+] = 0.48 noise^2 to the variance that the statistical part already holds, the
    95 % point 0.09; a shift far beyond its noise (a common bias) is kept almost whole."""
    from xcalib.calib.uncertainty import SHIFT_NOISE_Z, excess

    assert abs(SHIFT_NOISE_Z - 1.96) < 1e-3
    rng = np.random.default_rng(0)
    sd = np.full(6, 0.01)
    noise_only = rng.normal(0.0, 0.01, (20000, 6))
    plain = np.mean([excess(d, sd) ** 2 for d in noise_only[:4000]]) / 0.01 ** 2
    at95 = np.mean([excess(d, sd, SHIFT_NOISE_Z) ** 2 for d in noise_only[:4000]]) / 0.01 ** 2
    assert 0.42 < plain < 0.54 and 0.06 < at95 < 0.12, (plain, at95)
    bias = np.full(6, 0.08)  # 8 noise sigmas: a detector's tight outline
    assert np.all(excess(bias, sd, SHIFT_NOISE_Z) > 0.96 * bias)  # sqrt(64 - 3.84) / 8
    assert np.allclose(excess([0.03, -0.01], [0.01, 0.01], 2.0), [np.sqrt(0.03 ** 2 - 0.02 ** 2), 0.0])


def test_the_reported_sigma_is_rebuilt_from_the_stored_parts():
    """``scripts/sigma_parts.py`` measures changes of how the sigma's parts combine on stored realism
    runs: its rebuild gives the reported sigma of the run made at this code (s9_sigma_outline_all,
    shifts beyond ``SHIFT_NOISE_Z``) and, with ``z = 1``, of the run made before (s8_cr2_20sites)."""
    import importlib.util
    from pathlib import Path

    from xcalib.calib.uncertainty import SHIFT_NOISE_Z

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("sigma_parts", root / "scripts" / "sigma_parts.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    runs = mod.load_results()["runs"]
    checked = 0
    # runs made before session 13 combine the CR2 part with its whole stretch; s13W_clean at this code
    for label, z, cr2 in (("s9_sigma_outline_all", SHIFT_NOISE_Z, "full"), ("s8_cr2_20sites", 1.0, "full"),
                          ("s13W_clean", SHIFT_NOISE_Z, "beyond_model")):
        if label not in runs:
            continue
        for cond in runs[label]["conditions"]:
            for rec in (r for r in cond["per_site"] if r["success"] and "sigma_parts" in r):
                assert np.allclose(mod.rebuild(rec["sigma_parts"], z, cr2=cr2), rec["sigma_axes"], rtol=1e-9, atol=0), \
                    (label, rec["seed"])
                checked += 1
    assert checked >= 20 or not runs.get("s9_sigma_outline_all")


def test_the_jacobian_sigma_keeps_the_default_edge_noise_on_near_exact_boxes():
    """Issue 25: boxes that agree with their 3D boxes to far below a pixel (2D labels projected from
    the 3D labels) must not shrink the sigma with their residuals: the per-edge variance is floored at
    the default error model (1 px 2D), so 0 px and 0.05 px boxes give the same sigma, about what
    1 px boxes give, while boxes noisier than the floor still widen it."""
    sd = {}
    for noise in (0.0, 0.05, 1.0, 4.0):
        frames, T = sim_frames(seed=3, n_frames=2, noise_px=noise, miss=0.0, false_pos=0.0, extra_3d=0)
        cframes, pairs, intr, pose = _fit(frames, T)
        r, t, _ = pose_covariance(cframes, pairs, intr, pose.R, pose.t)
        sd[noise] = np.concatenate([r, t])
    assert np.all(np.isfinite(sd[0.0])) and np.all(sd[0.0] > 0)
    np.testing.assert_allclose(sd[0.05], sd[0.0], rtol=0.05)
    assert np.all(sd[0.0] > 0.5 * sd[1.0])
    assert np.all(sd[4.0] > 1.2 * sd[0.0])


def test_the_edge_noise_floor_only_where_no_frame_level_part_exists():
    """Issue 25: the default-model floor of the edge noise applies only where the residuals cannot
    see an error shared by a frame's edges: matches in fewer than ``MIN_FRAMES`` frames (one frame
    absorbs it whole; ``frames_checkable`` false). Over more frames the residual scale is the
    measured noise, so near-exact boxes over many frames keep their narrow sigma."""
    from xcalib.calib.uncertainty import MIN_FRAMES, frames_checkable

    def pairs_of(counts):
        return [np.zeros((c, 2), dtype=np.int64) for c in counts]

    assert MIN_FRAMES == 4
    assert not frames_checkable(pairs_of([40]))  # one frame
    assert not frames_checkable(pairs_of([20, 20, 20, 0, 0]))  # 3 frames with matches
    assert frames_checkable(pairs_of([1, 1, 1, 1]))  # 4 frames, however few matches each
    assert frames_checkable(pairs_of([0, 3, 0, 3, 3, 3]))  # frames without matches do not count
    sd = {}
    for noise in (0.05, 1.0):
        frames, T = sim_frames(seed=3, n_frames=6, noise_px=noise, miss=0.0, false_pos=0.0, extra_3d=0)
        cframes, pairs, intr, pose = _fit(frames, T)
        assert frames_checkable(pairs)
        r, t, _ = pose_covariance(cframes, pairs, intr, pose.R, pose.t)
        sd[noise] = np.concatenate([r, t])
        one = [p if k == 0 else p[:0] for k, p in enumerate(pairs)]  # the first frame's matches alone
        r1, t1, _ = pose_covariance(cframes, one, intr, pose.R, pose.t)
        sd[noise, 1] = np.concatenate([r1, t1])
    assert np.all(sd[0.05] < 0.25 * sd[1.0])  # many frames: the measured 0.05 px, not the floor
    assert np.all(sd[0.05, 1] > 0.5 * sd[1.0, 1])  # one frame: floored at the default model
