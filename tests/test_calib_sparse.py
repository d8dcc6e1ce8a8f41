"""calibrate() on sparse recordings (1-2 objects per frame): the static rig lets frames pool,
so the pose is found when the objects cover enough places off one line, and refused otherwise."""

from __future__ import annotations

import numpy as np
from test_calib_support import INTR, W, H, sim_frames, sim_rig

from xcalib.calib.api import calibrate
from xcalib.calib.decision import matched_places
from xcalib.calib.inputs import prepare_frames
from xcalib.geometry import box7_corners, project_points
from xcalib.types import Frame


def _true_pairs(frames) -> list[int]:
    return [int(np.asarray(f.match_matrix).any(1).sum()) for f in frames]


def test_one_or_two_objects_per_frame_calibrate_together():
    # 1 px noise, 10 % missed and 5 % false 2D boxes, 2 LiDAR-only boxes per frame
    frames, T = sim_frames(seed=15, n_frames=16, n_objects=(1, 3))
    assert max(_true_pairs(frames)) <= 2 and sum(_true_pairs(frames)) >= 16
    res = calibrate(frames, INTR)
    assert res.success, res.message
    rot, trans = res.pose_error(T)
    assert rot < 0.2 and trans < 0.1
    assert res.diagnostics.max_pairs_per_frame <= 2 and res.diagnostics.matched_places >= 10
    # the pseudo-labels are the true pairs
    hits = [bool(f.match_matrix[i, j]) for f, p in zip(frames, res.pairs) for i, j in p]
    assert len(hits) >= 14 and np.mean(hits) >= 0.9


def test_one_object_per_frame_at_few_places_fails_with_a_message():
    frames, T = sim_frames(seed=8, n_frames=14, n_objects=(1, 2), miss=0.0, false_pos=0.0, extra_3d=0)
    assert max(f.num_2d for f in frames) == 1
    few = calibrate(frames[:3], INTR)  # three places: P3P-ambiguous, and nothing to check it on
    assert not few.success and "not identifiable" in few.message and "distinct place" in few.message
    ten = calibrate(frames[:10], INTR)  # too few matches to check the pose on each half of the frames
    assert not ten.success and "each half" in ten.message
    res = calibrate(frames, INTR)  # fourteen places spread over the view: identifiable
    assert res.success, res.message
    assert res.pose_error(T)[0] < 0.2 and res.pose_error(T)[1] < 0.1


def _path_frames(seed: int, n_frames: int):
    """One car driving along a straight road across the view (one object per frame), plus two
    LiDAR-only boxes at random places behind the camera and one false 2D box per frame, so that
    neither all 3D nor all 2D boxes are on one line. The truth [4,4] is returned too."""
    rng = np.random.default_rng(seed)
    T_cw, T_lw, yaw = sim_rig(rng)
    T_cl = T_cw @ np.linalg.inv(T_lw)
    ahead, across = np.array([np.cos(yaw), np.sin(yaw), 0]), np.array([-np.sin(yaw), np.cos(yaw), 0])
    frames = []
    for k, s in enumerate(np.linspace(-12, 12, n_frames)):
        car = np.r_[25 * ahead + s * across + [0, 0, 0.75], 4.5, 1.8, 1.5, yaw + np.pi / 2]
        ang = yaw + np.pi + rng.uniform(-1, 1, 2)
        d = rng.uniform(8, 30, 2)
        other = np.column_stack([d * np.cos(ang), d * np.sin(ang), np.full(2, 0.75), np.tile([4.5, 1.8, 1.5], (2, 1)),
                                 rng.uniform(-np.pi, np.pi, 2)])
        box_w = np.vstack([car, other])
        ctr_l = box_w[:, :3] @ T_lw[:3, :3].T + T_lw[:3, 3]
        head = np.stack([np.cos(box_w[:, 6]), np.sin(box_w[:, 6]), 0 * box_w[:, 6]], 1) @ T_lw[:3, :3].T
        box_l = np.column_stack([ctr_l, box_w[:, 3:6], np.arctan2(head[:, 1], head[:, 0])])
        uv, _ = project_points(box7_corners(box_l[:1]).reshape(-1, 3), INTR, T_cl[:3, :3], T_cl[:3, 3])
        rect = np.clip([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()], 0, [W, H, W, H])
        fx, fy = rng.uniform(0, W - 120), rng.uniform(H * 0.3, H - 80)  # one false 2D box
        b2 = np.vstack([rect + rng.normal(0, 1.0, 4), [fx, fy, fx + rng.uniform(20, 120), fy + rng.uniform(20, 80)]])
        frames.append(Frame(image=np.zeros((1, 1, 3), np.uint8), point_cloud=np.zeros((0, 3), np.float32),
                            bboxes_2d=b2, bboxes_3d=box_l, camera_name="cam0", frame_key=f"{k:04d}",
                            match_matrix=np.array([[True, False, False], [False, False, False]]), intrinsics=INTR, extrinsics=T_cl,
                            meta={"image_size": (W, H)}))
    return frames, T_cl


def test_one_object_on_one_path_fails_with_a_message():
    frames, T = _path_frames(seed=4, n_frames=20)
    res = calibrate(frames, INTR)
    assert not res.success and "not identifiable" in res.message
    # even seeded with the true pose (20 matches, every one on the car's path): the roll about
    # the path is free, so it is refused
    seeded = calibrate(frames, INTR, prior=T)
    assert not seeded.success and "off one line" in seeded.message
    assert seeded.diagnostics.matched_places >= 15 and seeded.diagnostics.matched_places_off_line < 2


def test_matched_places_merge_repeats_but_not_a_slow_track():
    frames, _ = _path_frames(seed=4, n_frames=20)
    cf, _, _ = prepare_frames(frames, INTR)
    one = [np.array([[0, 0]])] * len(cf)  # the car, every frame: 24 m of road, 1.26 m per frame
    places, off = matched_places(cf, one)
    assert len(places) == 20 and np.all(off < 0.3)
    parked = [np.array([[0, 0]])] + [np.zeros((0, 2), np.int64)] * (len(cf) - 1)
    places, _ = matched_places(cf + cf[:1], parked + [np.array([[0, 0]])])  # the same box twice
    assert len(places) == 1


def _few_pairs_frame(seed: int, k: int):
    """One synthetic roadside frame keeping k objects seen by both sensors (and the false 2D
    boxes), with the generator's default 3D-detection noise (0.1 m centre, 3 % size, 2 deg yaw)."""
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(seed, preset="roadside")
    for f in generate_frames(site, 60, seed=seed, render_images=False, lidar=False, miss_rate_2d=0.1,
                             false_positive_rate_2d=0.05, box_noise_px=1.0)[::10]:
        mm = np.asarray(f.match_matrix, bool)
        rows = np.flatnonzero(mm.any(1))
        if len(rows) >= k:
            k3 = np.sort(mm[rows[:k]].argmax(1))
            k2 = np.sort(np.r_[rows[:k], np.flatnonzero(np.asarray(f.meta["ids_2d"]) < 0)])
            return Frame(**{**f.__dict__, "bboxes_2d": f.bboxes_2d[k2], "bboxes_3d": f.bboxes_3d[k3],
                            "match_matrix": mm[np.ix_(k2, k3)]}), site.T_cam_lidar
    raise AssertionError("no frame with enough objects")


def test_few_pairs_with_noisy_3d_boxes_are_refused_not_wrong():
    # 5 pairs, no frame-halves check: the Jacobian (and the error model, which cannot be fitted
    # to 5 pairs) believe the pose to 0.23 deg / 0.12 m, but it is 1.2 m off; leaving one pair
    # out at a time shows the spread, and the pose is refused with the reason
    frame, T = _few_pairs_frame(seed=14, k=5)
    res = calibrate([frame], frame.intrinsics)
    assert not res.success and res.n_pairs == 5
    assert "too few matched pairs to verify the pose" in res.message and "at least 7 more matched pairs" in res.message
    assert res.translation is None  # a failed result has no pose; the refused one is kept for diagnostics
    assert np.linalg.norm(T[:3, 3] - np.asarray(res.diagnostics.refused_T)[:3, 3]) > 0.5  # and it is wrong
    u = res.diagnostics.uncertainty
    jac, occl = np.asarray(u.jacobian), np.asarray(u.occlusion)
    assert np.linalg.norm(np.hypot(jac[3:], occl[3:])) < 0.25  # the Jacobian alone would accept it
    assert u.halves is None and np.linalg.norm(u.jackknife[3:]) > 0.5
