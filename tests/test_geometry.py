"""Property-based tests (hypothesis) of the geometry core against scipy, OpenCV and brute force."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from xcalib.geometry import (
    CameraIntrinsics,
    as_box7,
    box7_corners,
    boxes3d_to_center_size,
    boxes3d_to_extents,
    center_size_to_extents,
    compose,
    cxcywh_to_xyxy,
    detect_box3d_convention,
    euler_to_matrix,
    extents_to_center_size,
    invert_transform,
    iou_matrix,
    is_rotation_matrix,
    make_transform,
    matrix_to_euler,
    matrix_to_quaternion,
    matrix_to_rotvec,
    orthonormalize,
    points_in_boxes,
    pose_error,
    project_points,
    projection_matrix,
    quaternion_to_matrix,
    rotation_angle,
    rotvec_to_matrix,
    transform_points,
    xywh_to_xyxy,
    xyxy_to_cxcywh,
    xyxy_to_xywh,
)

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
finite = dict(allow_nan=False, allow_infinity=False)

angle = st.floats(-np.pi, np.pi, **finite)
mid_angle = st.floats(-np.pi / 2 + 0.05, np.pi / 2 - 0.05, **finite)  # away from gimbal lock
unit_quat = arrays(np.float64, 4, elements=st.floats(-1, 1, **finite)).filter(lambda q: np.linalg.norm(q) > 0.1)
rotvec = arrays(np.float64, 3, elements=st.floats(-3, 3, **finite)).filter(lambda v: np.linalg.norm(v) < np.pi - 1e-3)
seeds = st.integers(0, 2**31 - 1)


def _assert_angles_close(a, b, atol):
    """Angles equal modulo 2 pi (pi and -pi are the same heading)."""
    d = (np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(d).max() <= atol, (a, b)


def _random_transform(rng) -> np.ndarray:
    return make_transform(Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.normal(0, 5, 3))


# --------------------------------------------------------------------------- rotations
@SETTINGS
@given(a=angle, b=mid_angle, c=angle, seq=st.sampled_from(["xyz", "zyx", "XYZ", "ZYX"]))
def test_euler_round_trip_and_agreement_with_scipy(a, b, c, seq):
    angles = np.array([a, b, c])
    R = euler_to_matrix(angles, seq)
    assert is_rotation_matrix(R)
    np.testing.assert_allclose(R, Rotation.from_euler(seq, angles).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(euler_to_matrix(matrix_to_euler(R, seq), seq), R, atol=1e-9)
    _assert_angles_close(matrix_to_euler(R, seq), angles, atol=1e-7)


@SETTINGS
@given(a=angle, b=angle, c=angle)
def test_extrinsic_xyz_euler_is_rz_ry_rx(a, b, c):
    def rx(t):
        return np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])

    def ry(t):
        return np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])

    def rz(t):
        return np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])

    np.testing.assert_allclose(euler_to_matrix([a, b, c], "xyz"), rz(c) @ ry(b) @ rx(a), atol=1e-12)
    np.testing.assert_allclose(euler_to_matrix(np.degrees([a, b, c]), "xyz", degrees=True),
                               rz(c) @ ry(b) @ rx(a), atol=1e-12)


@SETTINGS
@given(q=unit_quat)
def test_quaternion_round_trip_both_orders(q):
    qn = q / np.linalg.norm(q)
    R = quaternion_to_matrix(q)  # not necessarily unit: normalised
    assert is_rotation_matrix(R)
    np.testing.assert_allclose(R, Rotation.from_quat(qn).as_matrix(), atol=1e-12)
    back = matrix_to_quaternion(R)
    assert back[3] >= 0
    sign = 1.0 if np.abs(back - qn).max() < np.abs(back + qn).max() else -1.0
    np.testing.assert_allclose(back, sign * qn, atol=1e-9)  # q and -q are the same rotation
    wxyz = np.roll(qn, 1)
    np.testing.assert_allclose(quaternion_to_matrix(wxyz, order="wxyz"), R, atol=1e-12)
    np.testing.assert_allclose(np.abs(matrix_to_quaternion(R, order="wxyz")), np.abs(wxyz), atol=1e-9)


def test_bad_quaternions_raise():
    with pytest.raises(ValueError, match="zero norm"):
        quaternion_to_matrix([0, 0, 0, 0])
    with pytest.raises(ValueError, match="4 components"):
        quaternion_to_matrix([0, 0, 1])
    with pytest.raises(ValueError, match="order"):
        quaternion_to_matrix([0, 0, 0, 1], order="zyxw")


@SETTINGS
@given(v=rotvec)
def test_rotvec_round_trip_and_rotation_angle(v):
    R = rotvec_to_matrix(v)
    np.testing.assert_allclose(matrix_to_rotvec(R), v, atol=1e-8)
    assert rotation_angle(R, degrees=False) == pytest.approx(np.linalg.norm(v), abs=1e-7)
    assert rotation_angle(R, R) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("theta", [1e-7, 1e-5, 1e-3, 0.5, 3.0])
def test_rotation_angle_is_accurate_at_small_and_large_angles(theta):
    R = rotvec_to_matrix([0, 0, theta])
    assert rotation_angle(R, degrees=False) == pytest.approx(theta, rel=1e-5)


@SETTINGS
@given(seed=seeds, noise=st.floats(0, 0.05, **finite))
def test_orthonormalize_gives_nearby_rotation(seed, noise):
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    Rn = orthonormalize(R + rng.normal(0, noise, (3, 3)))
    assert is_rotation_matrix(Rn, tol=1e-9)
    assert rotation_angle(Rn, R) < 10 * noise * 57.3 + 1e-6


# ------------------------------------------------------------------------------ 3D boxes
boxes_cs = st.builds(
    lambda c, d: np.hstack([c, d]),
    arrays(np.float64, (5, 3), elements=st.floats(-50, 50, **finite)),
    arrays(np.float64, (5, 3), elements=st.floats(0.1, 10, **finite)),
)


@SETTINGS
@given(cs=boxes_cs)
def test_extents_center_size_round_trip(cs):
    ext = center_size_to_extents(cs)
    assert np.all(ext[:, 3:] >= ext[:, :3])
    np.testing.assert_allclose(extents_to_center_size(ext), cs, atol=1e-9)
    # auto-detection reads extents rows as extents; an explicit override agrees
    assert (detect_box3d_convention(ext) == "extents").all()
    np.testing.assert_allclose(boxes3d_to_center_size(ext), cs, atol=1e-9)
    np.testing.assert_allclose(boxes3d_to_center_size(ext, convention="extents"), cs, atol=1e-9)
    np.testing.assert_allclose(boxes3d_to_extents(cs, convention="center"), ext, atol=1e-9)


def test_center_rows_are_detected_per_row_and_override_wins():
    b = np.array([[30, 5, 1, 4, 2, 2], [0, 0, 0, 4, 2, 2]], dtype=float)
    assert detect_box3d_convention(b).tolist() == ["center", "extents"]
    mixed = boxes3d_to_center_size(b)
    np.testing.assert_allclose(mixed[0], [30, 5, 1, 4, 2, 2])
    np.testing.assert_allclose(mixed[1], [2, 1, 1, 4, 2, 2])
    np.testing.assert_allclose(boxes3d_to_center_size(b, convention="center")[1], [0, 0, 0, 4, 2, 2])
    with pytest.raises(ValueError, match="convention"):
        boxes3d_to_center_size(b, convention="corners")


@SETTINGS
@given(cs=boxes_cs, yaw=arrays(np.float64, 5, elements=angle))
def test_box7_corners_geometry(cs, yaw):
    b7 = np.hstack([cs, yaw[:, None]])
    corners = box7_corners(b7)
    assert corners.shape == (5, 8, 3)
    np.testing.assert_allclose(corners.mean(axis=1), cs[:, :3], atol=1e-9)
    # edges from corner 0: along heading (dx), across (dy), up (dz)
    np.testing.assert_allclose(np.linalg.norm(corners[:, 0] - corners[:, 1], axis=1), cs[:, 3], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(corners[:, 0] - corners[:, 3], axis=1), cs[:, 4], atol=1e-9)
    np.testing.assert_allclose(corners[:, 4, 2] - corners[:, 0, 2], cs[:, 5], atol=1e-9)
    heading = corners[:, 0, :2] - corners[:, 1, :2]
    _assert_angles_close(np.arctan2(heading[:, 1], heading[:, 0]), yaw, atol=1e-7)
    # yaw 0: the corners span the extents
    c0 = box7_corners(as_box7(cs, convention="center"))
    ext = center_size_to_extents(cs)
    np.testing.assert_allclose(c0.min(axis=1), ext[:, :3], atol=1e-9)
    np.testing.assert_allclose(c0.max(axis=1), ext[:, 3:], atol=1e-9)


def _brute_points_in_boxes(pts, b7, expansion):
    """Reference: rotate every point into every box's frame (float64, loops over boxes)."""
    out, margin = [], []
    for cx, cy, cz, dx, dy, dz, yaw in b7:
        local = pts[:, :3].astype(np.float64) - [cx, cy, cz]
        c, s = np.cos(yaw), np.sin(yaw)
        lx = c * local[:, 0] + s * local[:, 1]
        ly = -s * local[:, 0] + c * local[:, 1]
        half = np.array([dx, dy, dz]) * expansion / 2
        q = np.abs(np.stack([lx, ly, local[:, 2]], 1)) - half
        out.append(np.all(q <= 0, axis=1))
        margin.append(np.abs(q).min(axis=1))
    P = len(pts)
    return np.array(out).reshape(-1, P), np.array(margin).reshape(-1, P)


@SETTINGS
@given(seed=seeds, expansion=st.sampled_from([1.0, 1.25]), m=st.integers(0, 12))
def test_points_in_boxes_matches_brute_force_with_yaw(seed, expansion, m):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-20, 20, size=(3000, 4)).astype(np.float32)
    b7 = np.hstack([rng.uniform(-18, 18, (m, 3)), rng.uniform(0.5, 8, (m, 3)), rng.uniform(-np.pi, np.pi, (m, 1))])
    got = points_in_boxes(pts, b7, expansion=expansion)
    want, margin = _brute_points_in_boxes(pts, b7, expansion)
    assert got.shape == (m, len(pts))
    clear = margin > 1e-4  # float32 rounding may flip points that sit on a face
    np.testing.assert_array_equal(got[clear], want[clear])


def test_points_in_protocol_boxes_and_empty_inputs(rng):
    pts = np.array([[1, 1, 1], [3, 3, 3], [5.2, 0, 0]], dtype=np.float32)
    ext = np.array([[0, 0, 0, 2, 2, 2], [4, -1, -1, 5, 1, 1]], dtype=float)
    np.testing.assert_array_equal(points_in_boxes(pts, ext), [[1, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(points_in_boxes(pts, ext, expansion=1.5), [[1, 0, 0], [0, 0, 1]])
    assert points_in_boxes(pts, np.zeros((0, 6))).shape == (0, 3)
    assert points_in_boxes(np.zeros((0, 3)), ext).shape == (2, 0)
    with pytest.raises(ValueError, match=r"\[P, >=3\]"):
        points_in_boxes(pts[:, :2], ext)


# ------------------------------------------------------------------------------ 2D boxes
boxes2d = st.builds(
    lambda xy, wh: np.hstack([xy, xy + wh]),
    arrays(np.float64, (6, 2), elements=st.floats(-100, 1000, **finite)),
    arrays(np.float64, (6, 2), elements=st.floats(1, 300, **finite)),
)


@SETTINGS
@given(a=boxes2d, b=boxes2d, shift=arrays(np.float64, 2, elements=st.floats(-50, 50, **finite)))
def test_iou_matrix_properties(a, b, shift):
    m = iou_matrix(a, b)
    assert m.shape == (6, 6) and np.all((m >= 0) & (m <= 1 + 1e-12))
    np.testing.assert_allclose(m, iou_matrix(b, a).T, atol=1e-12)
    np.testing.assert_allclose(np.diag(iou_matrix(a, a)), 1.0, atol=1e-12)
    t = np.tile(shift, 2)
    np.testing.assert_allclose(iou_matrix(a + t, b + t), m, atol=1e-6)
    # a box inside another: IoU = area ratio
    inner = np.hstack([a[:, :2] + 0.25 * (a[:, 2:] - a[:, :2]), a[:, :2] + 0.75 * (a[:, 2:] - a[:, :2])])
    np.testing.assert_allclose(np.diag(iou_matrix(a, inner)), 0.25, atol=1e-9)
    far = a + [1e5, 0, 1e5, 0]
    assert np.all(iou_matrix(a, far) == 0)


@SETTINGS
@given(a=boxes2d)
def test_2d_box_format_round_trips(a):
    np.testing.assert_allclose(xywh_to_xyxy(xyxy_to_xywh(a)), a, atol=1e-9)
    np.testing.assert_allclose(cxcywh_to_xyxy(xyxy_to_cxcywh(a)), a, atol=1e-9)


# ---------------------------------------------------------------------------- projection
intrinsics = st.builds(
    lambda f, a, cx, cy: (f, f * a, cx, cy),
    st.floats(300, 3000, **finite), st.floats(0.9, 1.1, **finite),
    st.floats(200, 1000, **finite), st.floats(200, 700, **finite),
)
distortions = st.one_of(
    st.none(),
    arrays(np.float64, 5, elements=st.floats(-0.05, 0.05, **finite)),
    arrays(np.float64, 8, elements=st.floats(-0.02, 0.02, **finite)),
)


@SETTINGS
@given(seed=seeds, intr=intrinsics, dist=distortions)
def test_projection_agrees_with_cv2_project_points(seed, intr, dist):
    rng = np.random.default_rng(seed)
    T = _random_transform(rng)
    R, t = T[:3, :3], T[:3, 3]
    # points in front of the camera, within a +-40 degree cone
    cam = np.column_stack([rng.uniform(-0.8, 0.8, (200, 2)), np.ones(200)]) * rng.uniform(1, 80, (200, 1))
    lidar = (cam - t) @ R  # = R^T (cam - t)
    K = CameraIntrinsics(*intr, distortion=dist)
    uv, depth = project_points(lidar, K, R, t)
    np.testing.assert_allclose(depth, cam[:, 2], rtol=1e-9)
    ref, _ = cv2.projectPoints(lidar.reshape(-1, 1, 3), cv2.Rodrigues(R)[0], t, K.K,
                               None if dist is None else np.asarray(dist))
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-6 * max(intr[0], 1))
    if dist is None:
        P = projection_matrix(K.K, R, t)
        h = np.hstack([lidar, np.ones((len(lidar), 1))]) @ P.T
        np.testing.assert_allclose(uv, h[:, :2] / h[:, 2:], rtol=1e-9, atol=1e-6)


def test_points_behind_the_camera_project_to_nan():
    uv, depth = project_points(np.array([[0, 0, -1.0], [0, 0, 2.0]]), np.eye(3))
    assert np.isnan(uv[0]).all() and np.isfinite(uv[1]).all() and depth[0] == -1.0


# ----------------------------------------------------------------------------- transforms
@SETTINGS
@given(seed=seeds)
def test_invert_compose_and_transform_points_identities(seed):
    rng = np.random.default_rng(seed)
    A, B = _random_transform(rng), _random_transform(rng)
    np.testing.assert_allclose(A @ invert_transform(A), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(invert_transform(compose(A, B)), compose(invert_transform(B), invert_transform(A)),
                               atol=1e-9)
    pts = rng.normal(0, 10, (50, 4))
    back = transform_points(invert_transform(A), transform_points(A, pts))
    np.testing.assert_allclose(back, pts, atol=1e-9)
    np.testing.assert_array_equal(transform_points(A, pts)[:, 3], pts[:, 3])  # extra columns kept
    np.testing.assert_allclose(transform_points(A[:3], pts), transform_points(A, pts))  # [3,4] accepted


@SETTINGS
@given(seed=seeds, v=rotvec, dt=arrays(np.float64, 3, elements=st.floats(-2, 2, **finite)))
def test_pose_error_identities(seed, v, dt):
    rng = np.random.default_rng(seed)
    T = _random_transform(rng)
    assert pose_error(T, T) == pytest.approx((0.0, 0.0), abs=1e-6)
    dR = rotvec_to_matrix(v)
    est = make_transform(dR @ T[:3, :3], T[:3, 3] + dt)
    rot_err, trans_err = pose_error(est, T)
    assert rot_err == pytest.approx(np.degrees(np.linalg.norm(v)), abs=1e-5)
    assert trans_err == pytest.approx(np.linalg.norm(dt), abs=1e-9)
    assert pose_error(T, est) == pytest.approx((rot_err, trans_err), abs=1e-6)  # symmetric


def test_transform_shape_errors_are_clear():
    with pytest.raises(ValueError, match="4x4 or 3x4"):
        invert_transform(np.eye(3))
    with pytest.raises(ValueError, match="NaN/Inf"):
        invert_transform(np.full((4, 4), np.nan))
