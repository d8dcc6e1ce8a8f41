"""Issue 29, consensus speed: the matches of the geometric consensus (``consensus_matches``) pinned
on fixed synthetic frames and on three real A9 frames, so that a change meant only to make it
faster shows whether it moved a match. The pairs were recorded at commit 4d64948 (session 15's
base). A change that moves one on purpose records the new pairs here and says why."""

from __future__ import annotations

import pytest

from xcalib.calib.consensus import consensus_matches
from xcalib.data.synth import generate_frames, sample_site

#: (site seed, preset, sample_site keywords) -> per frame of
#: ``generate_frames(site, 2, seed=100, render_images=False)``: (pairs, ambiguous) in the caller's
#: numbering (no image rendered: the boxes and points do not depend on it)
SYNTHETIC = {
    (2, "roadside", ()): [
        ([[0, 7], [1, 4], [3, 12], [4, 5], [6, 10], [8, 3], [9, 0]], []),
        ([[1, 2], [2, 4], [3, 5], [5, 9], [6, 6], [7, 7], [8, 1]], []),
    ],
    (3, "roadside", (("n_objects", 20),)): [
        ([[0, 12], [1, 6], [2, 16], [5, 8], [6, 20], [7, 11], [8, 14], [9, 17], [10, 10]], []),
        ([[0, 14], [1, 6], [2, 4], [3, 10], [4, 13], [5, 8], [6, 16], [7, 7], [9, 17], [10, 24], [11, 20],
          [13, 19]], []),
    ],
    (5, "vehicle", ()): [
        ([[0, 7], [1, 1], [2, 6]], []),
        ([], []),  # too few objects seen by both sensors for one pose
    ],
}

#: A9 frame -> pairs (none ambiguous), with the sequence's intrinsics
A9 = {
    0: [[1, 7], [2, 1], [3, 6], [4, 0], [5, 16], [6, 2], [7, 4], [8, 9], [9, 14], [10, 15]],
    7: [[0, 8], [4, 0], [5, 1], [6, 2], [7, 4], [8, 7], [9, 9], [10, 10], [11, 11], [12, 12]],
    10: [[1, 1], [2, 6], [3, 0], [4, 15], [5, 2], [6, 4], [7, 8], [8, 9], [9, 13], [10, 14]],
}


@pytest.mark.parametrize("key", list(SYNTHETIC), ids=lambda k: f"{k[1]}{k[0]}")
def test_consensus_matches_pinned_on_synthetic_frames(key):
    seed, preset, kw = key
    frames = generate_frames(sample_site(seed, preset, **dict(kw)), 2, seed=100, render_images=False)
    for f, (pairs, ambiguous) in zip(frames, SYNTHETIC[key]):
        cm = consensus_matches(f, f.intrinsics)
        assert cm.pairs.tolist() == pairs
        assert cm.ambiguous.tolist() == ambiguous


def test_consensus_matches_pinned_on_a9(a9_dir):
    from xcalib.io.frames import read_frames

    seq = read_frames(a9_dir)
    for i, pairs in A9.items():
        cm = consensus_matches(seq[i], seq.intrinsics)
        assert cm.pairs.tolist() == pairs
        assert cm.ambiguous.tolist() == []
