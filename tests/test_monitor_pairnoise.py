"""The 3D-box part of the monitor's noise model weighted per matched pair
(``MonitorConfig.pair_noise``, ``xcalib.monitor.pairnoise``): the edges' derivatives with respect to
a box's centre and size are the pose Jacobian's (checked against projecting moved boxes), the
covariance keeps the per-edge variances, and the whitened normal equations equal the independent
model's where the noise model has no 3D part and differ where it has one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from xcalib.calib.boxproj import project_rects
from xcalib.calib.diagnostics import NoiseModel
from xcalib.calib.result import CalibrationResult
from xcalib.geometry.boxes import box7_corners
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.monitor import Monitor, MonitorConfig
from xcalib.monitor.pairnoise import box_axes, pair_covariance, pair_whitening

INTR = CameraIntrinsics(fx=1000.0, fy=1000.0, cx=960.0, cy=540.0)
R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # LiDAR x forward -> camera z
T = np.array([0.1, 0.5, 0.2])


def _rect(c: np.ndarray) -> np.ndarray:
    return project_rects(c[None], R, T, INTR, (1920, 1080))[0][0]


def test_centre_and_size_derivatives_match_moved_boxes():
    box = np.array([20.0, 3.0, -0.5, 4.5, 1.9, 1.6, 0.6])
    c = box7_corners(box[None])[0]
    eps = 1e-6
    # the pose translation derivative (camera axes) of each edge: what the monitor has from its 13 poses
    Jt = np.stack([(project_rects(c[None], R, T + eps * np.eye(3)[k], INTR, (1920, 1080))[0][0]
                    - project_rects(c[None], R, T - eps * np.eye(3)[k], INTR, (1920, 1080))[0][0]) / (2 * eps)
                   for k in range(3)], -1)  # [4,3]
    rc, valid, u, v = project_rects(c[None], R, T, INTR, (1920, 1080), corner_uv=True)
    idx = np.array([np.argmin(u[0]), np.argmin(v[0]), np.argmax(u[0]), np.argmax(v[0])])
    ext = c[idx]
    A = box_axes(box[None])[0]
    Nc = Jt @ R
    for k in range(3):  # a shift of the box along LiDAR axis k
        d = np.eye(3)[k] * 1e-4
        fd = (_rect(c + d) - _rect(c - d)) / 2e-4
        assert np.allclose(Nc[:, k], fd, rtol=1e-4, atol=1e-3)
    dev = ext - box[:3]
    for k in range(3):  # a relative size change along the box's own axis k (about its centre)
        a = A[k]
        move = np.einsum("si,i->s", c - box[:3], a)[:, None] * a
        fd = (_rect(c + 1e-5 * move) - _rect(c - 1e-5 * move)) / 2e-5
        assert np.allclose((Nc @ a) * (dev @ a), fd, rtol=1e-4, atol=1e-3)


def test_covariance_keeps_the_edge_variances_and_whitens():
    rng = np.random.default_rng(3)
    n = 5
    Jt = rng.standard_normal((n, 4, 3)) * 30.0
    box7 = np.column_stack([rng.uniform(10, 40, (n, 3)), rng.uniform(1, 5, (n, 3)), rng.uniform(-3, 3, n)])
    ext = box7[:, None, :3] + rng.uniform(-2, 2, (n, 4, 3))
    info = np.ones((n, 4), dtype=bool)
    info[1, 2] = False  # a clipped edge
    v_c, v_s = np.full(n, 0.5), np.full(n, 0.3)
    C = pair_covariance(Jt, R, ext, box7, v_c, v_s, info)
    for p in range(n):
        m = info[p]
        assert np.mean(np.diag(C[p])[m]) == pytest.approx(1.0)  # the per-edge variance kept on average
        assert np.all(np.linalg.eigvalsh(C[p]) > 0.19)  # the 2D part (0.2) keeps it positive definite
    assert C[1, 2, 2] == 1.0 and np.all(C[1, 2, [0, 1, 3]] == 0.0)  # the clipped edge: an identity row
    assert np.abs(C[0] - np.diag(np.diag(C[0]))).max() > 0.1  # correlated edges
    L = pair_whitening(C)
    assert np.allclose(np.einsum("nij,njk,nlk->nil", L, C, L), np.eye(4)[None], atol=1e-10)
    # no 3D part: the independent model exactly
    C0 = pair_covariance(Jt, R, ext, box7, np.zeros(n), np.zeros(n), info)
    assert np.array_equal(C0, np.broadcast_to(np.eye(4), C0.shape))
    assert np.array_equal(pair_whitening(C0), C0)


def _stream(n: int = 6):
    from xcalib.data.synth import iter_frames, sample_site

    site = sample_site(5, n_objects=(15, 30))
    frames = [replace(f, bboxes_3d=np.asarray(f.meta["box7"], dtype=np.float32))
              for f in iter_frames(site, n, 0, render_images=False, lidar=False)]
    T = site.T_cam_lidar
    cal = CalibrationResult(success=True, intrinsics=site.intrinsics_given, rotation=T[:3, :3], translation=T[:3, 3],
                            rotation_std_deg=np.full(3, 0.05), translation_std_m=np.full(3, 0.02),
                            camera_name=site.camera_name, image_size=(site.width, site.height))
    return cal, frames


def _records(cal, frames, pair_noise: bool, noise: NoiseModel | None = None) -> list:
    mon = Monitor(cal, MonitorConfig(pair_noise=pair_noise))
    cm = next(iter(mon.cameras.values()))
    if noise is not None:
        cm.noise = noise
    cm.keep_edges = True  # the unshaped rows too (as the benchmark's recordings keep them)
    out = []
    for f in frames:
        mon.update(f)
        out.append(cm.recs[-1])
    return out


def test_whitened_equals_independent_without_a_3d_part_and_differs_with_one():
    cal, frames = _stream()
    flat = NoiseModel(sigma_px=2.0, sigma_3d_m=0.0, sigma_size=0.0)
    a, b = _records(cal, frames, False, flat), _records(cal, frames, True, flat)
    assert sum(q.n_pairs for q in a) > 30
    for qa, qb in zip(a, b):
        assert np.allclose(qa.H, qb.H, rtol=1e-9, atol=1e-9) and np.allclose(qa.g, qb.g, rtol=1e-9, atol=1e-9)
        assert qa.c == pytest.approx(qb.c, rel=1e-9)
        assert np.allclose(qa.obj_H, qb.obj_H, atol=1e-9) and np.allclose(qa.obj_g, qb.obj_g, atol=1e-9)
    box = NoiseModel(sigma_px=1.0, sigma_3d_m=0.1, sigma_size=0.03)
    a, b = _records(cal, frames, False, box), _records(cal, frames, True, box)
    Ha, Hb = sum(q.H for q in a), sum(q.H for q in b)
    assert np.abs(Hb - Ha).max() > 0.05 * np.abs(Ha).max()  # the edges' correlation moves the information
    for q in b:  # the per-object shares still add up to the frame's normal equations
        assert np.allclose(q.obj_H.sum(0), q.H) and np.allclose(q.obj_g.sum(0), q.g)
    assert MonitorConfig().pair_noise is False


def test_pair_noise_must_be_a_bool():
    """Review (session 14): a truthy non-bool (a "false" string from a config file, 0.0) is refused
    when the config is built, not silently read as on or off."""
    for bad in ("false", "no", 1, 0.0, None):
        with pytest.raises(ValueError, match="pair_noise"):
            MonitorConfig(pair_noise=bad)
    assert MonitorConfig(pair_noise=True).pair_noise is True
