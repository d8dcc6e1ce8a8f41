"""Frame folders: lazy reading, round trips through write_frame_folder, bad JSON, the A9 sample."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from xcalib.errors import FormatError
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.io.frames import FRAME_FOLDER_FORMAT, FrameFolder, read_frames, register_reader, write_frame_folder
from xcalib.protocol import validate_frame_inputs
from xcalib.types import Frame


def _frame(rng, i, k=3, m=4, with_gt=True):
    b2 = np.sort(rng.uniform(0, 60, size=(k, 2, 2)), axis=1).reshape(k, 4) + [0, 0, 8, 8]  # x1 y1 x2 y2
    lo = rng.uniform(-5, 5, size=(m, 3))
    b3 = np.hstack([lo, lo + rng.uniform(0.5, 2, size=(m, 3))])
    pts = rng.normal(0, 3, size=(100, 4)).astype(np.float32)
    return Frame(image=rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8), point_cloud=pts,
                 bboxes_2d=b2.astype(np.float32), bboxes_3d=b3.astype(np.float32), camera_name="cam0",
                 frame_key=f"{i:04d}", point_fields=("x", "y", "z", "intensity"),
                 match_matrix=(np.eye(k, m) > 0) if with_gt else None,
                 extrinsics=np.diag([1.0, -1.0, -1.0, 1.0]) if with_gt else None)


@pytest.fixture
def folder(tmp_path, rng):
    frames = [_frame(rng, i) for i in range(3)]
    write_frame_folder(tmp_path / "site", frames, camera="cam0",
                       intrinsics=CameraIntrinsics(500.0, 510.0, 32.0, 24.0, distortion=[0.1, -0.01, 0, 0, 0]),
                       pcd_encoding="binary_compressed")
    return tmp_path / "site", frames


def test_written_folder_reads_back_exactly(folder):
    root, frames = folder
    ff = FrameFolder(root)
    assert len(ff) == 3 and ff.camera == "cam0" and ff.frame_keys == ["0000", "0001", "0002"]
    assert ff.intrinsics.fx == 500.0 and ff.intrinsics.distortion[0] == pytest.approx(0.1)
    for want, got in zip(frames, ff):
        np.testing.assert_array_equal(got.image, want.image)
        np.testing.assert_array_equal(got.point_cloud, want.point_cloud)
        np.testing.assert_array_equal(got.bboxes_2d, want.bboxes_2d)
        np.testing.assert_array_equal(got.bboxes_3d, want.bboxes_3d)
        np.testing.assert_array_equal(got.match_matrix, want.match_matrix)
        np.testing.assert_array_equal(got.extrinsics, want.extrinsics)
        assert got.point_fields == ("x", "y", "z", "intensity")
        assert got.frame_key == want.frame_key and got.camera_name == "cam0"
        assert got.intrinsics is ff.intrinsics
    assert ff[-1].frame_key == "0002" and [f.frame_key for f in ff[0:2]] == ["0000", "0001"]


def test_frames_are_read_lazily(folder):
    root, _ = folder
    ff = FrameFolder(root)
    (root / "frame_0002" / "point_cloud.pcd").unlink()  # only frame 2 is broken now
    assert ff[0].frame_key == "0000"
    with pytest.raises(FileNotFoundError, match="frame_0002"):
        ff[2]


def test_read_frames_accepts_folder_manifest_and_bare_folder(folder, tmp_path):
    root, _ = folder
    assert len(read_frames(root)) == 3
    assert len(read_frames(root / "manifest.json")) == 3
    (root / "manifest.json").unlink()
    bare = read_frames(root)
    assert len(bare) == 3 and bare.frame_keys == ["frame_0000", "frame_0001", "frame_0002"]
    assert bare[1].frame_key == "0001"  # from detections.json
    assert len(read_frames(root / "frame_0001")) == 1
    with pytest.raises(FormatError, match="not a recognised frame source"):
        read_frames(tmp_path / "site" / "frame_0000" / "image.png")
    with pytest.raises(FileNotFoundError):
        read_frames(tmp_path / "nowhere")


def test_register_reader_takes_precedence(tmp_path):
    (tmp_path / "x.custom").write_text("")
    register_reader("custom-test", lambda p: p.suffix == ".custom", lambda p, **kw: ["sentinel"])
    try:
        assert read_frames(tmp_path / "x.custom") == ["sentinel"]
    finally:
        from xcalib.io.sources import unregister_source

        unregister_source("custom-test")


def _edit(root: Path, rel: str, fn) -> Path:
    p = root / rel
    obj = json.loads(p.read_text())
    fn(obj)
    p.write_text(json.dumps(obj))
    return p


@pytest.mark.parametrize("key", ["image", "point_cloud", "bboxes_2d", "bboxes_3d"])
def test_detections_missing_key_names_file_and_key(folder, key):
    root, _ = folder
    _edit(root, "frame_0001/detections.json", lambda d: d.pop(key))
    with pytest.raises(FormatError) as ei:
        FrameFolder(root)[1]
    assert ei.value.field == key and ei.value.path.endswith("frame_0001/detections.json")


@pytest.mark.parametrize("key, value, match", [
    ("bboxes_2d", [[1, 2, 3]], r"\[N, 4\]"),
    ("bboxes_2d", [[1, 2, 3, 4], [1, 2]], "rows must be lists"),
    ("bboxes_3d", [[0, 0, 0, 1, 1]], r"\[N, 6 or 7\]"),
    ("bboxes_3d", {"a": 1}, "expected a list"),
    ("bboxes_2d", [["a", 2, 3, 4]], "rows must be lists"),
    ("match_matrix", [[1, 0]], r"\[K, M\] = \[3, 4\]"),
    ("extrinsics", [[1, 0, 0], [0, 1, 0]], "4x4"),
])
def test_wrong_shape_arrays_name_the_key(folder, key, value, match):
    root, _ = folder
    _edit(root, "frame_0000/detections.json", lambda d: d.__setitem__(key, value))
    with pytest.raises(FormatError, match=match) as ei:
        FrameFolder(root)[0]
    assert ei.value.field == key


def test_empty_box_lists_give_empty_arrays(folder):
    root, _ = folder
    _edit(root, "frame_0000/detections.json",
          lambda d: d.update(bboxes_2d=[], bboxes_3d=[], match_matrix=None))
    fr = FrameFolder(root)[0]
    assert fr.bboxes_2d.shape == (0, 4) and fr.bboxes_3d.shape == (0, 6)


def test_manifest_problems_are_format_errors(folder):
    root, _ = folder
    _edit(root, "manifest.json", lambda m: m.__setitem__("format", "other-v9"))
    with pytest.raises(FormatError, match="unsupported format") as ei:
        FrameFolder(root)
    assert ei.value.field == "format"
    _edit(root, "manifest.json", lambda m: m.pop("format"))
    with pytest.raises(FormatError) as ei:
        FrameFolder(root)
    assert ei.value.field == "format"
    _edit(root, "manifest.json", lambda m: m.update(format=FRAME_FOLDER_FORMAT, frames=[{"frame_key": "x"}]))
    with pytest.raises(FormatError) as ei:
        FrameFolder(root)
    assert ei.value.field == "frames[0].detections"
    _edit(root, "manifest.json", lambda m: m.update(frames=[{"detections": "frame_0009/detections.json"}]))
    with pytest.raises(FormatError, match="does not exist"):
        FrameFolder(root)
    (root / "manifest.json").write_text("{ not json")
    with pytest.raises(FormatError, match="not valid JSON"):
        FrameFolder(root)


def test_bad_intrinsics_json_names_the_key(folder):
    root, _ = folder
    _edit(root, "intrinsics.json", lambda d: d.pop("fy"))
    with pytest.raises(FormatError) as ei:
        FrameFolder(root)
    assert ei.value.field == "fy" and ei.value.path.endswith("intrinsics.json")


def test_folder_without_frames_is_a_format_error(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(FormatError, match="not a frame folder"):
        FrameFolder(tmp_path / "empty")


def test_nonfinite_points_in_a_frame_surface_as_format_error(tmp_path, rng):
    fr = _frame(rng, 0)
    fr.point_cloud[5, 0] = np.nan
    write_frame_folder(tmp_path / "f", [fr])
    with pytest.raises(FormatError, match="NaN/Inf"):
        FrameFolder(tmp_path / "f")[0]
    ok = FrameFolder(tmp_path / "f", drop_nonfinite=True)[0]
    assert len(ok.point_cloud) == 99 and ok.meta["points_dropped_nonfinite"] == 1


# ------------------------------------------------------------------------------ real data
@pytest.mark.shared_data
def test_all_16_a9_frames_load_and_validate_without_errors(a9_dir):
    ff = read_frames(a9_dir)
    assert len(ff) == 16 and ff.camera == "s110_camera_basler_south1_8mm"
    assert ff.intrinsics is not None and ff.intrinsics.fx == pytest.approx(1305.59)
    keys = set()
    for fr in ff:
        keys.add(fr.frame_key)
        assert fr.image.shape == (1200, 1920, 3) and fr.image.dtype == np.uint8
        assert fr.point_cloud.dtype == np.float32 and 40_000 < len(fr.point_cloud) < 50_000
        assert 9 <= fr.num_2d <= 13 and 10 <= fr.num_3d <= 19
        errors = [v for v in validate_frame_inputs(*fr.inputs()) if v.severity == "error"]
        assert errors == []
    assert len(keys) == 16
