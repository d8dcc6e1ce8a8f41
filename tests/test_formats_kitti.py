"""KITTI calib / label / folder readers: directions, P2 offset, round trips and the real samples."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_path

from xcalib.errors import FormatError
from xcalib.formats.kitti import (
    KittiCalibration,
    box7_to_protocol,
    camera_boxes_to_lidar,
    format_kitti_calibration,
    kitti_frames,
    lidar_boxes_to_camera,
    load_kitti_calibration,
    parse_kitti_calibration,
    parse_kitti_labels,
    project_box7,
    read_velodyne_bin,
)
from xcalib.geometry import euler_to_matrix, iou_matrix, make_transform, transform_points

# KITTI 000001 calibration (recording day 2011_09_26), as in the devkit files.
CALIB_TEXT = """P0: 7.215377e+02 0 6.095593e+02 0 0 7.215377e+02 1.728540e+02 0 0 0 1 0
P1: 7.215377e+02 0 6.095593e+02 -3.875744e+02 0 7.215377e+02 1.728540e+02 0 0 0 1 0
P2: 7.215377e+02 0 6.095593e+02 4.485728e+01 0 7.215377e+02 1.728540e+02 2.163791e-01 0 0 1 2.745884e-03
P3: 7.215377e+02 0 6.095593e+02 -3.395242e+02 0 7.215377e+02 1.728540e+02 2.199936e+00 0 0 1 2.729905e-03
R0_rect: 9.999239e-01 9.837760e-03 -7.445048e-03 -9.869795e-03 9.999421e-01 -4.278459e-03 7.402527e-03 4.351614e-03 9.999631e-01
Tr_velo_to_cam: 7.533745e-03 -9.999714e-01 -6.166020e-04 -4.069766e-03 1.480249e-02 7.280733e-04 -9.998902e-01 -7.631618e-02 9.998621e-01 7.523790e-03 1.480755e-02 -2.717806e-01
Tr_imu_to_velo: 9.999976e-01 7.553071e-04 -2.035826e-03 -8.086759e-01 -7.854027e-04 9.998898e-01 -1.482298e-02 3.195559e-01 2.024406e-03 1.482454e-02 9.998881e-01 -7.997231e-01
"""

LABEL_TEXT = """Car 0.00 0 1.85 387.63 181.54 423.81 203.12 1.67 1.87 3.69 -16.53 2.39 58.49 1.57
DontCare -1 -1 -10 503.89 169.71 590.61 190.13 -1 -1 -1 -1000 -1000 -1000 -10
"""


@pytest.fixture
def calib() -> KittiCalibration:
    return parse_kitti_calibration(CALIB_TEXT, "mem.txt")


def test_p2_offset_is_in_camera2_extrinsics(calib):
    P2 = calib.P[2]
    t_off = calib.t_offset(2)
    np.testing.assert_allclose(calib.K(2) @ t_off, P2[:, 3], atol=1e-12)
    assert t_off[0] == pytest.approx(44.85728 / 721.5377 - 609.5593 * 2.745884e-03 / 721.5377, abs=1e-9)
    # K @ [R|t] of our extrinsics equals the devkit chain P2 @ R0_rect @ Tr_velo_to_cam exactly
    T = calib.T_cam_lidar(2)
    np.testing.assert_allclose(calib.K(2) @ T[:3], calib.projection(2), atol=1e-9)
    R0 = np.eye(4)
    R0[:3, :3] = calib.R0_rect
    np.testing.assert_allclose(calib.projection(2), P2 @ R0 @ calib.Tr_velo_to_cam, atol=1e-9)
    # camera 0 has no offset; camera 2 differs from it by the offset only
    np.testing.assert_allclose(calib.t_offset(0), 0.0, atol=1e-15)
    np.testing.assert_allclose(T[:3, 3] - calib.T_cam_lidar(0)[:3, 3], t_off, atol=1e-12)


def test_direction_lidar_to_camera(calib):
    """A point 10 m ahead of the LiDAR (+x) lands ~10 m in front of the camera (+z)."""
    p = transform_points(calib.T_cam_lidar(2), np.array([[10.0, 0.0, 0.0]]))[0]
    assert p[2] == pytest.approx(10.0 - 0.27, abs=0.1)
    assert abs(p[0]) < 0.2 and abs(p[1]) < 0.3


def test_label_boxes_roundtrip_and_yaw(calib):
    lab = parse_kitti_labels(LABEL_TEXT, "mem_label.txt")
    assert len(lab) == 2 and lab.care.tolist() == [True, False]
    car = lab.subset(lab.care)
    b7 = car.boxes_lidar(calib)
    # KITTI ry = pi/2 faces camera -x = LiDAR +y... yaw = -ry - pi/2 for the nominal rig
    assert b7[0, 6] == pytest.approx(-1.57 - np.pi / 2, abs=0.03)
    np.testing.assert_allclose(b7[0, 3:6], [3.69, 1.87, 1.67])  # dx=l, dy=w, dz=h
    back = lidar_boxes_to_camera(b7, calib)
    np.testing.assert_allclose(back[:, :6], car.boxes_camera()[:, :6], atol=1e-9)
    assert np.angle(np.exp(1j * (back[0, 6] - 1.57))) == pytest.approx(0.0, abs=2e-2)
    ext = box7_to_protocol(b7)
    assert np.all(ext[:, 3:] > ext[:, :3])
    # the centre is inside the extents and the extents are at least as large as the box
    assert np.all((ext[:, :3] < b7[:, :3]) & (b7[:, :3] < ext[:, 3:]))


def test_yaw_convention_exact_on_ideal_rig():
    """With an ideal rig (x_cam=-y_lidar, y_cam=-z_lidar, z_cam=x_lidar) yaw = -ry - pi/2."""
    R = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
    c = KittiCalibration(P={2: np.hstack([np.diag([700.0, 700, 1]), np.zeros((3, 1))])},
                         Tr_velo_to_cam=make_transform(R, [0, 0, 0]))
    rng = np.random.default_rng(0)
    ry = rng.uniform(-np.pi, np.pi, 20)
    boxes = np.column_stack([rng.normal(size=(20, 3)), np.full((20, 3), 2.0), ry])
    yaw = camera_boxes_to_lidar(boxes, c)[:, 6]
    np.testing.assert_allclose(np.angle(np.exp(1j * (yaw - (-ry - np.pi / 2)))), 0.0, atol=1e-12)


def test_calib_text_roundtrip_bit_exact(calib, tmp_path):
    again = parse_kitti_calibration(format_kitti_calibration(calib))
    for i in range(4):
        assert np.array_equal(again.P[i], calib.P[i])
    assert np.array_equal(again.R0_rect, calib.R0_rect)
    assert np.array_equal(again.Tr_velo_to_cam, calib.Tr_velo_to_cam)
    assert np.array_equal(again.Tr_imu_to_velo, calib.Tr_imu_to_velo)


def test_calib_variants():
    # [4,4] key-less P2 line (mmdetection3d demo) and raw-sequence key names
    c = parse_kitti_calibration("721.5 0 609.5 44.8 0 721.5 172.8 0.2 0 0 1 0.0027 0 0 0 1\n")
    assert c.P[2].shape == (3, 4) and c.Tr_velo_to_cam is None
    c = parse_kitti_calibration("P_rect_02: 700 0 600 0 0 700 170 0 0 0 1 0\nR_rect_00: 1 0 0 0 1 0 0 0 1\n"
                                "R: 0 -1 0 0 0 -1 1 0 0\nT: 0.1 0.2 0.3\n")
    np.testing.assert_allclose(c.T_cam_lidar(2)[:3, 3], [0.1, 0.2, 0.3])


@pytest.mark.parametrize("text, field", [
    ("P2: 1 2 3\n", "P2"),
    ("R0_rect: 1 0 0 0 1 0 0 0 1\n", "P2"),
    ("P2: 700 0 600 0 0 700 170 0 0 0 1 0\nTr_velo_to_cam: 1 0 0 0 0 1.01 0 0 0 0 1 0\n", "Tr_velo_to_cam"),
    ("P2: 700 5 600 0 0 700 170 0 0 0 1 0\n", "P2"),
    ("P2: 700 0 600 0 0 700 170 0 0 0 1 x\n", "P2"),
])
def test_bad_calib_names_file_and_field(text, field):
    with pytest.raises(FormatError) as ei:
        parse_kitti_calibration(text, "bad_calib.txt")
    assert ei.value.field == field and "bad_calib.txt" in str(ei.value)


def test_repair_only_small_rotation_errors():
    R = euler_to_matrix([0.1, 0.2, 0.3]) * (1 + 3e-4)
    line = "Tr_velo_to_cam: " + " ".join(f"{float(v)!r}" for v in np.hstack([R, np.zeros((3, 1))]).ravel())
    text = "P2: 700 0 600 0 0 700 170 0 0 0 1 0\n" + line + "\n"
    with pytest.raises(FormatError, match="repair"):
        parse_kitti_calibration(text, "c.txt")
    fixed = parse_kitti_calibration(text, "c.txt", repair=True).Tr_velo_to_cam[:3, :3]
    np.testing.assert_allclose(fixed, euler_to_matrix([0.1, 0.2, 0.3]), atol=1e-12)
    far = text.replace(line, "Tr_velo_to_cam: " + " ".join(
        f"{float(v)!r}" for v in np.hstack([R * 1.01, np.zeros((3, 1))]).ravel()))
    with pytest.raises(FormatError):
        parse_kitti_calibration(far, "c.txt", repair=True)


def test_bad_labels():
    with pytest.raises(FormatError, match="15 fields"):
        parse_kitti_labels("Car 0 0 0 1 2 3\n", "l.txt")
    with pytest.raises(FormatError, match="x1 <= x2"):
        parse_kitti_labels("Car 0 0 0 10 10 5 20 1 1 1 0 0 5 0\n", "l.txt")


def test_velodyne_bin_shape(tmp_path):
    pts = np.arange(24, dtype=np.float32).reshape(6, 4)
    pts.tofile(tmp_path / "a.bin")
    np.testing.assert_array_equal(read_velodyne_bin(tmp_path / "a.bin"), pts)
    assert read_velodyne_bin(tmp_path / "a.bin", 6).shape == (4, 6)
    with pytest.raises(FormatError, match="multiple of 5"):
        read_velodyne_bin(tmp_path / "a.bin", 5)


# ------------------------------------------------------------------------------ real samples
KITTI_ROOTS = ["openpcdet_pr653", "cvml_project", "pointpillars_demo/val", "mmdet3d_demo",
               "derived/kitti_mmdet3d_000008"]


@pytest.mark.shared_data
def test_every_kitti_calib_file_loads():
    root = shared_path("kitti")
    files = [p for p in root.rglob("*.txt") if "calib" in p.name or p.parent.name == "calib"
             or p.name in ("000134.txt", "000008.txt")]
    assert len(files) >= 9
    for f in files:
        c = load_kitti_calibration(f)
        assert 2 in c.P and 700 < c.P[2][0, 0] < 730, f
    # the mmdetection3d pickle and the KITTI text regenerated from it agree
    a = load_kitti_calibration(root / "mmdet3d_demo" / "000008.pkl")
    b = load_kitti_calibration(root / "derived" / "kitti_mmdet3d_000008" / "calib.txt")
    np.testing.assert_allclose(a.T_cam_lidar(2), b.T_cam_lidar(2), atol=1e-9)
    frames = kitti_frames(root / "derived" / "kitti_mmdet3d_000008", load_image=False, load_points=False)
    assert len(frames) == 1 and frames[0].num_3d == 6


@pytest.mark.shared_data
def test_kitti_label_boxes_project_onto_2d_boxes():
    """LiDAR-frame box7 -> our extrinsics and K -> enclosing rectangle vs label 2D box."""
    ious = []
    for sub in KITTI_ROOTS[:4]:
        for f in kitti_frames(shared_path("kitti", *sub.split("/")), load_image=False, load_points=False):
            assert f.match_matrix is not None and f.match_matrix.shape == (f.num_2d, f.num_3d)
            assert np.array_equal(f.match_matrix, np.eye(f.num_2d, dtype=bool))
            size = (f.intrinsics.width, f.intrinsics.height)
            proj = project_box7(f.bboxes_3d, f.intrinsics.K, f.extrinsics, size)
            ious.extend(np.diag(iou_matrix(proj, f.bboxes_2d)).tolist())
    assert len(ious) >= 43
    print(f"KITTI label 3D->2D mean IoU {np.mean(ious):.3f} over {len(ious)} boxes")
    assert np.mean(ious) >= 0.85


@pytest.mark.shared_data
def test_kitti_frames_full_load():
    frames = kitti_frames(shared_path("kitti", "openpcdet_pr653"), ids=[1])
    assert len(frames) == 1
    f = frames[0]
    assert f.frame_key == "000001" and f.image.shape == (375, 1242, 3) and f.image.dtype == np.uint8
    assert f.point_cloud.shape[1] == 4 and len(f.point_cloud) > 100_000
    assert f.bboxes_2d.shape == (3, 4) and f.bboxes_3d.shape == (3, 7)
    assert f.meta["types"] == ["Truck", "Car", "Cyclist"]
    assert len(f.meta["dontcare_boxes_2d"]) == 4
    assert f.intrinsics.width == 1242 and f.intrinsics.fx == pytest.approx(721.5377)
    ext = kitti_frames(shared_path("kitti", "openpcdet_pr653"), ids=["000001"], box_format="extents",
                       load_image=False, load_points=False)[0]
    assert ext.bboxes_3d.shape == (3, 6)


@pytest.mark.shared_data
def test_read_frames_dispatch():
    from xcalib.formats.calibanything_scene import CalibAnythingFrames
    from xcalib.formats.kitti import KittiFrames
    from xcalib.formats.mmdet3d import Mmdet3dFrames
    from xcalib.io.frames import read_frames

    assert isinstance(read_frames(shared_path("kitti", "openpcdet_pr653")), KittiFrames)
    assert isinstance(read_frames(shared_path("kitti", "mmdet3d_demo", "000008.pkl")), KittiFrames)
    assert isinstance(read_frames(shared_path("calibanything", "sensorscalibration")), CalibAnythingFrames)
    nus = read_frames(shared_path("nuscenes", "mmdet3d_demo", "n015-2018-07-24-11-22-45+0800.pkl"), load_points=False)
    assert isinstance(nus, Mmdet3dFrames) and len(nus) == 6


def test_kitti_to_kitti_keeps_matrices_and_estimate_inversion(calib, tmp_path):
    from xcalib.formats.export import export_calibration, read_calibration

    p = tmp_path / "c.txt"
    p.write_text(CALIB_TEXT)
    res = read_calibration(p, "kitti")
    out = export_calibration(res, "kitti", tmp_path / "again.txt")[0]
    again = load_kitti_calibration(out)
    for i in range(4):
        np.testing.assert_array_equal(again.P[i], calib.P[i])
    np.testing.assert_array_equal(again.R0_rect, calib.R0_rect)
    np.testing.assert_allclose(again.Tr_velo_to_cam, calib.Tr_velo_to_cam, atol=1e-12)
    # an estimate of T_cam_lidar(2) becomes the Tr_velo_to_cam that reproduces it
    est = calib.T_cam_lidar(2) @ make_transform(euler_to_matrix([0.01, -0.02, 0.005]), [0.05, 0, -0.02])
    c2 = calib.with_T_cam_lidar(est, 2)
    np.testing.assert_allclose(c2.T_cam_lidar(2), est, atol=1e-12)
    np.testing.assert_allclose(c2.projection(2), calib.K(2) @ est[:3], atol=1e-9)


@pytest.mark.shared_data
def test_kitti_frames_survive_hdf5_cache(tmp_path):
    from xcalib.io.hdf5 import CacheReader, write_cache

    f = kitti_frames(shared_path("kitti", "openpcdet_pr653"), ids=[1])[0]
    write_cache(tmp_path / "k.h5", [f])
    g = CacheReader(tmp_path / "k.h5")[0]
    np.testing.assert_allclose(g.meta["box7"], f.meta["box7"], atol=1e-6)
    assert g.meta["classes_3d"] == ["Truck", "Car", "Cyclist"]
    np.testing.assert_allclose(g.extrinsics, f.extrinsics, atol=1e-9)
    np.testing.assert_array_equal(g.match_matrix, f.match_matrix)
