"""benchmarks/bench_coverage_real.py's own statistics (issue 25 item 3): the Clopper-Pearson interval
and the per-row coverage figures, on hand-made records (no calibration, no shared data)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    import bench_coverage_real

    return bench_coverage_real


def test_clopper_pearson_interval_has_its_closed_forms(bench):
    n = 20
    lo, hi = bench.binom90(n, n)  # all covered: lower end 0.05 ** (1 / n), upper 1
    assert hi == 1.0 and lo == pytest.approx(0.05 ** (1 / n), rel=1e-9)
    lo, hi = bench.binom90(0, n)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.05 ** (1 / n), rel=1e-9)
    lo, hi = bench.binom90(19, 20)
    assert lo < 0.95 < hi and 0.7 < lo and hi < 1.0
    assert bench.binom90(0, 0) is None


def _rec(z, success=True, refused=False, approx=False, row="r"):
    z = np.asarray(z, dtype=float)
    return {"case": row, "row": row, "success": success, "refused": refused, "approx_truth": approx,
            "z": z.tolist(), "in_bound95": [bool(z[:3].max() < 2), bool(z[3:].max() < 2)],
            "covered_norm": bool(z.max() < 2), "wrong": False}


def test_row_statistics_count_axes_refusals_and_the_median_share(bench):
    recs = [_rec([0.1, 0.2, 3.0, 0.5, 1.0, 0.9]), _rec([1.0, 1.0, 1.0, 1.0, 1.0, 1.0]),
            _rec([5.0, 0.1, 0.1, 0.1, 0.1, 0.1], success=False, refused=True),
            {"case": "r", "row": "r", "success": False, "refusal": "too_few_detections"},
            _rec([0.1] * 6, approx=True, row="a")]
    rows = {r["case"]: r for r in bench.summarise(recs)}
    r = rows["r"]
    assert (r["runs"], r["success"], r["with_pose"], r["refused_with_pose"]) == (4, 2, 3, 1)
    assert r["cov2_axis_rot"] == pytest.approx(7 / 9) and r["cov2_axis_trans"] == pytest.approx(1.0)
    assert r["successes"]["cov2_axis_rot"] == pytest.approx(5 / 6)
    assert r["cov95_bound_rot"] == pytest.approx(1 / 3)
    assert r["share_above_median"] == pytest.approx(np.mean(np.array(
        [0.1, 0.2, 3.0, 0.5, 1.0, 0.9, 1, 1, 1, 1, 1, 1, 5.0, 0.1, 0.1, 0.1, 0.1, 0.1]) > 0.6745))
    lo, hi = r["cov2_axis_ci90"]
    assert lo < r["cov2_axis"] < hi
    pooled = rows["ALL exact truth (pooled)"]  # approximate-truth rows stay out of the pooled row
    assert pooled["runs"] == 4 and rows["a"]["approx_truth"] and not pooled["approx_truth"]
