"""Matcher: match / numbering / bad input / save-load / site weights."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

from _matching_frames import TINY, make_frame
from xcalib.engine.checkpoint import WeightsMismatchError, WeightsNotFoundError
from xcalib.engine.matcher import Matcher, assign
from xcalib.models import UnknownModelError, create_model
from xcalib.protocol import ProtocolError


def _matcher(name="fastmatch", seed=0, **over):
    torch.manual_seed(seed)
    return Matcher(create_model(name, {**TINY[name], **over}), device="cpu")


def test_match_returns_callers_numbering_and_deterministic_scores():
    m = _matcher()
    f = make_frame(1, n_obj=4)
    r = m.match(*f.inputs(), top_k=1, match_threshold=0.0)
    assert r.similarity.shape == (4, 5) and r.similarity.dtype == np.float32
    assert r.top_indices.shape == (4,) and r.model == "fastmatch" and r.device == "cpu"
    assert np.array_equal(r.similarity, m.match(*f.inputs()).similarity)  # seeded crops
    # prepend a degenerate 2D box and an empty 3D box: indices of the others shift by one
    b2 = np.vstack([[5, 5, 1, 1], f.bboxes_2d]).astype(np.float32)
    b3 = np.vstack([[200, 200, 0, 1, 1, 1], f.bboxes_3d]).astype(np.float32)
    r2 = m.match(f.image, f.point_cloud, b2, b3, validate="off")
    assert r2.kept_2d_indices.tolist() == [1, 2, 3, 4] and r2.kept_3d_indices.tolist() == [1, 2, 3, 4, 5]
    assert np.allclose(r2.similarity, r.similarity)
    assert [(i - 1, j - 1) for i, j, _ in r2.matches] == [(i, j) for i, j, _ in r.matches]


def test_top_k_threshold_and_hungarian_is_one_to_one():
    sim = np.array([[0.9, 0.8, 0.1], [0.85, 0.2, 0.3]], np.float32)
    top, pairs = assign(sim, top_k=2, threshold=0.5)
    assert top.tolist() == [0, 0] and [(i, j) for i, j, _ in pairs] == [(0, 0), (0, 1), (1, 0)]
    top, pairs = assign(sim, method="hungarian")
    assert sorted((i, j) for i, j, _ in pairs) == [(0, 1), (1, 0)] and top.tolist() == [1, 0]
    top, pairs = assign(np.array([[-1.0, 0.4]]), fill_value=-1.0, threshold=-2)
    assert [(i, j) for i, j, _ in pairs] == [(0, 1)]
    with pytest.raises(ValueError, match="assignment"):
        assign(sim, method="greedy")


def test_empty_detections_give_a_valid_empty_result():
    m = _matcher("crlite")
    f = make_frame(2)
    for b2, b3 in ((np.zeros((0, 4)), f.bboxes_3d), (f.bboxes_2d, np.zeros((0, 6)))):
        r = m.match(f.image, f.point_cloud, b2, b3)
        assert r.matches == [] and r.similarity.shape[0] * r.similarity.shape[1] == 0
    r = m.match(f.image, np.zeros((0, 3), np.float32), f.bboxes_2d, f.bboxes_3d)
    assert r.matches == [] and r.similarity.shape == (4, 0)


def test_nan_raises_protocol_error_and_warnings_are_logged_once(caplog):
    m = _matcher()
    f = make_frame(3)
    bad = f.point_cloud.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ProtocolError, match="point_cloud.finite"):
        m.match(f.image, bad, f.bboxes_2d, f.bboxes_3d)
    small = f.bboxes_2d.copy()
    small[0, 2] = small[0, 0] + 3
    with caplog.at_level(logging.WARNING, logger="xcalib.protocol"):
        m.match(f.image, f.point_cloud, small, f.bboxes_3d)
        m.match(f.image, f.point_cloud, small, f.bboxes_3d)
    assert sum("bboxes_2d.small" in r.getMessage() for r in caplog.records) == 1
    with pytest.raises(ProtocolError):
        m.match(f.image, f.point_cloud, small, f.bboxes_3d, validate="strict")


def test_box7_input_is_accepted():
    m = _matcher()
    f = make_frame(4)
    b7 = np.hstack([f.bboxes_3d, np.zeros((len(f.bboxes_3d), 1), np.float32)])
    assert np.allclose(m.match(f.image, f.point_cloud, f.bboxes_2d, b7).similarity,
                       m.match(*f.inputs()).similarity)


@pytest.mark.parametrize("name", ["fastmatch", "crlite_vit_exp4"])
def test_save_pretrained_reloads_bit_exactly_without_device(tmp_path, name):
    m = _matcher(name)
    paths = m.save_pretrained(tmp_path)
    assert "device" not in paths["config"].read_text()
    m2 = Matcher.from_pretrained(name, weights=tmp_path, device="cpu")
    for (k, a), b in zip(m.model.state_dict().items(), m2.model.state_dict().values()):
        assert torch.equal(a, b), k
    f = make_frame(5)
    assert np.array_equal(m.match(*f.inputs()).similarity, m2.match(*f.inputs()).similarity)


def test_fp16_storage_round_trips_exactly(tmp_path):
    m = _matcher()
    m.save_pretrained(tmp_path / "a", dtype="float16")
    m2 = Matcher.from_pretrained("fastmatch", weights=tmp_path / "a" / "fastmatch.pth")
    m2.save_pretrained(tmp_path / "b", dtype="float16")
    a = torch.load(tmp_path / "a" / "fastmatch.pth", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "b" / "fastmatch.pth", weights_only=True)["state_dict"]
    assert all(torch.equal(a[k], b[k]) and a[k].dtype == b[k].dtype for k in a)
    w = m2.model.state_dict()
    assert all(torch.equal(w[k], a[k].to(w[k].dtype)) for k in a)


def test_config_weights_mismatch_is_an_error(tmp_path):
    _matcher().save_pretrained(tmp_path)
    with pytest.raises(WeightsMismatchError, match="shape mismatch"):
        Matcher.from_pretrained("fastmatch", weights=tmp_path, config={**TINY["fastmatch"], "embed_dim": 24})
    with pytest.raises(ValueError, match="fastmatch"):
        Matcher.from_pretrained("crlite", weights=tmp_path / "fastmatch.pth")


def test_site_lookup_user_home_first_and_helpful_error(tmp_path, monkeypatch):
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path))
    with pytest.raises(WeightsNotFoundError, match="xcalib train --model fastmatch.*xcalib bootstrap"):
        Matcher.from_pretrained("fastmatch", site="nowhere")
    with pytest.raises(UnknownModelError):
        Matcher.from_pretrained("nope", site="nowhere")
    m = _matcher()
    m.save_pretrained(tmp_path / "sites" / "mysite")
    m2 = Matcher.from_pretrained("fastmatch", site="mysite")
    assert m2.weights_path == tmp_path / "sites" / "mysite" / "fastmatch.pth" and m2.site == "mysite"


def test_embed_score_split_matches_match():
    m = _matcher("crlite")
    f = make_frame(6)
    inputs = m.prepare(*f.inputs())
    emb = m.embed(inputs)
    assert emb.img.shape[0] == inputs.num_2d and emb.lid.shape[0] == inputs.num_3d
    assert np.allclose(m.score(emb, inputs), m.match(*f.inputs()).similarity)


def test_match_frame_and_calibrate_delegate(monkeypatch):
    m = _matcher()
    f = make_frame(7)
    assert np.array_equal(m.match_frame(f).similarity, m.match(*f.inputs()).similarity)
    seen = {}
    import xcalib.calib.api as api

    monkeypatch.setattr(api, "calibrate", lambda frames, intr=None, **kw: seen.update(frames=frames, kw=kw) or "ok")
    assert m.calibrate([f], "K") == "ok" and seen["kw"]["matcher"] is m
    assert m.calibrate(f, "K") == "ok" and seen["frames"] == [f]
