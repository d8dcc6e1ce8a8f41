"""The box-edge Jacobian of a camera model (``BoxEdgeTerm._model_jacobian``) takes the outline points
that define each rectangle edge from the projection of the residuals at the same pose
(``outline_rects_and_extremes``), instead of projecting and refining the outlines a second
time (``outline_extremes``; issue 29: half the lens check's projections). Checked against the
previous form, written out here: the same Jacobian and residuals (as numbers) for every wide-angle
model, with and without extra terms, at poses that leave some outlines behind the camera, and the
same fit to the bit."""

from __future__ import annotations

import numpy as np
import pytest
from test_calib_support import central_jacobian, vehicle_boxes7

from xcalib.calib.boxproj import MIN_DEPTH_M, project_rects
from xcalib.calib.cost import BoxEdgeTerm, CostModel, FocalScaleTerm, PrincipalPointTerm, TimeOffsetTerm, WideLensTerm
from xcalib.calib.pose import Pose
from xcalib.data.synth.site import WIDE_ANGLE_PARAMS
from xcalib.geometry.boxes import box7_corners
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.geometry.camera_models import get_model
from xcalib.geometry.camera_models.outline import outline_extremes, outline_rects_and_extremes, project_outline_rects

SIZE = (1280, 800)


def _previous_lookup(self, state):
    """The previous form: ``project_rects`` at the state, and the outline points defining the edges
    projected and refined once more at the pose (``outline_extremes``); nothing kept."""
    outlines = self.outlines if state.shift_m is None else self.outlines + np.asarray(state.shift_m)[:, None, :]
    rects, valid = project_rects(outlines, state.pose.R, state.pose.t, state.intr, self.size)
    return rects, valid, outline_extremes(outlines, state.pose.R, state.pose.t, state.intr)


def _scene(seed: int, model: str, behind: int = 0):
    r = np.random.default_rng(seed)
    n = 24
    box7 = vehicle_boxes7(r, n, 1.5, (4, 25))
    if behind:  # some boxes behind the camera (LiDAR -x): invalid rectangles, zero Jacobian rows
        box7[:behind, 0] *= -1.0
    outl = box7_corners(box7)
    R0 = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    pose = Pose(R0, np.array([0.1, 0.2, 0.3]))
    cam = get_model(model)(fx=380, fy=381, cx=640, cy=400, width=SIZE[0], height=SIZE[1], **WIDE_ANGLE_PARAMS[model])
    rects, valid = project_outline_rects(outl, pose.R, pose.t, cam, SIZE)
    obs = np.nan_to_num(rects) + r.normal(0, 6, (n, 4))
    obs[:, 2:] = np.maximum(obs[:, 2:], obs[:, :2] + 5)
    return outl, obs, pose, cam, r, valid


def _both(monkeypatch, make):
    """``make()`` (a fresh cost model) evaluated by ``use`` with this code and with the previous lookup."""
    def use(fn):
        out = fn(make())
        with monkeypatch.context() as m:
            m.setattr(BoxEdgeTerm, "_model_projection", _previous_lookup)
            return out, fn(make())
    return use


@pytest.mark.parametrize("model", sorted(WIDE_ANGLE_PARAMS))
@pytest.mark.parametrize("behind", [0, 5])
def test_model_jacobian_is_the_previous_one(model, behind, monkeypatch):
    outl, obs, pose, cam, r, valid = _scene(4, model, behind)
    assert valid.sum() >= 12 and (behind == 0 or not valid.all())  # some rectangles invalid
    v = r.normal(0, 5, (len(obs), 3))
    for extras in ([], [FocalScaleTerm(0.1), PrincipalPointTerm(5.0), TimeOffsetTerm(v)]):
        use = _both(monkeypatch, lambda: CostModel([BoxEdgeTerm(outl, obs, SIZE, np.full(len(obs), 3.0)), *extras],
                                                   pose, cam))
        for s in range(2):
            x = np.random.default_rng(s).normal(0, 2e-3, 6 + sum(e.n_params for e in extras))
            x2 = x.copy()
            x2[6:] *= 1.5  # the same pose, other intrinsics / shifts (nothing kept from x may be reused)
            (rn, Jn, rn2, Jn2), (ro, Jo, ro2, Jo2) = use(lambda m: (m.residuals(x), m.analytic_jacobian(x),
                                                                    m.residuals(x2), m.analytic_jacobian(x2)))
            np.testing.assert_array_equal(rn, ro)
            np.testing.assert_array_equal(Jn, Jo)  # equal as numbers (0.0 == -0.0 in the zero rows)
            np.testing.assert_array_equal(rn2, ro2)
            np.testing.assert_array_equal(Jn2, Jo2)
            assert np.count_nonzero(np.any(Jn != 0, axis=1)) > len(Jn) // 3


def test_points_are_outline_extremes_at_valid_rectangles():
    outl, _, pose, cam, _, _ = _scene(5, "kannala_brandt", behind=4)
    rects, valid, pts = outline_rects_and_extremes(outl, pose.R, pose.t, cam, SIZE, min_distance=MIN_DEPTH_M)
    ref_rects, ref_valid = project_outline_rects(outl, pose.R, pose.t, cam, SIZE, min_distance=MIN_DEPTH_M)
    assert rects.tobytes() == ref_rects.tobytes() and np.array_equal(valid, ref_valid)  # the rects to the bit
    ref = outline_extremes(outl, pose.R, pose.t, cam)
    assert pts.shape == ref.shape and 0 < valid.sum() < len(valid)
    np.testing.assert_array_equal(pts[valid], ref[valid])
    assert np.isfinite(pts).all()
    # one pose in a batch of one: [1,M,4,3]
    _, _, pts1 = outline_rects_and_extremes(outl, pose.R[None], pose.t[None], cam, SIZE, min_distance=MIN_DEPTH_M)
    np.testing.assert_array_equal(pts1[0], pts)


def test_points_of_point_outlines_and_none_off_the_path():
    outl, _, pose, cam, _, _ = _scene(6, "unified", behind=4)
    r = np.random.default_rng(6)
    hull = np.concatenate([outl, outl[:, :2] + r.normal(0, 0.3, (len(outl), 2, 3))], axis=1)  # 10 points: a hull
    rects, valid, pts = outline_rects_and_extremes(hull, pose.R, pose.t, cam, SIZE, min_distance=MIN_DEPTH_M)
    ref_rects, ref_valid = project_outline_rects(hull, pose.R, pose.t, cam, SIZE, min_distance=MIN_DEPTH_M)
    assert rects.tobytes() == ref_rects.tobytes() and np.array_equal(valid, ref_valid)  # the rects to the bit
    ref = outline_extremes(hull, pose.R, pose.t, cam)
    assert 0 < valid.sum() < len(valid)
    np.testing.assert_array_equal(pts[valid], ref[valid])
    empty = outline_rects_and_extremes(outl[:0], pose.R, pose.t, cam, SIZE)
    assert len(empty) == 3 and empty[2] is None and empty[0].shape == (0, 4)
    many = 180  # 180 poses x 24 outlines > 4096: not refined, no points
    Rs, ts = np.repeat(pose.R[None], many, 0), np.repeat(pose.t[None], many, 0)
    r_many, v_many, p_many = outline_rects_and_extremes(outl, Rs, ts, cam, SIZE, min_distance=MIN_DEPTH_M)
    assert p_many is None and r_many.shape == (many, len(outl), 4)
    ref_many = project_outline_rects(outl, Rs, ts, cam, SIZE, min_distance=MIN_DEPTH_M)[0]
    assert r_many.tobytes() == ref_many.tobytes()


def test_lens_fit_is_the_previous_one_to_the_bit(monkeypatch):
    outl, obs, pose, _, _, _ = _scene(7, "unified")
    pin = CameraIntrinsics(fx=380, fy=381, cx=640, cy=400, width=SIZE[0], height=SIZE[1])
    use = _both(monkeypatch, lambda: CostModel([BoxEdgeTerm(outl, obs, SIZE, np.full(len(obs), 3.0)),
                                                WideLensTerm(pin, None, 0.5), FocalScaleTerm()], pose, pin))
    a, b = use(lambda m: m.fit(f_scale=2.0, max_nfev=40))
    assert a.x.tobytes() == b.x.tobytes() and a.cost == b.cost
    assert a.residuals.tobytes() == b.residuals.tobytes()
    assert abs(a.params[WideLensTerm.name][0] - 0.5) > 1e-6  # the lens parameter moved: the fit ran


# --- WideLensTerm's xi column: analytic (Tangent.xi), not a forward difference (issue 29) ---

def _lens_model(start, fixed=None, dist=None, seed=7):
    outl, obs, pose, _, _, _ = _scene(seed, "unified")
    pin = CameraIntrinsics(fx=380, fy=381, cx=640, cy=400, width=SIZE[0], height=SIZE[1], distortion=dist)
    return CostModel([BoxEdgeTerm(outl, obs, SIZE, np.full(len(obs), 3.0)), WideLensTerm(pin, fixed, start),
                      FocalScaleTerm(), PrincipalPointTerm()], pose, pin)


@pytest.mark.parametrize("start", [0.0, 0.5, 1.3])
@pytest.mark.parametrize("dist", [None, (-0.1, 0.02, 0.001, -0.001)])
def test_xi_column_is_the_derivative(start, dist):
    m = _lens_model(start, dist=dist)
    x = np.random.default_rng(1).normal(0, 1e-3, m.n_params)
    x[6] = abs(x[6]) + 1e-3  # inside the clip
    Ja = m.analytic_jacobian(x)
    Jn = central_jacobian(m.residuals, x)
    scale = np.abs(Jn[:, 6]).max()
    assert scale > 10.0  # the lens moves the edges
    np.testing.assert_allclose(Ja[:, 6], Jn[:, 6], atol=2e-6 * scale)
    # closer to the central difference than the forward difference it replaces
    fwd = m._forward_columns(x, [6])[:, 0]
    assert np.abs(Ja[:, 6] - Jn[:, 6]).max() < np.abs(fwd - Jn[:, 6]).max()


def test_xi_column_zero_where_held():
    held = _lens_model(0.0, fixed=0.0)
    x = np.random.default_rng(2).normal(0, 1e-3, held.n_params)
    J = held.analytic_jacobian(x)
    assert np.all(J[:, 6] == 0.0) and np.any(J[:, 7] != 0.0)
    clipped = _lens_model(0.0)
    x[6] = -0.01  # xi clipped at 0: no derivative
    assert np.all(clipped.analytic_jacobian(x)[:, 6] == 0.0)
    x[6] = 0.0  # at the bound, the forward side (as the forward difference took it)
    assert np.any(clipped.analytic_jacobian(x)[:, 6] != 0.0)
    top = _lens_model(WideLensTerm.MAX_XI)
    x[6] = 0.0
    assert np.all(top.analytic_jacobian(x)[:, 6] == 0.0)
    x[6] = -0.01
    assert np.any(top.analytic_jacobian(x)[:, 6] != 0.0)


def test_model_jacobian_of_point_outlines_is_the_previous_one(monkeypatch):
    outl, obs, pose, cam, r, _ = _scene(8, "kannala_brandt", behind=3)
    hull = np.concatenate([outl, outl[:, :3] + r.normal(0, 0.3, (len(outl), 3, 3))], axis=1)  # 11-point hulls
    use = _both(monkeypatch, lambda: CostModel([BoxEdgeTerm(hull, obs, SIZE, np.full(len(obs), 3.0)),
                                                FocalScaleTerm(0.1)], pose, cam))
    x = np.random.default_rng(8).normal(0, 2e-3, 7)
    (rn, Jn), (ro, Jo) = use(lambda m: (m.residuals(x), m.analytic_jacobian(x)))
    np.testing.assert_array_equal(rn, ro)
    np.testing.assert_array_equal(Jn, Jo)
    assert np.count_nonzero(np.any(Jn != 0, axis=1)) > len(Jn) // 3
