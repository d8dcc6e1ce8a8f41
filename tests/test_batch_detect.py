"""``calibrate-many --detect`` (session 15, U): a folder of raw recordings calibrated in one command
with xcalib's own detections, the flags meaning and checked exactly as ``calibrate --detect``'s."""

from __future__ import annotations

import json

import pytest

from xcalib.cli import main


@pytest.fixture(scope="module")
def raw_recording(tmp_path_factory):
    """A frame folder with rendered images and clouds (and the generator's own boxes, which --detect replaces)."""
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.io.frames import write_frame_folder

    root = tmp_path_factory.mktemp("raw")
    site = sample_site(3, width=320, height=200, focal_px=300)
    write_frame_folder(root / "site3", generate_frames(site, 2, seed=0), intrinsics=site.intrinsics)
    return root


@pytest.mark.parametrize("command", ["calibrate", "calibrate-many"])
def test_detect_flags_are_checked_the_same_way(command, tmp_path, capsys):
    out = ["--out", str(tmp_path / "o")]
    assert main([command, str(tmp_path), "--detect", "--lidar-mode", "flying", *out]) == 2
    assert main([command, str(tmp_path), "--lidar-mode", "moving", *out]) == 2  # without --detect: said, not ignored
    assert "only with --detect" in capsys.readouterr().err
    assert main([command, str(tmp_path), "--detect", "--detector-2d", str(tmp_path / "no.onnx"), *out]) == 2
    assert "no.onnx" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # refused before anything is written


def test_calibrate_many_detect_replaces_the_recordings_boxes(raw_recording, tmp_path):
    pytest.importorskip("onnxruntime")
    from xcalib.types import OWN_DETECTIONS

    rc = main(["calibrate-many", str(raw_recording / "site3"), "--detect", "--lidar-mode", "moving",
               "--executor", "serial", "--out", str(tmp_path / "det")])
    assert rc in (0, 1)  # 2 frames: judged either way; what matters is whose boxes it judged
    table = json.loads((tmp_path / "det" / "results.json").read_text())
    row = table["recordings"][0]
    assert not row["error"], row["error"]
    assert table["detect"]["lidar"]["mode"] == "moving"
    res = json.loads((tmp_path / "det" / row["result"]).read_text())
    assert res["boxes_source"] == OWN_DETECTIONS and "detection_coverage" in json.dumps(res)
    # without --detect the recording's own (generator) boxes are calibrated
    main(["calibrate-many", str(raw_recording / "site3"), "--executor", "serial", "--out", str(tmp_path / "own")])
    table = json.loads((tmp_path / "own" / "results.json").read_text())
    own = json.loads((tmp_path / "own" / table["recordings"][0]["result"]).read_text())
    assert own.get("boxes_source", "") != OWN_DETECTIONS and table["detect"] is None
