"""A tiny box-level roadside simulator for the calibration tests (test support, not the package).

A camera 5-12 m up looks down at a ground plane (z = 0 in a world frame) with cars, trucks and
pedestrians on it; a LiDAR sits on the same pole. 2D boxes are the clipped enclosing rectangles
of the projected 3D box corners, plus noise, misses and false detections.
"""

from __future__ import annotations

import numpy as np

from xcalib.geometry import CameraIntrinsics, box7_corners, euler_to_matrix, make_transform, project_points
from xcalib.types import Frame

W, H = 1920, 1200
INTR = CameraIntrinsics(1300.0, 1300.0, 960.0, 600.0, width=W, height=H)


def vehicle_boxes7(r: np.random.Generator, n: int, az_half: float, dist: tuple) -> np.ndarray:
    """``n`` vehicle-sized 3D boxes (x, y, z, l, w, h, yaw) at azimuths within +-``az_half`` rad
    and distances ``dist`` (m) of the LiDAR, random yaw: the scenes of the cost-Jacobian tests."""
    az = r.uniform(-az_half, az_half, n)
    d = r.uniform(*dist, n)
    return np.column_stack([d * np.cos(az), d * np.sin(az), r.uniform(-1, 0.5, n), r.uniform(3.5, 5, n),
                            r.uniform(1.6, 2, n), r.uniform(1.4, 1.8, n), r.uniform(-np.pi, np.pi, n)])


def central_jacobian(fun, x: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    """Central differences of ``fun`` at ``x`` (the reference the analytic Jacobians are held to)."""
    return np.stack([(fun(x + eps * e) - fun(x - eps * e)) / (2 * eps) for e in np.eye(len(x))], 1)


def sim_rig(rng):
    """(T_cam_world, T_lidar_world) for a pole-mounted camera and LiDAR."""
    h = rng.uniform(5, 12)
    pitch = np.radians(rng.uniform(12, 30))
    yaw = rng.uniform(-np.pi, np.pi)
    # camera looks along world +x rotated by yaw; optical z forward, y down
    base = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], dtype=float)  # world(x fwd,y left,z up)->cam
    Rz = euler_to_matrix([0, 0, yaw])
    Ry = euler_to_matrix([0, pitch, 0])
    R_wc = Rz @ Ry  # camera axes in world (forward tilted down by pitch)
    R_cw = base @ R_wc.T
    C = np.array([0.0, 0.0, h])
    T_cam_world = make_transform(R_cw, -R_cw @ C)
    R_lw = euler_to_matrix(rng.uniform(-0.05, 0.05, 3) + np.array([0, 0, rng.uniform(-np.pi, np.pi)]))
    L = C + rng.uniform(-1, 1, 3)
    T_lidar_world = make_transform(R_lw, -R_lw @ L)
    return T_cam_world, T_lidar_world, yaw


_SIZES = np.array([[4.5, 1.8, 1.5], [10.0, 2.5, 3.2], [0.6, 0.6, 1.75], [5.2, 2.0, 1.9]])


def sim_frames(seed: int = 0, n_frames: int = 5, n_objects=(8, 14), noise_px: float = 1.0,
               miss: float = 0.1, false_pos: float = 0.05, extra_3d: int = 2, intr: CameraIntrinsics = INTR):
    """Frames with ground truth: list of Frame (extrinsics = T_cam_lidar) and the truth [4,4]."""
    rng = np.random.default_rng(seed)
    T_cw, T_lw, yaw = sim_rig(rng)
    T_cl = T_cw @ np.linalg.inv(T_lw)
    frames = []
    for f in range(n_frames):
        n = rng.integers(*n_objects)
        kind = rng.choice(len(_SIZES), n, p=[0.6, 0.1, 0.15, 0.15])
        dims = _SIZES[kind] * rng.uniform(0.9, 1.1, (n, 3))
        dist = rng.uniform(8, 60, n)
        ang = yaw + rng.uniform(-0.6, 0.6, n)
        ctr_w = np.stack([dist * np.cos(ang), dist * np.sin(ang), dims[:, 2] / 2], 1)
        # a few objects outside the camera view (only the LiDAR sees them)
        ex = rng.uniform(-np.pi, np.pi, extra_3d) + yaw + np.pi
        ed = rng.uniform(8, 40, extra_3d)
        ctr_w = np.vstack([ctr_w, np.stack([ed * np.cos(ex), ed * np.sin(ex), np.full(extra_3d, 0.75)], 1)])
        dims = np.vstack([dims, np.tile([4.5, 1.8, 1.5], (extra_3d, 1))])
        yaw_w = rng.uniform(-np.pi, np.pi, len(ctr_w))
        box_w = np.column_stack([ctr_w, dims, yaw_w])
        # box7 in the LiDAR frame: centre transformed; yaw about LiDAR z (LiDAR ~level)
        ctr_l = ctr_w @ T_lw[:3, :3].T + T_lw[:3, 3]
        R_lw = T_lw[:3, :3]
        head_w = np.stack([np.cos(yaw_w), np.sin(yaw_w), 0 * yaw_w], 1) @ R_lw.T
        box_l = np.column_stack([ctr_l, dims, np.arctan2(head_w[:, 1], head_w[:, 0])])
        cl = box7_corners(box_l).reshape(-1, 3)  # the annotation is the truth the camera sees
        uv, z = project_points(cl, intr, T_cl[:3, :3], T_cl[:3, 3])
        uv = uv.reshape(-1, 8, 2)
        z = z.reshape(-1, 8)
        rect = np.column_stack([uv[..., 0].min(1), uv[..., 1].min(1), uv[..., 0].max(1), uv[..., 1].max(1)])
        rect[:, [0, 2]] = np.clip(rect[:, [0, 2]], 0, W)
        rect[:, [1, 3]] = np.clip(rect[:, [1, 3]], 0, H)
        vis = np.all(z > 0.5, 1) & (rect[:, 2] - rect[:, 0] > 6) & (rect[:, 3] - rect[:, 1] > 6)
        vis &= rng.random(len(vis)) >= miss
        idx3 = np.arange(len(box_l))
        b2 = rect[vis] + rng.normal(0, noise_px, (int(vis.sum()), 4))
        truth_pairs = np.column_stack([np.arange(int(vis.sum())), idx3[vis]])
        n_fp = rng.binomial(max(len(b2), 1), false_pos) + (1 if rng.random() < false_pos else 0)
        fx = rng.uniform(0, W - 120, n_fp)
        fy = rng.uniform(H * 0.3, H - 80, n_fp)
        fp = np.column_stack([fx, fy, fx + rng.uniform(20, 120, n_fp), fy + rng.uniform(20, 80, n_fp)])
        b2 = np.vstack([b2, fp])
        perm = rng.permutation(len(b2))
        b2 = b2[perm]
        inv = np.argsort(perm)
        mm = np.zeros((len(b2), len(box_l)), dtype=bool)
        mm[inv[truth_pairs[:, 0]], truth_pairs[:, 1]] = True
        frames.append(Frame(image=np.zeros((1, 1, 3), np.uint8), point_cloud=np.zeros((0, 3), np.float32),
                            bboxes_2d=b2.astype(np.float64), bboxes_3d=box_l, camera_name="cam0",
                            frame_key=f"{f:04d}", match_matrix=mm, intrinsics=intr, extrinsics=T_cl,
                            meta={"image_size": (W, H)}))
    return frames, T_cl


def test_simulator_projects_truth_onto_its_boxes():
    frames, T = sim_frames(seed=3, n_frames=2, noise_px=0.0, miss=0.0, false_pos=0.0)
    fr = frames[0]
    assert fr.match_matrix.sum() >= 3
    i, j = np.argwhere(fr.match_matrix)[0]
    uv, _ = project_points(box7_corners(fr.bboxes_3d[j:j + 1]).reshape(-1, 3), INTR, T[:3, :3], T[:3, 3])
    rect = np.clip([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()], 0, [W, H, W, H])
    np.testing.assert_allclose(rect, fr.bboxes_2d[i], atol=1e-6)
