"""The fitted noise model's own pose covariance with its 3D centre error as a rigid shift of each box
(``uncertainty.centre_model_sd``, issue 26, session 11): measured and stored, not part of the sigma.

A seeded box-level scene (``test_calib_support.sim_frames``, exact boxes, true matches): the 3D boxes
shifted rigidly by a known centre noise and the 2D edges by a known edge noise, refitted per draw;
the spread of the poses is what the function predicts, and more than the edges-independent reading
of the same variance gives.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from test_calib_support import sim_frames
from test_calib_uncertainty import _truth_pairs

from xcalib.calib.diagnostics import NoiseModel
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import FitContext, build_cost, lsq
from xcalib.calib.uncertainty import centre_model_sd

NOISE = NoiseModel(sigma_px=1.0, sigma_3d_m=0.15, sigma_size=0.01)


def _scene():
    frames, T = sim_frames(seed=3, n_frames=4, n_objects=(10, 14), noise_px=0.0, miss=0.0, false_pos=0.0,
                           extra_3d=0)
    cframes, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    return cframes, _truth_pairs(frames, cframes), intr, Pose(T[:3, :3], T[:3, 3])


def test_the_predicted_sigma_is_the_spread_of_rigid_centre_and_edge_noise():
    cframes, pairs, intr, truth = _scene()
    ctx = FitContext(cframes, pairs, intr, truth, NOISE, 2.0, None)
    sd = centre_model_sd(ctx)
    assert sd is not None and sd.shape == (6,) and np.all(sd > 0)
    rng = np.random.default_rng(7)
    errs = []
    for _ in range(40):
        fr = []
        for cf in cframes:
            shift = rng.normal(0.0, NOISE.sigma_3d_m, (len(cf.corners), 1, 3))  # one rigid error per box
            b2 = cf.boxes2d + rng.normal(0.0, NOISE.sigma_px, cf.boxes2d.shape)
            fr.append(dataclasses.replace(cf, corners=cf.corners + shift, boxes2d=b2))
        R, t, *_ = lsq(FitContext(fr, pairs, intr, truth, NOISE, 2.0, None), 40)
        errs.append(Pose(R, t).delta(truth))
    spread = np.sqrt(np.mean(np.square(errs), axis=0))
    ratio = spread / sd
    assert np.all(ratio > 0.7) and np.all(ratio < 1.4), ratio  # 40 draws: ~11 % sampling error per axis
    # the same edge variance read as independent per edge (the classic part's reading) is too narrow
    model = build_cost(cframes, pairs, intr, truth, NOISE, None)
    _, J = model.jacobian(None)
    d = np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    classic = np.concatenate([np.degrees(d[:3]), d[3:]])
    assert np.all(sd >= classic * 0.999) and np.max(sd / classic) > 1.3


def test_no_centre_term_gives_the_independent_edge_covariance_and_few_matches_none():
    cframes, pairs, intr, truth = _scene()
    flat = NoiseModel(sigma_px=1.0, sigma_3d_m=0.0, sigma_size=0.0)
    sd = centre_model_sd(FitContext(cframes, pairs, intr, truth, flat, 2.0, None))
    _, J = build_cost(cframes, pairs, intr, truth, flat, None).jacobian(None)
    d = np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    np.testing.assert_allclose(sd, np.concatenate([np.degrees(d[:3]), d[3:]]), rtol=1e-9)
    one = [p[:1] if i == 0 else p[:0] for i, p in enumerate(pairs)]
    assert centre_model_sd(FitContext(cframes, one, intr, truth, NOISE, 2.0, None)) is None
