"""CalibConfig (one frozen, typed settings record), Pose (one parser), the cost model's terms, and
a result that carries its config and diagnostics through save/load."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_calib_support import INTR, sim_frames

import xcalib
from xcalib.calib import CalibConfig, Pose
from xcalib.calib.api import calibrate
from xcalib.calib.cost import BoxEdgeTerm, CostModel, FocalScaleTerm, PosePriorTerm
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.refine import DEFAULT_NOISE, edge_term, match_all
from xcalib.calib.result import CalibrationResult
from xcalib.geometry import euler_to_matrix, make_transform


@pytest.fixture(scope="module")
def site():
    return sim_frames(seed=1, n_frames=4)


def test_config_is_frozen_typed_and_exported_lazily():
    cfg = xcalib.CalibConfig()
    assert cfg is not None and xcalib.CalibConfig is CalibConfig
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.gate_iou = 0.5
    with pytest.raises(ValueError, match="box_model"):
        CalibConfig(box_model="hull")
    with pytest.raises(ValueError, match="gate_iou"):
        CalibConfig(gate_iou=0.0)
    assert cfg.replace(max_rot_std_deg=1.0).max_rot_std_deg == 1.0 and cfg.max_rot_std_deg == 0.5


def test_legacy_keywords_map_onto_the_config():
    cfg = CalibConfig.from_kwargs(gate=0.4, reestimate_yaw=False, max_trans_std_m=0.3)
    assert cfg.gate_iou == 0.4 and cfg.reestimate_yaw == "never" and cfg.max_trans_std_m == 0.3
    with pytest.raises(TypeError, match="max_rot_std"):  # names the unknown keyword
        CalibConfig.from_kwargs(max_rot_std=0.5)
    assert CalibConfig.from_dict(cfg.to_dict()) == cfg


def test_calibrate_with_a_config_and_with_legacy_keywords_agree(site):
    frames, T = site
    a = calibrate(frames, INTR, CalibConfig(gate_iou=0.35))
    b = calibrate(frames, INTR, gate=0.35)
    assert a.success and b.success, (a.message, b.message)
    np.testing.assert_allclose(a.translation, b.translation)
    assert a.config == b.config and a.config.gate_iou == 0.35
    with pytest.raises(TypeError, match="bogus"):
        calibrate(frames, INTR, bogus=1)


def test_result_carries_config_and_diagnostics_through_save(site, tmp_path):
    frames, T = site
    res = calibrate(frames, INTR)
    d = res.diagnostics
    assert d.seed_source == "geometry" and d.n_hypotheses > 0 and len(d.frames) == len(frames)
    assert sum(f.pairs for f in d.frames) == res.n_pairs and d.uncertainty.jacobian is not None
    assert np.asarray(d.bringup_T).shape == (4, 4) and d.noise_model.sigma_px >= DEFAULT_NOISE.sigma_px
    back = CalibrationResult.load(res.save(tmp_path / "c.json"))
    assert back.config == res.config
    assert back.diagnostics.frames == d.frames and back.diagnostics.noise_model == d.noise_model
    assert back.diagnostics.uncertainty.jacobian == pytest.approx(d.uncertainty.jacobian)


def test_pose_parser_takes_every_form():
    R, t = euler_to_matrix([0.1, -0.2, 0.3]), np.array([0.5, -1.0, 2.0])
    T = make_transform(R, t)
    res = CalibrationResult(success=True, rotation=R, translation=t)
    for obj in (T, T[:3], (R, t), [R, t.tolist()], res, Pose(R, t)):
        p = Pose.parse(obj)
        np.testing.assert_allclose(p.T, T)
    with pytest.raises(ValueError, match="4x4"):
        Pose.parse(np.eye(3))
    assert Pose(R, t).error(Pose(R, t + [0.3, 0.4, 0.0])) == pytest.approx((0.0, 0.5))


def test_a_new_cost_term_is_one_class(site):
    # a focal-scale term (one extra parameter that rescales fx, fy for every other term) finds the
    # true focal length again when the given one is 8 % off
    frames, T = site
    cf, intr, _ = prepare_frames(frames, INTR)
    pose = Pose(T[:3, :3], T[:3, 3])
    pairs = match_all(cf, intr, pose.R, pose.t, gate_iou=0.3)
    wrong = dataclasses.replace(intr, fx=intr.fx * 1.08, fy=intr.fy * 1.08)
    edges = edge_term(cf, pairs, wrong, pose)
    assert isinstance(edges, BoxEdgeTerm)
    fit = CostModel([edges, FocalScaleTerm()], pose, wrong).fit(f_scale=2.0, max_nfev=60)
    assert np.exp(fit.params["focal_scale"][0]) == pytest.approx(1 / 1.08, abs=0.01)
    # a pose prior term pulls the fit towards a given pose
    prior = Pose(euler_to_matrix([0.5, 0.0, 0.0], degrees=True) @ pose.R, pose.t + [0.2, 0, 0])
    model = CostModel([edge_term(cf, pairs, intr, pose), PosePriorTerm(prior, 1e-4, 1e-4)], pose, intr)
    near = model.fit(f_scale=2.0, max_nfev=60).pose
    assert near.error(prior)[0] < 0.01 and near.error(prior)[1] < 0.01
