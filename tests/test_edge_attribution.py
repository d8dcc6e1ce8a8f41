"""``scripts/edge_attribution.py`` (issue 25, session 15): the split of a pose's Gauss-Newton step over
groups of box-edge residuals. Synthetic linear problems (no calibration, no real data)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _mod():
    spec = importlib.util.spec_from_file_location("edge_attribution", ROOT / "scripts" / "edge_attribution.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_pulls_of_a_partition_sum_to_the_step_and_shares_to_one():
    m = _mod()
    rng = np.random.default_rng(3)
    J = rng.normal(size=(80, 6))
    r = rng.normal(size=80)
    a = np.zeros(80, bool)
    a[:30] = True
    out = m.split_pull(r, J, {"a": a, "b": ~a}, f_scale=1.0)
    pa, pb = out["groups"]["a"]["pull"], out["groups"]["b"]["pull"]
    np.testing.assert_allclose(pa + pb, out["step"], atol=1e-12)
    assert abs(out["groups"]["a"]["share"] + out["groups"]["b"]["share"] - 1.0) < 1e-9
    assert out["groups"]["a"]["n"] == 30


def test_a_biased_group_carries_the_error():
    """Rows of one group offset by a constant bias: that group's share is ~1, the unbiased rest ~0."""
    m = _mod()
    rng = np.random.default_rng(4)
    J = rng.normal(size=(400, 6))
    r = 0.01 * rng.normal(size=400)
    biased = np.zeros(400, bool)
    biased[::4] = True
    r[biased] += 0.5 * J[biased, 0]  # they pull along the first axis
    out = m.split_pull(r, J, {"biased": biased, "rest": ~biased}, f_scale=10.0)
    assert out["groups"]["biased"]["share"] > 0.9
    assert abs(out["groups"]["rest"]["share"]) < 0.1
    assert out["step"][0] < -0.05  # the fit moves to take up the bias


def test_edge_masks_partition_the_edges_by_kind():
    m = _mod()
    obs = np.array([[0.0, 10, 50, 60], [100, 100, 180, 160], [300, 50, 400, 200]])
    r = np.array([[0.0, 0, 0, 0], [-3.0, 0, 0, 0], [0.0, 0, 0, 0]])  # pair 1's left edge 3 sigma inside
    cens = np.zeros((3, 4), bool)
    cens[2, 3] = True
    masks = m.edge_masks(obs, (400, 300), r, cens, 1.5, scores=np.array([0.9, 0.4, 0.6]), objects=np.array([0, 1, 1]))
    kinds = sum(masks[k].astype(int) for k in ("border", "censored", "shaped", "free"))
    assert np.all(kinds == 1)  # every edge in exactly one kind
    assert masks["border"][0, 0] and masks["border"][2, 2]
    assert masks["shaped"][1, 0] and masks["censored"][2, 3]
    assert masks["object 1"][1:].all() and not masks["object 1"][0].any()
    assert masks["score 0.00-0.50"][1].all() and masks["score 0.85-inf"][0].all()


def test_attribution_of_a_clean_realism_site_rebuilds_the_calibration():
    """End to end on realism ``clean`` site 0 with 8 frames: the rebuilt cost's refit from the truth
    lands where the calibration did (its own minimum), and the edge kinds partition every edge."""
    m = _mod()
    from xcalib.calib.pose import Pose
    from xcalib.data.synth.realism import make_realism_case

    case = make_realism_case("clean", 0, 8)
    rec = m.attribute(list(case.frames), case.intrinsics_given, Pose.parse(case.T_cam_lidar))
    assert rec["n_pairs"] >= 12
    g = rec["groups"]
    assert sum(g[k]["n"] for k in ("border", "censored", "shaped", "free")) == 4 * rec["n_pairs"]
    assert sum(g[k]["n"] for k in g if k.startswith("side ")) == 4 * rec["n_pairs"]
    assert abs(sum(g[k]["share"] for k in g if k.startswith("side ")) - 1.0) < 0.01
    assert np.allclose(rec["fit"], rec["error"], atol=0.02)  # the refit from the truth ends at the calibration's pose
    assert max(abs(v) for v in rec["error"]) < 0.3  # clean boxes: a close pose


def test_usage_without_arguments():
    assert _mod().main([]) == 2
