"""Matching at a site the weights never saw: out-of-domain detection, geometric consensus
(``xcalib.calib.consensus``) and ``MatchResult.source``."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from xcalib.calib.consensus import ConsensusConfig, consensus_matches, pair_margins, searched_intrinsics
from xcalib.data.synth import generate_frames, sample_site
from xcalib.engine.domain import out_of_domain
from xcalib.engine.matcher import Matcher


def _pairs(mm: np.ndarray) -> set:
    return {(int(i), int(j)) for i, j in zip(*np.nonzero(mm))}


@pytest.fixture(scope="module")
def site2_frames():
    """Frames of synthetic site 2: the shipped 'synthetic' weights (site 0) score them out of domain."""
    return generate_frames(sample_site(2), 2, seed=100)


def test_out_of_domain_symptoms():
    good = np.full((5, 6), 0.02)
    good[np.arange(5), np.arange(5)] = 0.97
    assert out_of_domain(good) == ""
    assert "no confident pair" in out_of_domain(good * 0.3)
    collapsed = good.copy()
    collapsed[:, 2] = 0.99
    assert "collapsed" in out_of_domain(collapsed)
    assert "collapsed" in out_of_domain(2 * collapsed - 1, score_range=(-1.0, 1.0))  # cosine models
    assert out_of_domain(good[:1]) == ""  # one row: cannot tell


def test_consensus_recovers_the_true_matches(site2_frames):
    f = site2_frames[0]
    truth = _pairs(f.match_matrix)
    cm = consensus_matches(f, f.intrinsics)
    assert cm.found and cm.intrinsics_source == "given"
    got = {tuple(p) for p in cm.pairs.tolist()}
    assert len(got & truth) >= 0.9 * len(truth) and len(got - truth) <= 0.05 * len(got) + 1
    assert cm.iou.shape == f.match_matrix.shape and np.all((cm.iou >= 0) & (cm.iou <= 1))


def test_pair_margins_count_only_poses_that_pair_a_box_otherwise():
    best = np.array([[0, 5], [1, 6], [2, 7]])
    others = [(9.5, np.array([[0, 5], [1, 6]])),  # leaves box 2 unmatched: no alternative
              (8.0, np.array([[0, 5], [1, 7], [2, 6]])),  # pairs 1 and 2 otherwise
              (9.8, np.array([[3, 5]]))]  # 3D box 5 to another 2D box
    np.testing.assert_allclose(pair_margins(best, 10.0, others), [0.2, 2.0, 2.0])
    assert pair_margins(best, 10.0, []).tolist() == [10.0] * 3


def test_consensus_leaves_out_matches_another_pose_explains_as_well(site2_frames):
    f = site2_frames[0]
    cm = consensus_matches(f, f.intrinsics)
    assert len(cm.margin) == len(cm.pairs) and np.all(cm.margin >= cm.config.min_margin)
    strict = consensus_matches(f, f.intrinsics, ConsensusConfig(min_margin=1e6))  # nothing is that sure
    assert strict.found and len(strict.pairs) == 0 and len(strict.ambiguous) == len(cm.pairs) + len(cm.ambiguous)
    assert "left out" in strict.message


def test_consensus_without_intrinsics_searches_them(site2_frames):
    f = site2_frames[1]
    truth = _pairs(f.match_matrix)
    cm = consensus_matches(f.inputs())
    assert cm.found and cm.intrinsics_source == "searched"
    W, H = f.image_size
    assert (cm.intrinsics.cx, cm.intrinsics.cy) == (W / 2, H / 2)
    got = {tuple(p) for p in cm.pairs.tolist()}
    assert len(got & truth) >= 0.8 * len(truth) and len(got - truth) <= 0.1 * len(got) + 1


def test_consensus_refuses_too_few_boxes(site2_frames):
    f = site2_frames[0]
    i, j = np.nonzero(f.match_matrix)
    cm = consensus_matches((f.image, f.point_cloud, f.bboxes_2d[i[:2]], f.bboxes_3d[j[:2]]), f.intrinsics)
    assert not cm.found and len(cm.pairs) == 0 and cm.message
    with pytest.raises(ValueError, match="gate"):
        ConsensusConfig(gate=0.0)
    assert searched_intrinsics(1000, 500, 90.0).fx == pytest.approx(500.0)



def _match_frame_at(cm, frame):
    """``refine.match_frame`` at the consensus pose (caller numbering): pairs (rows of the frame's
    kept boxes mapped back) and the [K,M] IoU of every box with every projected outline."""
    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.refine import match_frame

    fr = prepare_frames([frame], cm.intrinsics)[0][0]
    pairs, _, rects = match_frame(fr, cm.intrinsics, cm.T_cam_lidar[:3, :3], cm.T_cam_lidar[:3, 3], gate_iou=cm.config.gate)
    from xcalib.calib.boxproj import iou_batched

    iou = np.zeros_like(cm.iou)
    iou[np.ix_(fr.idx2d, fr.idx3d)] = iou_batched(rects[None], fr.boxes2d)[0]
    return {(int(fr.idx2d[i]), int(fr.idx3d[j])) for i, j in pairs.tolist()}, iou


def test_consensus_pairs_and_iou_are_match_frame_at_its_pose(site2_frames):
    """The pairs (kept + ambiguous) and the IoU come from the refinement's last matching: they must
    be ``match_frame``'s at the reported pose, to the bit -- on a seeded frame and on a crafted scene of 3 objects and a false 2D box, also with a margin no pose reaches (every match
    ambiguous)."""
    f = site2_frames[0]
    i, j = np.nonzero(f.match_matrix)
    w, h = f.image_size
    false_box = np.array([[w * 0.45, h * 0.5, w * 0.45 + 40.0, h * 0.5 + 30.0]])
    crafted = (f.image, f.point_cloud, np.concatenate([np.asarray(f.bboxes_2d, dtype=np.float64)[i[:3]], false_box]),
               np.asarray(f.bboxes_3d)[j[:3]])
    n_ambiguous = 0
    for scene, cfg in (((f.image, f.point_cloud, f.bboxes_2d, f.bboxes_3d), None), (crafted, None),
                       (crafted, ConsensusConfig(min_margin=1e6))):
        cm = consensus_matches(scene, f.intrinsics, cfg)
        assert cm.found
        pairs, iou = _match_frame_at(cm, scene)
        got = {tuple(p) for p in cm.pairs.tolist()} | {tuple(p) for p in cm.ambiguous.tolist()}
        assert got == pairs and len(pairs) >= 3
        np.testing.assert_array_equal(cm.iou, iou)
        assert cm.score == pytest.approx(sum(iou[a, b] for a, b in pairs))
        n_ambiguous += len(cm.ambiguous)
    assert n_ambiguous >= 3

def test_shipped_weights_out_of_domain_fall_back_to_geometry(site2_frames, caplog):
    m = Matcher.from_pretrained("fastmatch", site="synthetic", device="cpu")
    f = site2_frames[0]
    with caplog.at_level(logging.WARNING, logger="xcalib.matcher"):
        r = m.match_frame(f, validate="off")
    assert r.source == "geometry" and r.assignment == "hungarian"
    assert "xcalib bootstrap" in caplog.text and "out of domain" in caplog.text
    truth = _pairs(f.match_matrix)
    got = set(map(tuple, r.as_pairs().tolist()))
    assert len(got & truth) >= 0.9 * len(truth) and len(got - truth) <= 0.05 * len(got) + 1
    model_only = m.match_frame(f, validate="off", geometry="off")
    assert model_only.source == "model" and out_of_domain(model_only.similarity) != ""


def test_in_domain_and_forced_paths():
    m = Matcher.from_pretrained("fastmatch", site="synthetic", device="cpu")
    f = generate_frames(sample_site(0), 1, seed=4)[0]  # the weights' own site: in domain
    r = m.match(*f.inputs(), validate="off")  # no intrinsics: the consensus would have to search them
    assert r.source == "model" and out_of_domain(r.similarity) == ""
    g = m.match_frame(f, validate="off")  # the frame's intrinsics: consensus (shipped weights, no calibration)
    assert g.source == "geometry" and np.array_equal(g.similarity, g.geometry_iou)
    truth = _pairs(f.match_matrix)
    assert len(set(map(tuple, g.as_pairs().tolist())) & truth) >= 0.9 * len(truth)
    assert m.match_frame(f, validate="off", geometry="off").source == "model"
    with pytest.raises(ValueError, match="geometry must be"):
        m.match_frame(f, geometry="maybe")


def test_from_pretrained_synthetic_site_warns(caplog):
    with caplog.at_level(logging.WARNING, logger="xcalib.matcher"):
        m = Matcher.from_pretrained("fastmatch", device="cpu")
    assert m.site == "synthetic" and "xcalib bootstrap" in caplog.text
