"""calibrate() on the real A9 sample (every other of its 16 frames, no labels): the pose must
explain the boxes. The full 16-frame figures are in benchmarks/bench_calibration.py."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_path


@pytest.mark.shared_data
def test_a9_calibration_explains_the_boxes():
    from xcalib.calib.api import calibrate
    from xcalib.io.frames import read_frames

    seq = read_frames(shared_path("a9_sample"))
    frames = [seq[i] for i in range(0, len(seq), 2)]
    res = calibrate(frames, seq.intrinsics)
    assert res.success, res.message
    assert res.n_pairs >= 0.6 * res.meta["n_2d"]
    assert res.residual_px_median < 15 and res.iou_median > 0.55
    # better than the reference's ~30 px median box-centre offset
    assert res.meta["centre_offset_px_median"] < 25
    assert np.all(res.rotation_std_deg < 0.5) and np.all(res.translation_std_m < 0.3)
    # camera and LiDAR sit on the same gantry: the baseline is short
    assert np.linalg.norm(res.translation) < 3.0
