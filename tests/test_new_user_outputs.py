"""What a new user reads in the outputs: the per-frame table of summary.txt stays aligned when
frames are named by a bag's nanosecond stamps."""

from __future__ import annotations

from xcalib.calib.report import _summary_text
from xcalib.calib.result import CalibrationResult


def test_summary_frame_table_aligns_long_frame_keys():
    rows = [dict(frame=str(1700000000000000000 + 10 ** 8 * i), n_2d=0, n_3d=6, pairs=0, px_median=None,
                 iou_median=None) for i in range(2)] + [dict(frame="0001", n_2d=11, n_3d=17, pairs=9, px_median=10.16,
                                                              iou_median=0.658)]
    text = _summary_text(CalibrationResult(success=False, message="too few detections"), rows)
    table = text.splitlines()[-4:]
    assert table[0].split() == ["frame", "2D", "3D", "pairs", "px", "med", "IoU", "med"]
    assert len({len(ln) for ln in table}) == 1, table  # every row as wide as the header
    assert table[-1].endswith("0.658") and table[1].startswith("1700000000000000000")


def test_summary_states_the_frames_used_once():
    """A success's summary() says "frames = N of M used"; summary.txt does not repeat it (a
    refusal's, which has no such line, gets it once)."""
    import numpy as np

    from xcalib.calib.diagnostics import CalibDiagnostics, FrameSelectionSummary

    diag = CalibDiagnostics(selection=FrameSelectionSummary(n_frames_given=2, n_frames_used=2, n_objects=4,
                                                            n_objects_used=4, object_identity="positions"))
    ok = CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3), residual_px_median=1.0,
                           iou_median=0.8, rotation_std_deg=np.full(3, 0.1), translation_std_m=np.full(3, 0.01),
                           frame_keys=["a", "b"], pairs=[np.zeros((3, 2), int)] * 2, n_inliers=5, reproj_error_px=1.0,
                           diagnostics=diag)
    no = CalibrationResult(success=False, message="ambiguous", diagnostics=diag)
    for res in (ok, no):
        text = _summary_text(res, [])
        assert text.count("2 of 2 used (4 of 4 distinct objects") == 1, text


def test_demo_table_says_coarse_as_calibrate_does():
    """The demo's tables carry the precision line: a COARSE success (the A9 sample's) is not shown
    as a bare "success"."""
    import numpy as np

    from xcalib.cli.demo_cmd import _precision_cell

    def res(rot_std, trans_std):
        return CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3),
                                 rotation_std_deg=np.full(3, rot_std), translation_std_m=np.full(3, trans_std))

    assert _precision_cell(res(0.05, 0.01)).startswith("fine: 95 % bound")
    coarse = _precision_cell(res(0.35, 0.3))
    assert "COARSE" in coarse and "a starting point" in coarse
