"""The provisional ``xcalib demo``: synthetic fallback frames and the summary it prints."""

from __future__ import annotations

import json

import numpy as np

from xcalib.cli import main
from xcalib.cli.demo_cmd import _write_tiny_frames
from xcalib.io import read_frames
from xcalib.protocol import validate_frame_inputs


def test_tiny_synthetic_frames_are_valid_and_consistent(tmp_path):
    ff = read_frames(_write_tiny_frames(tmp_path / "frames", num_frames=2))
    assert len(ff) == 2 and ff.intrinsics is not None
    for fr in ff:
        assert [v for v in validate_frame_inputs(*fr.inputs()) if v.severity == "error"] == []
        assert fr.match_matrix.shape == (fr.num_2d, fr.num_3d) and fr.extrinsics.shape == (4, 4)
        assert np.all(fr.bboxes_2d[:, 2] > fr.bboxes_2d[:, 0])


def test_demo_json_summary(tmp_path, capsys):
    frames = _write_tiny_frames(tmp_path / "frames", num_frames=2)
    assert main(["demo", "--frames", str(frames), "--out", str(tmp_path / "out"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["num_frames"] == 2 and out["frames_with_errors"] == 0
    assert out["camera"] == "synthetic_cam" and out["per_frame"][0]["points"] > 1000
    assert json.loads((tmp_path / "out" / "summary.json").read_text()) == out


def test_demo_fails_on_a_frame_with_protocol_errors(tmp_path, capsys):
    frames = _write_tiny_frames(tmp_path / "frames", num_frames=1)
    det = frames / "frame_0000" / "detections.json"
    d = json.loads(det.read_text())
    d["bboxes_3d"][0][0] = 1e400  # JSON Infinity: a hard protocol error
    det.write_text(json.dumps(d))
    assert main(["demo", "--frames", str(frames), "--out", str(tmp_path / "out"), "--json"]) == 1
    assert json.loads(capsys.readouterr().out)["per_frame"][0]["errors"] == ["bboxes_3d.finite"]
