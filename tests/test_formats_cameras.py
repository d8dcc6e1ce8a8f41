"""Camera files with the model kept (xcalib.formats.cameras): every model through every format
that can express it, exact in projected pixels over the image; refusals; bad input; the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from xcalib.cli import main
from xcalib.errors import FormatError
from xcalib.formats.cameras import (CAMERA_FORMATS, UnsupportedModelError, camera_text, detect_camera_format,
                                    formats_for, read_camera, read_kalibr_camchain, write_camera)
from xcalib.geometry import CameraIntrinsics
from xcalib.geometry.camera_models import (EUCM, UCM, DoubleSphere, KannalaBrandt, Pinhole, PinholeRadtan,
                                           Unified)

W, H = 1280, 800
CAMS = {
    "pinhole": Pinhole(fx=700.1234567891, fy=701, cx=640.5, cy=399.25, width=W, height=H),
    "plumb_bob": PinholeRadtan(fx=700, fy=701, cx=640, cy=400, width=W, height=H,
                               distortion=(-0.21, 0.04, 0.001, -0.0015, 0.003)),
    "radtan4": PinholeRadtan(fx=700, fy=701, cx=640, cy=400, width=W, height=H, distortion=(-0.21, 0.04, 0.001, -0.0015)),
    "rational": PinholeRadtan(fx=700, fy=701, cx=640, cy=400, width=W, height=H,
                              distortion=(0.12, -0.05, 0.001, -0.002, 0.01, 0.35, 0.02, 0.001)),
    "radtan14": PinholeRadtan(fx=700, fy=701, cx=640, cy=400, width=W, height=H,
                              distortion=(0.12, -0.05, 0.001, -0.002, 0.01, 0.35, 0.02, 0.001, 0.001, -0.002,
                                          0.003, 0.001, 0.01, -0.02)),
    "kannala_brandt": KannalaBrandt(fx=331.0000000001, fy=330.5, cx=640.3, cy=400.7, width=W, height=H,
                                    k=(0.0213, -0.0107, 0.0031, -0.00052)),
    "unified": Unified(fx=900, fy=899, cx=640, cy=400, width=W, height=H, xi=1.23,
                       distortion=(-0.1, 0.02, 0.001, 0.0005)),
    "unified_none": Unified(fx=900, fy=899, cx=640, cy=400, width=W, height=H, xi=0.93),
    "ucm": UCM(fx=420, fy=419, cx=640, cy=400, width=W, height=H, alpha=0.61),
    "eucm": EUCM(fx=420, fy=419, cx=640, cy=400, width=W, height=H, alpha=0.61, beta=1.13),
    "double_sphere": DoubleSphere(fx=350, fy=349, cx=640, cy=400, width=W, height=H, xi=-0.21, alpha=0.59),
}
EXPRESSIBLE = {
    "pinhole": set(CAMERA_FORMATS),
    "plumb_bob": {"intrinsics_json", "camera_info", "opencv_yaml", "opencv_json"},
    "radtan4": set(CAMERA_FORMATS),
    "rational": {"intrinsics_json", "camera_info", "opencv_yaml", "opencv_json"},
    "radtan14": {"intrinsics_json", "opencv_yaml", "opencv_json"},
    "kannala_brandt": set(CAMERA_FORMATS),
    "unified": {"intrinsics_json", "kalibr"},
    "unified_none": {"intrinsics_json", "kalibr"},
    "ucm": {"intrinsics_json", "kalibr"},
    "eucm": {"intrinsics_json", "kalibr"},
    "double_sphere": {"intrinsics_json", "kalibr"},
}
CASES = [(n, f) for n in CAMS for f in CAMERA_FORMATS]


def _suffix(fmt):
    return ".json" if fmt.endswith("json") else ".yaml"


def test_expressible_formats_are_as_documented():
    for name, cam in CAMS.items():
        assert set(formats_for(cam)) == EXPRESSIBLE[name], name


@pytest.mark.parametrize("name,fmt", CASES, ids=[f"{n}-{f}" for n, f in CASES])
def test_round_trip_is_exact_in_projected_pixels(name, fmt, tmp_path):
    cam = CAMS[name]
    path = tmp_path / f"cam{_suffix(fmt)}"
    if fmt not in EXPRESSIBLE[name]:
        with pytest.raises(UnsupportedModelError, match=f"cannot express a {cam.name} camera.*formats that can"):
            write_camera(cam, path, fmt)
        assert not path.exists()
        return
    write_camera(cam, path, fmt)
    assert detect_camera_format(path) == fmt
    back = read_camera(path)
    assert (back.width, back.height) == (W, H)
    u, v = np.meshgrid(np.linspace(0, W, 33), np.linspace(0, H, 21))
    rays, ok = cam.unproject(np.column_stack([u.ravel(), v.ravel()]))
    assert ok.sum() > 500
    a, va = cam.project(rays[ok])
    b, vb = back.project(rays[ok])
    assert va.all() and vb.all()
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)
    if not (name == "ucm" and fmt == "kalibr"):  # Kalibr writes the UCM as an EUCM with beta = 1
        assert back.name == cam.name


def test_written_files_load_in_their_ecosystems(tmp_path):
    import cv2
    import yaml

    kb = CAMS["kannala_brandt"]
    p = write_camera(kb, tmp_path / "fisheye.yaml", "opencv_yaml")
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    np.testing.assert_array_equal(fs.getNode("camera_matrix").mat(), kb.K)
    assert fs.getNode("fisheye_model").real() == 1
    fs.release()
    info = yaml.safe_load(camera_text(kb, "camera_info"))
    assert info["distortion_model"] == "equidistant" and info["distortion_coefficients"]["data"] == list(kb.k)
    assert len(info["projection_matrix"]["data"]) == 12
    kal = yaml.safe_load(camera_text(CAMS["double_sphere"], "kalibr"))
    assert kal["cam0"]["camera_model"] == "ds" and kal["cam0"]["intrinsics"][:2] == [-0.21, 0.59]
    assert kal["cam0"]["resolution"] == [W, H]
    rational = yaml.safe_load(camera_text(CAMS["rational"], "camera_info"))
    assert rational["distortion_model"] == "rational_polynomial"
    assert yaml.safe_load(camera_text(CAMS["radtan4"], "camera_info"))["distortion_model"] == "plumb_bob"


def test_camera_intrinsics_writes_as_pinhole_radtan(tmp_path):
    intr = CameraIntrinsics(700, 701, 640, 400, [-0.2, 0.03, 0, 0, 0], W, H)
    p = write_camera(intr, tmp_path / "c.json")
    assert json.loads(p.read_text())["model"] == "pinhole_radtan"
    assert read_camera(p).to_intrinsics() == intr
    # today's reader still reads it; a fisheye file given to it is refused, not read as pinhole
    assert CameraIntrinsics.from_json(p) == intr
    q = write_camera(CAMS["kannala_brandt"], tmp_path / "kb.json")
    with pytest.raises(FormatError, match=r"\[model\].*kannala_brandt.*cannot be read as pinhole"):
        CameraIntrinsics.from_json(q)


def test_kalibr_camchain_with_several_cameras(tmp_path):
    text = camera_text(CAMS["double_sphere"], "kalibr") + camera_text(CAMS["eucm"], "kalibr").replace("cam0", "cam1")
    text += "  T_cn_cnm1:\n  - [1, 0, 0, 0.1]\n  - [0, 1, 0, 0]\n  - [0, 0, 1, 0]\n  - [0, 0, 0, 1]\n"
    p = tmp_path / "camchain.yaml"
    p.write_text(text)
    cams = read_kalibr_camchain(p)
    assert list(cams) == ["cam0", "cam1"] and isinstance(cams["cam1"], EUCM)
    assert read_camera(p, camera="cam1") == cams["cam1"]
    with pytest.raises(FormatError, match="2 cameras"):
        read_camera(p)
    with pytest.raises(FormatError, match=r"\[cam7\]"):
        read_camera(p, camera="cam7")


BAD = [
    ("intrinsics_json", '{"model": "fisheye9", "fx": 1, "fy": 1, "cx": 0, "cy": 0}', "model", "unknown camera model"),
    ("intrinsics_json", '{"model": "kannala_brandt", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "k": [1, 2]}', "k",
     "expected 4 coefficients"),
    ("intrinsics_json", '{"model": "double_sphere", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "xi": 2, "alpha": 0.5}',
     "xi", r"\[-1, 1\]"),
    ("intrinsics_json", '{"model": "ucm", "fx": 1, "fy": 1, "cx": 0, "alpha": 0.5}', "cy", "missing"),
    ("intrinsics_json", '{"model": "ucm", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "alpha": 0.5, "width": -3}', "width",
     "positive pixel count"),
    ("intrinsics_json", '[1, 2]', None, "expected a JSON object"),
    ("camera_info", "camera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}\n"
                    "distortion_model: fisheye\ndistortion_coefficients: {rows: 1, cols: 4, data: [0, 0, 0, 0]}\n",
     "distortion_model", "unknown distortion_model 'fisheye'"),
    ("camera_info", "camera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}\n"
                    "distortion_model: equidistant\ndistortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n",
     "distortion_coefficients.data", "expected 4 values, got 5"),
    ("camera_info", "camera_matrix: {rows: 3, cols: 3, data: [1, 0.5, 0, 0, 1, 0, 0, 0, 1]}\n", "camera_matrix.data",
     "no skew"),
    ("camera_info", "camera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0]}\n", "camera_matrix.data",
     "expected 9 numbers"),
    ("camera_info", "camera_matrix: {rows: 3, cols: 3, data: [-1, 0, 0, 0, 1, 0, 0, 0, 1]}\n", "camera_matrix",
     "focal lengths must be positive"),
    ("kalibr", "cam0: {camera_model: pinhole-fov, intrinsics: [1, 1, 0, 0]}\n", "cam0.camera_model",
     "unsupported camera_model"),
    ("kalibr", "cam0: {camera_model: ds, intrinsics: [0.1, 0.5, 1, 1, 0, 0], distortion_model: radtan, "
               "distortion_coeffs: [0, 0, 0, 0]}\n", "cam0.distortion_model", "ds-radtan is not supported"),
    ("kalibr", "cam0: {camera_model: ds, intrinsics: [0.1, 0.5, 1, 1, 0], distortion_model: none}\n",
     "cam0.intrinsics", "expected 6 values, got 5"),
    ("kalibr", "cam0: {camera_model: eucm, intrinsics: [1.5, 1, 1, 1, 0, 0], distortion_model: none}\n",
     "cam0.intrinsics", r"alpha: expected a value in \[0, 1\]"),
    ("kalibr", "cam0: {camera_model: omni, intrinsics: [1, 1, 1, 0, 0], distortion_model: radtan, "
               "distortion_coeffs: [0.1, .nan, 0, 0]}\n", "cam0.distortion_coeffs", "finite"),
    ("kalibr", "cam0: {camera_model: pinhole, intrinsics: [1, 1, 0, 0], resolution: [640]}\n", "cam0.resolution",
     r"\[width, height\]"),
    ("opencv_yaml", "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
                    "   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n"
                    "   rows: 5\n   cols: 1\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\nfisheye_model: 1\n",
     "distortion_coefficients", "cv::fisheye camera .* has 4 coefficients"),
    ("opencv_yaml", "%YAML:1.0\n---\nimage_width: 640\n", "camera_matrix", "missing"),
]


@pytest.mark.parametrize("fmt,text,field,match", BAD, ids=[f"{b[0]}-{i}" for i, b in enumerate(BAD)])
def test_bad_input_names_file_field_and_problem(fmt, text, field, match, tmp_path):
    p = tmp_path / f"bad{_suffix(fmt)}"
    p.write_text(text)
    with pytest.raises(FormatError, match=match) as info:
        read_camera(p, fmt)
    assert info.value.path == str(p)
    assert info.value.field == field


def test_convert_cli_keeps_the_model(tmp_path, capsys):
    src = write_camera(CAMS["kannala_brandt"], tmp_path / "fisheye.json")
    out = tmp_path / "fisheye_info.yaml"
    assert main(["convert", str(src), "--to", "camera_info", "--out", str(out), "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["from"] == "intrinsics_json" and rec["camera"]["model"] == "kannala_brandt"
    assert read_camera(out) == CAMS["kannala_brandt"]
    ds = write_camera(CAMS["double_sphere"], tmp_path / "ds.json")
    rc = main(["convert", str(ds), "--to", "camera_info", "--out", str(tmp_path / "ds.yaml")])
    assert rc == 2  # a usage error: ROS CameraInfo cannot express a double-sphere camera
    assert "cannot express a double_sphere camera" in capsys.readouterr().err
    assert not (tmp_path / "ds.yaml").exists()


def test_intrinsics_option_reads_every_model(tmp_path):
    """``--intrinsics FILE`` (io.frames.read_intrinsics_json): a wide-angle model is kept, a
    pinhole one stays CameraIntrinsics, a bad one names its field."""
    from xcalib.io.frames import read_intrinsics_json

    p = tmp_path / "intrinsics.json"
    p.write_text(json.dumps({"name": "cam0", **CAMS["double_sphere"].to_dict()}))
    assert read_intrinsics_json(p) == CAMS["double_sphere"]
    p.write_text(json.dumps(CAMS["plumb_bob"].to_dict()))
    assert read_intrinsics_json(p) == CAMS["plumb_bob"].to_intrinsics()
    p.write_text(json.dumps({**CAMS["double_sphere"].to_dict(), "xi": 3}))
    with pytest.raises(FormatError, match=r"\[xi\].*\[-1, 1\]"):
        read_intrinsics_json(p)
