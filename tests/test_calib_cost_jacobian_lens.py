"""Issue 29: the wide-lens refit of the lens-misfit check (``cost.WideLensTerm``, a pinhole widened
into Mei's unified model) has an analytic Jacobian, its ``xi`` column included (``Tangent.xi``, since
session 13; a forward difference before): it matches central differences, and a fit with it lands where scipy's finite-difference fit lands."""

from __future__ import annotations

import numpy as np
import pytest
from test_calib_support import central_jacobian, vehicle_boxes7

from xcalib.calib.boxproj import project_rects
from xcalib.calib.cost import BoxEdgeTerm, CostModel, CostTerm, FocalScaleTerm, WideLensTerm
from xcalib.calib.pose import Pose
from xcalib.geometry.boxes import box7_corners
from xcalib.geometry.camera import CameraIntrinsics

SIZE = (1280, 800)


def _scene(seed: int):
    r = np.random.default_rng(seed)
    n = 30
    box7 = vehicle_boxes7(r, n, 0.5, (6, 30))
    outl = box7_corners(box7)
    pose = Pose(np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), np.array([0.1, 0.2, 0.3]))
    intr = CameraIntrinsics(fx=800.0, fy=801.0, cx=640.0, cy=400.0, width=SIZE[0], height=SIZE[1],
                            distortion=np.array([-0.05, 0.01, 0.0, 0.0]))
    rects, valid = project_rects(outl, pose.R, pose.t, intr, SIZE)
    obs = np.nan_to_num(rects) + r.normal(0, 6, (n, 4))
    obs[:, 2:] = np.maximum(obs[:, 2:], obs[:, :2] + 5)
    return BoxEdgeTerm(outl, obs, SIZE, np.full(n, 3.0)), pose, intr, r, valid


@pytest.mark.parametrize("start, fixed", [(0.3, None), (1.0, None), (0.0, 0.0)])
def test_wide_lens_jacobian_matches_differences(start, fixed):
    term, pose, intr, r, valid = _scene(1)
    assert valid.sum() >= 20
    m = CostModel([term, WideLensTerm(intr, fixed, start), FocalScaleTerm()], pose, intr)
    assert m.has_analytic_jacobian()
    x = r.normal(0, 1e-3, m.n_params)
    Ja = m.analytic_jacobian(x)
    Jn = central_jacobian(m.residuals, x, eps=1e-6)
    assert Ja.shape == Jn.shape
    np.testing.assert_allclose(Ja, Jn, atol=2e-3, rtol=2e-3)  # (the xi column: forward differences)
    assert np.count_nonzero(Ja[:, 6]) > len(Ja) // 2 if fixed is None else not np.any(Ja[:, 6])


def test_wide_lens_fit_lands_where_finite_differences_land():
    term, pose, intr, _, _ = _scene(3)

    class Opaque(CostTerm):  # an unknown parameterised term: the model falls back to finite differences
        name, n_params, x_scale = "opaque", 1, (1.0,)

        def residuals(self, state):
            return np.asarray(state.params[self.name]) * 10.0

    fast = CostModel([term, WideLensTerm(intr, None, 0.3), FocalScaleTerm()], pose, intr).fit(f_scale=2.0, max_nfev=60)
    slow = CostModel([term, WideLensTerm(intr, None, 0.3), FocalScaleTerm(), Opaque()], pose, intr)
    assert not slow.has_analytic_jacobian()
    ref = slow.fit(f_scale=2.0, max_nfev=60)
    assert abs(fast.cost - ref.cost) <= 1e-3 * ref.cost
    assert abs(fast.params[WideLensTerm.name][0] - ref.params[WideLensTerm.name][0]) < 1e-3
    rot, trans = fast.pose.error(ref.pose)
    assert rot < 1e-3 and trans < 1e-3
