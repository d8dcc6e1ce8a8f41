"""The 3D centre error the boxes' residuals show (``uncertainty.centre_noise``, issues 25 / 26, session 12) and
its part in the reported sigma (``centre_shift_sd``, ``with_centre_shift``).

A seeded box-level scene (``test_calib_support.sim_frames``, exact boxes, true matches): the 3D boxes shifted
rigidly by a known centre error, scaled by a known size error, and the 2D edges moved by a known edge noise;
the pose refitted, and the three errors read back at the fitted pose from the boxes' shift and spread
components.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from test_calib_support import sim_frames
from test_calib_uncertainty import _truth_pairs

from xcalib.calib.diagnostics import NoiseModel
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import FitContext, lsq
from xcalib.calib.uncertainty import centre_noise, centre_shift_sd, with_centre_shift

NOISE = NoiseModel(sigma_px=1.0, sigma_3d_m=0.03, sigma_size=0.01)  # the fit's weights: the default-like model


def _scene():
    frames, T = sim_frames(seed=3, n_frames=4, n_objects=(10, 14), noise_px=0.0, miss=0.0, false_pos=0.0,
                           extra_3d=0)
    cframes, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    return cframes, _truth_pairs(frames, cframes), intr, Pose(T[:3, :3], T[:3, 3])


def _draw(cframes, rng, centre_m: float, size_rel: float, px: float):
    out = []
    for cf in cframes:
        c = cf.corners
        mid = c.mean(axis=1, keepdims=True)
        scale = 1.0 + rng.normal(0.0, size_rel, (len(c), 1, 1))  # one size error per box, about its centre
        shift = rng.normal(0.0, centre_m, (len(c), 1, 3))  # one rigid centre error per box
        b2 = cf.boxes2d + rng.normal(0.0, px, cf.boxes2d.shape)
        out.append(dataclasses.replace(cf, corners=mid + (c - mid) * scale + shift, boxes2d=b2))
    return out


def _fitted(cframes, pairs, intr, truth, rng, **noise):
    fr = _draw(cframes, rng, **noise)
    R, t, *_ = lsq(FitContext(fr, pairs, intr, truth, NOISE, 2.0, None), 40)
    return FitContext(fr, pairs, intr, Pose(R, t), NOISE, 2.0, None)


def test_a_rigid_centre_error_is_read_back_at_the_fitted_pose_and_gives_a_part():
    cframes, pairs, intr, truth = _scene()
    rng = np.random.default_rng(11)
    est = [centre_noise(_fitted(cframes, pairs, intr, truth, rng, centre_m=0.15, size_rel=0.02, px=1.0))
           for _ in range(4)]
    assert all(e is not None and e.measured for e in est)
    s3 = np.sqrt(np.mean([e.sigma_3d_m ** 2 for e in est]))
    assert 0.11 < s3 < 0.19, s3  # 0.15 m drawn; ~45 boxes x 4 draws
    assert 0.6 < np.median([e.sigma_px for e in est]) < 1.4  # 1 px drawn, from the spread components
    ctx = _fitted(cframes, pairs, intr, truth, rng, centre_m=0.15, size_rel=0.02, px=1.0)
    part = centre_shift_sd(ctx)
    assert part is not None and part.shape == (6,) and np.all(part > 0)


def test_size_and_edge_noise_alone_are_not_read_as_a_centre_error():
    cframes, pairs, intr, truth = _scene()
    rng = np.random.default_rng(12)
    for _ in range(3):
        ctx = _fitted(cframes, pairs, intr, truth, rng, centre_m=0.0, size_rel=0.04, px=1.0)
        est = centre_noise(ctx)
        assert est is not None and est.sigma_3d_m < 0.05, est  # the size error moves opposite edges apart
        assert est.sigma_size > 0.02
        if not est.measured:
            assert centre_shift_sd(ctx, est) is None


def test_the_part_is_a_floor_of_the_sigma_and_few_matches_give_none():
    r, t = np.array([0.1, 0.2, 0.3]), np.array([0.01, 0.05, 0.02])
    r2, t2 = with_centre_shift(r, t, np.array([0.2, 0.1, 0.3, 0.03, 0.01, 0.02]))
    np.testing.assert_allclose(r2, [0.2, 0.2, 0.3])
    np.testing.assert_allclose(t2, [0.03, 0.05, 0.02])
    assert with_centre_shift(r, t, None) == (r, t)
    cframes, pairs, intr, truth = _scene()
    one = [p[:1] if i == 0 else p[:0] for i, p in enumerate(pairs)]
    ctx = FitContext(cframes, one, intr, truth, NOISE, 2.0, None)
    assert centre_noise(ctx) is None and centre_shift_sd(ctx) is None


def test_the_floor_part_counts_only_a_measured_centre_error_above_the_default():
    from xcalib.calib.uncertainty import centre_floor_sd, centre_model_sd

    cframes, pairs, intr, truth = _scene()
    rng = np.random.default_rng(13)
    ctx = _fitted(cframes, pairs, intr, truth, rng, centre_m=0.15, size_rel=0.02, px=1.0)
    est = centre_noise(ctx)
    part = centre_floor_sd(ctx, est)
    assert part is not None and np.all(part > 0)
    # D's part at the fit's own noise model (centre term 3 cm) is narrower: the measured 0.15 m is the difference
    assert np.all(part >= centre_model_sd(ctx) * 0.999) and np.max(part / centre_model_sd(ctx)) > 1.5
    exact = _fitted(cframes, pairs, intr, truth, rng, centre_m=0.0, size_rel=0.0, px=1.0)
    assert centre_floor_sd(exact) is None  # nothing measured (or below 3 cm): the sigma is left as it is
    assert centre_floor_sd(ctx, dataclasses.replace(est, sigma_3d_m=0.02)) is None  # below the default model's 3 cm
    assert centre_floor_sd(ctx, dataclasses.replace(est, measured=False)) is None
