"""The dense-scene gate (``xcalib.calib.densegate``, issue 29): which 2D boxes are in front, which 3D
boxes the LiDAR sees unoccluded, and the views built from them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from xcalib.calib.densegate import FRONT_MIN, front_rows, front_view, lidar_unoccluded, lidar_view
from xcalib.geometry.boxes import box7_corners


def test_a_box_covered_by_one_reaching_lower_is_hidden_the_lower_one_is_in_front():
    size = (1000, 800)
    b = np.array([[100.0, 100, 300, 300],   # behind: the next box covers half of it and reaches lower
                  [200.0, 150, 400, 400],   # in front (its bottom is the lowest of the two)
                  [600.0, 100, 700, 200],   # alone
                  [0.0, 500, 100, 600],     # truncated at the left edge
                  [600.0, 200, 700, 300]])  # touches box 2 along a row only, and reaches lower: in front
    keep = front_rows(b, size)
    assert keep.tolist() == [False, True, True, False, True]
    # box 2 is covered by box 4 only along its bottom row (zero area): still in front
    assert keep[2]


def test_front_view_keeps_front_boxes_largest_first_topped_up_to_the_minimum():
    from xcalib.calib.inputs import CalibFrame

    rng = np.random.default_rng(0)
    n = 40
    x, y = rng.uniform(10, 1800, n), rng.uniform(10, 900, n)
    w, h = rng.uniform(20, 80, n), rng.uniform(20, 80, n)
    b2 = np.column_stack([x, y, x + w, y + h])
    b3 = np.column_stack([rng.uniform(-40, 40, (5, 2)), np.zeros(5), np.tile([4.5, 1.9, 1.6], (5, 1)), np.zeros(5)])
    fr = CalibFrame(key="0", camera="", boxes2d=b2, boxes3d=b3, corners=box7_corners(b3), idx2d=np.arange(n) + 7,
                    idx3d=np.arange(5), size=(1920, 1080))
    front = front_rows(b2, fr.size)
    view, rows = front_view(fr, 24)
    assert view.n2 == min(max(int(front.sum()), FRONT_MIN), 24) == len(rows)
    assert np.all(np.diff(rows) > 0)
    np.testing.assert_array_equal(view.boxes2d, b2[rows])
    np.testing.assert_array_equal(view.idx2d, fr.idx2d[rows])
    kept_front = front[rows]
    area = (b2[:, 2] - b2[:, 0]) * (b2[:, 3] - b2[:, 1])
    if kept_front.sum() < front.sum():  # capped: the largest front boxes
        assert area[rows][kept_front].min() >= area[front & ~np.isin(np.arange(n), rows)].max()
    same, all_rows = front_view(fr, n)
    assert same is fr and all_rows.tolist() == list(range(n))


def _box(x: float, y: float, z: float = 0.0, l: float = 4.5, w: float = 1.9, h: float = 1.6) -> list[float]:
    return [x, y, z, l, w, h, 0.0]


def test_a_3d_box_behind_a_nearer_one_from_the_lidar_is_hidden_also_across_the_back():
    b = np.array([_box(10, 0), _box(25, 0.3),      # the far one is behind the near one
                  _box(0, 20), _box(-30, 0.2),      # alone to the left; alone behind the LiDAR
                  _box(-15, -0.1)])                 # behind the LiDAR, nearer than the one at -30 (az ~ +-pi)
    keep = lidar_unoccluded(box7_corners(b), b[:, :3])
    assert keep.tolist() == [True, False, True, False, True]
    assert lidar_unoccluded(np.zeros((0, 8, 3)), np.zeros((0, 3))).shape == (0,)


def test_lidar_view_keeps_the_unoccluded_boxes_with_their_per_box_fields():
    from xcalib.calib.inputs import CalibFrame

    b = np.array([_box(10, 0), _box(25, 0.3), _box(0, 20), _box(0, -20)])
    c = box7_corners(b)
    fr = CalibFrame(key="0", camera="", boxes2d=np.zeros((0, 4)), boxes3d=b, corners=c, idx2d=np.zeros(0, np.int64),
                    idx3d=np.arange(4) + 3, size=(1920, 1080), box_corners=c, from_points=np.array([0, 1, 0, 1], bool),
                    outline_sigma_m=np.arange(4.0))
    view = lidar_view(fr)
    assert view.idx3d.tolist() == [3, 5, 6]
    np.testing.assert_array_equal(view.boxes3d, b[[0, 2, 3]])
    np.testing.assert_array_equal(view.corners, c[[0, 2, 3]])
    np.testing.assert_array_equal(view.box_corners, c[[0, 2, 3]])
    assert view.from_points.tolist() == [False, False, True] and view.outline_sigma_m.tolist() == [0.0, 2.0, 3.0]
    assert view.yaw_ambiguous is None
    few = replace(fr, boxes3d=b[:2], corners=c[:2], idx3d=fr.idx3d[:2], box_corners=None, from_points=None,
                  outline_sigma_m=None)
    assert lidar_view(few) is few  # fewer than 3 kept: the frame itself


def _site_frames(n2: int, n3: int, n_frames: int = 1):
    """CalibFrames of a synthetic site with ``n2`` random 2D and ``n3`` random 3D boxes each."""
    from _dense_frames import random_box_frames

    return random_box_frames(n2, n3, n_frames)


def test_unoccluded_frames_cut_only_crowded_frames_and_are_none_when_none_is():
    from xcalib.calib import CalibConfig
    from xcalib.calib.bringup import GATE_2D, unoccluded_frames

    mc = CalibConfig().max_candidates
    quiet, busy = _site_frames(12, 30)[0], _site_frames(60, 120)[0]
    assert quiet.n2 * quiet.n3 <= 2 * mc < busy.n2 * busy.n3
    assert unoccluded_frames([quiet, quiet], mc) is None
    views = unoccluded_frames([quiet, busy], mc)
    assert views[0] is quiet
    front, _ = front_view(busy, GATE_2D)
    np.testing.assert_array_equal(views[1].boxes2d, front.boxes2d)
    keep = lidar_unoccluded(busy.corners, busy.boxes3d[:, :3])
    assert 3 <= views[1].n3 == int(keep.sum()) < busy.n3
    np.testing.assert_array_equal(views[1].idx3d, busy.idx3d[keep])


def test_the_full_refinement_keeps_the_better_scoring_of_the_direct_and_the_staged_fit(monkeypatch):
    """``api._full_refine``: without a view the direct refinement as before; with one, the
    refinement from the view's fit replaces it only where it scores higher on every box."""
    import xcalib.calib.api as api
    from xcalib.calib.refine import RefineResult

    calls = []

    def fake_refine(frames, intr, R, t, *, options, occlusion):
        calls.append(frames)
        return RefineResult(R=np.asarray(R), t=np.zeros(3) + len(calls), pairs=[], cost=0.0, n_iter=1)

    scores = {}
    monkeypatch.setattr(api, "refine_pose", fake_refine)
    monkeypatch.setattr(api, "_score", lambda frames, intr, rr: scores[float(rr.t[0])])
    R, t = np.eye(3), np.zeros(3)
    scores.update({1.0: 5.0})
    s, rr = api._full_refine(("all", None, R, t, None, None))
    assert (s, float(rr.t[0])) == (5.0, 1.0) and calls == ["all"]
    for staged, want in ((9.0, (9.0, 3.0)), (4.0, (5.0, 1.0)), (5.0, (5.0, 1.0))):  # ties keep the direct fit
        calls.clear()
        scores.update({1.0: 5.0, 3.0: staged})
        s, rr = api._full_refine(("all", None, R, t, None, "view"))
        assert calls == ["all", "view", "all"] and (s, float(rr.t[0])) == want
