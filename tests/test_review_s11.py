"""Session 11's review (R) of the merged changes: what the review fixed.

``validate --limit-frames 0`` said "the source holds no frames" of a source with frames; the mark
of xcalib's own detections was a literal in ``detect.pipeline`` and a constant in the bag reader
(one name now, ``types.OWN_DETECTIONS``): a frame from ``detect_frame`` written to a bag and read
back is recognised as xcalib's own boxes; ``write_bag`` wrote no frame without 3D boxes."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from test_new_user_s11 import _folder

from xcalib.types import OWN_DETECTIONS, FrameDetections


def test_validate_with_no_frame_checked_does_not_say_the_source_is_empty(tmp_path, capsys):
    from xcalib.cli import main

    root = _folder(tmp_path)
    assert main(["validate", str(root), "--limit-frames", "0", "--json"]) == 1
    r = json.loads(capsys.readouterr().out)
    assert r["frames"] == 1 and r["checked"] == 0 and r["missing"] == ["no frame checked (--limit-frames 0)"]


class _FakeDetector:
    """A 2D detector that finds one box in any image (``detect_frame``'s interface)."""

    path = Path("fake.onnx")

    def __call__(self, image):
        return SimpleNamespace(boxes=np.array([[10, 10, 30, 26]], np.float32), scores=np.array([0.9]),
                               class_names=["car"])


def test_detect_frame_marks_its_boxes_as_the_bag_reader_reads_them(tmp_path):
    from xcalib.cli.calibrate_cmd import _own_detections
    from xcalib.detect.lidar import LidarDetectConfig
    from xcalib.detect.pipeline import detect_frame
    from xcalib.io.bags import write_bag
    from xcalib.io.frames import FrameFolder
    from xcalib.io.sources import open_source

    frame = FrameFolder(_folder(tmp_path))[0]
    det = detect_frame(frame, _FakeDetector(), LidarDetectConfig())
    assert det.detections.source == OWN_DETECTIONS and _own_detections([det])
    back = open_source(write_bag(tmp_path / "det.mcap", [det]))
    assert back[0].detections == FrameDetections(OWN_DETECTIONS) and _own_detections(back)


def test_a_frame_without_3d_boxes_is_written_to_a_bag(tmp_path):
    """``write_bag`` raised "cannot reshape array of size 0" for a frame with no 3D box (``xcalib
    detect --out X.mcap`` on a frame where the LiDAR detector finds nothing)."""
    import dataclasses
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from _bag_cases import sample_frames

    from xcalib.io.bags import write_bag
    from xcalib.io.sources import open_source

    f = sample_frames(2)
    empty = dataclasses.replace(f[0], bboxes_3d=np.zeros((0, 7), np.float32), match_matrix=None,
                                track_ids_3d=None, velocities_3d=None)
    back = open_source(write_bag(tmp_path / "x.mcap", [empty, f[1]]))
    assert [len(x.bboxes_3d) for x in back] == [0, len(f[1].bboxes_3d)]
    np.testing.assert_allclose(back[1].bboxes_3d, f[1].bboxes_3d, atol=1e-5)


def _pandaset_with(tmp_path: Path, edit) -> Path:
    """The shared PandaSet sequence's calibration and first cuboid file, ``edit``-ed (no points)."""
    import shutil

    from conftest import shared_path

    src = shared_path("pandaset_002")
    root = tmp_path / "ps"
    (root / "lidar").mkdir(parents=True)
    (root / "cuboids").mkdir()
    shutil.copy(src / "cuboids" / "00.json", root / "cuboids" / "00.json")
    cal = json.loads((src / "calibration.json").read_text())
    edit(cal)
    (root / "calibration.json").write_text(json.dumps(cal))
    return root


def test_pandaset_and_sustech_times_are_bounded_like_the_other_readers(tmp_path):
    """The CHANGELOG said "any reader's times beyond 1e11 s" are refused; PandaSet's timestamps and
    SUSTech's point times were read without the bound (``io.timing.checked_time`` now)."""
    import pytest

    from xcalib.errors import FormatError
    from xcalib.formats.pandaset import PandaSetFrames
    from xcalib.formats.sustech import _RECORD, read_sustech_pcd

    def lidar_ms(cal):
        cal["lidar"]["frames"]["00"]["timestamp"] *= 1000.0  # a Unix time in milliseconds

    def camera_ms(cal):
        cal["cameras"]["front_camera"]["frames"]["00"]["camera_timestamp"] *= 1000.0

    for edit, field in ((lidar_ms, "lidar.frames.00.timestamp"), (camera_ms, "camera_timestamp")):
        seq = PandaSetFrames(_pandaset_with(tmp_path / field, edit), read_images=False, read_points=False)
        with pytest.raises(FormatError, match=r"calibration\.json \[.*" + field + r"\]: time 1\.\d+e\+12 s is beyond"):
            seq[0]
    ok = PandaSetFrames(_pandaset_with(tmp_path / "ok", lambda cal: None), read_images=False, read_points=False)[0]
    assert 1e9 < ok.lidar_time_s < 1e11 and 1e9 < ok.camera_time_s < 1e11
    rec = np.zeros(3, dtype=_RECORD)
    rec["x"], rec["t"] = 5.0, [1.7e9, 1.7e9 + 0.05, 1.7e12]
    pcd = tmp_path / "x.pcd"
    pcd.write_bytes(b"VERSION 0.7\nPOINTS 3\nDATA binary\n" + rec.tobytes())
    with pytest.raises(FormatError, match=r"x\.pcd \[t\]: time 1\.7e\+12 s is beyond"):
        read_sustech_pcd(pcd)
    rec["t"][2] = 1.7e9 + 0.1
    pcd.write_bytes(b"VERSION 0.7\nPOINTS 3\nDATA binary\n" + rec.tobytes())
    assert read_sustech_pcd(pcd)[1] == pytest.approx(1.7e9 + 0.1)
