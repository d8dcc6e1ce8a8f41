"""3D box models for yaw-less boxes (calib.boxmodel, calib.inputs): yaw fitted to the LiDAR points,
point hulls grown by the scan gap, the automatic choice of outlines, a no-yaw site calibrated."""

from __future__ import annotations

import dataclasses

import numpy as np

from xcalib.calib.boxmodel import expand_by_scan_gap, fit_yaw_to_points, lidar_angular_step, shapes_from_points
from xcalib.calib.config import CalibConfig
from xcalib.calib.inputs import prepare_frames, with_corner_outlines
from xcalib.geometry.boxes import box7_corners


def _ray_box(dirs: np.ndarray, box7: np.ndarray) -> np.ndarray:
    """Distance along unit rays from the origin to a yawed box (inf: miss)."""
    c, s = np.cos(box7[6]), np.sin(box7[6])
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    o, d = -box7[:3] @ R, dirs @ R
    d = np.where(np.abs(d) < 1e-12, 1e-12, d)
    t1, t2 = (-box7[3:6] / 2 - o) / d, (box7[3:6] / 2 - o) / d
    near, far = np.minimum(t1, t2).max(1), np.maximum(t1, t2).min(1)
    return np.where((near <= far) & (near > 0), near, np.inf)


def _scan(boxes7: np.ndarray, d_az=np.radians(0.2), d_el=np.radians(0.7), rng=None) -> np.ndarray:
    """A LiDAR at the origin (grid of az x el rays) hitting the boxes (no ground), 1 cm range noise."""
    az = np.arange(-np.pi, np.pi, d_az)
    el = np.arange(np.radians(-30), np.radians(5), d_el)
    A, E = np.meshgrid(az, el)
    dirs = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    t = np.min([_ray_box(dirs, b) for b in boxes7], axis=0)
    hit = np.isfinite(t)
    r = t[hit] + (0 if rng is None else rng.normal(0, 0.01, hit.sum()))
    return dirs[hit] * r[:, None]


def _yaw_err_deg(a, b):
    return np.degrees(np.abs((a - b + np.pi / 2) % np.pi - np.pi / 2))


def test_yaw_fitted_to_the_box_outline(rng):
    # cars at 15-40 m, turned every way, LiDAR 6 m above the road (boxes' centres at z = -5.25)
    yaws = np.radians([10.0, 35.0, 62.0, 95.0, 140.0, 170.0])
    ranges = [15.0, 22.0, 28.0, 33.0, 38.0, 40.0]
    bearing = np.radians([0.0, 60.0, 120.0, 180.0, 240.0, 300.0])
    truth = np.array([[r * np.cos(b), r * np.sin(b), -5.25, 4.5, 1.9, 1.5, y] for r, b, y in zip(ranges, bearing, yaws)])
    pts = _scan(truth, rng=rng)
    given = truth.copy()
    given[:, 6] = 0.0  # exported without yaw: length along x
    fit = fit_yaw_to_points(given, pts)
    assert fit.fitted.all() and not fit.ambiguous.any()
    assert np.all(fit.contrast >= 1.5)
    err = _yaw_err_deg(fit.boxes7[:, 6], truth[:, 6])
    assert err.max() < 1.0, err
    np.testing.assert_allclose(fit.boxes7[:, :6], given[:, :6])  # centre and size kept


def test_yaw_left_open_without_points():
    box = np.array([[20.0, 0.0, -5.25, 4.5, 1.9, 1.5, 0.0], [25.0, 5.0, -5.0, 0.6, 0.6, 1.7, 0.0]])
    fit = fit_yaw_to_points(box, np.zeros((0, 3)))
    assert not fit.fitted.any()
    assert fit.ambiguous.tolist() == [True, False]  # a pedestrian's heading hardly changes its outline
    np.testing.assert_array_equal(fit.boxes7, box)


def test_scan_step_estimated_from_the_cloud(rng):
    boxes = np.array([[12.0 * np.cos(a), 12.0 * np.sin(a), -1.0, 3.0, 8.0, 6.0, a] for a in np.linspace(0, 6, 6)])
    step = lidar_angular_step(_scan(boxes, rng=rng))
    assert step is not None
    np.testing.assert_allclose(np.degrees(step), [0.2, 0.7], rtol=0.1)
    assert lidar_angular_step(np.zeros((10, 3))) is None


def test_hull_grown_by_half_a_scan_step():
    box = np.array([30.0, 5.0, -5.25, 4.5, 1.9, 1.5, 0.4])
    pts = _scan(box[None])
    step = (np.radians(0.2), np.radians(0.7))
    grown = expand_by_scan_gap(pts, step)
    assert grown.shape == (4 * len(pts), 3)
    np.testing.assert_allclose(np.linalg.norm(grown, axis=1), np.tile(np.linalg.norm(pts, axis=1), 4))  # ranges kept
    bare, used = shapes_from_points(box[None], box7_corners(box[None]), pts)
    wide, _ = shapes_from_points(box[None], box7_corners(box[None]), pts, scan_step_rad=step)
    assert used.all()

    def elevation(v):  # as the LiDAR sees it (the top of the object in a camera beside it)
        return np.degrees(np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1])))

    top_true, top_bare, top_wide = (elevation(v).max() for v in (box7_corners(box[None])[0], bare[0], wide[0]))
    # the last scan line sits up to one step (0.7 deg) below the far roof edge; half a step is added back
    assert 0.1 < top_true - top_bare <= 0.7 + 1e-6
    np.testing.assert_allclose(top_wide - top_bare, 0.35, atol=1e-3)
    assert abs(top_wide - top_true) < top_true - top_bare


def _no_yaw_case(seed: int, n_frames: int):
    from xcalib.data.synth.realism import make_realism_case

    return make_realism_case("no_yaw", seed, n_frames)


def test_corner_outlines_for_clear_yaws_only():
    case = _no_yaw_case(2, 3)
    cf, _, _ = prepare_frames(list(case.frames), case.intrinsics_given)
    assert any(f.from_points.any() for f in cf)
    alt = with_corner_outlines(cf)
    for f, g in zip(cf, alt):
        kept_hull = g.from_points
        assert np.array_equal(kept_hull, f.from_points & f.yaw_ambiguous)
        clear = f.from_points & ~f.yaw_ambiguous
        np.testing.assert_allclose(g.corners[clear, :8], f.box_corners[clear])
        assert np.all(g.outline_sigma_m[kept_hull] > 0)
    with_yaw = [dataclasses.replace(f, meta={**f.meta, "box7": f.meta["box7_gt"]}) for f in case.frames]
    cf7, _, _ = prepare_frames(with_yaw, case.intrinsics_given)
    assert with_corner_outlines(cf7) is None  # boxes with yaw: corners, nothing to choose


def test_no_yaw_site_calibrates_as_well_as_a_clean_one():
    import xcalib

    case = _no_yaw_case(2, 20)
    res = xcalib.calibrate(list(case.frames), case.intrinsics_given, CalibConfig())
    assert res.success, res.message
    rot, tr = res.pose_error(case.T_cam_lidar)
    assert rot < 0.1 and tr < 0.1, (rot, tr)  # PCA yaw + point hulls (0.4.0): 0.34 deg / 0.16 m here
    assert res.diagnostics.box_model in ("corners", "corners+points")
