"""benchmarks/bench_camera_models.py's own logic (issue 26): the round trips of every model
through every camera format, and the Done-when table pooled over stored runs."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    import bench_camera_models

    return bench_camera_models


def test_round_trips_are_exact_where_the_format_can_express_the_model(bench):
    from xcalib.data.synth.site import WIDE_ANGLE_PARAMS

    rows = bench.round_trips()
    assert {r["model"] for r in rows} >= set(WIDE_ANGLE_PARAMS) | {"pinhole", "pinhole_radtan"}
    assert all(r["written"] == r["expressible"] and r["refused"] != r["written"] for r in rows)
    done = [r for r in rows if r["written"]]
    assert len(done) >= 30 and all(r["all_valid"] and r["n_pixels"] > 500 for r in done)
    assert max(r["max_px_diff"] for r in done) <= 1e-9


def _rec(row, seed, success=True, rot=0.1, tr=0.05):
    r = {"row": row, "seed": seed, "success": success, "time_s": 1.0, "refusal": "" if success else "uncertain"}
    if success:
        r.update(rot_deg=rot, trans_m=tr, wrong=rot > 1.0, within_2sigma=True, within_95=True,
                 z_axes=[0.5, 1.0, 2.5, 0.1, 0.2, 0.3])
    return r


def test_pooled_table_keeps_current_runs_and_the_newest_record_per_site(bench, monkeypatch):
    monkeypatch.setattr(bench, "_at_or_after", lambda commit, base=bench.POOL_SINCE: commit == "new")
    doc = {
        "throughput": {"rows": []},
        "old": {"records": [_rec("kannala_brandt 185 deg", 0, rot=5.0)], "provenance": None},
        "a": {"records": [_rec("pinhole 90 deg", 0, rot=0.10), _rec("pinhole 90 deg", 1, rot=0.20),
                          _rec("kannala_brandt 185 deg", 0, rot=0.30)], "provenance": {"git_commit": "new"}},
        "b": {"records": [_rec("kannala_brandt 185 deg", 0, rot=0.15), _rec("kannala_brandt 185 deg", 2, False)],
              "provenance": {"git_commit": "new"}},
    }
    rows, used, stale = bench.pooled(doc)
    assert used == ["a", "b"] and stale == ["old"]
    by = {r["row"]: r for r in rows}
    assert [r["row"] for r in rows] == ["pinhole 90 deg", "kannala_brandt 185 deg"]
    kb = by["kannala_brandt 185 deg"]
    assert kb["n"] == 2 and kb["success"] == 0.5 and kb["seeds"] == [0, 2]
    assert kb["rot_deg_median"] == pytest.approx(0.15)  # run b's record of site 0, not a's nor the stale one
    assert kb["rot_vs_pinhole"] == pytest.approx(0.15 / 0.15)
    assert kb["same_sites"] == 1 and kb["rot_vs_pinhole_same_sites"] == pytest.approx(0.15 / 0.10)
    assert kb["coverage_axis_rot"] == pytest.approx(2 / 3) and kb["coverage_axis_trans"] == 1.0


def test_pp_shift_items_are_parsed_and_named_and_bad_ones_refused(bench):
    assert bench.parse_pp_shifts("cx+0.03, cx-0.03,cy+0.03,0.02") == [("cx", 0.03), ("cx", -0.03), ("cy", 0.03),
                                                                      ("cx", 0.02)]
    assert bench.parse_pp_shifts("") == []
    assert bench._pp_row(("cx", 0.03)) == " cx+3%W" and bench._pp_row(("cy", -0.03)) == " cy-3%W"
    assert bench._pp_row(None) == ""
    with pytest.raises(ValueError, match="cz0.03"):
        bench.parse_pp_shifts("cx+0.03,cz0.03")
