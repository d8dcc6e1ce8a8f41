"""The analytic Jacobian of the calibration cost (issue 29: it replaces scipy's finite differences)
matches central differences for every term and the distortion model, and a fit with it lands
where the finite-difference fit lands."""

from __future__ import annotations

import numpy as np
import pytest
from test_calib_support import central_jacobian

from xcalib.calib.boxproj import project_rects
from xcalib.calib.cost import (BoxEdgeTerm, CostModel, CostTerm, FocalScaleTerm, PosePriorTerm, PrincipalPointTerm,
                               TimeOffsetTerm)
from xcalib.calib.pose import Pose
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.geometry.rotations import rotvec_to_matrix, so3_exp, so3_left_jacobian

SIZE = (1920, 1200)


def _scene(seed: int, dist):
    r = np.random.default_rng(seed)
    n = 30
    ctr = np.column_stack([r.uniform(5, 40, n), r.uniform(-15, 15, n), r.uniform(-1, 1, n)])
    outl = ctr[:, None, :] + r.uniform(-1.5, 1.5, (n, 8, 3))
    R0 = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    pose = Pose(R0, np.array([0.1, 0.2, 0.3]))
    intr = CameraIntrinsics(fx=1000, fy=1010, cx=960, cy=600, width=SIZE[0], height=SIZE[1], distortion=dist)
    rects, _ = project_rects(outl, pose.R, pose.t, intr, SIZE)
    obs = np.nan_to_num(rects) + r.normal(0, 6, (n, 4))  # 6 px at sigma 3: occlusion shaping active
    obs[:, 2:] = np.maximum(obs[:, 2:], obs[:, :2] + 5)
    return BoxEdgeTerm(outl, obs, SIZE, np.full(n, 3.0)), pose, intr, r


@pytest.mark.parametrize("dist", [None, [-0.2, 0.05, 1e-3, -2e-3, 0.01]])
@pytest.mark.parametrize("extra", ["none", "focal", "principal", "time", "all", "prior"])
def test_analytic_jacobian_matches_differences(dist, extra):
    term, pose, intr, r = _scene(1, dist)
    v = r.normal(0, 5, (len(term.obs), 3))
    extras = {"none": [], "focal": [FocalScaleTerm(0.1)], "principal": [PrincipalPointTerm(5.0)],
              "time": [TimeOffsetTerm(v)], "all": [FocalScaleTerm(), PrincipalPointTerm(), TimeOffsetTerm(v)],
              "prior": [PosePriorTerm(pose, 1.0, 0.5)]}[extra]
    m = CostModel([term, *extras], pose, intr)
    assert m.has_analytic_jacobian()
    x = r.normal(0, 1e-3, m.n_params)
    Ja = m.analytic_jacobian(x)
    Jn = central_jacobian(m.residuals, x)
    assert Ja.shape == Jn.shape
    np.testing.assert_allclose(Ja, Jn, atol=1e-4, rtol=1e-4)
    # clipped edges and boxes that cannot be projected carry exact zeros (the sandwich drops them)
    assert np.any(np.all(Ja == 0, axis=1)) and np.count_nonzero(np.any(Ja != 0, axis=1)) > len(Ja) // 2


def test_fit_lands_where_finite_differences_land():
    term, pose, intr, _ = _scene(2, None)
    m = CostModel([term], pose, intr)
    fast = m.fit(f_scale=2.0, max_nfev=60)

    class Opaque(CostTerm):  # an unknown parameterised term: the model falls back to finite differences
        name, n_params, x_scale = "opaque", 1, (1.0,)

        def residuals(self, state):
            return np.asarray(state.params[self.name]) * 10.0

    slow = CostModel([term, Opaque()], pose, intr)
    assert not slow.has_analytic_jacobian()
    ref = slow.fit(f_scale=2.0, max_nfev=60)
    assert Pose(fast.pose.R, fast.pose.t).error(ref.pose) < (1e-4, 1e-5)


def test_so3_exp_and_left_jacobian():
    r = np.random.default_rng(0)
    for scale in (0.0, 1e-9, 1e-4, 0.3, 2.5):
        w = r.normal(size=3) * scale
        np.testing.assert_allclose(so3_exp(w), rotvec_to_matrix(w), atol=1e-14)
        y, d = r.normal(size=3), 1e-7
        num = np.stack([(so3_exp(w + d * e) @ y - so3_exp(w - d * e) @ y) / (2 * d) for e in np.eye(3)], 1)
        P = so3_exp(w) @ y
        skew = np.array([[0, -P[2], P[1]], [P[2], 0, -P[0]], [-P[1], P[0], 0]])
        np.testing.assert_allclose(num, -skew @ so3_left_jacobian(w), atol=1e-7)
