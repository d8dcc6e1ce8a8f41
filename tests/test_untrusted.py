"""Issue 16: untrusted files (no code execution, paths stay inside, special files refused, validated
loads) and safe writers (atomic, no silent overwrite)."""

from __future__ import annotations

import io
import json
import os
import pickle
import stat
from pathlib import Path

import numpy as np
import pytest

from xcalib.calib.result import CalibrationResult
from xcalib.errors import FormatError
from xcalib.geometry import CameraIntrinsics, euler_to_matrix
from xcalib.io import read_detections, read_point_cloud, write_frame_folder, write_pcd
from xcalib.io._files import atomic_dir, atomic_write, inside, safe_name, sweep_stale
from xcalib.types import Frame


def _frame(k: int = 0, key: str = "0000") -> Frame:
    rng = np.random.default_rng(k)
    b2 = np.array([[10, 10, 40, 30], [50, 20, 70, 60]], np.float32)
    b3 = np.array([[1, 1, 0, 2, 2, 1], [4, -1, 0, 5, 0, 2]], np.float32)
    return Frame(image=rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),
                 point_cloud=rng.normal(size=(30, 3)).astype(np.float32), bboxes_2d=b2, bboxes_3d=b3,
                 camera_name="cam", frame_key=key, match_matrix=np.eye(2, dtype=bool), extrinsics=np.eye(4))


def _result(**kw) -> CalibrationResult:
    base = dict(success=True, intrinsics=CameraIntrinsics(500, 500, 32, 24, None, 64, 48),
                rotation=euler_to_matrix([-1.5, 0.02, -1.6]), translation=[0.1, -0.3, -0.2], camera_name="cam")
    base.update(kw)
    return CalibrationResult(**base)


# ------------------------------------------------------------------ code execution
class _Boom:
    def __reduce__(self):
        return (os.system, ("touch PWNED_BY_PICKLE",))


def test_malicious_resume_checkpoint_does_not_run_code(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    last = tmp_path / "last.pt"
    last.write_bytes(pickle.dumps({"state_dict": {}, "optimizer": _Boom(), "epoch": 0, "best_mrr": 0.0}))
    from xcalib.engine.checkpoint import load_resume_state, read_checkpoint

    with pytest.raises(FormatError, match="last.pt"):
        load_resume_state(last)
    with pytest.raises(FormatError, match="weights_only"):
        read_checkpoint(last)
    assert not (tmp_path / "PWNED_BY_PICKLE").exists()


def test_train_resume_refuses_crafted_last_pt(tmp_path, monkeypatch):
    import torch  # noqa: F401 - trainer needs it

    from xcalib.engine.trainer import train

    monkeypatch.chdir(tmp_path)
    out = tmp_path / "run"
    out.mkdir()
    buf = io.BytesIO()
    import torch

    torch.save({"x": _Boom()}, buf)
    (out / "last.pt").write_bytes(buf.getvalue())
    from xcalib.data.synth import iter_frames, sample_site

    frames = list(iter_frames(sample_site(0, "roadside"), 2, seed=1, render_images=False))
    with pytest.raises(FormatError, match="last.pt"):
        train("fastmatch", frames, epochs=1, output_dir=out, resume=True, progress=False, device="cpu")
    assert not (tmp_path / "PWNED_BY_PICKLE").exists()


def test_weights_checksum_and_nan_refused(tmp_path):
    import torch

    from xcalib.engine.checkpoint import WeightsMismatchError, read_checkpoint
    from xcalib.engine.matcher import Matcher

    paths = Matcher("fastmatch", device="cpu", allow_random=True).save_pretrained(tmp_path / "w")
    w = paths["weights"]
    assert w.with_suffix(".sha256").is_file()
    read_checkpoint(w)  # intact: loads
    raw = bytearray(w.read_bytes())
    raw[len(raw) // 2] ^= 0x01
    w.write_bytes(bytes(raw))
    with pytest.raises(WeightsMismatchError, match="sha256"):
        read_checkpoint(w)
    sd = {"a": torch.tensor([1.0, float("nan")])}
    torch.save(sd, tmp_path / "nan.pt")
    with pytest.raises(WeightsMismatchError, match="non-finite"):
        read_checkpoint(tmp_path / "nan.pt")


def test_save_pretrained_no_silent_overwrite_and_keeps_other_files(tmp_path):
    from xcalib.engine.matcher import Matcher

    d = tmp_path / "site"
    d.mkdir()
    (d / "other.txt").write_text("keep me")
    Matcher("fastmatch", device="cpu", allow_random=True).save_pretrained(d)
    with pytest.raises(FileExistsError):
        Matcher("fastmatch", device="cpu", allow_random=True).save_pretrained(d)
    Matcher("fastmatch", device="cpu", allow_random=True).save_pretrained(d, overwrite=True)
    assert (d / "other.txt").read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["site"]  # no temp folder left
    Matcher.from_pretrained("fastmatch", weights=d, device="cpu")


# ------------------------------------------------------------------ paths and special files
def test_detections_paths_stay_inside_their_folder(tmp_path):
    root = tmp_path / "frames"
    write_frame_folder(root, [_frame()])
    det = root / "frame_0000" / "detections.json"
    (tmp_path / "outside").mkdir()
    write_pcd(tmp_path / "outside" / "secret.pcd", np.zeros((3, 3), np.float32))
    for bad in ("../../outside/secret.pcd", str(tmp_path / "outside" / "secret.pcd")):
        d = json.loads(det.read_text())
        d["point_cloud"] = bad
        det.write_text(json.dumps(d))
        with pytest.raises(FormatError, match="outside") as e:
            read_detections(det)
        assert e.value.field == "point_cloud"
    fr = read_detections(det, allow_outside=True)
    assert fr.point_cloud.shape == (3, 3)


def test_manifest_paths_stay_inside(tmp_path):
    from xcalib.io import FrameFolder

    root = tmp_path / "frames"
    write_frame_folder(root, [_frame()])
    m = json.loads((root / "manifest.json").read_text())
    m["frames"][0]["detections"] = "../elsewhere/detections.json"
    (root / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(FormatError, match="outside"):
        FrameFolder(root)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_fifo_and_device_symlink_refused_without_blocking(tmp_path):
    fifo = tmp_path / "cloud.pcd"
    os.mkfifo(fifo)
    with pytest.raises(FormatError, match="FIFO"):
        read_point_cloud(fifo)
    link = tmp_path / "zero.bin"
    link.symlink_to("/dev/zero")
    with pytest.raises(FormatError, match="device"):
        read_point_cloud(link)
    from xcalib.io import read_image

    with pytest.raises(FormatError, match="FIFO"):
        read_image(fifo)


def test_report_overlay_names_are_sanitised(tmp_path):
    assert safe_name("../../x") == "_.._x" and "/" not in safe_name("a/b\\c")
    with pytest.raises(FormatError):
        inside(tmp_path, "../x", source="f.json", field="image")


# ------------------------------------------------------------------ validate on load
def test_calibration_load_validates(tmp_path):
    good = _result().save(tmp_path / "c.json")
    d = json.loads(good.read_text())
    cases = {"rotation": (np.eye(3) * 2).tolist(), "translation": [1e30, 0, 0], "success": "yes"}
    for key, value in cases.items():
        bad = dict(d, **{key: value})
        p = tmp_path / f"bad_{key}.json"
        p.write_text(json.dumps(bad))
        with pytest.raises(FormatError, match=f"bad_{key}") as e:
            CalibrationResult.load(p)
        assert e.value.field == key
    p = tmp_path / "nan.json"
    p.write_text(good.read_text().replace(str(d["rotation"][0][0]), "NaN", 1))
    with pytest.raises(FormatError, match="rotation"):
        CalibrationResult.load(p)
    # npz whose arrays disagree with its JSON
    npz = _result().save(tmp_path / "c.npz")
    with np.load(npz) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["rotation"] = euler_to_matrix([0.1, 0.2, 0.3])
    np.savez(tmp_path / "mixed.npz", **arrays)
    with pytest.raises(FormatError, match="disagrees"):
        CalibrationResult.load(tmp_path / "mixed.npz")


def test_calibration_save_ignores_planted_symlink(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("untouched")
    (tmp_path / "c.json.tmp").symlink_to(victim)
    _result().save(tmp_path / "c.json")
    assert victim.read_text() == "untouched"
    assert CalibrationResult.load(tmp_path / "c.json").success


def test_pcd_silent_garbage_refused(tmp_path):
    p = tmp_path / "a.pcd"
    write_pcd(p, np.arange(12, dtype=np.float32).reshape(4, 3))
    raw = p.read_bytes()
    for old, new, field in ((b"FIELDS x y z", b"FIELDS x y x", "FIELDS"), (b"COUNT 1 1 1", b"COUNT 2 1 1", "COUNT"),
                            (b"WIDTH 4\n", b"", "WIDTH")):
        (tmp_path / "b.pcd").write_bytes(raw.replace(old, new))
        with pytest.raises(FormatError) as e:
            read_point_cloud(tmp_path / "b.pcd")
        assert e.value.field in (field, "DATA", "POINTS"), e.value
    (tmp_path / "c.pcd").write_bytes(raw + b"\x00\x00\x00\x00")
    with pytest.raises(FormatError, match="trailing"):
        read_point_cloud(tmp_path / "c.pcd")
    (tmp_path / "d.pcd").write_bytes(raw.replace(b"COUNT 1 1 1", b"COUNT 1 1 1000000000"))
    with pytest.raises(FormatError, match="COUNT"):
        read_point_cloud(tmp_path / "d.pcd")


def test_six_column_bin_is_detected(tmp_path):
    rng = np.random.default_rng(0)
    pts = np.hstack([rng.uniform(-50, 50, (100, 3)), rng.uniform(0, 1, (100, 2)),
                     np.full((100, 1), 1.55e15)]).astype(np.float32)
    p = tmp_path / "0000000.bin"
    p.write_bytes(pts.tobytes())
    with pytest.raises(FormatError, match="columns=6") as e:
        read_point_cloud(p)
    assert e.value.field == "columns"
    assert read_point_cloud(p, columns=6).points.shape == (100, 6)


def test_shared_waymo_export_bin_is_not_silent_garbage():
    from conftest import shared_path

    p = shared_path("waymo/mmdet3d_tests/kitti_format/training/velodyne/0000000.bin")
    with pytest.raises(FormatError, match="columns=6"):
        read_point_cloud(p)
    pts = read_point_cloud(p, columns=6).points
    assert np.abs(pts[:, :3]).max() < 200


def test_detections_nan_inverted_boxes_and_non_rigid_extrinsics(tmp_path):
    root = tmp_path / "frames"
    write_frame_folder(root, [_frame()])
    det = root / "frame_0000" / "detections.json"
    orig = json.loads(det.read_text())
    s = 2.0 * np.eye(4)
    s[3, 3] = 1
    for key, value in (("bboxes_2d", [[40, 10, 10, 30], [50, 20, 70, 60]]), ("bboxes_3d", [[1, 1, 0, float("nan"), 2, 1]]),
                       ("extrinsics", s.tolist())):
        det.write_text(json.dumps(dict(orig, **{key: value})))
        with pytest.raises(FormatError) as e:
            read_detections(det)
        assert e.value.field == key


def test_hdf5_non_integral_count_refused(tmp_path):
    import h5py

    from xcalib.io.hdf5 import CacheReader, write_cache

    p = write_cache(tmp_path / "c.h5", [_frame()], image_format="png")
    with h5py.File(p, "a") as f:
        g = f["labels/cam/0000"]
        del g["num_camera_detections"]
        g["num_camera_detections"] = 1.7
    with CacheReader(p) as r, pytest.raises(FormatError, match="num_camera_detections"):
        r[0]


def test_kitti_label_row_with_extra_number_refused(tmp_path):
    from xcalib.formats.kitti import parse_kitti_labels

    good = "Car 0.00 0 -1.58 587.01 173.33 614.12 200.12 1.65 1.67 3.64 -0.65 1.71 46.70 -1.59"
    shifted = "Car 0.00 0 5 -1.58 587.01 173.33 614.12 200.12 1.65 1.67 3.64 -0.65 1.71 46.70 -1.59"
    assert len(parse_kitti_labels(good)) == 1
    with pytest.raises(FormatError):
        parse_kitti_labels(good + "\n" + shifted)


def test_image_pixel_bomb_refused_from_header():
    import zlib

    from xcalib.io import decode_image

    def chunk(t, d):
        return len(d).to_bytes(4, "big") + t + d + zlib.crc32(t + d).to_bytes(4, "big")

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", (20000).to_bytes(4, "big") * 2 + b"\x08\x02\x00\x00\x00")
    with pytest.raises(FormatError, match="pixels"):
        decode_image(png, source="bomb.png")


# ------------------------------------------------------------------ writers
def test_atomic_dir_swaps_whole_and_refuses_overwrite(tmp_path):
    d = tmp_path / "out"
    with atomic_dir(d) as t:
        (t / "a.txt").write_text("1")
        (t / "b.txt").write_text("1")
    with pytest.raises(FileExistsError):
        with atomic_dir(d) as t:
            pass
    with pytest.raises(RuntimeError):
        with atomic_dir(d, overwrite=True) as t:
            (t / "a.txt").write_text("2")
            raise RuntimeError("fail mid-write")
    assert (d / "a.txt").read_text() == "1" and (d / "b.txt").read_text() == "1"
    with atomic_dir(d, overwrite=True) as t:
        (t / "a.txt").write_text("2")
    assert sorted(p.name for p in d.iterdir()) == ["a.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_atomic_write_permissions_and_stale_temp_sweep(tmp_path):
    p = atomic_write(tmp_path / "x.json", [b"{}"])
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~mask
    stale = tmp_path / ".x.json.999999999.abcd1234.tmp"  # a writer that no longer runs
    stale.write_bytes(b"half")
    assert sweep_stale(tmp_path, "x.json") == 1 and not stale.exists()
    with pytest.raises(FileExistsError):
        atomic_write(tmp_path / "x.json", [b"{}"], overwrite=False)


def test_cli_refuses_overwrite_and_prints_format_error(tmp_path, capsys):
    from xcalib.cli import main

    src = _result().save(tmp_path / "c.json")
    out = tmp_path / "calib.txt"
    assert main(["convert", str(src), "--to", "kitti", "--out", str(out)]) == 0
    assert main(["convert", str(src), "--to", "kitti", "--out", str(out)]) == 1
    assert "already exists" in capsys.readouterr().err
    assert main(["convert", str(src), "--to", "kitti", "--out", str(out), "--force"]) == 0
    bad = tmp_path / "bad.json"
    bad.write_text("[" * 100000)
    assert main(["convert", str(bad), "--to", "kitti", "--out", str(tmp_path / "k.txt")]) == 1
    err = capsys.readouterr().err
    assert "bad.json" in err and "Traceback" not in err
