"""The censored-edge box model (issues 25 / 26): an edge of a matched 2D box that a nearer matched
box hides is a bound (the box covers the visible part only), so it counts only outward.

Seeded box-level scenes (``test_calib_support.sim_frames``), matches from the truth, no search.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from test_calib_support import sim_frames
from test_calib_uncertainty import _truth_pairs

from xcalib.calib.censor import occluded_edges
from xcalib.calib.config import CalibConfig
from xcalib.calib.cost import Occlusion
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import FitContext, edge_term, estimate_noise, lsq
from xcalib.calib.terms import CostSpec


def _occluded(frames, T):
    """The frames with each matched 2D box cut to its visible part where a nearer matched box
    (camera range of the 3D box centre) covers its side or bottom across the whole edge."""
    out, cut = [], 0
    for f in frames:
        b = np.asarray(f.bboxes_2d, dtype=np.float64).copy()
        ij = np.argwhere(f.match_matrix)
        rng = np.linalg.norm(f.bboxes_3d[ij[:, 1], :3] @ T[:3, :3].T + T[:3, 3], axis=1)
        orig = b.copy()
        for a, i in enumerate(ij[:, 0]):
            for c, j in enumerate(ij[:, 0]):
                if rng[c] >= rng[a]:
                    continue
                bi, bj = orig[i], orig[j]
                if bj[1] <= bi[1] + 1 and bj[3] >= bi[3] - 1:  # the nearer box spans this one's height
                    if bi[0] < bj[0] < bi[2] <= bj[2]:
                        b[i, 2], cut = min(b[i, 2], bj[0]), cut + 1
                    if bj[0] <= bi[0] < bj[2] < bi[2]:
                        b[i, 0], cut = max(b[i, 0], bj[2]), cut + 1
                if bj[0] <= bi[0] + 1 and bj[2] >= bi[2] - 1 and bi[1] < bj[1] < bi[3] <= bj[3]:
                    b[i, 3], cut = min(b[i, 3], bj[1]), cut + 1
        out.append(dataclasses.replace(f, bboxes_2d=b))
    return out, cut


def _rot_err_deg(R, T) -> float:
    c = (np.trace(R @ T[:3, :3].T) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def test_an_edge_on_a_nearer_box_is_censored_and_only_that_one():
    outl = np.zeros((3, 8, 3))
    outl[0, :, 0], outl[1, :, 0], outl[2, :, 0] = 20.0, 10.0, 30.0  # ranges 20, 10, 30 m
    obs = np.array([[100, 100, 200, 180],   # far car, its right part hidden by box 1
                    [200, 90, 300, 220],    # nearer car: its left edge lies on box 0's right edge
                    [500, 100, 560, 150]])  # far away and apart: nothing
    sig = np.full(3, 1.0)
    m = occluded_edges(outl, obs, np.zeros(3, int), np.zeros(3), sig)
    np.testing.assert_array_equal(m, [[False, False, True, False], [False] * 4, [False] * 4])
    # range order decides: put box 1 behind box 0 and box 1's left edge is the hidden one
    outl2 = outl.copy()
    outl2[1, :, 0] = 25.0
    m2 = occluded_edges(outl2, obs, np.zeros(3, int), np.zeros(3), sig)
    np.testing.assert_array_equal(m2, [[False] * 4, [True, False, False, False], [False] * 4])
    # boxes of different frames never occlude each other; an edge 3 sigma away does not touch
    assert not occluded_edges(outl, obs, np.array([0, 1, 0]), np.zeros(3), sig).any()
    far = obs.astype(float).copy()
    far[0, 2] = 200 - 3 * np.sqrt(2) * 1.0
    assert not occluded_edges(outl, far, np.zeros(3, int), np.zeros(3), sig)[0].any()
    # a nearer box covering less than half of the edge leaves it (the rest of the edge is visible)
    low = obs.astype(float).copy()
    low[1] = [200, 150, 300, 220]
    assert not occluded_edges(outl, low, np.zeros(3, int), np.zeros(3), sig)[0, 2]


def test_censoring_removes_the_bias_of_occluded_boxes():
    biased, exact = [], []
    for seed in (0, 2):
        frames, T = sim_frames(seed=seed, n_frames=8, n_objects=(14, 22), noise_px=0.0, miss=0.0, false_pos=0.0,
                               extra_3d=0)
        occ, cut = _occluded(frames, T)
        assert cut >= 15  # the scene has occluded boxes
        cframes, intr, _ = prepare_frames(occ, occ[0].intrinsics)
        pairs = _truth_pairs(occ, cframes)
        truth = Pose(T[:3, :3], T[:3, 3])
        noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
        term = edge_term(cframes, pairs, intr, truth, noise, Occlusion(censor=True))
        assert term.censored is not None and term.censored.sum() >= cut // 2
        for cen, into in ((False, biased), (True, exact)):
            R, t, *_ = lsq(FitContext(cframes, pairs, intr, truth, noise, 2.0, Occlusion(censor=cen)), 60)
            into.append((_rot_err_deg(R, T), float(np.linalg.norm(t - T[:3, 3]))))
    assert min(r for r, _ in biased) > 1e-3  # the hidden edges, fitted as exact, pull the pose
    assert max(r for r, _ in exact) < 1e-5 and max(m for _, m in exact) < 1e-5  # bounds only: no pull


def test_censoring_is_a_config_option_off_by_default():
    assert CalibConfig().censor_occluded_edges is False
    assert CostSpec.from_config(CalibConfig()).occlusion.censor is False
    spec = CostSpec.from_config(CalibConfig(censor_occluded_edges=True))
    assert spec.occlusion.censor is True and spec.occlusion.tau == CalibConfig().occlusion_tau


def test_analytic_jacobian_of_censored_edges_matches_differences():
    from test_calib_cost_jacobian import _scene
    from test_calib_support import central_jacobian

    from xcalib.calib.cost import BoxEdgeTerm, CostModel

    base, pose, intr, r = _scene(1, None)
    cens = r.random((len(base.obs), 4)) < 0.4
    term = BoxEdgeTerm(base.outlines, base.obs, base.size, 1.0 / base.w[:, 0], base.occlusion, cens)
    m = CostModel([term], pose, intr)
    x = r.normal(0, 1e-3, m.n_params)
    np.testing.assert_allclose(m.analytic_jacobian(x), central_jacobian(m.residuals, x), atol=1e-4, rtol=1e-4)
    res = m.residuals(x).reshape(-1, 4)
    plain = CostModel([base], pose, intr).residuals(x).reshape(-1, 4)
    from xcalib.calib.cost import INWARD
    hidden_in = cens & (plain * INWARD > 0)
    assert hidden_in.sum() > 5 and np.all(res[hidden_in] == 0)  # a censored edge's inward residual costs nothing
    np.testing.assert_array_equal(res[~hidden_in], plain[~hidden_in])  # everything else as before


def test_auto_censors_boxes_of_the_visible_part_and_keeps_amodal_boxes():
    frames, T = sim_frames(seed=1, n_frames=8, n_objects=(14, 22), noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    truth = Pose(T[:3, :3], T[:3, 3])
    occ, _ = _occluded(frames, T)
    decided = {}
    for name, frs in (("amodal", frames), ("visible", occ)):
        cframes, intr, _ = prepare_frames(frs, frs[0].intrinsics)
        pairs = _truth_pairs(frs, cframes)
        noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
        always = edge_term(cframes, pairs, intr, truth, noise, Occlusion(censor=True))
        assert always.censored is not None and always.censored.sum() >= 10  # the same geometry: candidates in both
        decided[name] = edge_term(cframes, pairs, intr, truth, noise, Occlusion(censor="auto")).censored is not None
    assert decided == {"amodal": False, "visible": True}
    assert CostSpec.from_config(CalibConfig(censor_occluded_edges="auto")).occlusion.censor == "auto"
    import pytest
    with pytest.raises(ValueError, match="censor_occluded_edges"):
        CalibConfig(censor_occluded_edges="sometimes")
