"""Envelope profiles and batch-axis chunking (numpy only)."""

import numpy as np
import pytest

from xcalib.deploy.chunking import PROTOCOL_ENVELOPE, Envelope, Profile, chunk_slices, run_chunked


def test_protocol_envelope_matches_spec():
    e = PROTOCOL_ENVELOPE
    assert (e.image.min, e.image.opt, e.image.max) == (1, 8, 32)
    assert (e.lidar.min, e.lidar.opt, e.lidar.max) == (1, 12, 32)
    assert (e.stage2.min, e.stage2.opt, e.stage2.max) == (1, 80, 320)
    assert (e.pairwise.min, e.pairwise.opt, e.pairwise.max) == (1, 96, 1024)
    with pytest.raises(ValueError, match="role"):
        e.profile("stage3")
    with pytest.raises(ValueError, match="min <= opt <= max"):
        Profile(1, 40, 32)


def test_chunk_slices_cover_range():
    s = chunk_slices(80, 32)
    assert [(x.start, x.stop) for x in s] == [(0, 32), (32, 64), (64, 80)]
    assert chunk_slices(5, 32) == [slice(0, 5)]
    assert chunk_slices(7, None) == [slice(0, 7)]


def test_run_chunked_merges_like_unsplit():
    rng = np.random.default_rng(0)
    feeds = {"a": rng.standard_normal((70, 3)).astype(np.float32), "b": rng.standard_normal((70,)).astype(np.float32)}
    seen = []

    def fn(f):
        seen.append(len(f["a"]))
        return {"y": f["a"].sum(1) * f["b"], "z": f["a"] * 2}

    out = run_chunked(fn, feeds, 32)
    ref = fn(feeds)
    assert seen[:3] == [32, 32, 6]
    np.testing.assert_array_equal(out["y"], ref["y"])
    np.testing.assert_array_equal(out["z"], ref["z"])
    with pytest.raises(ValueError, match="share their first axis"):
        run_chunked(fn, {"a": feeds["a"], "b": feeds["b"][:3]}, 32)


def test_custom_envelope():
    e = Envelope(image=Profile(1, 4, 8))
    assert e.profile("image").max == 8 and e.profile("lidar").max == 32
