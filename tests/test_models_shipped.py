"""The shipped synthetic-site weights load strictly, offline, and still match their site."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
import pytest

from xcalib.engine.matcher import Matcher
from xcalib.engine.metrics import MetricsAccumulator

MANIFEST = resources.files("xcalib").joinpath("weights", "synthetic", "manifest.json")
SHIPPED = sorted(json.loads(MANIFEST.read_text())["models"]) if MANIFEST.is_file() else []


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_weights_load_offline_and_are_small(name, monkeypatch, tmp_path):
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path))  # no user site: the packaged weights are used
    m = Matcher.from_pretrained(name, site="synthetic", device="cpu")
    assert m.weights_path.stat().st_size < 8e6
    assert "device" not in m.weights_path.with_suffix(".yaml").read_text()


def test_shipped_fastmatch_matches_its_site(monkeypatch, tmp_path):
    if "fastmatch" not in SHIPPED:
        pytest.skip("no shipped fastmatch weights")
    from xcalib.data.synth import iter_frames, sample_site

    monkeypatch.setenv("XCALIB_HOME", str(tmp_path))
    m = Matcher.from_pretrained("fastmatch", site="synthetic", device="cpu")
    acc = MetricsAccumulator()
    for f in iter_frames(sample_site(0, "roadside"), 4, seed=3, start=20):  # the held-out test sequence
        r = m.match_frame(f, validate="off", geometry="off")  # the weights themselves
        acc.add(r.full_similarity(f.num_2d, f.num_3d, -np.inf), f.match_matrix)
    res = acc.result()
    assert res.n_cameras_with_match >= 10 and res.top1 >= 0.7


GENERIC = resources.files("xcalib").joinpath("weights", "generic", "fastmatch.pt")


def test_generic_fastmatch_transfers_to_an_unseen_site(monkeypatch, tmp_path):
    if not GENERIC.is_file():
        pytest.skip("no shipped generic weights")
    from xcalib.data.synth import iter_frames, sample_site

    monkeypatch.setenv("XCALIB_HOME", str(tmp_path))
    m = Matcher.from_pretrained("fastmatch", site="generic", device="cpu")
    assert m.weights_path.stat().st_size < 1e6
    # a site none of the generic training/validation seeds (7000-7239, 7600-7603) drew, with its own lens
    site = sample_site(7950, "roadside", width=960, height=600, focal_px=(500.0, 1000.0))
    acc, chance = MetricsAccumulator(), []
    for f in iter_frames(site, 4, seed=1, start=10):
        r = m.match_frame(f, validate="off", geometry="off")  # the weights themselves
        acc.add(r.full_similarity(f.num_2d, f.num_3d, -np.inf), f.match_matrix)
        chance += [1.0 / len(r.kept_3d_indices)] * int(np.asarray(f.match_matrix).any(1).sum())
    res = acc.result()
    assert res.n_cameras_with_match >= 10
    assert res.top1 >= 0.6 and res.top1 > 5 * np.mean(chance)
