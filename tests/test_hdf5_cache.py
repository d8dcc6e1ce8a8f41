"""HDF5 cache reader/writer: round trip and each rule of ../shared/specs/hdf5-cache-format.md."""

from __future__ import annotations

import gc
import json
import logging

import h5py
import numpy as np
import pytest

from xcalib.errors import FormatError
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.io.hdf5 import CacheReader, CacheWriter, CorruptImageError, cache_summary, load_dataset, write_cache
from xcalib.types import Frame


def _frame(rng, k: int, K: int = 3, M: int = 4, size=(24, 32)) -> Frame:
    img = rng.integers(0, 255, (*size, 3), dtype=np.uint8)
    b2 = np.sort(rng.uniform(0, 30, (K, 4)).astype(np.float32).reshape(K, 2, 2), axis=1).reshape(K, 4)
    lo = rng.uniform(-5, 5, (M, 3))
    b3 = np.hstack([lo, lo + rng.uniform(0.5, 3, (M, 3))]).astype(np.float32)
    mm = np.zeros((K, M), bool)
    for i in range(min(K, M)):
        mm[i, (i + k) % M] = True
    T = np.eye(4)
    T[:3, 3] = [0.1 * k, 0.2, 0.3]
    return Frame(image=img, point_cloud=rng.normal(size=(50 + k, 3)).astype(np.float32), bboxes_2d=b2,
                 bboxes_3d=b3, camera_name="cam", match_matrix=mm,
                 intrinsics=CameraIntrinsics(100.0, 101.0, 16.0, 12.0, [0.01, -0.02, 0.0, 0.0, 0.0], 32, 24),
                 extrinsics=T, meta={"box7": np.hstack([lo, np.ones((M, 3)), np.zeros((M, 1))])})


def _raw_cache(path, keys, *, K=2, M=3, stored=(2, 3), mm_shape=None, cams=("cam",), cam_names=None,
               calib=None, drop=None, blobs=None):
    """Hand-written cache (not via CacheWriter) to exercise the reader's spec rules."""
    import cv2

    rng = np.random.default_rng(1)
    with h5py.File(path, "w") as f:
        n = max([int(k) for k in keys if k.isdigit()] + [len(keys) - 1]) + 1
        for ci, cam in enumerate(cams):
            ds = f.create_dataset(f"images/{cam}/data", (n,), dtype=h5py.vlen_dtype(np.uint8))
            for i in range(n):
                img = np.full((8, 10, 3), (i * 10 + ci) % 256, np.uint8)
                ds[i] = np.frombuffer(cv2.imencode(".png", img)[1].tobytes(), np.uint8)
            if blobs:
                for i, b in blobs.items():
                    ds[i] = np.frombuffer(b, np.uint8)
        for k in keys:
            g = f.create_group(f"labels/cam/{k}")
            g["num_camera_detections"] = K
            g["num_lidar_detections"] = M
            g["camera_bbox_2d"] = np.sort(rng.uniform(0, 5, (stored[0], 2, 2)), axis=1).reshape(-1, 4).astype(np.float32)
            g["lidar_bbox_3d"] = rng.uniform(0, 5, (stored[1], 6)).astype(np.float32)
            g["match_matrix"] = np.eye(*(mm_shape or (K, M)), dtype=np.uint8)
            if cam_names is not None:
                g["camera_names"] = np.array([c.encode() for c in cam_names])
            f[f"point_clouds/lidar/{k}/xyz"] = rng.normal(size=(7, 3)).astype(np.float32)
            if drop:
                del f[drop.format(key=k)]
        for cname, (Km, T) in (calib or {}).items():
            f[f"calibration/{cname}/intrinsics"] = Km
            if T is not None:
                f[f"calibration/{cname}/extrinsics"] = T
    return path


# ----------------------------------------------------------------------------- round trip
def test_round_trip_lossless(tmp_path, rng):
    frames = [_frame(rng, k) for k in range(4)]
    frames[2] = _frame(rng, 2, K=0, M=2)   # K == 0 and M == 0 frames are kept, not dropped
    frames[3] = _frame(rng, 3, K=2, M=0)
    p = write_cache(tmp_path / "c.h5", frames, image_format="png")
    with CacheReader(p) as r:
        assert len(r) == 4
        back = list(r)
    assert len(back) == 4
    for a, b in zip(frames, back):
        assert np.array_equal(a.image, b.image)
        assert np.array_equal(a.point_cloud, b.point_cloud)
        assert np.array_equal(a.bboxes_2d, b.bboxes_2d) and b.bboxes_2d.shape == (a.num_2d, 4)
        assert np.array_equal(a.bboxes_3d, b.bboxes_3d) and b.bboxes_3d.shape == (a.num_3d, 6)
        assert b.match_matrix.dtype == bool and np.array_equal(a.match_matrix, b.match_matrix)
        assert np.allclose(a.extrinsics, b.extrinsics)
        assert b.intrinsics == a.intrinsics and np.allclose(b.intrinsics.dist_coeffs, a.intrinsics.dist_coeffs)
        assert np.array_equal(a.meta["box7"], b.meta["box7"])


def test_round_trip_jpeg_within_tolerance(tmp_path, rng):
    f = _frame(rng, 0, size=(64, 80))
    f.image = np.full((64, 80, 3), 120, np.uint8)
    f.image[16:48, 20:60] = (200, 40, 30)
    p = write_cache(tmp_path / "c.h5", [f], jpeg_quality=95)
    with CacheReader(p) as r:
        img = r[0].image
    assert img.shape == f.image.shape
    assert np.abs(img.astype(int) - f.image.astype(int)).mean() < 3.0


def test_box7_input_written_as_protocol_boxes(tmp_path, rng):
    f = _frame(rng, 0)
    f.bboxes_3d = np.array([[1, 2, 0.5, 4, 2, 1.5, np.pi / 2]], np.float32)
    f.match_matrix = np.ones((f.num_2d, 1), bool)
    f.meta = {}
    with CacheReader(write_cache(tmp_path / "c.h5", [f])) as r:
        fr = r[0]
    assert fr.bboxes_3d.shape == (1, 6)
    assert np.allclose(fr.bboxes_3d[0], [0, 0, -0.25, 2, 4, 1.25], atol=1e-5)  # yawed box's enclosing extents
    assert np.allclose(fr.meta["box7"][0], f.bboxes_3d[0], atol=1e-6)


# ------------------------------------------------------------------------------ spec rules
def test_truncation_to_counts(tmp_path):
    p = _raw_cache(tmp_path / "c.h5", ["00000", "00001"], K=2, M=3, stored=(5, 6), mm_shape=(5, 6))
    with CacheReader(p) as r:
        f = r[0]
    assert f.bboxes_2d.shape == (2, 4) and f.bboxes_3d.shape == (3, 6) and f.match_matrix.shape == (2, 3)


def test_count_larger_than_stored_rows(tmp_path):
    p = _raw_cache(tmp_path / "c.h5", ["00000"], K=4, M=3, stored=(2, 3), mm_shape=(4, 3))
    with CacheReader(p) as r, pytest.raises(FormatError) as e:
        r[0]
    assert "00000" in str(e.value) and "camera_bbox_2d" in str(e.value)


def test_match_matrix_shape_mismatch(tmp_path):
    p = _raw_cache(tmp_path / "c.h5", ["00000"], K=2, M=3, mm_shape=(3, 2))
    with CacheReader(p) as r, pytest.raises(FormatError) as e:
        r[0]
    assert "match_matrix" in str(e.value) and "00000" in str(e.value)


@pytest.mark.parametrize("drop,name", [("labels/cam/{key}/lidar_bbox_3d", "lidar_bbox_3d"),
                                       ("labels/cam/{key}/num_camera_detections", "num_camera_detections"),
                                       ("point_clouds/lidar/{key}/xyz", "xyz")])
def test_missing_dataset(tmp_path, drop, name):
    p = _raw_cache(tmp_path / "c.h5", ["00000"], drop=drop)
    with CacheReader(p) as r, pytest.raises(FormatError) as e:
        r["00000"]
    assert name in str(e.value) and "00000" in str(e.value)


def test_missing_root_group(tmp_path):
    p = tmp_path / "c.h5"
    with h5py.File(p, "w") as f:
        f.create_group("labels/cam")
        f.create_group("images/cam")
    with pytest.raises(FormatError, match="point_clouds"):
        CacheReader(p)


def test_key_order_lexicographic_warns_and_numeric_option(tmp_path, caplog):
    p = _raw_cache(tmp_path / "c.h5", ["1", "2", "10"])
    with caplog.at_level(logging.WARNING, logger="xcalib.io.hdf5"):
        r = CacheReader(p)
    assert r.frame_keys == ["1", "10", "2"]          # the spec's order
    assert sum("zero-padded" in m for m in caplog.messages) == 1
    # numeric keys index the blob array: frame "10" shows blob 10 (value 100)
    assert int(r["10"].image[0, 0, 0]) == 100 and int(r["2"].image[0, 0, 0]) == 20
    r.close()
    with CacheReader(p, key_order="numeric") as r2:
        assert r2.frame_keys == ["1", "2", "10"]
        assert [int(f.image[0, 0, 0]) for f in r2] == [10, 20, 100]


def test_non_numeric_keys_use_sorted_position(tmp_path):
    p = _raw_cache(tmp_path / "c.h5", ["b", "a", "c"])
    with CacheReader(p) as r:
        assert r.frame_keys == ["a", "b", "c"]
        assert [int(f.image[0, 0, 0]) for f in r] == [0, 10, 20]
        with pytest.raises(FormatError):
            CacheReader(p, key_order="numeric")


def test_multi_camera_and_camera_view_filters_match_matrix(tmp_path):
    p = _raw_cache(tmp_path / "c.h5", ["00000"], K=3, M=3, stored=(3, 3), cams=("south1", "south2"),
                   cam_names=["south2", "south1", "south2"])
    with CacheReader(p) as r:
        f = r[0]
        assert f.camera_name == "south2" and set(f.images) == {"south1", "south2"}
        assert f.camera_per_det == ["south2", "south1", "south2"]
        assert int(f.images["south1"][0, 0, 0]) == 0 and int(f.images["south2"][0, 0, 0]) == 1
        img, pts, b2, b3, mm = f.camera_view("south1")  # for_camera: the reference's 4 values
        assert b2.shape == (1, 4) and mm.shape == (1, 3) and np.array_equal(mm, f.match_matrix[[1]])
        assert b3.shape == (3, 6) and img is f.images["south1"]
        per_cam = list(r.camera_views("south2"))
        assert len(per_cam) == 1 and per_cam[0][4].shape == (2, 3)
        assert [len(v) for v in r.for_camera("south2")] == [4] and len(f.for_camera("south1")) == 4


def test_calibration_optional_and_canonicalised(tmp_path):
    p = _raw_cache(tmp_path / "none.h5", ["00000"])
    with CacheReader(p) as r:
        f = r[0]
    assert f.intrinsics is None and f.extrinsics is None
    Km = np.array([[500.0, 0, 5], [0, 500, 4], [0, 0, 1]])
    T = np.eye(4)
    T[0, 3] = 2.0
    p = _raw_cache(tmp_path / "cal.h5", ["00000"], cams=("s110_camera_south1",),
                   calib={"camera_south1": (Km, T)})
    with CacheReader(p) as r:
        f = r[0]
    assert np.allclose(f.intrinsics.K, Km) and (f.intrinsics.width, f.intrinsics.height) == (10, 8)
    assert np.allclose(f.extrinsics, T)


def test_per_frame_extrinsics(tmp_path, rng):
    frames = [_frame(rng, k) for k in range(3)]  # translations differ per frame
    p = write_cache(tmp_path / "c.h5", frames)
    with h5py.File(p) as f:
        assert isinstance(f["calibration/cam/extrinsics"], h5py.Group)
    with CacheReader(p) as r:
        assert [float(fr.extrinsics[0, 3]) for fr in r] == pytest.approx([0.0, 0.1, 0.2])


def test_corrupt_image_skipped_with_one_warning(tmp_path, caplog):
    p = _raw_cache(tmp_path / "c.h5", ["00000", "00001", "00002"], blobs={1: b"not a jpeg", 2: b"\xff\xd8junk"})
    r = CacheReader(p)
    assert len(r) == 3
    with caplog.at_level(logging.WARNING, logger="xcalib.io.hdf5"):
        got = [f.frame_key for f in r]
    assert got == ["00000"] and r.skipped_keys == ["00001", "00002"]
    warn = [m for m in caplog.messages if "did not decode" in m]
    assert len(warn) == 1 and "00001" in warn[0] and "00002" in warn[0]
    with pytest.raises(CorruptImageError, match="00001"):
        r[1]
    # labels + points still readable without decoding
    with CacheReader(p, decode_images=False) as r2:
        assert len(list(r2)) == 3 and r2[1].meta["image_bytes"]["cam"] == b"not a jpeg"
    r.close()


def test_label_sensor_choice_and_warning(tmp_path, caplog):
    p = _raw_cache(tmp_path / "c.h5", ["00000"])
    with h5py.File(p, "a") as f:
        f.copy(f["labels/cam"], "labels/zcam")
        f["labels/zcam/00000/num_camera_detections"][()] = 1
    with caplog.at_level(logging.WARNING, logger="xcalib.io.hdf5"):
        r = CacheReader(p)
    assert r.label_sensor == "cam" and any("zcam" in m for m in caplog.messages)
    r.close()
    with CacheReader(p, label_sensor="zcam") as r2:
        assert r2[0].num_2d == 1
    with pytest.raises(FormatError, match="nope"):
        CacheReader(p, label_sensor="nope")


def test_reader_closes_without_context_manager(tmp_path, rng):
    p = write_cache(tmp_path / "c.h5", [_frame(rng, 0)])
    r = CacheReader(p)
    fh = r._f
    assert fh.id.valid
    del r
    gc.collect()
    assert not fh.id.valid
    r = CacheReader(p)
    r.close()
    assert r.closed
    with pytest.raises(ValueError, match="closed"):
        r[0]


def test_fast_path_without_images(tmp_path, rng):
    p = write_cache(tmp_path / "c.h5", [_frame(rng, k) for k in range(2)])
    with CacheReader(p, read_images=False) as r:
        f = r[1]
    assert f.image.shape == (0, 0, 3) and f.point_cloud.shape == (51, 3) and f.match_matrix.shape == (3, 4)


# ----------------------------------------------------------------------------------- writer
def test_atomic_write(tmp_path, rng):
    final = tmp_path / "c.h5"
    final.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with CacheWriter(final) as w:
            w.add(_frame(rng, 0))
            raise RuntimeError("boom")
    assert final.read_bytes() == b"old"
    assert [q.name for q in tmp_path.iterdir()] == ["c.h5"]   # no temporary left behind
    w = CacheWriter(tmp_path / "d.h5")
    w.add(_frame(rng, 0))
    assert not (tmp_path / "d.h5").exists()                   # nothing under the final name yet
    w.close()
    assert (tmp_path / "d.h5").exists()


def test_atomic_write_gives_umask_permissions(tmp_path):
    import os
    import stat

    from xcalib.io._files import atomic_write

    old = os.umask(0o027)
    try:
        p = atomic_write(tmp_path / "w.bin", [b"ab", b"c"])
    finally:
        os.umask(old)
    assert p.read_bytes() == b"abc"
    assert stat.S_IMODE(p.stat().st_mode) == 0o640  # like open(), not mkstemp's 0o600


def test_writer_rejects_bad_match_matrix(tmp_path, rng):
    f = _frame(rng, 0)
    f.match_matrix = np.zeros((2, 2), bool)
    with pytest.raises(ValueError, match="match_matrix"):
        write_cache(tmp_path / "c.h5", [f])
    assert not (tmp_path / "c.h5").exists()


def test_writer_multi_camera(tmp_path, rng):
    f = _frame(rng, 0, K=2, M=2)
    f.images = {"left": f.image, "right": f.image[::-1].copy()}
    f.camera_name = "left"
    f.camera_per_det = ["right", "left"]
    p = write_cache(tmp_path / "c.h5", [f], image_format="png")
    with CacheReader(p) as r:
        g = r[0]
    assert g.camera_per_det == ["right", "left"] and g.camera_name == "right"
    assert np.array_equal(g.images["left"], f.images["left"]) and np.array_equal(g.images["right"], f.images["right"])


def test_summary_and_load_dataset(tmp_path, rng, monkeypatch):
    (tmp_path / "site").mkdir()
    write_cache(tmp_path / "site" / "test.h5", [_frame(rng, k) for k in range(3)])
    s = cache_summary(tmp_path / "site" / "test.h5")
    assert s["frames"] == 3 and s["detections_2d"] == 9 and s["matches"] == 9
    assert s["calibration"]["cam"]["intrinsics"] and s["calibration"]["cam"]["extrinsics"] == "per-frame"
    with load_dataset(tmp_path / "site", split="test") as r:
        assert len(r) == 3
    with pytest.raises(FileNotFoundError, match="never downloads"):
        load_dataset("a9_dataset_r02_s01")
    with pytest.raises(FileNotFoundError, match="val"):
        load_dataset(tmp_path / "site", split="val")
    with pytest.raises(ValueError, match="never downloads"):
        load_dataset("a9_dataset_r02_s01", repo_id="UArizona/xcalib-a9")
    with load_dataset("ignored", local=tmp_path / "site") as r:
        assert len(r) == 3
    # the reference's checkout-local default: ./datasets/<site>/hdf5_cache/*_<split>.h5
    d = tmp_path / "datasets" / "a9_dataset_r02_s01" / "hdf5_cache"
    d.mkdir(parents=True)
    (tmp_path / "site" / "test.h5").rename(d / "a9_r02_s01_test.h5")
    monkeypatch.chdir(tmp_path)
    with load_dataset("a9_dataset_r02_s01") as r:
        assert len(r) == 3


def test_read_frames_dispatches_hdf5(tmp_path, rng):
    from xcalib.io import read_frames

    p = write_cache(tmp_path / "c.h5", [_frame(rng, 0)])
    frames = read_frames(p)
    assert len(frames) == 1 and frames[0].num_2d == 3
    frames.close()


def test_cli_cache_build_from_frame_folder(tmp_path, rng, capsys):
    from xcalib.cli import main
    from xcalib.io.frames import write_frame_folder

    frames = [_frame(rng, k) for k in range(3)]
    for k, f in enumerate(frames):
        f.frame_key = f"{k:04d}"
    write_frame_folder(tmp_path / "ff", frames, camera="cam", intrinsics=frames[0].intrinsics)
    out = tmp_path / "c.h5"
    assert main(["cache", "build", str(tmp_path / "ff"), "--out", str(out), "--lossless", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["frames"] == 3 and summary["cameras"] == ["cam"]
    with CacheReader(out) as r:
        for a, b in zip(frames, r):
            assert np.array_equal(a.image, b.image) and np.array_equal(a.bboxes_2d, b.bboxes_2d)
            assert np.allclose(a.point_cloud, b.point_cloud)


def test_read_extras_switch(tmp_path, rng):
    p = write_cache(tmp_path / "c.h5", [_frame(rng, 0)])
    with CacheReader(p, read_extras=False, read_images=False) as r:
        f = r[0]
    assert "box7" not in f.meta and f.bboxes_3d.shape == (4, 6)
    with CacheReader(p, read_images=False) as r:
        assert r[0].meta["box7"].shape == (4, 7)
