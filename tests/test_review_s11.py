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

from xcalib.types import OWN_DETECTIONS


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
    assert det.meta["detections"]["source"] == OWN_DETECTIONS and _own_detections([det])
    back = open_source(write_bag(tmp_path / "det.mcap", [det]))
    assert back[0].meta["detections"] == {"source": OWN_DETECTIONS} and _own_detections(back)


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
