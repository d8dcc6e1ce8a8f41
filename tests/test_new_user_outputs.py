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
