"""calibration_realism.json keeps its per-site ``sigma_parts`` in a gzip side file (session 15, U: the main
file had grown to 14.4 MB, 60 % of it those parts, which only scripts/sigma_parts.py and
scripts/refusal_audit.py read)."""

from __future__ import annotations

import gzip
import json
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCH))

import bench_calibration_realism as b  # noqa: E402


def _runs():
    recs = [{"condition": "clean", "seed": s, "success": True, "sigma_parts": {"jacobian": [0.1 * s] * 6}}
            for s in (0, 3)]
    return {"r1": {"label": "r1", "conditions": [{"condition": "clean", "n": 2, "per_site": recs},
                                                 {"condition": "old", "n": 1}]}}


def test_write_runs_moves_the_parts_to_the_side_file_and_load_runs_joins_them(tmp_path):
    out = tmp_path / "calibration_realism.json"
    b.write_runs(out, _runs())
    side = b.detail_path(out)
    assert side.name == "calibration_realism_detail.json.gz"
    main = json.loads(out.read_text())
    assert all("sigma_parts" not in r for r in main["runs"]["r1"]["conditions"][0]["per_site"])
    assert json.loads(gzip.decompress(side.read_bytes()))["runs"]["r1"]["clean"]["3"]["sigma_parts"]
    assert b.load_runs(out) == _runs()
    assert b.load_runs(out, detail=False) == main["runs"]
    first = side.read_bytes()
    b.write_runs(out, b.load_runs(out))
    assert side.read_bytes() == first  # deterministic bytes (no time stamp in the gzip header)
    assert not list(tmp_path.glob(".*.tmp"))  # written through temporary files, renamed


def test_the_committed_main_file_stays_small():
    out = BENCH / "results" / "calibration_realism.json"
    assert out.stat().st_size < 8e6, "per-site detail belongs in the side file (bench_calibration_realism.DETAIL_FIELDS)"
    assert b.detail_path(out).is_file()
