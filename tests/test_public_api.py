"""The public names of reference-behaviour §1 exist with compatible signatures (inspect only;
nothing is loaded or run)."""

from __future__ import annotations

import dataclasses
import inspect

import pytest

import xcalib

pytest.importorskip("torch")


def _params(fn) -> dict[str, inspect.Parameter]:
    return dict(inspect.signature(fn).parameters)


def _positional(fn) -> list[str]:
    return [n for n, p in _params(fn).items()
            if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) and n != "self"]


def _fields(cls) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


@pytest.mark.parametrize("name", ["Matcher", "train", "load_dataset", "MatchResult", "BuildResult",
                                  "CalibrationResult", "PROTOCOL_VERSION", "CameraIntrinsics", "ProtocolError",
                                  "ProtocolViolation", "validate_frame_inputs", "draw_matching_overlay",
                                  "draw_calibration_overlay", "calibrate", "__version__"])
def test_name_is_exported(name):
    assert name in xcalib.__all__
    assert getattr(xcalib, name) is not None


def test_protocol_names():
    assert xcalib.PROTOCOL_VERSION == "1.0"
    assert issubclass(xcalib.ProtocolError, ValueError)
    assert list(_params(xcalib.ProtocolViolation)) == ["code", "severity", "message"]
    assert _positional(xcalib.validate_frame_inputs) == ["image", "point_cloud", "bboxes_2d", "bboxes_3d"]
    assert _positional(xcalib.CameraIntrinsics)[:5] == ["fx", "fy", "cx", "cy", "distortion"]
    assert _positional(xcalib.CameraIntrinsics.from_matrix)[:2] == ["K", "distortion"]


def test_from_pretrained_signature():
    p = _params(xcalib.Matcher.from_pretrained)
    assert list(p)[:4] == ["model", "weights", "config", "device"]
    assert all(p[k].default is None for k in ("weights", "config", "device"))
    for k in ("site", "repo_id", "revision", "token"):
        assert p[k].kind is inspect.Parameter.KEYWORD_ONLY


def test_from_pretrained_refuses_hub_arguments():
    with pytest.raises(ValueError, match="never downloads"):
        xcalib.Matcher.from_pretrained("fastmatch", repo_id="org/repo")


@pytest.mark.parametrize("method", ["match", "pair"])
def test_match_signature(method):
    fn = getattr(xcalib.Matcher, method)
    assert _positional(fn)[:6] == ["image", "point_cloud", "bboxes_2d", "bboxes_3d", "top_k", "match_threshold"]
    p = _params(fn)
    # None = the site's threshold chosen by bootstrap, else 0.0 (the reference's default value)
    assert p["top_k"].default == 1 and p["match_threshold"].default is None
    assert p["validate"].default == "warn" and p["return_latency"].default is False
    assert xcalib.Matcher.pair is xcalib.Matcher.match


def test_other_matcher_methods():
    M = xcalib.Matcher
    assert _positional(M.match_frame) == ["frame"]
    assert "intrinsics" in inspect.getdoc(M.calibrate) and inspect.signature(M.calibrate).parameters
    assert _positional(M.train) == ["train_data", "val_data"]
    assert _params(M.train)["output_dir"].default == "runs/finetune"
    assert _positional(M.build)[:2] == ["target", "output_dir"] and _params(M.build)["target"].default == "onnx"
    assert _positional(M.save_pretrained) == ["save_dir"]
    assert _positional(M.oneshot) == ["intrinsics"]


def test_result_types():
    assert {"similarity", "top_indices", "matches", "kept_2d_indices", "kept_3d_indices", "latency_ms", "model",
            "device"} <= _fields(xcalib.MatchResult)
    assert {"target", "model", "output_dir", "artifacts", "parity", "logs"} <= _fields(xcalib.BuildResult)
    assert isinstance(xcalib.BuildResult.parity_ok, property)
    C = xcalib.CalibrationResult
    assert {"success", "intrinsics", "rotation", "translation", "n_correspondences", "n_inliers", "reproj_error_px",
            "message", "buffer_reproj_px", "accepted"} <= _fields(C)
    assert isinstance(C.extrinsics, property) and isinstance(C.projection, property)
    assert _positional(C.pose_error)[:1] and callable(C.project) and callable(C.save)


def test_entry_points():
    tp = _params(xcalib.train)
    assert _positional(xcalib.train)[:3] == ["model", "train_data", "val_data"]
    assert tp["output_dir"].kind is inspect.Parameter.KEYWORD_ONLY
    lp = _params(xcalib.load_dataset)
    assert list(lp)[1] == "split" and lp["split"].default == "test"
    assert all(lp[k].default is None for k in ("repo_id", "revision", "token", "local"))
    assert _positional(xcalib.draw_matching_overlay)[:4] == ["image", "point_cloud", "bboxes_2d", "bboxes_3d"]
    assert _positional(xcalib.draw_calibration_overlay)[:1] == ["image"]
    assert {"calibration", "intrinsics", "rotation", "translation"} <= set(_params(xcalib.draw_calibration_overlay))
    assert _positional(xcalib.calibrate)[:2] == ["frames", "intrinsics"]
