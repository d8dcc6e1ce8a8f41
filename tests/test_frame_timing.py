"""Frame timing / track fields (lidar_time_s, camera_time_s, track_ids_3d, velocities_3d): synthetic
frames carry them; frame folders and HDF5 caches write and read them back; bad values are refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import shared_path
from xcalib.data.synth import generate_frames, sample_site
from xcalib.errors import FormatError
from xcalib.io.frames import FrameFolder, write_frame_folder
from xcalib.io.hdf5 import CacheReader, write_cache

SMALL = dict(width=480, height=300, focal_px=(250.0, 625.0), camera_time_offset_s=-0.05)


@pytest.fixture(scope="module")
def frames():
    return generate_frames(sample_site(0, **SMALL), 2, seed=0, render_images=False, lidar=False)


def _same_timing(a, b):
    assert b.lidar_time_s == pytest.approx(a.lidar_time_s) and b.camera_time_s == pytest.approx(a.camera_time_s)
    assert np.array_equal(a.track_ids_3d, b.track_ids_3d) and b.track_ids_3d.dtype == np.int64
    assert np.allclose(a.velocities_3d, b.velocities_3d)


def test_synth_frames_carry_timing(frames):
    f = frames[1]
    assert f.lidar_time_s == pytest.approx(0.1) and f.camera_time_s == pytest.approx(0.05)
    assert f.track_ids_3d.shape == (f.num_3d,) and f.velocities_3d.shape == (f.num_3d, 3)
    assert np.all(f.velocities_3d[f.track_ids_3d < 0] == 0)
    assert np.linalg.norm(f.velocities_3d, axis=1).max() > 1.0


def test_roundtrip_frame_folder_and_hdf5(frames, tmp_path):
    write_frame_folder(tmp_path / "ff", frames)
    for a, b in zip(frames, FrameFolder(tmp_path / "ff")):
        _same_timing(a, b)
    write_cache(tmp_path / "c.h5", frames)
    with CacheReader(tmp_path / "c.h5", read_images=False) as r:
        for a, b in zip(frames, r):
            _same_timing(a, b)


@pytest.mark.parametrize("key,value,problem", [
    ("lidar_time_s", "noon", "one number"),
    ("camera_time_s", float("nan"), "finite"),
    ("track_ids_3d", [1, 2], "track ids"),
    ("velocities_3d", [[0.0, 1.0]], "velocities"),
])
def test_bad_timing_in_detections_json(frames, tmp_path, key, value, problem):
    write_frame_folder(tmp_path / "ff", frames[:1])
    det_path = tmp_path / "ff" / "frame_0000" / "detections.json"
    det = json.loads(det_path.read_text())
    det[key] = value
    det_path.write_text(json.dumps(det))
    with pytest.raises(FormatError) as e:
        FrameFolder(tmp_path / "ff")[0]
    assert e.value.field == key and problem in e.value.problem and "detections.json" in str(e.value)


def test_real_readers_fill_timing():
    from xcalib.io.sources import open_source

    pkl = next(shared_path("nuscenes", "mmdet3d_demo").glob("*.pkl"))
    f = open_source(pkl, camera="CAM_FRONT")[0]
    assert f.camera_time_s - f.lidar_time_s == pytest.approx(-0.0355, abs=1e-3)  # info timestamps
    assert f.velocities_3d.shape == (f.num_3d, 3) and np.all(np.isfinite(f.velocities_3d))
    w = open_source(shared_path("waymo", "mmdet3d_tests", "waymo_format", "validation", "val.tfrecord"))[0]
    assert w.lidar_time_s > 1.5e9 and len(set(w.track_ids_3d.tolist())) == w.num_3d


def test_bag_frames_carry_header_stamps(frames, tmp_path):
    from xcalib.io.bags import write_bag
    from xcalib.io.frames import read_frames

    path = write_bag(tmp_path / "s.mcap", frames, start_s=1000.0, camera_delay_s=0.02)
    back = read_frames(path, camera="camera")
    # the frames' own (relative) times come back exactly; the header stamps are start_s + time
    assert back[1].lidar_time_s == frames[1].lidar_time_s and back[1].camera_time_s == frames[1].camera_time_s
    assert back[1].meta["lidar_stamp_ns"] == round((1000.0 + frames[1].lidar_time_s) * 1e9)
