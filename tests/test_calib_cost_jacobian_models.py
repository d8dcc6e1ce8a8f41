"""The analytic Jacobian of the box-edge cost for the wide-angle camera models (issue 26): each
rectangle edge moves with the densified outline point that defines it, through the model's own
``project_jacobian``. It matches central differences for every model and extra term, and a fit
with it lands where scipy's finite-difference fit lands."""

from __future__ import annotations

import numpy as np
import pytest
from test_calib_support import central_jacobian, vehicle_boxes7

from xcalib.calib.cost import (BoxEdgeTerm, CostModel, CostTerm, FocalScaleTerm, PrincipalPointTerm,
                               TimeOffsetTerm)
from xcalib.calib.pose import Pose
from xcalib.data.synth.site import WIDE_ANGLE_PARAMS
from xcalib.geometry.boxes import box7_corners
from xcalib.geometry.camera_models import get_model
from xcalib.geometry.camera_models.outline import outline_extremes, project_outline_rects

SIZE = (1280, 800)


def _scene(seed: int, model: str):
    r = np.random.default_rng(seed)
    n = 30
    # boxes all around a 185-degree camera looking along LiDAR x: ahead, beside and slightly behind
    box7 = vehicle_boxes7(r, n, 1.5, (4, 25))
    outl = box7_corners(box7)
    R0 = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    pose = Pose(R0, np.array([0.1, 0.2, 0.3]))
    cam = get_model(model)(fx=380, fy=381, cx=640, cy=400, width=SIZE[0], height=SIZE[1], **WIDE_ANGLE_PARAMS[model])
    rects, valid = project_outline_rects(outl, pose.R, pose.t, cam, SIZE)
    obs = np.nan_to_num(rects) + r.normal(0, 6, (n, 4))  # 6 px at sigma 3: occlusion shaping active
    obs[:, 2:] = np.maximum(obs[:, 2:], obs[:, :2] + 5)
    return BoxEdgeTerm(outl, obs, SIZE, np.full(n, 3.0)), pose, cam, r, valid


@pytest.mark.parametrize("model", sorted(WIDE_ANGLE_PARAMS))
@pytest.mark.parametrize("extra", ["none", "all"])
def test_model_jacobian_matches_differences(model, extra):
    term, pose, cam, r, valid = _scene(1, model)
    assert valid.sum() >= 20
    v = r.normal(0, 5, (len(term.obs), 3))
    extras = [] if extra == "none" else [FocalScaleTerm(0.1), PrincipalPointTerm(5.0), TimeOffsetTerm(v)]
    m = CostModel([term, *extras], pose, cam)
    assert m.has_analytic_jacobian()
    x = r.normal(0, 1e-3, m.n_params)
    Ja = m.analytic_jacobian(x)
    Jn = central_jacobian(m.residuals, x)
    assert Ja.shape == Jn.shape
    np.testing.assert_allclose(Ja, Jn, atol=2e-4, rtol=2e-4)
    assert np.count_nonzero(np.any(Ja != 0, axis=1)) > len(Ja) // 2


def test_outline_extremes_define_the_rectangle():
    term, pose, cam, _, valid = _scene(2, "kannala_brandt")
    ext = outline_extremes(term.outlines, pose.R, pose.t, cam)
    uv, _ = cam.project(ext.reshape(-1, 3) @ pose.R.T + pose.t)
    edges = uv.reshape(-1, 4, 2)[:, np.arange(4), [0, 1, 0, 1]]
    rects, _ = project_outline_rects(term.outlines, pose.R, pose.t, cam, SIZE, clip=False)
    np.testing.assert_allclose(edges[valid], rects[valid], atol=1e-9)


def test_model_fit_lands_where_finite_differences_land():
    term, pose, cam, _, _ = _scene(3, "double_sphere")
    m = CostModel([term, FocalScaleTerm(0.1)], pose, cam)
    fast = m.fit(f_scale=2.0, max_nfev=60)

    class Opaque(CostTerm):  # an unknown parameterised term: the model falls back to finite differences
        name, n_params, x_scale = "opaque", 1, (1.0,)

        def residuals(self, state):
            return np.asarray(state.params[self.name]) * 10.0

    slow = CostModel([term, FocalScaleTerm(0.1), Opaque()], pose, cam)
    assert not slow.has_analytic_jacobian()
    ref = slow.fit(f_scale=2.0, max_nfev=60)
    assert Pose(fast.pose.R, fast.pose.t).error(ref.pose) < (1e-4, 1e-5)
