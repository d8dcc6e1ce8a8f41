"""The frame-source registry: every source registered, camera and frame selection everywhere."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from xcalib.errors import FormatError
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.io.hdf5 import write_cache
from xcalib.io.sources import find_source, frame_sources, open_source, parse_frame_range
from xcalib.types import Frame

from conftest import shared_path


def test_parse_frame_range():
    assert parse_frame_range("0:3", 10) == [0, 1, 2]
    assert parse_frame_range("0,3,5", 10) == [0, 3, 5]
    assert parse_frame_range("8:", 10) == [8, 9]
    assert parse_frame_range("::4", 10) == [0, 4, 8]
    assert parse_frame_range("-1", 10) == [9]
    assert parse_frame_range([1, 2], 10) == [1, 2]
    assert parse_frame_range(None, 3) == [0, 1, 2]
    for bad in ("12", "a:b", "5:2", "1:2:3:4"):
        with pytest.raises(ValueError, match="frames"):
            parse_frame_range(bad, 10)


def test_every_source_registered_and_io_does_not_import_formats():
    names = [s.name for s in frame_sources()]
    for want in ("frame-folder", "hdf5-cache", "kitti", "calibanything", "mmdet3d-info", "waymo", "bag"):
        assert want in names
    code = "import sys, xcalib.io, xcalib.io.frames, xcalib.io.sources; print('xcalib.formats' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _two_camera_frame(rng, k: int) -> Frame:
    img = rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
    b2 = np.array([[1, 1, 5, 5], [2, 2, 9, 9], [3, 3, 7, 8]], np.float32) + k
    b3 = np.array([[0, 0, 0, 1, 1, 1], [2, 2, 2, 3, 3, 3]], np.float32)
    mm = np.array([[1, 0], [0, 1], [1, 0]], bool)
    return Frame(image=img, point_cloud=rng.normal(size=(20, 3)).astype(np.float32), bboxes_2d=b2,
                 bboxes_3d=b3, camera_name="left", match_matrix=mm,
                 images={"left": img, "right": img[::-1].copy()}, camera_per_det=["left", "right", "left"],
                 intrinsics=CameraIntrinsics(100.0, 100.0, 16.0, 12.0, width=32, height=24))


def test_hdf5_camera_and_frames_selection(tmp_path, rng):
    p = write_cache(tmp_path / "c.h5", [_two_camera_frame(rng, k) for k in range(5)], image_format="png")
    assert find_source(p).name == "hdf5-cache"
    right = open_source(p, camera="right", frames="1:4")
    assert len(right) == 3
    f = right[0]
    assert f.camera_name == "right" and f.bboxes_2d.shape == (1, 4) and f.match_matrix.tolist() == [[False, True]]
    assert np.allclose(f.bboxes_2d[0], [3, 3, 10, 10])          # frame 1's second box (+1 offset)
    left = open_source(p, camera="left", frames="0,4")
    assert [len(x.bboxes_2d) for x in left] == [2, 2] and np.allclose(left[1].bboxes_2d[0], [5, 5, 9, 9])
    with pytest.raises(FormatError, match="cameras"):
        open_source(p, camera="middle")


def test_frame_folder_camera_check(a9_dir):
    seq = open_source(a9_dir, frames="2:4")
    assert len(seq) == 2 and seq.intrinsics is not None and seq.source_name == "frame-folder"
    with pytest.raises(FormatError, match="holds camera"):
        open_source(a9_dir, camera="nope")


def test_dataset_sources_take_camera():
    kitti = open_source(shared_path("kitti", "openpcdet_pr653"), camera="image_2", frames="0:2")
    assert len(kitti) == 2 and kitti[0].camera_name == "image_2"
    pkl = shared_path("nuscenes", "mmdet3d_demo", "n015-2018-07-24-11-22-45+0800.pkl")
    nus = open_source(pkl, camera="CAM_BACK", load_points=False)
    assert len(nus) == 1 and nus[0].camera_name == "CAM_BACK"
    assert len(open_source(pkl, load_points=False, load_image=False)) == 6


def test_sustech_scene_three_cameras():
    root = shared_path("sustech_example")
    assert find_source(root).name == "sustech"
    for cam in ("front", "left", "right"):
        seq = open_source(root, camera=cam, frames="0")
        f = seq[0]
        assert len(seq) == 1 and f.frame_key.endswith("000965") and f.bboxes_3d.shape == (21, 7)
        assert f.extrinsics is not None and f.intrinsics is not None
    with pytest.raises(FormatError, match="rear"):
        open_source(root, camera="rear")


def test_merge_cameras_unions_3d_boxes_and_keeps_matches(rng):
    from xcalib.io.sources import camera_view, merge_cameras

    shared = np.array([[0, 0, 0, 1, 1, 1], [2, 2, 2, 3, 3, 3], [5, 5, 5, 6, 6, 6]], np.float32)
    intr = CameraIntrinsics(100.0, 100.0, 16.0, 12.0, width=32, height=24)

    def view(name, rows, b2, pairs, t):
        mm = np.zeros((len(b2), len(rows)), bool)
        for i, j in pairs:
            mm[i, j] = True
        return Frame(image=rng.integers(0, 255, (24, 32, 3), dtype=np.uint8), point_cloud=np.zeros((4, 3), np.float32),
                     bboxes_2d=np.asarray(b2, np.float32), bboxes_3d=shared[rows], camera_name=name, match_matrix=mm,
                     intrinsics=intr, extrinsics=np.eye(4), camera_time_s=t, lidar_time_s=10.0,
                     track_ids_3d=np.asarray(rows, np.int64) + 100)

    a = view("a", [0, 1], [[1, 1, 4, 4], [5, 5, 9, 9]], [(0, 1), (1, 0)], 9.95)
    b = view("b", [1, 2], [[2, 2, 6, 6]], [(0, 1)], 9.97)
    (m,) = merge_cameras({"a": [a], "b": [b]})
    assert np.array_equal(m.bboxes_3d, shared) and m.camera_per_det == ["a", "a", "b"]
    assert m.match_matrix.tolist() == [[False, True, False], [True, False, False], [False, False, True]]
    assert m.track_ids_3d.tolist() == [100, 101, 102]
    vb = camera_view(m, "b")
    assert np.array_equal(vb.bboxes_2d, b.bboxes_2d) and vb.match_matrix.tolist() == [[False, False, True]]
    assert m.meta["camera_time_s_by_camera"] == {"a": 9.95, "b": 9.97}
    with pytest.raises(ValueError, match="frame counts"):
        merge_cameras({"a": [a], "b": []})


def test_merge_cameras_keeps_each_cameras_detector_scores_in_box_order(rng):
    """merge_cameras carries Frame.detections: the scores and classes of every camera's 2D boxes in the
    merged frame's box order; cameras from different detectors give a warning and no record."""
    from xcalib.io.sources import camera_view, merge_cameras
    from xcalib.types import FrameDetections

    intr = CameraIntrinsics(100.0, 100.0, 16.0, 12.0, width=32, height=24)
    b3 = np.array([[0, 0, 0, 1, 1, 1]], np.float32)

    def view(name, b2, det):
        return Frame(image=np.zeros((24, 32, 3), np.uint8), point_cloud=np.zeros((4, 3), np.float32),
                     bboxes_2d=np.asarray(b2, np.float32), bboxes_3d=b3, camera_name=name, intrinsics=intr,
                     extrinsics=np.eye(4), detections=det)

    da = FrameDetections("yolo", scores_2d=(0.9, 0.4), classes_2d=("car", "person"))
    db = FrameDetections("yolo", scores_2d=(0.7,), classes_2d=("truck",))
    a = view("a", [[1, 1, 4, 4], [5, 5, 9, 9]], da)
    b = view("b", [[2, 2, 6, 6]], db)
    (m,) = merge_cameras({"a": [a], "b": [b]})
    assert m.detections.source == "yolo"
    assert m.detections.scores_2d == (0.9, 0.4, 0.7) and m.detections.classes_2d == ("car", "person", "truck")
    assert camera_view(m, "b").detections.scores_2d == (0.7,)
    (m,) = merge_cameras({"a": [a], "b": [view("b", [[2, 2, 6, 6]], FrameDetections("yolo"))]})
    assert m.detections.source == "yolo" and m.detections.scores_2d is None  # b's boxes have no scores
    with pytest.warns(UserWarning, match="a: yolo, b: none"):  # b's boxes are the source's own
        (m,) = merge_cameras({"a": [a], "b": [view("b", [[2, 2, 6, 6]], None)]})
    assert m.detections is None
    with pytest.warns(UserWarning, match="different detectors"):
        (m,) = merge_cameras({"a": [a], "b": [view("b", [[2, 2, 6, 6]], FrameDetections("other"))]})
    assert m.detections is None
    (m,) = merge_cameras({"a": [view("a", [[1, 1, 4, 4]], None)], "b": [view("b", [[2, 2, 6, 6]], None)]})
    assert m.detections is None


def test_layering_of_bags_and_site():
    code = ("import sys, xcalib.io.bags, xcalib.io.sources; a = sorted(m for m in ('xcalib.formats', 'xcalib.calib', "
            "'xcalib.site', 'torch') if m in sys.modules); import xcalib.site; "
            "b = sorted(m for m in ('xcalib.viz', 'xcalib.cli', 'torch') if m in sys.modules); print(a, b)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[] []"
