"""derive_matches: pseudo-labels by projection recover the true matches."""

from __future__ import annotations

import numpy as np
import pytest
from test_calib_support import INTR, sim_frames

from xcalib.calib.matching import derive_matches
from xcalib.calib.result import CalibrationResult


def test_derive_matches_recovers_the_truth():
    frames, T = sim_frames(seed=5, n_frames=3, noise_px=1.0, miss=0.1, false_pos=0.1)
    calib = CalibrationResult(success=True, intrinsics=INTR, rotation=T[:3, :3], translation=T[:3, 3])
    for f in frames:
        pl = derive_matches(f, calib)
        truth = {tuple(x) for x in np.argwhere(f.match_matrix)}
        got = {tuple(x) for x in pl.pairs}
        assert len(got & truth) >= 0.9 * len(truth)
        assert len(got - truth) <= 1
        assert pl.match_matrix.shape == f.match_matrix.shape and pl.match_matrix.sum() == len(pl)
        assert np.all((pl.confidence >= 0.3) & (pl.confidence <= 1.0))


def test_derive_matches_accepts_a_matrix_and_rejects_failures():
    frames, T = sim_frames(seed=6, n_frames=1)
    pl = derive_matches(frames[0], T, intrinsics=INTR, gate=0.5)
    assert len(pl) >= 3 and np.all(pl.confidence >= 0.5)
    with pytest.raises(ValueError, match="failed"):
        derive_matches(frames[0], CalibrationResult(success=False, message="x"))
    with pytest.raises(ValueError, match="gate"):
        derive_matches(frames[0], T, intrinsics=INTR, gate=0.0)
