"""Bad input as a new user makes it, through the command line: each is exit 1 with one line
``error: FILE [FIELD]: problem`` (what to do where there is something to do), never a traceback."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from xcalib.cli import main
from xcalib.errors import FormatError


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """A 2-frame frame folder (demo layout) with its intrinsics.json."""
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.io.frames import write_frame_folder

    d = tmp_path_factory.mktemp("frames") / "rec"
    site = sample_site(2, "roadside")
    write_frame_folder(d, generate_frames(site, 2, seed=2, render_images=False), intrinsics=site.intrinsics)
    return d


def _broken(folder: Path, tmp_path: Path, edit) -> Path:
    """A copy of ``folder`` whose second frame's detections.json is changed by ``edit(dict)``."""
    import shutil

    out = tmp_path / "broken"
    shutil.copytree(folder, out)
    man = json.loads((out / "manifest.json").read_text())
    det_path = out / man["frames"][1]["detections"]
    det = json.loads(det_path.read_text())
    edit(det)
    det_path.write_text(json.dumps(det))
    return out


def _error(capsys, argv) -> str:
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 1, err
    assert "Traceback" not in err
    line = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert len(line) == 1, err
    return line[0]


@pytest.mark.parametrize("edit,field,says", [
    (lambda d: d.pop("bboxes_3d"), "bboxes_3d", "missing key"),
    (lambda d: d["bboxes_2d"][0].__setitem__(0, "abc"), "bboxes_2d", "row 0 is ['abc'"),
    (lambda d: d["bboxes_2d"][-1].pop(), "bboxes_2d", "rows must be lists of 4 numbers; row "),
    (lambda d: d["bboxes_3d"].append([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.0, 1.0, 2.0]), "bboxes_3d", "6 or 7 numbers"),
])
def test_a_detection_file_with_a_bad_field_names_file_field_and_row(folder, tmp_path, capsys, edit, field, says):
    bad = _broken(folder, tmp_path, edit)
    msg = _error(capsys, ["calibrate", str(bad), "--out", str(tmp_path / "out")])
    assert "detections.json" in msg and f"[{field}]" in msg and says in msg
    assert not (tmp_path / "out").exists()


def test_ragged_rows_of_allowed_widths_say_so(tmp_path):
    from xcalib.io.frames import _box_array

    with pytest.raises(FormatError, match=r"rows of different lengths \[6, 7\]"):
        _box_array(tmp_path / "d.json", "bboxes_3d", [[0.0] * 6, [0.0] * 7], (6, 7))


def test_an_intrinsics_file_that_is_not_a_camera_file(folder, tmp_path, capsys):
    p = tmp_path / "K.json"
    p.write_text("hello")
    msg = _error(capsys, ["calibrate", str(folder), "--intrinsics", str(p), "--out", str(tmp_path / "o")])
    assert "K.json" in msg and "not a camera file" in msg and "'hello'" in msg and "YAML mapping, got" not in msg


def test_intrinsics_of_another_resolution_are_refused_before_a_pose(folder, tmp_path, capsys):
    """The intrinsics file of another camera (a 640x480 one) for frames of 960x600 images: said
    up front, not fitted into a misleading model misfit."""
    from xcalib.io.images import read_image

    man = json.loads((folder / "manifest.json").read_text())
    det = json.loads((folder / man["frames"][0]["detections"]).read_text())
    h, w = read_image(folder / Path(man["frames"][0]["detections"]).parent / det["image"]).shape[:2]
    p = tmp_path / "vga.json"
    p.write_text(json.dumps({"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480}))
    msg = _error(capsys, ["calibrate", str(folder), "--intrinsics", str(p), "--out", str(tmp_path / "o")])
    assert "for a 640x480 image, but frame" in msg and f"image is {w}x{h}" in msg
    # the same camera's intrinsics with its size: no such error (a few rows cropped is fine)
    from xcalib.calib.inputs import _check_declared_size
    from xcalib.geometry.camera import CameraIntrinsics

    _check_declared_size(CameraIntrinsics(fx=900.0, fy=900.0, cx=w / 2, cy=h / 2, width=w, height=h), (w, h - 8), 0)
    _check_declared_size(CameraIntrinsics(fx=900.0, fy=900.0, cx=w / 2, cy=h / 2), (w, h), 0)


def test_a_calibration_file_that_is_not_a_calibration(folder, tmp_path, capsys):
    p = tmp_path / "K.json"
    p.write_text(json.dumps({"fx": 1000.0, "fy": 1000.0, "cx": 480.0, "cy": 300.0}))
    msg = _error(capsys, ["monitor", str(folder), "--calibration", str(p), "--out", str(tmp_path / "o")])
    assert "K.json [success]" in msg and "not an xcalib calibration" in msg and "xcalib convert" in msg


@pytest.mark.parametrize("argv,says", [
    (["calibrate", "{tmp}/no_such_dir"], "frame source not found"),
    (["calibrate", "{tmp}/empty"], "not a recognised frame source; supported:"),
    (["calibrate", "{tmp}/empty"], "(the folder is empty)"),
    (["calibrate", "{folder}", "--intrinsics", "{tmp}/nothere.json"], "intrinsics file not found"),
    (["convert", "{tmp}/missing.json", "--to", "kitti"], "not found"),
])
def test_wrong_paths_and_empty_folders(folder, tmp_path, capsys, argv, says):
    (tmp_path / "empty").mkdir()
    argv = [a.format(tmp=tmp_path, folder=folder) for a in argv]
    msg = _error(capsys, argv + (["--out", str(tmp_path / "o")] if argv[0] == "calibrate" else []))
    assert says in msg


def test_a_dataset_root_names_the_recordings_inside_it(folder, tmp_path, capsys):
    """A user gives the folder above the recordings: the error lists those it would read."""
    import shutil

    root = tmp_path / "dataset"
    for name in ("day1", "day2"):
        shutil.copytree(folder, root / name)
    (root / "notes").mkdir()
    msg = _error(capsys, ["calibrate", str(root), "--out", str(tmp_path / "o")])
    assert "not a recognised frame source" in msg and "frame sources inside it:" in msg
    assert f"{root / 'day1'} (frame-folder)" in msg and f"{root / 'day2'} (frame-folder)" in msg and "notes" not in msg


def test_a_bag_without_camera_info_says_what_to_pass(folder, tmp_path, capsys):
    pytest.importorskip("mcap")
    from mcap.reader import make_reader
    from mcap.writer import Writer

    full = tmp_path / "full.mcap"
    assert main(["bag", "write", str(folder), str(full)]) == 0
    bare = tmp_path / "bare.mcap"
    with open(full, "rb") as src, open(bare, "wb") as dst:
        w = Writer(dst)
        w.start(profile="ros2")
        schemas, channels = {}, {}
        for schema, ch, m in make_reader(src).iter_messages():
            if schema.name.endswith("CameraInfo"):
                continue
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if ch.id not in channels:
                channels[ch.id] = w.register_channel(ch.topic, ch.message_encoding, schemas[schema.id])
            w.add_message(channels[ch.id], m.log_time, m.data, m.publish_time)
        w.finish()
    msg = _error(capsys, ["calibrate", str(bare), "--out", str(tmp_path / "o")])
    assert "bare.mcap" in msg and "no CameraInfo topic" in msg and "--intrinsics" in msg


def test_calibrate_many_with_a_pattern_naming_nothing_says_so_before_any_progress(tmp_path, capsys):
    rc = main(["calibrate-many", str(tmp_path / "recordings" / "*"), "--out", str(tmp_path / "batch")])
    err = capsys.readouterr().err
    assert rc == 1 and "no recording matches" in err
    assert "0/?" not in err and "calibrate" not in err.split("error:")[0]
