"""PandaSet and SUSTechPOINTS loaders (real samples, skipped when absent) and synthetic 2D boxes made from their 3D boxes."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest

from conftest import shared_path
from xcalib.data.boxes2d import Synth2DConfig, box_corners_lidar, synthetic_2d_boxes
from xcalib.errors import FormatError
from xcalib.formats.pandaset import PandaSetFrames, is_pandaset_root
from xcalib.geometry import iou_matrix, project_points
from xcalib.io.sources import open_source

EXACT = Synth2DConfig(noise_px=0.0, miss_rate=0.0, false_rate=0.0)


@pytest.fixture(scope="module")
def seq():
    return PandaSetFrames(shared_path("pandaset_002"), read_images=False)


def test_pandaset_frames(seq):
    assert len(seq) == 30 and is_pandaset_root(seq.root)
    assert open_source(seq.root).source_name == "pandaset"
    f = seq[0]
    assert f.bboxes_3d.shape == (91, 7) and f.num_2d == 0 and f.point_cloud.shape[1] == 4
    assert f.camera_time_s - f.lidar_time_s == pytest.approx(-0.04985, abs=1e-3)
    assert f.intrinsics.fx == pytest.approx(1970.0131) and f.extrinsics.shape == (4, 4)
    # track ids are stable across frames: the same uuid -> the same int
    g = seq[1]
    common = set(f.meta["track_uuids"]) & set(g.meta["track_uuids"])
    assert len(common) > 50
    u = sorted(common)[0]
    assert f.track_ids_3d[f.meta["track_uuids"].index(u)] == g.track_ids_3d[g.meta["track_uuids"].index(u)]
    speed = np.linalg.norm(f.velocities_3d, axis=1)
    assert np.all(speed[f.meta["stationary"]] == 0) and 5 < speed.max() < 25
    # the camera sees the LiDAR points of its frame: most points in front project inside the image
    pts = f.point_cloud
    uv, d = project_points(pts[:, :3], f.intrinsics, f.extrinsics[:3, :3], f.extrinsics[:3, 3])
    inside = (d > 1) & (uv[:, 0] >= 0) & (uv[:, 0] < 1920) & (uv[:, 1] >= 0) & (uv[:, 1] < 1080)
    assert inside.sum() > 10000


def test_synthetic_2d_boxes_at_camera_time(seq):
    f = seq[0]
    a = synthetic_2d_boxes(f, 0, EXACT)
    assert a.num_2d >= 8 and a.match_matrix.shape == (a.num_2d, f.num_3d) and a.match_matrix.sum() == a.num_2d
    assert "boxes_2d_synthetic" in a.meta
    # a fully visible moving box is the projection of its cuboid moved by v * (t_cam - t_lidar)
    moved = synthetic_2d_boxes(f, 0, EXACT)
    still = synthetic_2d_boxes(f, 0, dataclasses.replace(EXACT, at_camera_time=False))
    speed = np.linalg.norm(f.velocities_3d, axis=1)
    ids_m, ids_s = list(moved.meta["ids_2d"]), list(still.meta["ids_2d"])
    fast = [j for j in ids_m if j >= 0 and j in ids_s and speed[j] > 5]
    assert fast
    j = fast[0]
    dt = f.camera_time_s - f.lidar_time_s
    c = box_corners_lidar(f)[j] + f.velocities_3d[j] * dt
    uv, _ = project_points(c, f.intrinsics, f.extrinsics[:3, :3], f.extrinsics[:3, 3])
    proj = np.clip(np.r_[uv.min(0), uv.max(0)], 0, [1920, 1080, 1920, 1080])
    box_m = moved.bboxes_2d[ids_m.index(j)]
    assert iou_matrix(box_m[None], proj[None])[0, 0] > 0.9
    assert np.abs(box_m - still.bboxes_2d[ids_s.index(j)]).max() > 2.0
    # seeded noise, misses and false boxes
    n1, n2 = synthetic_2d_boxes(f, 3), synthetic_2d_boxes(f, 3)
    assert np.array_equal(n1.bboxes_2d, n2.bboxes_2d)
    assert not np.array_equal(n1.bboxes_2d, synthetic_2d_boxes(f, 4).bboxes_2d)


def test_bad_cuboid_file_names_field(tmp_path):
    src = shared_path("pandaset_002")
    root = tmp_path / "ps"
    root.mkdir()
    shutil.copy(src / "calibration.json", root / "calibration.json")
    (root / "lidar").mkdir()
    (root / "cuboids").mkdir()
    cub = json.loads((src / "cuboids" / "00.json").read_text())[:2]
    cub[1]["size"] = [4.0, -1.0, 1.5]
    (root / "cuboids" / "00.json").write_text(json.dumps(cub))
    seq = PandaSetFrames(root, read_images=False, read_points=False)
    assert len(seq) == 1
    with pytest.raises(FormatError) as e:
        seq[0]
    assert e.value.field == "[1].size" and "00.json" in str(e.value)


def test_sustech_frames_and_synthetic_boxes():
    from xcalib.formats.sustech import SustechFrames

    root = shared_path("sustech_example")
    seq = open_source(root)
    assert isinstance(seq, SustechFrames) and seq.frame_keys == ["000965", "000970", "000975"]
    f = SustechFrames(root, read_images=False)[0]
    assert f.point_cloud.shape == (66781, 4) and 0 <= f.point_cloud[:, 3].max() <= 255
    assert f.bboxes_3d.shape[1] == 7 and f.track_ids_3d.shape == (f.num_3d,) and f.lidar_time_s > 1000
    g = synthetic_2d_boxes(f, 0, EXACT)
    assert g.num_2d >= 5 and g.match_matrix.sum() == g.num_2d
