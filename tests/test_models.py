"""Model registry, configs and every model's forward (tiny configs)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from _matching_frames import TINY, make_frame
from xcalib.data.crops import CropConfig, prepare_frame
from xcalib.models import ModelBatch, UnknownModelError, create_model, default_config, list_models

REFERENCE = ["crlite", "crlite_2dpe", "crlite_vit_exp1", "crlite_vit_exp3", "crlite_vit_exp4", "calibrefine"]


def _batch(model, frames):
    cfg = CropConfig.from_config(model.config)
    return ModelBatch.from_frames([prepare_frame(*f.inputs(), cfg) for f in frames])


def test_registry_lists_reference_models_and_ours():
    names = list_models()
    assert set(REFERENCE) <= set(names)
    assert "fastmatch" in names


def test_unknown_model_names_the_choices():
    with pytest.raises(UnknownModelError, match="available: .*crlite"):
        create_model("nope")


def test_default_config_travels_and_merges():
    cfg = default_config("crlite")
    assert cfg["model"] == "crlite" and cfg["crop_size"] == 32 and "device" not in cfg
    m = create_model("crlite", {"embed_dim": 32, "similarity_head": {"hidden_dims": [8]}}, token_len=16)
    assert m.config["embed_dim"] == 32 and m.config["token_len"] == 16
    assert m.config["similarity_head"]["dropout"] == 0.1  # deep merge keeps the other keys
    assert [l.out_features for l in m.similarity_head if isinstance(l, torch.nn.Linear)] == [8, 1]
    with pytest.raises(ValueError, match="config is for model"):
        create_model("crlite", {"model": "fastmatch"})


def test_reference_size_parameter_counts():
    assert abs(create_model("crlite").num_parameters() / 1e6 - 2.06) < 0.1
    assert abs(create_model("calibrefine").num_parameters() / 1e6 - 18.05) < 0.05
    assert create_model("fastmatch").num_parameters() < 0.3e6


def test_2dpe_forces_2d_only():
    assert create_model("crlite_2dpe", {"pe_mode": "full"}).config["pe_mode"] == "2d_only"


def test_calibrefine_rejects_bad_dense_dims():
    with pytest.raises(ValueError, match="dense.hidden_dim"):
        create_model("calibrefine", {"dense": {"hidden_dim": 0}})


@pytest.mark.parametrize("name", sorted(TINY))
def test_forward_shapes_ranges_and_single_detection_training(name):
    torch.manual_seed(0)
    m = create_model(name, TINY[name])
    frames = [make_frame(1, n_obj=3), make_frame(2, n_obj=1)]
    b = _batch(m, frames)
    m.eval()
    with torch.no_grad():
        s = m.score(m.embed(b), b)
    assert s.shape == (b.num_2d, b.num_3d)
    lo, hi = m.score_range
    scored = s if m.fill_value is None else s[s != m.fill_value]
    assert torch.isfinite(s).all() and scored.min() >= lo - 1e-5 and scored.max() <= hi + 1e-5
    # a frame with ONE detection on each side must train (BatchNorm with a batch of one)
    single = make_frame(3, n_obj=1)
    single.bboxes_3d = single.bboxes_3d[single.match_matrix[0]]
    m.train()
    out = m(_batch(m, [single]), train=True)
    loss = sum(o.logits.sum() for o in out)
    loss.backward()
    assert all(o.logits.shape == (1, 1) for o in out)


def test_exp3_uses_position_encoding_at_inference():
    torch.manual_seed(0)
    m = create_model("crlite_vit_exp3", TINY["crlite_vit_exp3"]).eval()
    b = _batch(m, [make_frame(4)])
    with torch.no_grad():
        s0 = m.score(m.embed(b), b)
        b.boxes_3d = b.boxes_3d + torch.tensor([5.0, -3.0, 0, 0, 0, 0, 0])
        s1 = m.score(m.embed(b), b)
    assert not torch.allclose(s0, s1)


def test_exp4_graph_context_changes_embeddings():
    torch.manual_seed(0)
    m = create_model("crlite_vit_exp4", TINY["crlite_vit_exp4"]).eval()
    f = make_frame(5, n_obj=4)
    b_all = _batch(m, [f])
    with torch.no_grad():
        e_all = m.embed(b_all).img[0]
        f.bboxes_2d = f.bboxes_2d[:1]
        e_one = m.embed(_batch(m, [f])).img[0]
    assert not torch.allclose(e_all, e_one)  # neighbours influence the embedding


def test_crlite_scores_are_absolute_probabilities_not_rank_normalised():
    torch.manual_seed(0)
    m = create_model("crlite", TINY["crlite"]).eval()
    b = _batch(m, [make_frame(6)])
    with torch.no_grad():
        s = m.score(m.embed(b), b)
    top = s.max(dim=1).values
    assert (top < 1.0).all()  # reference min-max normalisation would make every row max 1.0
    assert ((s == -1.0).sum(dim=1) == b.num_3d - 3).all()  # top_k=3 scored, rest filled -1
