"""Self-calibration with few matched pairs (issue 25, session 11): with no more pairs than the joint
fit has parameters (6 pose + focal scale) the per-pair sandwich is singular, so the focal scale is
unconstrained -- "focal" refuses, "auto" keeps the given focal length -- instead of getting a
1-sigma of a fraction of a percent from 6 pairs."""

from __future__ import annotations

import numpy as np
import pytest
from test_calib_sparse import _few_pairs_frame

from xcalib.calib.config import CalibConfig
from xcalib.calib.cost import Occlusion
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.selfcal import joint_refine


def _fit(k: int, seed: int = 11):
    frame, T = _few_pairs_frame(seed=seed, k=k)
    cf, intr, _ = prepare_frames([frame], frame.intrinsics)
    return joint_refine(cf, intr, Pose.parse(T), CalibConfig(refine_intrinsics="focal"), None, Occlusion())


@pytest.mark.parametrize("k", [6, 7])
def test_focal_scale_is_unconstrained_with_no_more_pairs_than_parameters(k):
    fit = _fit(k)
    assert fit is not None and 6 <= fit.n_pairs <= 7
    assert fit.focal_log_sd is not None and np.isinf(fit.focal_log_sd)
    assert np.all(np.isinf(fit.pose_inflation))


def test_focal_scale_has_a_sigma_with_more_pairs_than_parameters():
    fit = _fit(10)
    assert fit is not None and fit.n_pairs >= 8
    assert fit.focal_log_sd is not None and 0 < fit.focal_log_sd < 0.5
