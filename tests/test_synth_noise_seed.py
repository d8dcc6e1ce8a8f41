"""Fresh draws of a synthetic scene's detection noise (``generate_frames(noise_seed=)``, issue 26) and
the bias-or-spread analysis built on them (``bench_camera_models.resample_case``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from xcalib.data.synth import generate_frames, sample_site

SMALL = dict(width=480, height=300, focal_px=(250.0, 625.0))
BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _by_id(ids, rows):
    return {int(t): r for t, r in zip(ids, rows) if t >= 0}


def test_noise_seed_redraws_the_detections_of_the_same_scene():
    site = sample_site(2, **SMALL)
    base = generate_frames(site, 2, seed=4, lidar=False, render_images=False)
    same = generate_frames(site, 2, seed=4, lidar=False, render_images=False, noise_seed=None)
    a = generate_frames(site, 2, seed=4, lidar=False, render_images=False, noise_seed=0)
    a2 = generate_frames(site, 2, seed=4, lidar=False, render_images=False, noise_seed=0)
    b = generate_frames(site, 2, seed=4, lidar=False, render_images=False, noise_seed=1)
    for f0, fs in zip(base, same):  # None is the default draw, bit for bit
        assert np.array_equal(f0.bboxes_2d, fs.bboxes_2d) and np.array_equal(f0.bboxes_3d, fs.bboxes_3d)
    for fa, fa2, fb, f0 in zip(a, a2, b, base):
        assert np.array_equal(fa.bboxes_3d, fa2.bboxes_3d) and np.array_equal(fa.bboxes_2d, fa2.bboxes_2d)
        assert not np.array_equal(fa.bboxes_3d, fb.bboxes_3d) and not np.array_equal(fa.bboxes_3d, f0.bboxes_3d)
        # the scene is the same: every object seen in two draws has the same true 3D box and clean 2D box
        for x, y in ((fa, fb), (fa, f0)):
            gx, gy = _by_id(x.meta["ids_3d"], x.meta["box7_gt"]), _by_id(y.meta["ids_3d"], y.meta["box7_gt"])
            common = set(gx) & set(gy)
            assert len(common) >= 3 and all(np.array_equal(gx[t], gy[t]) for t in common)
            cx = _by_id(x.meta["ids_2d"], x.meta["boxes_2d_clean"])
            cy = _by_id(y.meta["ids_2d"], y.meta["boxes_2d_clean"])
            assert all(np.array_equal(cx[t], cy[t]) for t in set(cx) & set(cy))


def test_noise_seed_keeps_the_point_clouds_and_rejects_negative_seeds():
    site = sample_site(1, **SMALL)
    p0 = generate_frames(site, 1, seed=0, render_images=False)[0].point_cloud
    p1 = generate_frames(site, 1, seed=0, render_images=False, noise_seed=3)[0].point_cloud
    assert len(p0) > 100 and np.array_equal(p0, p1)
    with pytest.raises(ValueError, match="noise_seed"):
        generate_frames(site, 1, seed=0, render_images=False, lidar=False, noise_seed=-1)


@pytest.fixture(scope="module")
def bench():
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    import bench_camera_models

    return bench_camera_models


def test_linearised_sigma_scales_with_the_noise_levels(bench):
    from xcalib.calib.pose import Pose

    site = sample_site(0, camera_model="pinhole", hfov_deg=90.0, width=1280, height=800, box_noise_px=1.0)
    T = np.asarray(site.T_cam_lidar)
    true = Pose(T[:3, :3], T[:3, 3])
    raw = generate_frames(site, 4, 0, render_images=False, lidar=False)
    d, s1 = bench._true_pair_fit(site, raw, true, (1.0, 0.1))
    _, s0 = bench._true_pair_fit(site, raw, true, (0.0, 0.0))
    _, s2 = bench._true_pair_fit(site, raw, true, (2.0, 0.2))
    _, sc = bench._true_pair_fit(site, raw, true, (0.0, 0.1))
    assert np.all(np.isfinite(d)) and np.all(s1 > 0) and np.allclose(s0, 0.0)
    assert np.allclose(s2, 2 * s1, rtol=1e-9)
    assert np.all(sc < s1) and np.all(sc > 0)  # the centre noise is one part of it


def test_resample_summary_pools_draws_and_sites(bench):
    recs = [{"row": "r", "z": [[1.0] * 6, [-1.0] * 6], "z_mean": [0.0] * 6},
            {"row": "r", "z": [[3.0] * 6, [1.0] * 6], "z_mean": [2.0] * 6}]
    (row,) = bench.summarise_resample(recs)
    assert row["sites"] == 2 and row["draws"] == 4
    assert np.allclose(row["z_rms"], np.sqrt(3.0)) and np.allclose(row["within_2"], 0.75)
    assert np.allclose(row["bias_z_rms"], np.sqrt(2.0))


def test_a_noise_source_switched_off_keeps_every_other_draw(bench):
    """``--sources``' premise: a noise field at 0 changes that source only (the random streams are
    drawn whatever the level), so full minus source-off is exactly what that source did."""
    site = sample_site(3, **SMALL)
    full = generate_frames(site, 2, seed=1, lidar=False, render_images=False, noise_seed=2)
    no_yaw = generate_frames(site, 2, seed=1, lidar=False, render_images=False, noise_seed=2,
                             **{bench.SOURCES["yaw"]: 0.0})
    no_centre = generate_frames(site, 2, seed=1, lidar=False, render_images=False, noise_seed=2,
                                **{bench.SOURCES["centre"]: 0.0})
    for f, fy, fc in zip(full, no_yaw, no_centre):
        assert np.array_equal(f.bboxes_2d, fy.bboxes_2d) and np.array_equal(f.bboxes_2d, fc.bboxes_2d)
        b, by, bc, gt = f.meta["box7"], fy.meta["box7"], fc.meta["box7"], f.meta["box7_gt"]
        real = f.meta["ids_3d"] >= 0
        assert np.array_equal(b[:, :6], by[:, :6]) and not np.allclose(b[real, 6], by[real, 6])
        assert np.allclose(by[real, 6], gt[real, 6])  # yaw off: the true heading
        assert np.array_equal(b[:, 3:], bc[:, 3:]) and np.allclose(bc[real, :3], gt[real, :3])


def test_source_effects_split_the_error_by_source(bench):
    D = np.array([[2.0, 0, 0, 0, 0, 1.0], [-2.0, 0, 0, 0, 0, 1.0]])
    off = {"yaw": D - np.array([[1.0, 0, 0, 0, 0, 0]] * 2), "centre": np.zeros((2, 6))}
    S = np.full((2, 6), 0.5)
    out = bench.source_effects(D, off, S)
    assert out["yaw"]["rms"][0] == pytest.approx(1.0) and out["yaw"]["z_rms"][0] == pytest.approx(2.0)
    assert out["yaw"]["share"][0] == pytest.approx(0.25) and out["yaw"]["share"][5] == 0.0
    assert out["centre"]["share"] == pytest.approx([1.0, 0, 0, 0, 0, 1.0])
    recs = [{"row": "r", "z": [[1.0] * 6], "z_mean": [1.0] * 6, "sources": out},
            {"row": "r", "z": [[1.0] * 6], "z_mean": [1.0] * 6, "sources": {"yaw": {"z_rms": [0.0] * 6}}}]
    (row,) = bench.summarise_resample(recs)
    assert list(row["sources_z_rms"]) == ["yaw"]  # centre is not in every site's record
    assert row["sources_z_rms"]["yaw"][0] == pytest.approx(np.sqrt(2.0))
