"""What a new user ran into following the README, the docs and every ``--help`` example (the
new-user pass): each test holds one fix."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import yaml

from xcalib.calib.diagnostics import MisfitCheck
from xcalib.calib.report import _check_value
from xcalib.calib.result import CalibrationResult
from xcalib.cli import main
from xcalib.geometry.camera import CameraIntrinsics


def test_python_dash_m_runs_the_command_line():
    """``python -m xcalib`` and ``python -m xcalib.cli`` are the ``xcalib`` command (no console
    script on PATH needed); they were 'No module named xcalib.cli.__main__'."""
    for mod in ("xcalib", "xcalib.cli"):
        run = subprocess.run([sys.executable, "-m", mod, "version", "--json"], capture_output=True, text=True,
                             timeout=120)
        assert run.returncode == 0, run.stderr
        assert '"protocol"' in run.stdout


def _calibration(tmp_path, size=None):
    k = CameraIntrinsics(1400.0, 1400.0, 960.0, 600.0, distortion=np.array([-0.05, 0.09, 1e-4, 1e-3, 0.1]))
    res = CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3), intrinsics=k,
                            camera_name="cam", image_size=size)
    return res.save(tmp_path / "calib.json")


def test_convert_a_calibration_files_intrinsics_to_a_camera_format(tmp_path, capsys):
    """``--to camera_info / opencv_yaml`` of a camera-LiDAR calibration file takes its intrinsics
    (was: '[fx]: missing'); a CameraInfo YAML without the image size is refused (ROS's
    camera_calibration_parsers will not load it) unless --image-size gives it."""
    src = _calibration(tmp_path)
    assert main(["convert", str(src), "--to", "opencv_yaml", "--out", str(tmp_path / "cv.yaml")]) == 0
    assert "1400" in (tmp_path / "cv.yaml").read_text()
    capsys.readouterr()
    assert main(["convert", str(src), "--to", "camera_info", "--out", str(tmp_path / "a.yaml")]) == 2
    assert "--image-size" in capsys.readouterr().err and not (tmp_path / "a.yaml").exists()
    assert main(["convert", str(src), "--to", "camera_info", "--out", str(tmp_path / "a.yaml"),
                 "--image-size", "1920x1200"]) == 0
    d = yaml.safe_load((tmp_path / "a.yaml").read_text())
    assert (d["image_width"], d["image_height"]) == (1920, 1200)
    assert d["distortion_model"] == "plumb_bob" and len(d["distortion_coefficients"]["data"]) == 5
    # a file that is neither a camera file nor a calibration keeps the camera reader's error
    bad = tmp_path / "bad.json"
    bad.write_text('{"hello": 1}')
    assert main(["convert", str(bad), "--to", "camera_info", "--image-size", "10x10"]) == 1
    assert "fx" in capsys.readouterr().err


def test_misfit_lines_state_the_direction_of_their_limit():
    """The report printed 'focal_scale: 0.99 (limit 0.03)' and 'focal_checkable: 8.59 (limit 2)',
    both passing checks that read as far over their limit."""
    assert _check_value(MisfitCheck("focal_scale", 0.99, 0.03, False)) == "x0.99 (limit x0.971-x1.03)"
    assert _check_value(MisfitCheck("focal_checkable", 8.59, 2.0, False)) == "8.59 (at least 2)"
    assert _check_value(MisfitCheck("mirrored", 0.869, 1.25, False)) == "0.869 (limit 1.25)"


def test_demo_does_not_warn_that_the_shipped_weights_do_not_know_their_own_site(caplog):
    """The demo matches sample_site(0), the site the shipped 'synthetic' weights were trained on:
    'they do not know yours' was printed in the middle of it. Elsewhere the warning stays."""
    import logging

    from xcalib.cli import _demo

    with caplog.at_level(logging.WARNING, logger="xcalib.matcher"):
        m, why = _demo.load_matcher("fastmatch", None, own_site=True)
    assert m is not None, why
    assert not [r for r in caplog.records if "shipped 'synthetic' weights" in r.getMessage()]
    assert not logging.getLogger("xcalib.matcher").filters  # the filter is removed again
    with caplog.at_level(logging.WARNING, logger="xcalib.matcher"):
        _demo.load_matcher("fastmatch", None)
    assert [r for r in caplog.records if "shipped 'synthetic' weights" in r.getMessage()]


def test_bootstrap_starting_from_the_shipped_weights_does_not_advise_bootstrap(caplog):
    """``xcalib bootstrap`` printed the shipped weights' warning, whose advice is to run bootstrap."""
    import logging

    from xcalib.oneshot.bootstrap import starting_matcher

    with caplog.at_level(logging.WARNING, logger="xcalib.matcher"):
        _, how, _ = starting_matcher("fastmatch", "auto")
    assert how == "site:synthetic"
    assert not [r for r in caplog.records if "shipped 'synthetic' weights" in r.getMessage()]


def test_a_cache_of_frames_without_image_pixels_reads_back(tmp_path, capsys):
    """``xcalib cache build`` of the Waymo test record (labels, calibration, no pixels) wrote a
    cache its own reader refused ('missing root group /images', naming the new cache)."""
    from xcalib.io.hdf5 import CacheReader, write_cache
    from xcalib.types import Frame

    k = CameraIntrinsics(800.0, 800.0, 320.0, 240.0, width=640, height=480)
    b2 = np.array([[10, 20, 50, 60], [100, 120, 160, 200]], np.float32)
    b3 = np.array([[10.0, 1.0, 0.0, 4.0, 1.8, 1.5], [15.0, -2.0, 0.0, 4.0, 1.8, 1.5]], np.float32)
    frames = [Frame(np.zeros((0, 0, 3), np.uint8), np.zeros((0, 3), np.float32), b2, b3, frame_key=f"{i}",
                    intrinsics=k) for i in range(2)]
    p = write_cache(tmp_path / "c.h5", frames)
    with CacheReader(p) as r:
        got = list(r)
    assert len(got) == 2 and got[0].image.shape == (0, 0, 3)
    np.testing.assert_allclose(got[1].bboxes_2d, b2)
    assert main(["cache", "info", str(p), "--json"]) == 0
    assert '"frames": 2' in capsys.readouterr().out


def test_a_recording_without_2d_boxes_is_pointed_at_detect():
    """SUSTech's example (3D labels only) was refused 'too few detections: 0 valid 2D', with no word
    on the way to make them."""
    import xcalib
    from xcalib.types import Frame

    k = CameraIntrinsics(800.0, 800.0, 320.0, 240.0, width=640, height=480)
    b3 = np.array([[10.0 + i, 1.0, 0.0, 4.0, 1.8, 1.5] for i in range(4)], np.float32)
    f = Frame(np.zeros((480, 640, 3), np.uint8), np.zeros((10, 3), np.float32), np.zeros((0, 4), np.float32), b3,
              frame_key="0", intrinsics=k)
    res = xcalib.calibrate([f], k)
    assert not res.success and "too few detections" in res.message
    assert "no 2D boxes" in res.message and "--detect" in res.message


def test_bag_info_prints_no_rate_for_a_single_message():
    """``xcalib bag info`` printed 'rate Hz 0.00' for every topic of a one-frame bag."""
    from xcalib.io.bags import BagInfo, BagTopic

    info = BagInfo("x.mcap", "mcap", (BagTopic("/a", "std_msgs/msg/String", 1, 5, 5),
                                      BagTopic("/b", "std_msgs/msg/String", 11, 0, 1_000_000_000)), 0.0, 1.0)
    a, b = info.lines()[2:4]
    assert a.split()[-1] == "-" and "0.00" not in a
    assert b.split()[-1] == "10.00"


def test_mixed_intrinsics_name_the_frames_that_differ():
    """KITTI's training folder holds frames of several drives (their own calibrations): the refusal
    said 'different camera intrinsics (mixed cameras?)' without saying where."""
    import xcalib
    from xcalib.types import Frame

    b2 = np.array([[100, 100, 200, 200], [300, 300, 400, 380], [50, 60, 90, 120]], np.float32)
    b3 = np.array([[10.0, 0.0, 0.0, 4.0, 2.0, 1.5], [20.0, 3.0, 0.0, 4.0, 2.0, 1.5], [15.0, -4.0, 0.0, 4.0, 2.0, 1.5]],
                  np.float32)
    ks = [CameraIntrinsics(700.0, 700.0, 320.0, 240.0, width=640, height=480),
          CameraIntrinsics(720.0, 720.0, 330.0, 240.0, width=640, height=480)]
    frames = [Frame(np.zeros((480, 640, 3), np.uint8), np.zeros((10, 3), np.float32), b2, b3, frame_key=f"k{i}",
                    intrinsics=k) for i, k in enumerate(ks)]
    res = xcalib.calibrate(frames, ks[0])
    assert not res.success
    assert "frame k0: fx 700" in res.message and "frame k1: fx 720" in res.message


def test_convert_reads_a_sustech_camera_calibration(tmp_path, capsys):
    """``xcalib convert sustech_example/calib/camera/front.json`` was 'unrecognised calibration JSON'
    though ``xcalib calibrate`` reads the scene; now a read-only format ``sustech``."""
    import json

    from xcalib.formats.export import read_calibration

    T = np.array([[0.0, -1.0, 0.0, 0.2], [0.0, 0.0, -1.0, 0.1], [1.0, 0.0, 0.0, -0.3], [0, 0, 0, 1]])
    d = tmp_path / "calib" / "camera"
    d.mkdir(parents=True)
    (d / "front.json").write_text(json.dumps({"extrinsic": T.ravel().tolist(),
                                              "intrinsic": [1000.0, 0, 640.0, 0, 1000.0, 360.0, 0, 0, 1]}))
    res = read_calibration(d / "front.json")
    np.testing.assert_allclose(res.extrinsics, T)
    assert res.camera_name == "front" and res.intrinsics.fx == 1000.0
    assert main(["convert", str(d / "front.json"), "--to", "urdf", "--out", str(tmp_path / "s.urdf")]) == 0
    assert "(sustech)" in capsys.readouterr().out
    (d / "left.json").write_text(json.dumps({"extrinsic": [1.0] * 15, "intrinsic": [1.0] * 9}))
    assert main(["convert", str(d / "left.json"), "--to", "json", "--out", str(tmp_path / "l.json")]) == 1
    err = capsys.readouterr().err
    assert "left.json" in err and "extrinsic" in err


def test_convert_of_a_nuscenes_info_pickle_says_what_to_do(capsys):
    """``xcalib convert <nuScenes info>.pkl`` said only 'no camera-2 projection'."""
    from conftest import shared_path

    pkl = shared_path("nuscenes", "mmdet3d_demo", "n015-2018-07-24-11-22-45+0800.pkl")
    assert main(["convert", str(pkl), "--to", "urdf", "--out", "/nonexistent/never.urdf"]) == 1
    err = capsys.readouterr().err
    assert "CAM_FRONT" in err and "xcalib calibrate" in err
