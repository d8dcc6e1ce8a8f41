"""nuScenes/Lyft calibrated_sensor tables and mmdetection3d info pickles (nuScenes, Waymo)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from conftest import shared_path

from xcalib.errors import FormatError
from xcalib.formats._pickle import load_pickle_restricted
from xcalib.formats.kitti import project_box7
from xcalib.formats.mmdet3d import mmdet3d_frames, read_mmdet3d_infos
from xcalib.formats.nuscenes import nuscenes_calibration, read_nuscenes_sensors
from xcalib.geometry import iou_matrix, transform_points


class _Evil:
    def __reduce__(self):
        return (print, ("code ran",))


def test_restricted_unpickler_refuses_code(tmp_path):
    p = tmp_path / "evil.pkl"
    p.write_bytes(pickle.dumps({"data_list": [_Evil()]}))
    with pytest.raises(FormatError, match="refusing to load builtins.print"):
        load_pickle_restricted(p)
    ok = tmp_path / "ok.pkl"
    ok.write_bytes(pickle.dumps({"a": np.arange(3, dtype=np.float32), "b": [np.float64(1.5)]}))
    d = load_pickle_restricted(ok)
    np.testing.assert_array_equal(d["a"], [0, 1, 2]) and d["b"][0] == 1.5


@pytest.mark.shared_data
def test_lyft_calibrated_sensor_tables():
    tables = shared_path("lyft_format_only", "mmdet3d_tests", "v1.01-train")
    sensors = read_nuscenes_sensors(tables)
    cams = [c for c, s in sensors.items() if s.modality == "camera"]
    assert "CAM_FRONT" in cams and "LIDAR_TOP" in sensors
    for c in cams:
        assert sensors[c].intrinsics is not None
    res = nuscenes_calibration(tables, "CAM_FRONT")
    # Lyft's roof LiDAR is mounted turned by 180 deg: its +x points backwards
    T_lidar_ego = np.linalg.inv(sensors["LIDAR_TOP"].T_ego_sensor)
    assert T_lidar_ego[0, 0] < -0.99
    ahead = transform_points(res.extrinsics @ T_lidar_ego, np.array([[20.0, 0.0, 1.0]]))[0]  # ego frame
    assert ahead[2] > 15 and abs(ahead[0]) < 3
    back = nuscenes_calibration(tables, "CAM_BACK")
    assert transform_points(back.extrinsics @ T_lidar_ego, np.array([[-20.0, 0.0, 1.0]]))[0][2] > 15


@pytest.mark.shared_data
def test_nuscenes_sample_pickle_frames():
    pkl = shared_path("nuscenes", "mmdet3d_demo", "n015-2018-07-24-11-22-45+0800.pkl")
    samples = read_mmdet3d_infos(pkl)
    assert len(samples) == 1 and len(samples[0].cameras) == 6 and samples[0].boxes7.shape == (69, 7)
    frames = mmdet3d_frames(pkl, load_points=False)
    assert len(frames) == 6
    ious = []
    for f in frames:
        assert f.image.shape == (900, 1600, 3)
        i, j = np.nonzero(f.match_matrix)
        pb = project_box7(f.bboxes_3d, f.intrinsics.K, f.extrinsics, f.image_size)
        ious += np.diag(iou_matrix(pb[j], f.bboxes_2d[i])).tolist()
    print(f"nuScenes pkl: 3D->2D mean IoU {np.mean(ious):.3f} over {len(ious)} boxes")
    assert len(ious) == 84 and np.mean(ious) > 0.9
    f = mmdet3d_frames(pkl, camera="CAM_FRONT")[0]
    assert f.point_cloud.shape == (34688, 5)


@pytest.mark.shared_data
def test_waymo_kitti_format_infos():
    pkl = shared_path("waymo", "mmdet3d_tests", "kitti_format", "waymo_infos_train.pkl")
    f = mmdet3d_frames(pkl)[0]
    assert f.image.shape == (1280, 1920, 3) and f.point_cloud.shape == (800, 6)
    # vehicle-frame LiDAR -> optical FRONT camera: vehicle +x is the optical axis
    assert f.extrinsics[2, 0] > 0.99
    pb = project_box7(f.bboxes_3d, f.intrinsics.K, f.extrinsics, f.image_size)
    assert iou_matrix(pb, f.bboxes_2d)[0, 0] > 0.9  # bottom-centre boxes lifted to the centre
    # the Waymo infos' timestamp is the frame's timestamp_micros: read as Unix seconds (2019-02-13)
    assert f.lidar_time_s == pytest.approx(1550083467.346370, abs=1e-6)
    val = mmdet3d_frames(shared_path("waymo", "mmdet3d_tests", "kitti_format", "waymo_infos_val.pkl"),
                         load_points=False)
    assert len(val) == 1


@pytest.mark.shared_data
def test_calibrated_sensor_direction_on_nuscenes_sample():
    """cam2ego / lidar2ego of the sample are sensor -> ego poses: as calibrated_sensor records
    (w, x, y, z) they reproduce the sample's own lidar2cam through nuscenes_T_cam_lidar, up to the
    ego motion between the LiDAR and camera timestamps that mmdetection3d folds in (<= 40 ms)."""
    from xcalib.formats.nuscenes import T_to_calibrated_sensor, nuscenes_T_cam_lidar
    from xcalib.geometry import pose_error

    info = load_pickle_restricted(shared_path("nuscenes", "mmdet3d_demo", "n015-2018-07-24-11-22-45+0800.pkl"))
    info = info["data_list"][0]
    lidar_rec = T_to_calibrated_sensor(np.asarray(info["lidar_points"]["lidar2ego"], dtype=np.float64))
    for name, cam in info["images"].items():
        cam_rec = T_to_calibrated_sensor(np.asarray(cam["cam2ego"], dtype=np.float64))
        ref = np.asarray(cam["lidar2cam"], dtype=np.float64)
        drift = 10.0 * abs(info["timestamp"] - cam["timestamp"]) + 0.02  # metres at <= 10 m/s
        rot, trans = pose_error(nuscenes_T_cam_lidar(cam_rec, lidar_rec), ref)
        assert rot < 0.1 and trans < drift, (name, rot, trans, drift)
        rot_w, trans_w = pose_error(nuscenes_T_cam_lidar(lidar_rec, cam_rec), ref)  # the other direction
        assert rot_w > 1.0 or trans_w > drift, (name, rot_w, trans_w)
