"""Calibration-aware matching: ``Matcher.set_calibration`` / ``calibration.json`` beside site
weights, ``match(use_calibration=...)`` fusing the model with the projection IoU, the one-shot
session's matcher carrying its pose, and the same fusion in the ONNX Runtime matcher."""

from __future__ import annotations

import numpy as np
import pytest

from _matching_frames import small_site, states_equal, tiny_matcher
from xcalib.calib.result import CalibrationResult
from xcalib.data.synth import generate_frames
from xcalib.engine.fusion import fuse_scores
from xcalib.engine.matcher import Matcher
from xcalib.engine.metrics import MetricsAccumulator


@pytest.fixture(scope="module")
def site():
    return small_site()


@pytest.fixture(scope="module")
def frames(site):
    return generate_frames(site, 6, seed=1, render_images=False)


_matcher = tiny_matcher


def _gt_pose(site) -> CalibrationResult:
    T = site.T_cam_lidar
    return CalibrationResult(success=True, intrinsics=site.intrinsics, rotation=T[:3, :3], translation=T[:3, 3],
                             method="survey")


def _top1(matcher, frames, use_calibration) -> float:
    acc = MetricsAccumulator()
    for f in frames:
        r = matcher.match(*f.inputs(), validate="off", use_calibration=use_calibration)
        gt = np.asarray(f.match_matrix, bool)[np.ix_(r.kept_2d_indices, r.kept_3d_indices)]
        if gt.any():
            acc.add(r.similarity, gt, 0.0)
    return acc.result().top1


_states_equal = states_equal


def test_fusion_lifts_top1_on_a_site_the_model_was_not_trained_on(site, frames):
    m = _matcher()  # never trained on this site (random weights)
    m.set_calibration(_gt_pose(site))
    alone, fused = _top1(m, frames, False), _top1(m, frames, "auto")
    assert alone < 0.5
    assert fused >= 0.95 and fused > alone + 0.4
    r = m.match(*frames[0].inputs(), validate="off")
    assert r.geometry_iou is not None and r.geometry_iou.shape == r.similarity.shape
    assert r.fusion_weight == m.fusion_weight > 0
    assert r.similarity.dtype == np.float32 and np.all((r.similarity >= 0) & (r.similarity <= 1))


def test_use_calibration_false_returns_the_model_scores_unchanged(site, frames):
    plain, calibrated = _matcher(), _matcher()
    calibrated.set_calibration(_gt_pose(site))
    f = frames[1]
    a = plain.match(*f.inputs(), validate="off")  # no calibration: "auto" is the model alone
    b = calibrated.match(*f.inputs(), validate="off", use_calibration=False)
    c = calibrated.match(*f.inputs(), validate="off")
    assert np.array_equal(a.similarity, b.similarity) and a.matches == b.matches
    assert b.geometry_iou is None and b.fusion_weight == 0.0
    assert not np.array_equal(b.similarity, c.similarity)
    with pytest.raises(ValueError, match="no calibration"):
        plain.match(*f.inputs(), validate="off", use_calibration=True)
    with pytest.raises(ValueError, match="use_calibration"):
        calibrated.match(*f.inputs(), validate="off", use_calibration="yes")


def test_box7_gives_the_projection_the_detector_yaw(site, frames):
    m = _matcher()
    m.set_calibration(_gt_pose(site))
    f = frames[2]
    r = m.match(*f.inputs(), validate="off", box7=f.meta["box7"])
    gt = np.asarray(f.match_matrix, bool)[np.ix_(r.kept_2d_indices, r.kept_3d_indices)]
    rows = gt.any(1)
    # the true pair has the row's best IoU through the true pose
    assert np.mean(gt[rows, r.geometry_iou[rows].argmax(1)]) >= 0.95


def test_fuse_scores_keeps_range_fill_and_endpoints():
    rng = np.random.default_rng(0)
    iou = rng.uniform(0, 1, (4, 5))
    cos = rng.uniform(-1, 1, (4, 5)).astype(np.float32)
    f = fuse_scores(cos, iou, score_range=(-1.0, 1.0), weight=0.5)
    assert f.dtype == np.float32 and np.all((f >= -1) & (f <= 1))
    p = rng.uniform(0.01, 0.99, (4, 5)).astype(np.float32)
    assert np.allclose(fuse_scores(p, iou, weight=0.0), p, atol=1e-6)
    only_geo = fuse_scores(p, iou, weight=1.0, eps=0.02)
    assert np.allclose(only_geo, np.clip(iou, 0.02, 0.98), atol=1e-6)
    p[0, 0] = -1.0  # crlite's "not scored"
    assert fuse_scores(p, iou, weight=0.5, fill_value=-1.0)[0, 0] == -1.0
    with pytest.raises(ValueError, match="weight"):
        fuse_scores(p, iou, weight=1.5)


def test_saved_site_reloads_weights_and_calibration(site, frames, tmp_path, monkeypatch):
    m = _matcher(model="fastmatch")
    s = m.oneshot(site.intrinsics, min_frames=100)
    assert m.calibration is None
    s.set_calibration(_gt_pose(site))
    assert m.calibration is s.calibration  # the session's matcher carries the pose
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path / "home"))
    paths = s.save_site("fused_site")
    assert paths["calibration"].name == "calibration.json"
    again = Matcher.from_pretrained("fastmatch", site="fused_site", device="cpu")
    assert _states_equal(m.model, again.model)
    assert again.calibration is not None
    assert np.array_equal(again.calibration.extrinsics, m.calibration.extrinsics)
    assert again.calibration.intrinsics.to_dict() == m.calibration.intrinsics.to_dict()
    f = frames[3]
    a, b = m.match(*f.inputs(), validate="off"), again.match(*f.inputs(), validate="off")
    assert b.fusion_weight > 0 and np.array_equal(a.similarity, b.similarity)
    # save_pretrained writes it too; a folder without one gives no calibration
    d = again.save_pretrained(tmp_path / "copy")
    assert "calibration" in d and Matcher.from_pretrained("fastmatch", weights=tmp_path / "copy").calibration
    _matcher().save_pretrained(tmp_path / "plain")
    assert Matcher.from_pretrained("fastmatch", weights=tmp_path / "plain").calibration is None
    with pytest.raises(ValueError, match="failed"):
        m.set_calibration(CalibrationResult(success=False, message="no"))


def test_onnx_runtime_matcher_fuses_the_same_way(site, frames, tmp_path):
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    from xcalib.deploy.ort_runtime import OnnxMatcher

    m = _matcher()
    m.set_calibration(_gt_pose(site))
    res = m.build("onnx", tmp_path / "onnx", site="fused", allow_random=True)
    om = OnnxMatcher(res.output_dir)
    assert om.calibration is not None and np.array_equal(om.calibration.extrinsics, m.calibration.extrinsics)
    f = frames[4]
    a, b = m.match(*f.inputs(), validate="off"), om.match(*f.inputs(), validate="off")
    assert b.fusion_weight > 0 and np.array_equal(a.geometry_iou, b.geometry_iou)
    assert np.max(np.abs(a.similarity - b.similarity)) < 1e-4
    plain = om.match(*f.inputs(), validate="off", use_calibration=False)
    assert plain.geometry_iou is None and np.max(np.abs(plain.similarity - m.similarity(m.prepare(*f.inputs())))) < 1e-4


def test_match_cli_fuses_a_site_calibration(site, frames, tmp_path, monkeypatch, capsys):
    import json

    from xcalib.cli import main
    from xcalib.io.hdf5 import write_cache

    monkeypatch.setenv("XCALIB_HOME", str(tmp_path / "home"))
    m = _matcher()
    m.set_calibration(_gt_pose(site))
    m.save_pretrained(tmp_path / "home" / "sites" / "cal_site")
    fr = frames[:2]
    for f in fr:
        f.camera_name = "cam"
    cache = write_cache(tmp_path / "b.h5", fr, camera_names=["cam"])
    assert main(["match", str(cache), "--site", "cal_site", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["fusion_weight"] == m.fusion_weight
    assert main(["match", str(cache), "--site", "cal_site", "--json", "--no-calibration"]) == 0
    assert json.loads(capsys.readouterr().out)["fusion_weight"] == 0.0
