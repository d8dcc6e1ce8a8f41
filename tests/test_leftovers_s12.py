"""Session 12 (T): the leftovers of session 11's review. ``Frame.detections`` (one meaning, typed) in
place of ``meta["detections"]``; ``calibrate`` decides xcalib's own detections from every frame;
``xcalib validate SOURCE`` reads image sizes from headers (a sample decoded, all with ``--decode``)
and refuses the ``--hdf5`` mode's options (and the other way round) by name."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from xcalib.geometry.camera import CameraIntrinsics
from xcalib.types import OWN_DETECTIONS, Frame, FrameDetections

SMALL = CameraIntrinsics(60.0, 60.0, 32.0, 24.0, width=64, height=48)


def _frame(key: str, seed: int = 0, **kw) -> Frame:
    rng = np.random.default_rng(seed)
    cloud = np.column_stack([rng.uniform(5, 30, 200), rng.uniform(-8, 8, 200), rng.uniform(-1.5, 1, 200)])
    return Frame(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8), cloud.astype(np.float32),
                 np.array([[10, 10, 30, 26]], np.float32), np.array([[10.0, -1, -0.8, 4.5, 1.8, 1.5, 0.1]], np.float32),
                 frame_key=key, intrinsics=SMALL, **kw)


def _folder(tmp_path: Path, n: int) -> Path:
    from xcalib.io.frames import write_frame_folder

    frames = [_frame(f"{i:04d}", i) for i in range(n)]
    return write_frame_folder(tmp_path / "ff", frames, camera="front", intrinsics=SMALL).parent


# ------------------------------------------------------------------ Frame.detections
def test_frame_detections_is_a_typed_field_and_the_old_dict_fills_it():
    old = _frame("0", meta={"detections": {"source": OWN_DETECTIONS, "scores_2d": [0.5], "classes_2d": ["car"]},
                            "other": 1})
    assert old.detections == FrameDetections(OWN_DETECTIONS, (0.5,), ("car",))
    assert old.meta == {"other": 1}  # one place for it: the dict left meta
    with pytest.raises(dataclasses.FrozenInstanceError):
        old.detections.source = "x"
    # dataclasses.replace with the old dict sets it (as before); without, the field is kept
    again = dataclasses.replace(old, meta={**old.meta, "detections": {"source": "synth detector"}})
    assert again.detections == FrameDetections("synth detector") and "detections" not in again.meta
    assert dataclasses.replace(old, bboxes_2d=old.bboxes_2d[:0]).detections == old.detections
    assert _frame("1").detections is None


def test_a_frame_folder_keeps_its_detections_path_under_its_own_name(tmp_path):
    from xcalib.io.frames import FrameFolder

    f = FrameFolder(_folder(tmp_path, 1))[0]
    assert f.detections is None and f.meta["detections_path"].endswith("detections.json")


def test_scores_reach_the_calibration_from_the_typed_field():
    from xcalib.calib.inputs import input_scores

    made = FrameDetections("x", (0.25, 0.5))
    assert np.array_equal(input_scores({}, 2, 0, made), [0.25, 0.5])
    assert np.array_equal(input_scores({"scores_2d": [0.1, 0.2]}, 2, 0, made), [0.1, 0.2])  # meta's own first
    assert input_scores({}, 2, 0, FrameDetections("x")) is None


def test_camera_view_keeps_the_detections():
    from xcalib.io.sources import camera_view

    f = _frame("0", detections=FrameDetections(OWN_DETECTIONS, (0.9,)))
    assert camera_view(f, f.camera_name).detections == f.detections


# ------------------------------------------------------------------ own detections from every frame
def test_own_detections_are_decided_from_every_frame_and_a_mix_is_said():
    from xcalib.cli.calibrate_cmd import _mixed_detections_note, _own_detections

    own = FrameDetections(OWN_DETECTIONS)
    empty = dataclasses.replace(_frame("0"), bboxes_2d=np.zeros((0, 4), np.float32),
                                bboxes_3d=np.zeros((0, 7), np.float32))
    later = [empty, _frame("1", detections=own), _frame("2", detections=own)]
    assert _own_detections(later) and _mixed_detections_note(later) is None  # the first frame alone said no
    mixed = [_frame("0"), _frame("1", detections=own)]
    note = _mixed_detections_note(mixed)
    assert _own_detections(mixed) and note.startswith("note: 1 frame(s) hold boxes made by `xcalib detect` and 1")
    plain = [_frame("0"), _frame("1", detections=FrameDetections("synth detector"))]
    assert not _own_detections(plain) and _mixed_detections_note(plain) is None


def test_a_bag_whose_first_frame_has_no_mark_is_still_own_detections(tmp_path):
    from xcalib.cli.calibrate_cmd import _own_detections
    from xcalib.io.bags import write_bag
    from xcalib.io.sources import open_source

    own = FrameDetections(OWN_DETECTIONS)
    frames = [_frame("0000", 0), _frame("0001", 1, detections=own), _frame("0002", 2, detections=own)]
    frames = [dataclasses.replace(f, lidar_time_s=100.0 + i, camera_time_s=100.0 + i) for i, f in enumerate(frames)]
    back = open_source(write_bag(tmp_path / "own.mcap", frames))
    assert [f.detections for f in back] == [None, own, own]
    assert _own_detections(list(back))


# ------------------------------------------------------------------ validate SOURCE
def test_validate_reads_image_sizes_from_headers_and_decodes_a_sample(tmp_path):
    from xcalib.cli.source_check import check_source
    from xcalib.io.frames import FrameFolder
    from xcalib.io.sources import image_size_of

    root = _folder(tmp_path, 5)
    lazy = FrameFolder(root, decode_images=False)[3]
    assert lazy.image.shape == (0, 0, 3) and image_size_of(lazy) == (64, 48)
    assert image_size_of(FrameFolder(root)[3]) == (64, 48)
    r = check_source(root)
    assert r["images_decoded"] == 3 and r["image_sizes"] == {"64x48": 5} and r["with"]["image"] == 5
    assert check_source(root, decode=True)["images_decoded"] == 5
    # a broken image in a decoded (sampled) frame is found; in another frame, with --decode
    bad = sorted(root.glob("*/*.png"))
    for i in (1, 4):
        bad[i].write_bytes(bad[i].read_bytes()[:40])  # header kept, pixels cut
    r = check_source(root)
    assert r["unreadable"] == 1 and "frame 4" in r["errors"][0]
    assert check_source(root, decode=True)["unreadable"] == 2


def test_validate_reads_hdf5_image_sizes_from_headers(tmp_path):
    from xcalib.cli.source_check import check_source
    from xcalib.io.hdf5 import write_cache

    frames = [_frame(f"{i:04d}", i) for i in range(4)]
    path = write_cache(tmp_path / "c.h5", frames)
    r = check_source(path)
    assert r["kind"] == "hdf5-cache" and r["images_decoded"] == 3 and r["image_sizes"] == {"64x48": 4}


@pytest.mark.parametrize("argv,named", [
    (["SRC", "--model", "crlite"], "--model applies only to --hdf5 CACHE"),
    (["SRC", "--site", "x", "--device", "cuda"], "--site, --device apply only to --hdf5 CACHE"),
    (["SRC", "--runtime", "onnx", "--onnx-dir", "x"], "--runtime, --onnx-dir apply only"),
    (["SRC", "--weights", "w.pt"], "--weights applies only"),
    (["--hdf5", "SRC", "--decode"], "--decode applies only to checking a frame SOURCE"),
    (["--hdf5", "SRC", "--camera", "front"], "--camera applies only to checking a frame SOURCE"),
])
def test_validate_refuses_options_of_the_other_mode_by_name(tmp_path, capsys, argv, named):
    from xcalib.cli import main

    root = str(_folder(tmp_path, 1))
    assert main(["validate", *[root if a == "SRC" else a for a in argv]]) == 2
    assert named in " ".join(capsys.readouterr().err.split())


def test_validate_source_with_its_own_options_runs(tmp_path, capsys):
    from xcalib.cli import main

    root = str(_folder(tmp_path, 1))
    assert main(["validate", root, "--decode", "--camera", "front", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["images_decoded"] == 1


def test_bag_stamps_and_rectification_are_read_through_the_bag_package():
    """``meta`` keys the bag reader writes are read outside ``io.bags`` only through its accessors."""
    from xcalib.io.bags import recorded_stamp_ns, rectified_from

    f = _frame("0", meta={"lidar_stamp_ns": 1_700_000_000_000_000_000, "rectified_from": "equidistant"})
    assert recorded_stamp_ns(f, "lidar") == 1_700_000_000_000_000_000 and recorded_stamp_ns(f, "camera") is None
    assert rectified_from(f) == "equidistant" and rectified_from(_frame("1")) is None
    with pytest.raises(ValueError, match="sensor"):
        recorded_stamp_ns(f, "radar")


def test_validate_checks_a_sensors_only_bag_instead_of_failing(tmp_path):
    """``bag write --no-detections`` (docs/cli.md) makes a bag without detection topics: validate
    checks it as sensors only and says what is missing, as for any source without boxes."""
    from xcalib.cli.source_check import check_source
    from xcalib.io.bags import write_bag

    frames = [dataclasses.replace(_frame(f"{i:04d}", i), lidar_time_s=100.0 + i, camera_time_s=100.0 + i)
              for i in range(2)]
    r = check_source(write_bag(tmp_path / "raw.mcap", frames, detections=False))
    assert r["sensors_only"] and r["readable"] and r["read"] == 2 and r["boxes_2d"]["max"] == 0
    assert r["missing"][0].startswith("the bag has no detection topics")
    assert any(m.startswith("no 2D boxes in any frame: calibrate --detect") for m in r["missing"])
    assert not check_source(write_bag(tmp_path / "det.mcap", frames))["sensors_only"]


def test_validate_hdf5_without_labels_says_no_frame_was_evaluated(tmp_path, capsys):
    """A cache without a match matrix evaluates no frame: exit 1 with a line saying so (it printed scores
    of 0 over 0 frames, exit 0, which read like a bad model)."""
    from xcalib.cli import main
    from xcalib.io.hdf5 import write_cache

    path = write_cache(tmp_path / "c.h5", [_frame(f"{i:04d}", i) for i in range(2)])
    assert main(["validate", "--hdf5", str(path), "--json"]) == 1
    cap = capsys.readouterr()
    assert json.loads(cap.out)["results"]["fastmatch"]["n_frames"] == 0
    assert "no frame with labels (match_matrix) was evaluated" in " ".join(cap.err.split())
