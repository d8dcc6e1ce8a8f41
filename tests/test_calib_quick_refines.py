"""Issue 29 (session 11): the candidates' quick refinements run in lockstep and a run that reaches
another's matches and pose goes on as that one; ``_centre_hits`` works in place.

* ``refine_pose`` is ``refine_start``, ``refine_step`` until done, ``refine_finish``, and a run
  advanced in lockstep with others gives what it gives alone;
* ``api._quick_refines`` leaves out exactly the runs ``_merged`` finds (a candidate that lands on
  another's matches at the same iteration within ``SAME_RUN``) and keeps every other run's result
  bit for bit (one and two workers: ``test_calib_parallel``'s whole calibration);
* ``_centre_hits`` counts what the written-out test counts (boxes behind the camera, on a box edge).
"""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.calib import api
from xcalib.calib.config import CalibConfig
from xcalib.calib.hypotheses import Hypotheses, _centre_hits
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import RefineOptions, refine_finish, refine_pose, refine_start, refine_step
from xcalib.calib.terms import CostSpec
from xcalib.data.synth import generate_frames, sample_site


@pytest.fixture(scope="module")
def site():
    s = sample_site(0, "roadside")
    frames = generate_frames(s, 6, seed=3, render_images=False, lidar=False, box_noise_px=1.0)
    cf, intr, problem = prepare_frames(frames, s.intrinsics)
    assert not problem
    return cf, intr, Pose.parse(s.T_cam_lidar)


def _same(a, b) -> bool:
    return (np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t) and a.n_iter == b.n_iter and a.history == b.history
            and all(np.array_equal(p, q) for p, q in zip(a.pairs, b.pairs)))


def test_refine_pose_is_its_steps(site):
    cf, intr, truth = site
    start = truth.moved(np.array([0.02, -0.015, 0.01]), np.array([0.3, -0.2, 0.1]))
    for opts in (RefineOptions(), api.QUICK, RefineOptions(max_outer=1)):
        whole = refine_pose(cf, intr, start.R, start.t, options=opts)
        run = refine_start(cf, intr, start.R, start.t, opts)
        steps = 0
        while not run.done:
            refine_step(cf, intr, run, opts)
            steps += 1
        assert steps == len(whole.history) >= 1
        assert _same(whole, refine_finish(cf, intr, run, opts))


def test_lockstep_merges_a_candidate_on_another_and_keeps_the_rest(site):
    cf, intr, truth = site
    near = [truth.moved(np.array([0.01, 0.0, -0.005]), np.array([0.2, 0.0, 0.1])),
            truth.moved(np.array([0.0101, 0.0, -0.005]), np.array([0.2, 0.0, 0.1001])),  # lands on the first
            truth.moved(np.array([0.6, 0.3, 0.0]), np.array([3.0, 1.0, 0.0]))]  # far: a run of its own
    cand = Hypotheses(np.stack([p.R for p in near]), np.stack([p.t for p in near]), np.zeros(3),
                      np.zeros(3, dtype=np.int64))
    occl = CostSpec.from_config(CalibConfig())
    got = api._quick_refines(cf, intr, cand, occl, 1)
    alone = [refine_pose(cf, intr, p.R, p.t, options=api.QUICK, occlusion=occl) for p in near]
    # the second run met the first (same matches, within SAME_RUN) and is left out; the others are bit for bit
    assert len(got) == 2
    assert _same(got[0][1], alone[0]) and _same(got[1][1], alone[2])
    deg, m = Pose(alone[1].R, alone[1].t).error(Pose(alone[0].R, alone[0].t))
    assert deg < api.SAME_RUN[0] and m < api.SAME_RUN[1]  # what it left out is what it kept
    assert got[0][0] == pytest.approx(api._score(cf, intr, alone[1]), rel=1e-6)


def test_centre_hits_counts_what_the_test_says(site):
    cf, intr, truth = site
    fr = next(f for f in cf if f.n2 >= 3 and f.n3 >= 3)
    rng = np.random.default_rng(4)
    poses = [truth] + [truth.moved(rng.normal(0, 0.2, 3), rng.normal(0, 2.0, 3)) for _ in range(40)]
    poses.append(Pose(truth.R, truth.t + np.array([0.0, 0.0, -200.0])))  # every box behind the camera
    R, t = np.stack([p.R for p in poses]), np.stack([p.t for p in poses])
    # a 2D box with an edge exactly on a projected centre (inclusive) must count it
    Xc = fr.boxes3d[0, :3] @ truth.R.T + truth.t
    u0, v0 = Xc[0] / Xc[2] * intr.fx + intr.cx, Xc[1] / Xc[2] * intr.fy + intr.cy
    from dataclasses import replace

    edge = np.array([[u0, v0 - 5.0, u0 + 30.0, v0 + 5.0]])
    fr = replace(fr, boxes2d=np.concatenate([fr.boxes2d, edge]), idx2d=np.r_[fr.idx2d, -1])
    want = np.zeros(len(poses))
    for h, p in enumerate(poses):
        X = fr.boxes3d[:, :3] @ p.R.T + p.t
        ahead = X[:, 2] > 0.5
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = X[:, 0] / X[:, 2] * intr.fx + intr.cx, X[:, 1] / X[:, 2] * intr.fy + intr.cy
        for x0, y0, x1, y1 in fr.boxes2d:
            want[h] += np.any(ahead & (u >= x0) & (u <= x1) & (v >= y0) & (v <= y1))
    got = _centre_hits(fr, intr, R, t)
    np.testing.assert_array_equal(got, want)
    assert got[0] >= 1 and got[-1] == 0 and got.max() > got.min()
