"""benchmarks/bench_calibration_speed.py --merge (issue 29): re-running some cases replaces only
their rows; every other row of the results file is kept as it was."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _bench():
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    import bench_calibration_speed as b

    return b


def test_merged_rows_replace_in_place_and_append_new_cases():
    b = _bench()
    old = [{"case": "a9", "v": 1}, {"case": "synth1000", "v": 1}, {"case": "dense", "v": 1}]
    got = b.merged_rows(old, [{"case": "synth1000", "v": 2}, {"case": "realism:clean:0", "v": 2}])
    assert [r["case"] for r in got] == ["a9", "synth1000", "dense", "realism:clean:0"]
    assert [r["v"] for r in got] == [1, 2, 1, 2]
    assert b.merged_rows(old, []) == old


def test_merge_keeps_the_other_rows_and_the_full_runs_command(tmp_path):
    b = _bench()
    out = tmp_path / "calibration_speed.json"
    out.write_text(json.dumps({"command": "full run", "cases": [{"case": "a9", "v": 1}, {"case": "synth1000", "v": 1}],
                               "parallel": [{"case": "a9", "wall_speedup": 1.2}]}))
    args = argparse.Namespace(merge=True, out=out, base="v0.5.0")
    b._write(args, ["--cases", "synth1000", "--merge"], [{"case": "synth1000", "v": 2}], [], 0.0, partial=True)
    assert json.loads(out.read_text())["cases"][1]["v"] == 1  # an unfinished merge leaves the file alone
    b._write(args, ["--cases", "synth1000", "--merge"], [{"case": "synth1000", "v": 2}], [], 0.0)
    doc = json.loads(out.read_text())
    assert doc["command"] == "full run"
    assert [(r["case"], r["v"]) for r in doc["cases"]] == [("a9", 1), ("synth1000", 2)]
    assert doc["cases"][1]["rerun"].endswith("--cases synth1000 --merge") and "rerun" not in doc["cases"][0]
    assert doc["parallel"] == [{"case": "a9", "wall_speedup": 1.2}]
    assert doc["merged"][-1]["cases"] == ["synth1000"]
