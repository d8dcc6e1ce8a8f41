"""A new wide-angle user's files (issue 26): ``--intrinsics FILE`` reads xcalib's intrinsics JSON
with a ``model`` and every camera file (Kalibr camchain, CameraInfo, OpenCV YAML); bad input is a
FormatError naming the file, the field and the expected range; a synthetic fisheye site's HDF5
cache keeps its camera model; calibration overlays draw through the model."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from xcalib.errors import FormatError
from xcalib.formats.cameras import read_intrinsics, write_camera
from xcalib.geometry import CameraIntrinsics
from xcalib.geometry.camera_models import DoubleSphere, KannalaBrandt

KB = KannalaBrandt(fx=300.0, fy=300.0, cx=640.0, cy=400.0, width=1280, height=800, k=(0.03, -0.006, 0.001, -0.0002))
DS = DoubleSphere(fx=330.0, fy=330.0, cx=640.0, cy=400.0, width=1280, height=800, xi=-0.2, alpha=0.6)


@pytest.mark.parametrize("fmt,cam", [("intrinsics_json", KB), ("kalibr", KB), ("camera_info", KB),
                                     ("opencv_yaml", KB), ("intrinsics_json", DS), ("kalibr", DS)])
def test_intrinsics_option_reads_every_camera_file_with_its_model(tmp_path, fmt, cam):
    path = write_camera(cam, tmp_path / ("cam.json" if fmt == "intrinsics_json" else "cam.yaml"), fmt)
    assert read_intrinsics(path) == cam


def test_intrinsics_option_keeps_pinhole_files_as_intrinsics(tmp_path):
    K = CameraIntrinsics(1000.0, 1000.0, 960.0, 600.0, [-0.1, 0.01, 0.0, 0.0, 0.0], 1920, 1200)
    (tmp_path / "k.json").write_text(json.dumps({"fx": 1000, "fy": 1000, "cx": 960, "cy": 600}))
    assert isinstance(read_intrinsics(tmp_path / "k.json"), CameraIntrinsics)
    got = read_intrinsics(write_camera(K, tmp_path / "info.yaml", "camera_info"))
    assert isinstance(got, CameraIntrinsics) and np.allclose(got.K, K.K)


@pytest.mark.parametrize("name,body,field,expect", [
    ("model.json", {"model": "fishy"}, "model", "expected one of"),
    ("k.json", {"model": "kannala_brandt", "k": [0.1, 0.0, 0.0]}, "k", "expected 4 coefficients"),
    ("xi.json", {"model": "double_sphere", "xi": 3.0, "alpha": 0.5}, "xi", "[-1, 1]"),
    ("alpha.json", {"model": "double_sphere", "xi": 0.0, "alpha": 1.5}, "alpha", "[0, 1]"),
    ("uxi.json", {"model": "unified", "xi": -0.5}, "xi", "[0, "),
    ("ucm.json", {"model": "ucm", "alpha": 2.0}, "alpha", "[0, 1]"),
    ("radtan.json", {"model": "pinhole_radtan", "distortion": [0.1] * 7}, "distortion", "got 7"),
])
def test_bad_intrinsics_name_file_field_and_range(tmp_path, name, body, field, expect):
    path = tmp_path / name
    path.write_text(json.dumps({"fx": 300, "fy": 300, "cx": 640, "cy": 400, "width": 1280, "height": 800, **body}))
    with pytest.raises(FormatError) as e:
        read_intrinsics(path)
    msg = str(e.value)
    assert name in msg and f"[{field}]" in msg and expect in msg, msg


def test_bad_kalibr_camchain_names_the_field(tmp_path):
    path = tmp_path / "camchain.yaml"
    path.write_text("cam0:\n  camera_model: ds\n  intrinsics: [0.0, 1.7, 300, 300, 640, 400]\n  distortion_model: none\n"
                    "  distortion_coeffs: []\n  resolution: [1280, 800]\n")
    with pytest.raises(FormatError, match=r"camchain.yaml \[cam0.intrinsics\]: DoubleSphere.alpha: expected a value "
                                          r"in \[0, 1\], got 1.7"):
        read_intrinsics(path)


def test_fisheye_site_cache_keeps_its_model(tmp_path):
    from xcalib.data.synth import write_site
    from xcalib.io.sources import open_source

    write_site(tmp_path / "site", 0, 0, 2, seed=0, render_images=False, lidar=False, camera_model="kannala_brandt",
               hfov_deg=185.0)
    frames = list(open_source(tmp_path / "site" / "test.h5"))
    cam = frames[0].intrinsics
    assert isinstance(cam, KannalaBrandt) and cam.field_of_view()[0] > 180.0
    # a camera_model attribute that is not a camera is a FormatError naming it
    with h5py.File(tmp_path / "site" / "test.h5", "r+") as f:
        ds = next(g["intrinsics"] for g in f["calibration"].values() if "intrinsics" in g)
        ds.attrs["camera_model"] = json.dumps({**cam.to_dict(), "k": [1.0]})
    with pytest.raises(FormatError, match="camera_model"):
        list(open_source(tmp_path / "site" / "test.h5"))


def test_calibration_overlay_draws_through_a_fisheye_model():
    from xcalib.viz.calibration import draw_calibration_overlay

    img = np.zeros((800, 1280, 3), np.uint8)
    # points all around the camera (LiDAR frame = camera frame here): a fisheye sees some behind Z = 0
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(4000, 3)) * 5.0
    box = np.array([[3.0, 0.5, -0.5, 2.0, 1.0, 1.0, 0.0]])  # beside the camera, partly behind its image plane
    out = draw_calibration_overlay(img, pts, intrinsics=KB, rotation=np.eye(3), translation=np.zeros(3),
                                   bboxes_3d=box)
    assert out.shape == img.shape and (out.sum(-1) > 0).sum() > 1000


def test_ros_camera_info_of_a_calibrated_model_is_the_model_or_refused():
    from xcalib.formats.cameras import UnsupportedModelError
    from xcalib.formats.ros import camera_info_dict

    d = camera_info_dict(KB, "cam")  # the site ROS export of a fisheye camera (it crashed before)
    assert d["distortion_model"] == "equidistant" and d["distortion_coefficients"]["data"] == list(KB.k)
    assert d["image_width"] == 1280 and d["camera_matrix"]["data"][0] == 300.0
    with pytest.raises(UnsupportedModelError, match="double_sphere.*formats that can: intrinsics_json, kalibr"):
        camera_info_dict(DS, "cam")  # never a pinhole CameraInfo of its fx, fy, cx, cy


def test_convert_a_camera_file_to_a_calibration_format_says_what_it_is(tmp_path, capsys):
    from xcalib.cli import main

    src = write_camera(DS, tmp_path / "camchain.yaml", "kalibr")
    assert main(["convert", str(src), "--to", "calib_json", "--out", str(tmp_path / "x.json")]) == 1
    err = capsys.readouterr().err
    assert "camchain.yaml" in err and "a camera file (kalibr" in err and "--to a camera format" in err
    assert main(["convert", str(src), "--to", "intrinsics_json", "--out", str(tmp_path / "ds.json")]) == 0
    assert read_intrinsics(tmp_path / "ds.json") == DS


def _two_camera_camchain(tmp_path):
    import yaml

    a = yaml.safe_load(write_camera(KB, tmp_path / "a.yaml", "kalibr").read_text())
    b = yaml.safe_load(write_camera(DS, tmp_path / "b.yaml", "kalibr").read_text())
    path = tmp_path / "camchain.yaml"
    path.write_text(yaml.safe_dump({"cam0": a["cam0"], "cam1": b["cam0"]}))
    return path


def test_a_camchain_camera_is_picked_by_file_hash_camera(tmp_path):
    from xcalib.formats.cameras import read_camera

    chain = _two_camera_camchain(tmp_path)
    assert read_intrinsics(f"{chain}#cam1") == DS and read_intrinsics(f"{chain}#cam0") == KB
    assert read_camera(f"{chain}#cam1") == DS and read_intrinsics(chain, camera="cam1") == DS
    with pytest.raises(FormatError, match=r"camchain.yaml: 2 cameras \(cam0, cam1\); name one: camchain.yaml#cam0"):
        read_intrinsics(chain)
    with pytest.raises(FormatError, match=r"camchain.yaml \[cam7\]: no camera 'cam7'; found cam0, cam1"):
        read_intrinsics(f"{chain}#cam7")
    with pytest.raises(ValueError, match="names camera 'cam1' but camera='cam0'"):
        read_intrinsics(f"{chain}#cam1", camera="cam0")
    with pytest.raises(ValueError, match="empty camera name"):
        read_intrinsics(f"{chain}#")
    # only a camchain has cameras to pick; a file whose name holds '#' is read whole
    info = write_camera(KB, tmp_path / "info.yaml", "camera_info")
    with pytest.raises(FormatError, match=r"info.yaml: camera 'cam1' named, but this camera_info file holds one camera"):
        read_intrinsics(f"{info}#cam1")
    odd = write_camera(DS, tmp_path / "rig#2.json", "intrinsics_json")
    assert read_intrinsics(odd) == DS


@pytest.mark.parametrize("argv", [["calibrate", "nosuch"], ["bag", "frames", "nosuch.mcap"],
                                  ["detect", "nosuch", "--out", "o.mcap"]])
def test_every_intrinsics_option_names_the_camchain_camera(tmp_path, capsys, monkeypatch, argv):
    """``--intrinsics FILE#camN`` in the commands (read before the source is opened): a camchain of two
    cameras without ``#camN`` is refused naming the entries and the form; ``#cam7`` names the missing one."""
    from xcalib.cli import main

    monkeypatch.chdir(tmp_path)
    chain = _two_camera_camchain(tmp_path)
    assert main([*argv, "--intrinsics", str(chain)]) != 0
    assert "2 cameras (cam0, cam1); name one: camchain.yaml#cam0" in capsys.readouterr().err
    assert main([*argv, "--intrinsics", f"{chain}#cam7"]) != 0
    assert "no camera 'cam7'; found cam0, cam1" in capsys.readouterr().err
    # with the camera named the camera file is read, and the command goes on to the (missing) source
    assert main([*argv, "--intrinsics", f"{chain}#cam1"]) != 0
    err = capsys.readouterr().err
    assert "nosuch" in err and "camchain" not in err, err


def test_calibrate_many_checks_the_camchain_camera_before_any_recording(tmp_path):
    from xcalib.batch import calibrate_many

    chain = _two_camera_camchain(tmp_path)
    with pytest.raises(FormatError, match="name one: camchain.yaml#cam0"):
        calibrate_many([str(tmp_path / "no_recording_yet")], tmp_path / "out", intrinsics=chain, executor="serial")


@pytest.mark.parametrize("cam,model", [(KB, "kannala_brandt"), (DS, None)])
def test_review_mcap_camera_calibration_keeps_the_model(tmp_path, caplog, cam, model):
    """The review MCAP's foxglove.CameraCalibration of a Kannala-Brandt camera is Foxglove's
    ``kannala_brandt`` (k1-k4); a model it cannot express (double sphere) gets no message, and one
    warning for the camera, not one per frame."""
    import logging

    from mcap.reader import make_reader

    from xcalib.calib.result import CalibrationResult
    from xcalib.site import calibrate_site
    from xcalib.types import Frame
    from xcalib.viz.review import write_review_mcap

    T = np.array([[0, -1, 0, 0.1], [0, 0, -1, 0.2], [1, 0, 0, -0.3], [0, 0, 0, 1]], dtype=np.float64)
    rng = np.random.default_rng(0)
    frames = [Frame(rng.integers(0, 255, (800, 1280, 3), dtype=np.uint8),
                    np.column_stack([rng.uniform(5, 30, 200), rng.uniform(-8, 8, 200), rng.uniform(-1.5, 1, 200)]),
                    np.array([[500, 300, 600, 360]], np.float32),
                    np.array([[10.0 + i, -1.0, -0.8, 4.5, 1.8, 1.5, 0.1]], np.float32), frame_key=f"{i:04d}",
                    intrinsics=cam, meta={"lidar_stamp_ns": 1_700_000_000_000_000_000 + i * 100_000_000})
              for i in range(3)]

    def ok(frames, intrinsics, progress=None, **_):
        return CalibrationResult(success=True, intrinsics=intrinsics, rotation=T[:3, :3], translation=T[:3, 3],
                                 camera_name="fish", pairs=[np.array([[0, 0]])] * len(frames),
                                 rotation_std_deg=np.full(3, 0.1), translation_std_m=np.full(3, 0.02))

    site, loaded = calibrate_site({"fish": frames}, calibrate=ok, lidar_frame="velodyne")
    with caplog.at_level(logging.WARNING, logger="xcalib.viz.review"):
        path = write_review_mcap(tmp_path / "r.mcap", site, loaded)
    with open(path, "rb") as f:
        cals = [json.loads(m.data) for s, _, m in make_reader(f).iter_messages() if s.name == "foxglove.CameraCalibration"]
    warnings = [r for r in caplog.records if "CameraCalibration" in r.getMessage()]
    if model is None:
        assert cals == [] and len(warnings) == 1 and "double_sphere" in warnings[0].getMessage()
    else:
        assert len(cals) == 3 and not warnings
        assert {c["distortion_model"] for c in cals} == {model} and cals[0]["D"] == list(cam.k)
        assert cals[0]["K"] == [300.0, 0.0, 640.0, 0.0, 300.0, 400.0, 0.0, 0.0, 1.0]


def test_convert_takes_a_camchain_camera_as_file_hash_camera(tmp_path, capsys):
    from xcalib.cli import main

    chain = _two_camera_camchain(tmp_path)
    assert main(["convert", f"{chain}#cam1", "--to", "intrinsics_json", "--out", str(tmp_path / "ds.json")]) == 0
    assert read_intrinsics(tmp_path / "ds.json") == DS
    assert main(["convert", f"{chain}#cam1", "--camera", "cam0", "--to", "intrinsics_json",
                 "--out", str(tmp_path / "x.json")]) != 0
    assert "names camera 'cam1' but camera='cam0'" in capsys.readouterr().err


def test_bag_frames_says_how_a_fisheye_camera_info_is_read(tmp_path, capsys):
    """``xcalib bag frames`` of a bag with an equidistant CameraInfo says that the frames are rectified
    to pinhole and how to keep the fisheye; with ``--fisheye keep`` it names the kannala_brandt model."""
    from xcalib.cli import main
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.io.bags.writer import write_bag

    site = sample_site(3, camera_model="kannala_brandt", hfov_deg=185, width=320, height=200, box_noise_px=1.0)
    path = write_bag(tmp_path / "fe.mcap", generate_frames(site, 2, seed=3, render_images=False))
    assert main(["bag", "frames", str(path)]) == 0
    out = capsys.readouterr().out
    assert "the CameraInfo is equidistant (fisheye), its images and 2D boxes are rectified" in out
    assert "--fisheye keep" in out
    assert main(["bag", "frames", str(path), "--fisheye", "keep", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["camera_model"] == "kannala_brandt"


@pytest.mark.parametrize("fmt", ["kitti", "calib_json", "lucid", "calib_txt", "opencalib", "openlabel", "nuscenes"])
def test_pinhole_only_calibration_formats_refuse_a_fisheye_result(tmp_path, fmt):
    """A fisheye calibration exported to a format whose intrinsics are a pinhole K (+ radial-tangential)
    is refused naming the model and the formats that keep it, nothing written (before: an
    AttributeError, or nuScenes' camera_intrinsic the fisheye's K as a pinhole one); the formats that
    can express it, or hold the pose alone, still write."""
    from xcalib.calib.result import CalibrationResult
    from xcalib.formats.cameras import UnsupportedModelError
    from xcalib.formats.export import export_calibration

    T = np.array([[0, -1, 0, 0.1], [0, 0, -1, 0.2], [1, 0, 0, -0.3], [0, 0, 0, 1]], dtype=np.float64)
    res = CalibrationResult(success=True, intrinsics=KB, rotation=T[:3, :3], translation=T[:3, 3], camera_name="fish",
                            rotation_std_deg=np.full(3, 0.1), translation_std_m=np.full(3, 0.02))
    with pytest.raises(UnsupportedModelError, match=rf"{fmt}: cannot express a kannala_brandt camera.*nothing written"
                                                    r".*keep the kannala_brandt camera or hold the pose alone: ros, urdf"):
        export_calibration(res, fmt, tmp_path / fmt / "out")
    assert not (tmp_path / fmt).exists() or not any((tmp_path / fmt).iterdir())
    for ok in ("ros", "tf_static", "json"):
        assert export_calibration(res, ok, tmp_path / ok / "out.yaml")
