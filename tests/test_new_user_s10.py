"""Session 10's new-user pass: the review file spread over the whole recording, the plain-words
verdict of ``calibrate``, the synthetic contact sheet's legend, ``match --site`` on data the
weights do not fit, and hostile input to the readers a user points at."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from xcalib.calib.result import CalibrationResult
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.types import Frame

SRC = Path(__file__).resolve().parents[1] / "src" / "xcalib"
K = CameraIntrinsics(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
T = np.array([[0, -1, 0, 0.1], [0, 0, -1, 0.2], [1, 0, 0, -0.3], [0, 0, 0, 1]], dtype=np.float64)


def _frames(n: int, stamps: bool = True) -> list[Frame]:
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        cloud = np.column_stack([rng.uniform(5, 30, 200), rng.uniform(-8, 8, 200), rng.uniform(-1.5, 1, 200)])
        b3 = np.array([[10.0 + i, -1.0, -0.8, 4.5, 1.8, 1.5, 0.1]], np.float32)
        b2 = np.array([[200, 200, 300, 260]], np.float32)
        img = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
        meta = {"lidar_stamp_ns": 1_700_000_000_000_000_000 + i * 100_000_000} if stamps else {}
        out.append(Frame(img, cloud.astype(np.float32), b2, b3, frame_key=f"{i:04d}", intrinsics=K, meta=meta))
    return out


# ------------------------------------------------------------------ review.mcap: spread, bounded
def test_review_indices_spread_over_the_whole_recording():
    from xcalib.viz.review import review_indices

    assert review_indices(200, 5) == [0, 50, 100, 149, 199]  # first and last included
    assert review_indices(16, 50) == list(range(16)) and review_indices(16, 0) == list(range(16))
    assert review_indices(0, 8) == [] and review_indices(1, 8) == [0]
    got = review_indices(1000, 50)
    assert len(got) == 50 and got[0] == 0 and got[-1] == 999 and max(np.diff(got)) <= 21


@pytest.mark.parametrize("stamps", [True, False])
def test_review_file_holds_frames_from_the_whole_recording(tmp_path, stamps):
    from mcap.reader import make_reader

    from xcalib.site import calibrate_site
    from xcalib.viz.review import write_review_mcap

    def ok(frames, intrinsics, progress=None, **_):
        return CalibrationResult(success=True, intrinsics=intrinsics, rotation=T[:3, :3], translation=T[:3, 3],
                                 camera_name="front", pairs=[np.array([[0, 0]])] * len(frames),
                                 rotation_std_deg=np.full(3, 0.1), translation_std_m=np.full(3, 0.02))

    frames = _frames(12, stamps)
    site, loaded = calibrate_site({"front": frames}, calibrate=ok)
    path = write_review_mcap(tmp_path / "r.mcap", site, loaded, max_frames=4)
    with open(path, "rb") as f:
        times = [m.log_time for _, c, m in make_reader(f).iter_messages(topics=["/lidar/points"])]
    picked = [0, 4, 7, 11]  # not the first four: the last frame is there
    want = ([frames[i].meta["lidar_stamp_ns"] for i in picked] if stamps
            else [1_000_000_000 + i * 100_000_000 for i in picked])  # the index's time: gaps show
    assert times == want
    with open(path, "rb") as f:
        ann = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages(topics=["/front/annotations"])]
    key = ann[0]["texts"][0]["text"]  # the key: orange is the boxes' colour only, the points go by depth
    assert len(ann) == 4 and "green: 2D detections; orange: 3D boxes;" in key and "points, blue near to red far" in key
    path = write_review_mcap(tmp_path / "all.mcap", site, loaded, max_frames=0)
    with open(path, "rb") as f:
        assert sum(1 for _ in make_reader(f).iter_messages(topics=["/front/image"])) == 12


def test_calibrate_states_what_the_review_file_holds():
    from xcalib.cli.calibrate_cmd import _review_line

    assert "all 16 frame(s)" in _review_line(16, 16)
    line = _review_line(50, 300)
    assert "50 of the recording's 300 frames" in line and "--review-frames 0" in line


# ------------------------------------------------------------------ plain words on a verdict
def _refusal_codes() -> set[str]:
    codes = set()
    for p in SRC.rglob("*.py"):
        text = p.read_text()
        codes |= set(re.findall(r'Refusal\("([a-z_0-9]+)"', text))
        codes |= set(re.findall(r'found\.append\(\([^)]*"(misfit_[a-z_]+)"\)\)', text))
    return codes


def test_every_refusal_reason_has_plain_advice():
    from xcalib.viz.advice import ADVICE

    codes = _refusal_codes()
    assert len(codes) >= 20  # the scan finds them
    assert sorted(codes - set(ADVICE)) == []
    for means, todo in ADVICE.values():
        assert means and todo and "statistic" not in means and "sigma" not in todo


def test_plain_advice_says_what_to_do():
    from xcalib.calib.diagnostics import CalibDiagnostics
    from xcalib.viz.advice import plain_advice

    d = CalibDiagnostics()
    d.refusal = "misfit_focal_length"
    lines = plain_advice(CalibrationResult(success=False, message="model misfit: ...", diagnostics=d))
    assert "(misfit_focal_length)" in lines[0] and lines[1].startswith("What to do:") and "--intrinsics" in lines[1]
    d2 = CalibDiagnostics()
    d2.refusal = "some_future_reason"
    assert "What to do:" in plain_advice(CalibrationResult(success=False, diagnostics=d2))[1]
    coarse = CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3),
                               rotation_std_deg=np.full(3, 2.0), translation_std_m=np.full(3, 1.0))
    assert coarse.coarse and "COARSE" in plain_advice(coarse)[0] and "What to do" in plain_advice(coarse)[1]
    fine = CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3),
                             rotation_std_deg=np.full(3, 0.05), translation_std_m=np.full(3, 0.01))
    assert not fine.coarse and "fine" in plain_advice(fine)[0]
    from xcalib.calib.diagnostics import MisfitCheck

    d3 = CalibDiagnostics()
    d3.misfit = [MisfitCheck("mirrored", 0.8, 1.25, False), MisfitCheck("lens", 12.0, 10.0, True)]
    lines = plain_advice(CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3),
                                           rotation_std_deg=np.full(3, 0.05), translation_std_m=np.full(3, 0.01),
                                           diagnostics=d3))
    assert any("1 of 2 checks for a model misfit flagged (lens)" in line for line in lines)


# ------------------------------------------------------------------ contact sheet legend
def test_contact_sheet_has_a_legend(tmp_path):
    import cv2

    from xcalib.data.synth.contact import contact_sheet, legend

    strip = legend(960)
    assert strip.shape == (96, 960, 3) and strip.dtype == np.uint8
    assert (np.abs(strip.astype(int) - 24).sum(axis=2) > 0).mean() > 0.02  # something is drawn on it
    f = _frames(1)[0]
    path = contact_sheet([f, f], tmp_path / "s.png", cols=2, tile_width=320)
    im = cv2.imread(str(path))
    assert im.shape == (240 + 96, 640, 3)


# ------------------------------------------------------------------ match --site: weights that do not fit
def test_match_warns_when_chosen_weights_do_not_fit(tmp_path, monkeypatch, a9_dir):
    import shutil

    from typer.testing import CliRunner

    from xcalib.cli import app
    from xcalib.engine.checkpoint import packaged_weights_dir

    site = tmp_path / "home" / "sites" / "othersite"  # a user site whose weights were made elsewhere
    site.mkdir(parents=True)
    for p in (packaged_weights_dir() / "generic").glob("fastmatch.*"):
        shutil.copy(p, site / p.name)
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path / "home"))
    r = CliRunner().invoke(app, ["match", str(a9_dir), "--index", "0", "--site", "othersite", "--json",
                                 "--validate", "off"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["source"] == "model" and "--site othersite do not fit this frame" in out["weights_misfit"]
    assert "no confident pair" in out["weights_misfit"] or "collapsed" in out["weights_misfit"]


# ------------------------------------------------------------------ hostile frame folders
def _folder(tmp_path: Path, det_edit=None, intr_edit=None) -> Path:
    from xcalib.io.frames import write_frame_folder

    small = CameraIntrinsics(fx=60.0, fy=60.0, cx=32.0, cy=24.0, width=64, height=48)
    f = _frames(1, stamps=False)[0]
    f = Frame(f.image, f.point_cloud, np.array([[10, 10, 30, 26]], np.float32), f.bboxes_3d, frame_key="0000",
              intrinsics=small)
    root = write_frame_folder(tmp_path / "ff", [f], camera="front", intrinsics=small).parent
    if det_edit:
        p = next(root.glob("*/detections.json"))
        d = json.loads(p.read_text())
        det_edit(d)
        p.write_text(json.dumps(d))
    if intr_edit:
        p = root / "intrinsics.json"
        d = json.loads(p.read_text())
        intr_edit(d)
        p.write_text(json.dumps(d))
    return root


@pytest.mark.parametrize("value", [[1, 2], {"a": 1}, True, 1.5, float("nan")])
@pytest.mark.parametrize("field", ["frame_key", "camera_name"])
def test_frame_names_must_be_names(tmp_path, field, value):
    from xcalib.errors import FormatError
    from xcalib.io.frames import FrameFolder

    root = _folder(tmp_path, lambda d: d.__setitem__(field, value))
    with pytest.raises(FormatError, match=rf"detections\.json.*{field}.*expected a name"):
        FrameFolder(root)[0]


def test_integer_frame_key_still_reads(tmp_path):
    from xcalib.io.frames import FrameFolder

    root = _folder(tmp_path, lambda d: d.__setitem__("frame_key", 7))
    assert FrameFolder(root)[0].frame_key == "7"


def test_box_beyond_float32_is_named_not_inf(tmp_path, recwarn):
    from xcalib.errors import FormatError
    from xcalib.io.frames import FrameFolder

    def edit(d):
        d["bboxes_2d"][0][2] = 1e300

    with pytest.raises(FormatError, match=r"bboxes_2d.*row 0 holds 1e\+300, beyond a 32-bit float"):
        FrameFolder(_folder(tmp_path, edit))[0]
    assert not [w for w in recwarn if "overflow" in str(w.message)]


def test_principal_point_outside_the_image_names_intrinsics_json(tmp_path):
    from xcalib.errors import FormatError
    from xcalib.io.frames import FrameFolder

    root = _folder(tmp_path, intr_edit=lambda d: (d.__setitem__("cx", 1e12), d.pop("width", None),
                                                  d.pop("height", None)))
    with pytest.raises(FormatError, match=r"intrinsics\.json.*cx, cy.*principal point .* far outside the 64x48"):
        FrameFolder(root)[0]


def test_a_one_pixel_placeholder_image_is_not_checked_against_the_principal_point(tmp_path):
    """A 1x1 image is a placeholder whose size comes from the intrinsics (the calibration's
    convention): a frame folder holding one reads, whatever the principal point."""
    import numpy as np

    from xcalib.io.frames import FrameFolder, write_frame_folder
    from xcalib.types import Frame

    from test_calib_support import INTR

    frame = Frame(image=np.zeros((1, 1, 3), np.uint8), point_cloud=np.zeros((0, 3), np.float32),
                  bboxes_2d=np.array([[100.0, 100.0, 200.0, 180.0]], np.float32),
                  bboxes_3d=np.array([[1.0, 0.0, 10.0, 2.0, 1.5, 4.0]], np.float32))
    root = write_frame_folder(tmp_path / "f", [frame], intrinsics=INTR)
    read = FrameFolder(root)[0]
    assert read.image.shape[:2] == (1, 1) and len(read.bboxes_2d) == 1


def test_box_beyond_the_lidar_range_is_named(tmp_path):
    from xcalib.errors import FormatError
    from xcalib.io.frames import FrameFolder

    def edit(d):
        d["bboxes_3d"][0][0] = 1e12

    with pytest.raises(FormatError, match=r"bboxes_3d.*row 0: a 3D box coordinate or size beyond 100000 m"):
        FrameFolder(_folder(tmp_path, edit))[0]


@pytest.mark.parametrize("where,value,match", [
    (("psr", "position", "x"), 1e12, r"\[0\]\.psr\.position.*beyond 100000 m"),
    (("psr", "scale", "y"), True, r"\[0\]\.psr\.scale\.y.*expected a number, got True"),
])
def test_sustech_labels_refuse_absurd_or_mistyped_values(tmp_path, where, value, match):
    from xcalib.errors import FormatError
    from xcalib.formats.sustech import read_sustech_labels

    obj = {"psr": {"position": {"x": 4.0, "y": -5.0, "z": 1.0}, "scale": {"x": 4.5, "y": 1.8, "z": 1.6},
                   "rotation": {"x": 0.0, "y": 0.0, "z": 1.4}}, "obj_type": "Car", "obj_id": "8"}
    assert read_sustech_labels(_write(tmp_path / "ok.json", [obj]))["box7"].shape == (1, 7)
    obj["psr"][where[1]][where[2]] = value
    with pytest.raises(FormatError, match=match):
        read_sustech_labels(_write(tmp_path / "bad.json", [obj]))


def _write(path: Path, obj) -> Path:
    path.write_text(json.dumps(obj))
    return path


# ------------------------------------------------------------------ KITTI calib.txt: absurd values named
_KITTI = """P0: 7.2e+02 0 6.1e+02 0 0 7.2e+02 1.7e+02 0 0 0 1 0
P1: 7.2e+02 0 6.1e+02 -3.9e+02 0 7.2e+02 1.7e+02 0 0 0 1 0
P2: 7.2e+02 0 6.1e+02 4.5e+01 0 7.2e+02 1.7e+02 2.2e-01 0 0 1 2.7e-03
P3: 7.2e+02 0 6.1e+02 -3.4e+02 0 7.2e+02 1.7e+02 2.3e+00 0 0 1 3.7e-03
R0_rect: 1 0 0 0 1 0 0 0 1
Tr_velo_to_cam: 0 -1 0 -4.1e-03 0 0 -1 -7.6e-02 1 0 0 -2.7e-01
"""


@pytest.mark.parametrize("old,new,match", [
    ("-4.1e-03", "1e12", r"Tr_velo_to_cam.*translation .* beyond 10000 m"),
    ("P2: 7.2e+02", "P2: 1e300", r"P2.*fx=1e\+300.*beyond 1e\+06 px"),
    ("P2: 7.2e+02 0 6.1e+02 4.5e+01", "P2: 7.2e+02 0 6.1e+02 1e12", r"P2 \(its offset.*beyond 10000 m"),
    ("7.2e+02 1.7e+02 2.2e-01", "7.2e+02 1e12 2.2e-01", r"P2.*cy=1e\+12.*beyond 1e\+06 px"),
])
def test_kitti_calibration_refuses_absurd_values(tmp_path, old, new, match):
    from xcalib.errors import FormatError
    from xcalib.formats.kitti import load_kitti_calibration

    good = tmp_path / "calib.txt"
    good.write_text(_KITTI)
    assert load_kitti_calibration(good).K(2)[0, 0] == pytest.approx(720.0)
    bad = tmp_path / "bad.txt"
    bad.write_text(_KITTI.replace(old, new, 1))
    with pytest.raises(FormatError, match=r"bad\.txt.*" + match):
        load_kitti_calibration(bad)


# ------------------------------------------------------------------ camera files: absurd numbers named
_CAM = CameraIntrinsics(fx=1000.0, fy=1001.0, cx=640.0, cy=360.0, distortion=np.array([-0.1, 0.01, 0.001, 0, 0]),
                        width=1280, height=720)


@pytest.mark.parametrize("fmt", ["camera_info", "kalibr", "opencv_yaml", "opencv_json"])
@pytest.mark.parametrize("old,match", [
    ("1000.0", r"1e\+12"),  # fx
    ("640.0", r"principal point \(1000000000000\.0, 360\.0\) px lies far outside"),
])
def test_camera_files_refuse_absurd_numbers_naming_the_file(tmp_path, fmt, old, match):
    from xcalib.errors import FormatError
    from xcalib.formats.cameras import camera_text, read_intrinsics

    text = camera_text(_CAM, fmt)
    ext = ".json" if "json" in fmt else ".yaml"
    good = tmp_path / f"good{ext}"
    good.write_text(text)
    assert read_intrinsics(good).fx == pytest.approx(1000.0)
    if old not in text:
        old = old[:-1]  # OpenCV's YAML writes 1000. and 640.
    assert old in text
    bad = tmp_path / f"bad{ext}"
    bad.write_text(text.replace(old, "1e12", 1))
    with pytest.raises(FormatError, match=rf"bad{ext}.*{match}"):
        read_intrinsics(bad)


@pytest.mark.parametrize("value", [".nan", "100000000", "-5", "abc"])
def test_opencv_matrix_size_checked_before_opencv_allocates(tmp_path, value):
    from xcalib.errors import FormatError
    from xcalib.formats.cameras import camera_text, read_intrinsics

    text = camera_text(_CAM, "opencv_yaml")
    bad = tmp_path / "cv.yaml"
    bad.write_text(text.replace("rows: 3", f"rows: {value}", 1))
    with pytest.raises(FormatError, match=r"cv\.yaml.*camera_matrix\.rows.*rows must be an integer 1\.\.16"):
        read_intrinsics(bad)


# ------------------------------------------------------------------ calibration files: absurd cameras named
@pytest.mark.parametrize("fmt", ["calib_json", "lucid", "calib_txt", "nuscenes", "json"])
def test_calibration_files_refuse_an_absurd_camera(tmp_path, fmt):
    from xcalib.errors import FormatError
    from xcalib.formats.export import export_calibration, read_calibration
    from xcalib.geometry.rotations import euler_to_matrix

    cam = CameraIntrinsics(fx=1000.0, fy=1001.0, cx=640.0, cy=360.0, width=1280, height=720)
    res = CalibrationResult(success=True, intrinsics=cam, rotation=euler_to_matrix([-90.5, 0.3, -89.7], "xyz",
                                                                                     degrees=True),
                            translation=np.array([0.11, -0.32, 0.25]), camera_name="cam")
    path = export_calibration(res, fmt, tmp_path / "good")[0]
    assert read_calibration(path, fmt).intrinsics.fx == pytest.approx(1000.0)
    text = path.read_text()
    bad = path.with_name("bad" + path.suffix)
    bad.write_text(text.replace("1000.0", "1e12", 1).replace("1001.0", "1e12", 1))
    with pytest.raises(FormatError, match=r"bad.*(beyond 1e\+06 px|implausible)"):
        read_calibration(bad, fmt)


@pytest.mark.parametrize("old,new,match", [
    ("1.65 1.67 3.64", "1.65 1.67 1e300", r"row 1: dimensions / location \(m\) = 1e\+300 is out of range"),
    ("587.01 173.33", "1e12 173.33", r"row 1: bbox = 1e\+12 is out of range"),
])
def test_kitti_labels_refuse_absurd_values(tmp_path, old, new, match):
    from xcalib.errors import FormatError
    from xcalib.formats.kitti import load_kitti_labels

    row = "Car 0.00 0 -1.58 587.01 173.33 614.12 200.12 1.65 1.67 3.64 -0.65 1.71 46.70 -1.59\n"
    good = tmp_path / "000000.txt"
    good.write_text(row)
    assert len(load_kitti_labels(good).bboxes_2d) == 1
    bad = tmp_path / "000001.txt"
    bad.write_text(row.replace(old, new))
    with pytest.raises(FormatError, match=r"000001\.txt.*" + match):
        load_kitti_labels(bad)


@pytest.mark.parametrize("edit,match", [
    (lambda d: d["cam_K"]["data"][0].__setitem__(0, 1e12), r"cam_K / cam_dist.*(beyond 1e\+06 px|fx/fy)"),
    (lambda d: d["cam_dist"]["data"].__setitem__(0, -1e300), r"cam_K / cam_dist.*distortion"),
])
def test_calibanything_calib_json_refuses_an_absurd_camera(tmp_path, edit, match):
    from xcalib.errors import FormatError
    from xcalib.formats.calibanything import read_calib_json

    d = {"cam_K": {"rows": 3, "cols": 3, "data": [[1070.2, 0.0, 961.7], [0.0, 1070.5, 524.8], [0.0, 0.0, 1.0]]},
         "cam_dist": {"cols": 5, "data": [0, 0, 0, 0, 0]},
         "T_lidar_to_cam": {"rows": 4, "cols": 4, "data": [[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]]}}
    assert read_calib_json(_write(tmp_path / "calib.json", d)).intrinsics.fx == pytest.approx(1070.2)
    edit(d)
    with pytest.raises(FormatError, match=r"bad\.json.*" + match):
        read_calib_json(_write(tmp_path / "bad.json", d))


def test_site_index_page_says_each_cameras_verdict_in_plain_words(tmp_path):
    from xcalib.calib.diagnostics import CalibDiagnostics
    from xcalib.site import calibrate_site
    from xcalib.viz.site_report import write_site_report

    def fake(frames, intrinsics, progress=None, **_):
        d = CalibDiagnostics()
        d.refusal = "ambiguous"
        return CalibrationResult(success=False, message="ambiguous: two poses", diagnostics=d)

    small = CameraIntrinsics(fx=60.0, fy=60.0, cx=32.0, cy=24.0, width=64, height=48)
    frames = [Frame(f.image, f.point_cloud, np.array([[10, 10, 30, 26]], np.float32), f.bboxes_3d,
                    frame_key=f.frame_key, intrinsics=small) for f in _frames(3)]
    site, loaded = calibrate_site({"front": frames, "left": list(frames)}, calibrate=fake)
    paths = write_site_report(tmp_path / "out", site, loaded, max_overlays=0, review_frames=2)
    page = paths.html.read_text()
    assert page.count("In short: no pose was delivered (ambiguous)") == 2 and "What to do: add frames" in page


# ------------------------------------------------------------------ HDF5 caches
@pytest.mark.parametrize("dataset,value,match", [
    ("calibration/camera/intrinsics", 1e12, r"/calibration/camera/intrinsics.*beyond 1e\+06 px"),
    ("labels/camera/000000/lidar_bbox_7", np.nan, r"lidar_bbox_7.*NaN/Inf in a 3D box"),
])
def test_hdf5_cache_refuses_an_absurd_camera_and_nan_yawed_boxes(tmp_path, dataset, value, match):
    import h5py

    from xcalib.data.synth import write_site
    from xcalib.errors import FormatError
    from xcalib.io.sources import open_source

    write_site(tmp_path / "s", 0, 0, 2, seed=3, render_images=False, lidar=False)
    path = tmp_path / "s" / "test.h5"
    assert len(open_source(path)[0].meta["box7"]) > 0
    bad = tmp_path / "bad.h5"
    bad.write_bytes(path.read_bytes())
    with h5py.File(bad, "r+") as f:
        a = np.array(f[dataset][()], dtype=np.float64)
        attrs = dict(f[dataset].attrs)
        a.flat[0] = value
        del f[dataset]
        f[dataset] = a
        f[dataset].attrs.update(attrs)
    with pytest.raises(FormatError, match=r"bad\.h5.*" + match):
        open_source(bad)[0]


def _pandaset_edited(tmp_path, src, edit):
    """A copy of the PandaSet folder ``src`` (its files linked) whose calibration.json ``edit`` changed."""
    root = tmp_path / "pandaset_002"
    root.mkdir()
    for p in src.iterdir():
        if p.name != "calibration.json":
            (root / p.name).symlink_to(p)
    cal = json.loads((src / "calibration.json").read_text())
    edit(cal)
    (root / "calibration.json").write_text(json.dumps(cal))
    return root


@pytest.mark.parametrize("key,value,match", [
    ("width", float("inf"), r"cameras\.front_camera\.width.*expected an image size"),
    ("height", [1080], r"cameras\.front_camera\.height.*expected an image size"),
    ("width", False, r"cameras\.front_camera\.width.*expected an image size"),
    ("model", "fisheye", r"cameras\.front_camera\.model.*unsupported camera model 'fisheye'"),
    ("distortion", [0.1, 0.0, 0.0, 0.0], r"cameras\.front_camera\.distortion.*undistorted"),
    ("fx", 1e12, r"cameras\.front_camera\.fx"),
])
def test_pandaset_camera_fields_are_checked(tmp_path, key, value, match):
    from conftest import shared_path

    from xcalib.errors import FormatError
    from xcalib.io.sources import open_source

    def edit(cal):
        cal["cameras"]["front_camera"][key] = value

    root = _pandaset_edited(tmp_path, shared_path("pandaset_002"), edit)
    with pytest.raises(FormatError, match=r"calibration\.json.*" + match):
        open_source(root)[0]


@pytest.mark.parametrize("entry,value,match", [((0, 1), 1e12, r"T_cam_lidar.*(rotation|orthonormal|rigid)"),
                                               ((0, 1), True, r"T_cam_lidar.*(true / false|rotation)"),
                                               # true where 1 stands was read as 1.0: a valid pose
                                               ((3, 3), True, r"T_cam_lidar.*expected 4x4 numbers, got true / false")])
def test_pandaset_recorded_pose_must_be_rigid(tmp_path, entry, value, match):
    from conftest import shared_path

    from xcalib.errors import FormatError
    from xcalib.io.sources import open_source

    def edit(cal):
        cal["cameras"]["front_camera"]["frames"]["00"]["T_cam_lidar"][entry[0]][entry[1]] = value

    root = _pandaset_edited(tmp_path, shared_path("pandaset_002"), edit)
    with pytest.raises(FormatError, match=r"calibration\.json.*frames\.00\." + match):
        open_source(root)[0]
