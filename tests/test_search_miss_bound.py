"""Issue 29: the second-pose search skips its pooled groups only where the search over every
leftover frame already finds a pose that a flag needs with probability >= 99 %
(``hypotheses.triple_miss_bound``, a RANSAC-style miss bound). The bound is checked here against the
search's own sampling (``_third_members``) on planted inlier sets, and the skip against the search
with the pooled groups on a crafted sparse site where the second pose must be found."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.calib.hypotheses import (MISS_STATS_MAX_CANDIDATES, TripleSearch, _third_members, draw_triples,
                                     triple_miss_bound)
from xcalib.calib.misfit import SECOND_POSE_MIN_PAIRS, SECOND_POSE_SHARE, second_pose_support


def _planted(seed: int, n: int, k: int, p: float):
    """A symmetric consistency matrix of n candidates with a planted clique (inliers 0..k-1)."""
    r = np.random.default_rng(seed)
    C = np.triu(r.random((n, n)) < p, 1)
    C[:k, :k] = np.triu(np.ones((k, k), dtype=bool), 1)
    Cs = C | C.T
    F = Cs.astype(np.float64)
    common = -np.sort(-(F @ F)[C])
    return C, Cs, common


@pytest.mark.parametrize("seed,n,k,p,m", [(0, 40, 7, 0.35, 40), (1, 60, 8, 0.3, 60), (2, 50, 6, 0.5, 120),
                                          (3, 30, 6, 0.4, 10_000)])
def test_miss_bound_holds_for_the_search_s_own_sampling(seed, n, k, p, m):
    """Over 300 seeded repetitions of the draw (pairs of pairs uniformly without replacement, two
    third members by ``_third_members``), the share of draws with no all-inlier triple stays below
    the bound (plus 3 sigma of its sampling noise); the last case draws every pair (exhaustive)."""
    C, Cs, common = _planted(seed, n, k, p)
    pq_all = np.argwhere(C)
    m = min(m, len(pq_all))
    bound = triple_miss_bound(k, (len(pq_all), m, common))
    assert 0.0 <= bound < 1.0
    inl = np.zeros(n, dtype=bool)
    inl[:k] = True
    reps, missed = 300, 0
    r = np.random.default_rng(100 + seed)
    for _ in range(reps):
        pq = pq_all if m >= len(pq_all) else pq_all[r.choice(len(pq_all), m, replace=False)]
        tri = _third_members(Cs, pq, r, None)
        missed += not np.any(inl[tri].all(1))
    assert missed / reps <= bound + 3 * np.sqrt(max(bound * (1 - bound), 1e-4) / reps) + 1e-9
    if m < len(pq_all):
        assert bound > 0.02  # the case tests something: the bound is not trivially near 0


def test_miss_bound_is_one_where_it_cannot_bound():
    common = np.array([30.0, 20.0, 10.0])
    assert triple_miss_bound(2, (100, 50, common)) == 1.0  # fewer than 3 inliers: no triple
    assert triple_miss_bound(10, (100, 50, None)) == 1.0  # no counts
    assert triple_miss_bound(10, (100, 50, common)) == 1.0  # counts of fewer pairs than C(10,2)
    assert triple_miss_bound(10, (20, 50, np.full(20, 30.0))) == 1.0  # fewer pairs than inlier pairs
    # more draws, more support: a smaller bound
    big = np.full(2000, 60.0)
    assert triple_miss_bound(12, (5000, 2000, big)) < triple_miss_bound(12, (5000, 500, big)) < 1.0
    assert triple_miss_bound(20, (5000, 500, big)) < triple_miss_bound(12, (5000, 500, big))


@pytest.mark.parametrize("best", [None, 10.0, 49.9, 50.0, 97.3, 300.0])
def test_second_pose_support_is_the_fewest_matches_a_flag_needs(best):
    k = second_pose_support(best)
    assert k >= SECOND_POSE_MIN_PAIRS
    if best is not None:  # a score (sum of IoUs <= 1 over its matches) of k-1 matches cannot reach the share
        assert k - 1 < SECOND_POSE_SHARE * best or k == SECOND_POSE_MIN_PAIRS
        assert k >= SECOND_POSE_SHARE * best - 1e-9


def _sparse_frames(seed: int = 3, n_frames: int = 2):
    from xcalib.calib.inputs import prepare_frames
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(seed, preset="roadside")
    frames = generate_frames(site, n_frames, seed=seed, render_images=False, lidar=False)
    return prepare_frames(frames, site.intrinsics)[0], site.intrinsics


def test_miss_stats_change_no_draw():
    """``TripleSearch.miss_stats`` only counts: the drawn triples are the same bits, and the counts
    (windows of at most ``MISS_STATS_MAX_CANDIDATES`` candidates) are the largest numbers of
    partners consistent with both pairs of a pair, descending."""
    cf, intr = _sparse_frames()
    cf = cf[:2]  # two frames of a static rig, searched together (as a pooled group)
    a = draw_triples(cf, intr, rng=np.random.default_rng(0), search=TripleSearch(max_triples=4000))
    b = draw_triples(cf, intr, rng=np.random.default_rng(0), search=TripleSearch(max_triples=4000, miss_stats=True))
    assert len(a.windows) == len(b.windows) == len(b.pair_stats) > 0
    counted = 0
    for (ia, ta), (ib, tb), sa, sb in zip(a.windows, b.windows, a.pair_stats, b.pair_stats):
        assert ia.tobytes() == ib.tobytes() and ta.tobytes() == tb.tobytes()
        assert sa[:2] == sb[:2] and sa[2] is None
        if len(ia) <= MISS_STATS_MAX_CANDIDATES:
            common = sb[2]
            assert len(common) > 0 and np.all(np.diff(common) <= 0) and np.all(common == np.round(common))
            assert common[0] <= len(ia) - 2
            counted += 1
        else:
            assert sb[2] is None
    assert counted > 0


def _leftover_site():
    """16 frames of a synthetic site with 2 of each frame's 2D boxes (a second camera's few boxes
    among the leftovers: a sparse scene, searched over every frame and in pooled groups) and every
    3D box; the site's pose and intrinsics."""
    from dataclasses import replace

    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.pose import Pose
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(1, preset="roadside")
    cf = prepare_frames(generate_frames(site, 16, seed=1, render_images=False, lidar=False), site.intrinsics)[0]
    r = np.random.default_rng(0)
    left = []
    for f in cf:
        keep = np.sort(r.choice(f.n2, min(2, f.n2), replace=False))
        left.append(replace(f, boxes2d=f.boxes2d[keep], idx2d=f.idx2d[keep]))
    T = np.asarray(site.T_cam_lidar)
    return left, site.intrinsics, Pose(T[:3, :3], T[:3, 3])


def test_the_second_pose_is_found_and_flagged_as_with_the_pooled_groups(monkeypatch):
    """A crafted sparse leftover set where the second pose must be found: with the support a flag
    needs (best score 100: 20 matches) the pooled group is skipped (miss bound <= 1 %), and the
    search finds the second camera and flags it as the search with every group does."""
    from xcalib.calib import api, bringup
    from xcalib.calib.config import CalibConfig
    from xcalib.calib.cost import Occlusion
    from xcalib.calib.misfit import second_pose_check
    from xcalib.calib.pose import Pose
    from xcalib.geometry.rotations import rotvec_to_matrix

    left, intr, truth = _leftover_site()
    assert sum(f.n2 for f in left) <= bringup.SPARSE_SCENE_MAX_2D
    main = Pose(rotvec_to_matrix(np.array([0.0, 0.6, 0.0])) @ truth.R, truth.t + np.array([0.5, 0.0, 0.0]))
    pairs = [np.zeros((0, 2), dtype=np.int64) for _ in left]
    seen = []
    real = bringup.pose_hypotheses

    def spy(*a, **k):
        out = real(*a, **k)
        seen.append((k.get("support"), out.pooled_skipped))
        return out

    monkeypatch.setattr(api, "pose_hypotheses", spy)
    cfg = CalibConfig(workers=1)
    fast = api._second_pose(left, pairs, intr, main, cfg, Occlusion(), 100.0)
    monkeypatch.setattr(api, "second_pose_support", lambda best: None)  # the search with every group
    full = api._second_pose(left, pairs, intr, main, cfg, Occlusion(), 100.0)
    assert seen == [(20, 1), (None, 0)]
    for score, n2, dist, admissible, screened in (fast, full):
        assert screened is None and admissible and n2 >= 20
        assert dist[0] > 20.0  # (from the main pose, ~34 deg away)
    chk_fast = second_pose_check(100.0, 140, *fast[:4])[0]
    chk_full = second_pose_check(100.0, 140, *full[:4])[0]
    assert chk_fast.flagged and chk_full.flagged
