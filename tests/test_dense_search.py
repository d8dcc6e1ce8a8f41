"""Dense scenes (issue 29): the search's gate on crowded frames (``hypotheses.informative_view``,
``bringup._gated``) and the crowded-site verdict given the share of 2D boxes the pose matches."""

from __future__ import annotations

import numpy as np

from xcalib.calib import CalibConfig
from xcalib.calib.bringup import GATE_2D, _gated
from xcalib.calib.decision import CROWDED_EXPLAINED, crowded_check
from xcalib.calib.hypotheses import informative_view


def _frames(n2: int, n3: int, n_frames: int = 2):
    from _dense_frames import random_box_frames

    return random_box_frames(n2, n3, n_frames)


def test_informative_view_keeps_the_largest_well_separated_2d_boxes_and_every_3d_box():
    from dataclasses import replace

    fr = _frames(8, 90)[0]
    W, H = fr.size
    b2 = np.array([[0.0, 100, 600, 500],  # the largest, truncated at the left edge
                   [800, 100, 1300, 500],  # large, but covered by the next one for more than a quarter
                   [900, 150, 1200, 450],
                   [100, 700, 300, 900], [400, 700, 550, 850], [700, 700, 800, 800],  # separated, 200/150/100 px
                   [1500, 100, 1520, 120], [1600, 100, 1610, 110]])  # separated, small
    fr = replace(fr, boxes2d=b2, idx2d=np.arange(10, 18))
    assert W > 1620 and H > 900
    view, rows = informative_view(fr, 4)
    assert rows.tolist() == [3, 4, 5, 6] and view.n3 == fr.n3
    np.testing.assert_array_equal(view.boxes2d, b2[rows])
    np.testing.assert_array_equal(view.idx2d, fr.idx2d[rows])
    _, rows = informative_view(fr, 7)  # too few separated ones: the largest others fill up
    assert rows.tolist() == [0, 1, 3, 4, 5, 6, 7]
    same, all_rows = informative_view(fr, 100)
    assert same is fr and all_rows.tolist() == list(range(fr.n2))


def test_only_crowded_frames_are_gated():
    cfg = CalibConfig()
    quiet, busy = _frames(12, 30, 1)[0], _frames(60, 120, 1)[0]
    assert quiet.n2 * quiet.n3 <= 2 * cfg.max_candidates < busy.n2 * busy.n3
    sims = [np.zeros((quiet.n2, quiet.n3)), np.arange(busy.n2 * busy.n3, dtype=float).reshape(busy.n2, busy.n3)]
    views, vs = _gated([quiet, busy], sims, cfg.max_candidates)
    assert views[0] is quiet and vs[0] is sims[0]
    assert views[1].n2 == GATE_2D and views[1].n3 == busy.n3
    rows = np.searchsorted(busy.idx2d, views[1].idx2d)
    np.testing.assert_array_equal(vs[1], sims[1][rows])


def test_a_crowded_site_is_refused_unless_the_pose_matches_most_2d_boxes():
    cf = _frames(32, 270, 3)
    assert crowded_check(cf, CalibConfig()).code == "crowded"
    assert crowded_check(cf, CalibConfig(), explained=CROWDED_EXPLAINED - 0.1).code == "crowded"
    assert crowded_check(cf, CalibConfig(), explained=CROWDED_EXPLAINED) is None
    assert crowded_check(_frames(10, 20, 3), CalibConfig()) is None  # not crowded


def test_gated_frames_views_only_crowded_frames_and_none_when_none_is():
    from xcalib.calib.bringup import gated_frames

    cfg = CalibConfig()
    quiet, busy = _frames(12, 30, 1)[0], _frames(60, 120, 1)[0]
    assert gated_frames([quiet, quiet], cfg.max_candidates) is None  # nothing crowded: the frames as they are
    views = gated_frames([quiet, busy], cfg.max_candidates)
    assert views[0] is quiet
    assert views[1].n2 == GATE_2D and views[1].n3 == busy.n3
    np.testing.assert_array_equal(views[1].boxes3d, busy.boxes3d)


def test_a_crowded_frame_spends_its_azimuth_windows_of_the_search_budget():
    from xcalib.calib.bringup import search_cost

    assert search_cost(6, crowded=True) == 6
    assert search_cost(6, crowded=False) == 1  # a frame that is not crowded costs one, split or not
    assert search_cost(0, crowded=True) == 1


def test_the_bring_up_searches_crowded_frames_until_the_budget_is_spent(monkeypatch):
    import xcalib.calib.bringup as bu
    from xcalib.calib.hypotheses import TripleDraw

    cf = _frames(60, 120, 4) + _frames(12, 30, 2)  # four crowded frames, then two quiet ones
    seen = []

    def fake(frs, intr, **kw):
        if len(frs) == 1:  # the per-frame searches (pooled groups may follow)
            seen.append(next(i for i, f in enumerate(cf) if f.key == frs[0].key and f.n3 == frs[0].n3))
        return TripleDraw(None, [None] * (6 if frs[0].n3 == 120 else 1))

    monkeypatch.setattr(bu, "draw_triples", fake)
    bu.pose_hypotheses(cf, None, CalibConfig(max_hyp_frames=10))
    assert seen == [0, 1, 4, 5]  # 6 + 6 windows spend the 10; quiet frames are searched whatever the budget
    seen.clear()
    bu.pose_hypotheses(cf[4:], None, CalibConfig(max_hyp_frames=10))
    assert seen == [4, 5]  # not crowded: every frame, as before


def test_gated_matches_keep_the_matches_on_the_gate_s_boxes_renumbered():
    from xcalib.calib.bringup import gated_matches

    cfg = CalibConfig()
    quiet, busy = _frames(12, 30, 1)[0], _frames(60, 120, 1)[0]
    p_quiet = np.array([[0, 1], [3, 2]])
    p_busy = np.column_stack([np.arange(0, 60, 2), np.arange(30)])  # every other 2D box matched
    assert gated_matches([quiet], [p_quiet], cfg.max_candidates) is None
    frames, pairs = gated_matches([quiet, busy], [p_quiet, p_busy], cfg.max_candidates)
    assert frames[0] is quiet and pairs[0] is p_quiet
    view = frames[1]
    _, rows = informative_view(busy, GATE_2D)
    want = p_busy[np.isin(p_busy[:, 0], rows)]
    assert len(pairs[1]) == len(want) > 0
    # the renumbered rows name the same 2D boxes, the 3D columns are unchanged
    np.testing.assert_array_equal(view.boxes2d[pairs[1][:, 0]], busy.boxes2d[want[:, 0]])
    np.testing.assert_array_equal(pairs[1][:, 1], want[:, 1])


def test_the_misfit_searches_see_a_crowded_site_through_the_gate_and_compare_there():
    from xcalib.calib.api import _search_view
    from xcalib.calib.context import FitContext
    from xcalib.calib.pose import Pose
    from xcalib.calib.refine import match_all, pair_metrics
    from xcalib.data.synth import sample_site

    site = sample_site(1)
    cfg = CalibConfig()
    quiet = _frames(12, 30, 2)
    pose = Pose(site.T_cam_lidar[:3, :3], site.T_cam_lidar[:3, 3])
    pairs = match_all(quiet, site.intrinsics, pose.R, pose.t)
    assert _search_view(FitContext(quiet, pairs, site.intrinsics, pose), cfg) is None  # not crowded: every box
    busy = _frames(60, 120, 2)
    pairs = [np.column_stack([np.arange(0, 60, 3), np.arange(20)]) for _ in busy]
    view = _search_view(FitContext(busy, pairs, site.intrinsics, pose), cfg)
    assert [f.n2 for f in view.frames] == [GATE_2D, GATE_2D]
    _, iou = pair_metrics(view.frames, site.intrinsics, pose.R, pose.t, view.pairs)
    assert view.score == float(np.sum(iou))
    assert sum(len(p) for p in view.pairs) < sum(len(p) for p in pairs)
