"""Session 11's new-user / hostile-input leftovers: HDF5 caches with absurd times, velocities and
points; a frame folder naming a missing image; the readers fuzz's determinism; ``validate`` given
a frame source; the plain advice of a refused calibration from xcalib's own detections."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from xcalib.errors import FormatError, MissingFileError
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.types import Frame

SMALL = CameraIntrinsics(fx=60.0, fy=60.0, cx=32.0, cy=24.0, width=64, height=48)


# ------------------------------------------------------------------ HDF5 caches: times, velocities, points
@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    from xcalib.data.synth import write_site

    root = tmp_path_factory.mktemp("site")
    write_site(root, 0, 0, 2, seed=3, render_images=False)
    return root / "test.h5"


def _edited(cache: Path, tmp_path: Path, dataset: str, value) -> Path:
    import h5py

    bad = tmp_path / "bad.h5"
    bad.write_bytes(cache.read_bytes())
    with h5py.File(bad, "r+") as f:
        a = np.array(f[dataset][()], dtype=np.float64)
        attrs = dict(f[dataset].attrs)
        a.flat[0] = value
        del f[dataset]
        f[dataset] = a
        f[dataset].attrs.update(attrs)
    return bad


XYZ = "point_clouds/lidar/000000/xyz"
LAB = "labels/camera/000000/"


@pytest.mark.parametrize("dataset,value,match", [
    (XYZ, 1e12, r"point 0 has a coordinate of 1e\+12 m, beyond 100000 m"),
    (XYZ, -1e300, r"beyond 100000 m"),
    (XYZ, np.inf, r"1 of \d+ point\(s\) have NaN/Inf in x, y, z \(first at row 0\)"),
    (XYZ, np.nan, r"NaN/Inf in x, y, z"),
    (LAB + "lidar_time_s", 1e12, r"time 1e\+12 s is beyond 1e\+11 s in magnitude: not a clock in seconds"),
    (LAB + "camera_time_s", -1e300, r"beyond 1e\+11 s"),
    (LAB + "lidar_time_s", np.inf, r"expected a finite time"),
    (LAB + "lidar_velocities", 1e12, r"row 0 holds a velocity of 1e\+12 m/s, beyond 1000 m/s"),
    (LAB + "lidar_velocities", 1e300, r"beyond 1000 m/s"),
    (LAB + "lidar_velocities", np.nan, r"velocities must be finite"),
])
def test_hdf5_cache_refuses_absurd_times_velocities_and_points(cache, tmp_path, dataset, value, match):
    from xcalib.io.sources import open_source

    bad = _edited(cache, tmp_path, dataset, value)
    with pytest.raises(FormatError, match=r"bad\.h5 \[/" + dataset.replace("/", "/") + r"\]: .*" + match):
        open_source(bad)[0]


@pytest.mark.parametrize("dataset,value", [(XYZ, 99_999.0), (LAB + "lidar_time_s", 1.7e9),
                                           (LAB + "lidar_time_s", -5.0), (LAB + "lidar_velocities", 70.0)])
def test_hdf5_cache_plausible_values_read_unchanged(cache, tmp_path, dataset, value):
    from xcalib.io.sources import open_source

    frame = open_source(_edited(cache, tmp_path, dataset, value))[0]
    got = {XYZ: lambda f: f.point_cloud[0, 0], LAB + "lidar_time_s": lambda f: f.lidar_time_s,
           LAB + "lidar_velocities": lambda f: f.velocities_3d[0, 0]}[dataset](frame)
    assert got == pytest.approx(value)


def test_hdf5_cache_reads_identically(cache):
    """The checks change nothing for a valid cache: every field as stored."""
    import h5py

    from xcalib.io.sources import open_source

    frame = open_source(cache)[0]
    with h5py.File(cache) as f:
        xyz = f[XYZ][()]
        t = float(f[LAB + "lidar_time_s"][()])
        v = f[LAB + "lidar_velocities"][()]
    assert frame.point_cloud.dtype == np.float32
    np.testing.assert_array_equal(frame.point_cloud[:, :3], xyz)
    assert frame.lidar_time_s == t
    np.testing.assert_array_equal(frame.velocities_3d, v[: len(frame.velocities_3d)])


def test_frame_folder_times_are_bounded_too(tmp_path):
    """The bound lives in io.timing, shared by every reader of times (frame folder, cache, mmdet3d)."""
    from xcalib.io.frames import FrameFolder

    root = _folder(tmp_path, lambda d: d.update(lidar_time_s=1.7e12))  # a Unix time in milliseconds
    with pytest.raises(FormatError, match=r"detections\.json \[lidar_time_s\]: time 1\.7e\+12 s .*milliseconds"):
        FrameFolder(root)[0]
    root = _folder(tmp_path / "ok", lambda d: d.update(lidar_time_s=1.7e9, camera_time_s=1.7e9 + 0.01))
    assert FrameFolder(root)[0].lidar_time_s == 1.7e9


# ------------------------------------------------------------------ frame folders: files named inside files
def _folder(tmp_path: Path, det_edit=None) -> Path:
    from xcalib.io.frames import write_frame_folder

    rng = np.random.default_rng(0)
    cloud = np.column_stack([rng.uniform(5, 30, 200), rng.uniform(-8, 8, 200), rng.uniform(-1.5, 1, 200)])
    f = Frame(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8), cloud.astype(np.float32),
              np.array([[10, 10, 30, 26]], np.float32), np.array([[10.0, -1, -0.8, 4.5, 1.8, 1.5, 0.1]], np.float32),
              frame_key="0000", intrinsics=SMALL)
    root = write_frame_folder(tmp_path / "ff", [f], camera="front", intrinsics=SMALL).parent
    if det_edit:
        p = next(root.glob("*/detections.json"))
        d = json.loads(p.read_text())
        det_edit(d)
        p.write_text(json.dumps(d))
    return root


@pytest.mark.parametrize("field,value,match", [
    ("image", "abc", r"\[image\]: names the image 'abc', which does not exist \(.*abc\)"),
    ("point_cloud", "nope.pcd", r"\[point_cloud\]: names the point cloud 'nope\.pcd', which does not exist"),
    ("image", ".", r"\[image\]: names the image '\.', which is not a file"),
])
def test_missing_file_named_in_detections_is_a_format_error(tmp_path, field, value, match):
    from xcalib.io.frames import FrameFolder

    root = _folder(tmp_path, lambda d: d.__setitem__(field, value))
    with pytest.raises(MissingFileError, match=r"detections\.json " + match) as err:
        FrameFolder(root)[0]
    assert isinstance(err.value, FormatError) and isinstance(err.value, FileNotFoundError)
    assert err.value.field == field and err.value.path.endswith("detections.json")


@pytest.mark.parametrize("value", ["../../etc/passwd", "/etc/passwd", "sub/../../x.png", "../ff/frame_0000/image.png"])
def test_paths_named_in_detections_stay_inside_the_folder(tmp_path, value):
    """The folder check comes before the existence check: a path leaving the folder is refused as
    such, whether or not the file exists."""
    from xcalib.io.frames import FrameFolder

    root = _folder(tmp_path, lambda d: d.__setitem__("image", value))
    with pytest.raises(FormatError, match=r"\[image\]: path .* points outside"):
        FrameFolder(root)[0]


def test_cli_names_the_missing_image_field(tmp_path, capsys):
    from xcalib.cli import main

    root = _folder(tmp_path, lambda d: d.__setitem__("image", "abc"))
    assert main(["calibrate", str(root), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "error: " in err and "detections.json [image]: names the image 'abc', which does not exist" in err


# ------------------------------------------------------------------ xcalib validate SOURCE: a source check
def test_validate_source_checks_a_frame_folder(tmp_path, capsys):
    from xcalib.cli import main

    root = _folder(tmp_path)
    assert main(["validate", str(root), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["kind"] == "frame-folder" and r["frames"] == r["read"] == 1 and r["unreadable"] == 0
    assert r["boxes_2d"]["max"] == 1 and r["boxes_3d"]["max"] == 1 and r["points"]["min"] == 200
    assert r["with"]["intrinsics"] == 1 and r["missing"] == [] and r["readable"] is True
    assert main(["validate", str(root)]) == 0
    out = capsys.readouterr().out
    assert "read 1, unreadable 0" in out and "Next: xcalib calibrate" in out and "--hdf5 CACHE evaluates" in out


def test_validate_source_lists_unreadable_frames_and_what_is_missing(tmp_path, capsys):
    from xcalib.cli import main

    root = _folder(tmp_path, lambda d: d.__setitem__("image", "abc"))
    assert main(["validate", str(root), "--json"]) == 1
    r = json.loads(capsys.readouterr().out)
    assert r["unreadable"] == 1 and r["readable"] is False and "names the image 'abc'" in r["errors"][0]
    empty = _folder(tmp_path / "e", lambda d: d.update(bboxes_2d=[], match_matrix=None))
    assert main(["validate", str(empty), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert any(m.startswith("no 2D boxes in any frame: calibrate --detect") for m in r["missing"])


@pytest.mark.parametrize("argv,match", [([], "give a frame SOURCE to check it"),
                                        (["SRC", "--hdf5", "SRC"], "not both")])
def test_validate_needs_a_source_or_a_cache(tmp_path, capsys, argv, match):
    from xcalib.cli import main

    root = str(_folder(tmp_path))
    assert main(["validate", *[root if a == "SRC" else a for a in argv]]) == 2
    assert match in capsys.readouterr().err


# ------------------------------------------------------------------ --help as a new user reads it
def _commands():
    import typer.main

    from xcalib.cli import app

    def walk(cmd, path):
        yield path, cmd
        for name, sub in getattr(cmd, "commands", {}).items():
            yield from walk(sub, path + [name])
    return list(walk(typer.main.get_command(app), []))


def test_help_paragraphs_are_not_broken_mid_sentence():
    """A single newline inside a help paragraph prints as a ragged line break (rich keeps it and
    wraps as well): every command's help is paragraphs joined by blank lines."""
    import re

    ragged = {" ".join(p): len(re.findall(r"(?<!\n)\n(?!\n)", c.help or "")) for p, c in _commands()}
    assert {k: v for k, v in ragged.items() if v} == {}


def test_help_text_in_brackets_is_printed(monkeypatch):
    """Rich reads "[word]" as a markup tag and drops it: calibrate-many's help said
    "pip install 'xcalib'" for "pip install 'xcalib[ray]'"."""
    from typer.testing import CliRunner

    from xcalib.cli import app

    monkeypatch.setenv("COLUMNS", "200")
    out = CliRunner().invoke(app, ["calibrate-many", "--help"]).output
    assert "pip install 'xcalib[ray]'" in out and "[--ray-address ADDR]" in out


# ------------------------------------------------------------------ bags: the same bounds; xcalib's own boxes named
def _bag_with_record(tmp_path: Path, edit, meta=None) -> Path:
    """A small .mcap of the bag test frames (``meta`` added to each), its frame records edited."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from _bag_cases import rewrite_bag, sample_frames

    from xcalib.io.bags import write_bag

    frames = [dataclasses.replace(f, meta={**f.meta, **(meta or {})}) for f in sample_frames(2)]
    src = write_bag(tmp_path / "src.mcap", frames)
    if edit is None:
        return src

    def fn(topic, msgtype, k, msg):
        if topic == "/xcalib/frames":
            rec = json.loads(msg.data)
            edit(rec)
            msg.data = json.dumps(rec)
        return [(topic, msg)]
    return rewrite_bag(src, tmp_path / "bad.mcap", fn)


@pytest.mark.parametrize("edit,match", [
    (lambda r: r.update(lidar_time_s=1.7e12), r"frame record lidar_time_s: time 1\.7e\+12 s is beyond 1e\+11 s"),
    (lambda r: next(iter(r["cameras"].values())).update(camera_time_s=-1e300), r"camera_time_s: time -1e\+300 s"),
    (lambda r: r.update(velocities_3d=[[1e12, 0, 0], [0, 0, 0]], track_ids_3d=[1, 2]),
     r"velocities_3d: a velocity of 1e\+12 m/s, beyond 1000 m/s"),
    (lambda r: r.update(detections_source=["x"]), r"detections_source: expected 'xcalib detect' or nothing"),
])
def test_bag_frame_records_are_bounded_like_the_other_readers(tmp_path, edit, match):
    from xcalib.io.sources import open_source

    with pytest.raises(FormatError, match=r"bad\.mcap.*" + match):
        open_source(_bag_with_record(tmp_path, edit))[0]


def test_bag_written_from_own_detections_says_so(tmp_path):
    """A bag written from frames with xcalib's own boxes (``xcalib detect``) carries that in its
    frame records; read back, the frames say so (calibrate then explains a refusal by the boxes)."""
    from xcalib.cli.calibrate_cmd import _own_detections
    from xcalib.io.sources import open_source

    own = open_source(_bag_with_record(tmp_path, None, meta={"detections": {"source": "xcalib detect"}}))
    assert own[0].detections.source == "xcalib detect" and _own_detections(own)
    plain = open_source(_bag_with_record(tmp_path / "p", None))
    assert "detections" not in plain[0].meta and not _own_detections(plain)


def test_focal_misfit_from_own_detections_advises_on_the_boxes():
    """misfit_focal_length says "the intrinsics are probably wrong"; with xcalib's own boxes
    (``boxes_source``, set by calibrate for them) the boxes are named as the likely
    cause and the user is told to keep the intrinsics."""
    from xcalib.viz.advice import plain_advice

    @dataclasses.dataclass
    class Diag:
        refusal: str = "misfit_focal_length"

    labelled = type("R", (), {"success": False, "diagnostics": Diag(), "meta": {}})()
    own = type("R", (), {"success": False, "diagnostics": Diag(), "meta": {}, "boxes_source": "xcalib detect"})()
    lab, mine = " ".join(plain_advice(labelled)), " ".join(plain_advice(own))
    assert "the intrinsics are probably wrong" in lab
    assert "xcalib's own label-free detectors" in mine and "keep the intrinsics" in mine
    assert "probably wrong" not in mine and "(misfit_focal_length)" in mine
