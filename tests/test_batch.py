"""xcalib.batch / ``xcalib calibrate-many`` (issue 29): many recordings through an executor, the
same rows on a process pool, serially and on a local Ray instance; failures are rows; the CSV /
JSON tables and the HTML index are written."""

from __future__ import annotations

import csv
import json

import pytest
from test_calib_support import INTR, sim_frames

from xcalib.batch import calibrate_many, expand_recordings
from xcalib.errors import FormatError
from xcalib.io.frames import write_frame_folder


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    root = tmp_path_factory.mktemp("recs")
    for k in range(2):
        frames, _ = sim_frames(seed=10 + k, n_frames=4)
        write_frame_folder(root / f"site{k}", frames, intrinsics=INTR)
    (root / "broken").mkdir()
    (root / "broken" / "manifest.json").write_text("{not json")
    return root


def _rows(summary):
    return [(r.name, r.success, r.refusal, r.n_pairs, r.T, bool(r.error)) for r in summary.records]


def test_process_pool_and_serial_give_the_same_table(recordings, tmp_path):
    serial = calibrate_many([str(recordings / "site*"), str(recordings / "broken")], tmp_path / "a", executor="serial")
    pool = calibrate_many([str(recordings / "site*"), str(recordings / "broken")], tmp_path / "b", jobs=2)
    assert _rows(serial) == _rows(pool)
    assert [r.name for r in pool.records] == ["site0", "site1", "broken"]
    assert pool.records[0].success and pool.records[1].success, [r.message for r in pool.records]
    assert pool.records[2].error and not pool.records[2].success  # a bad recording is a row, not a crash
    rows = list(csv.DictReader(pool.csv.open()))
    assert [r["name"] for r in rows] == ["site0", "site1", "broken"] and rows[0]["success"] == "True"
    doc = json.loads(pool.json.read_text())
    assert doc["format"] == "xcalib-batch-v1" and len(doc["recordings"]) == 3
    page = pool.html.read_text()
    assert "site0/calibration.json" in page and "broken" in page and "1 error" in page
    assert (tmp_path / "b" / "site0" / "calibration.json").is_file()


def test_list_file_paths_stay_in_their_folder(recordings, tmp_path):
    lst = recordings / "list.txt"
    lst.write_text("# two sites\nsite0\n\nsite1\n")
    assert [p.name for p in expand_recordings(lst)] == ["site0", "site1"]
    # a folder of recordings: every sub-folder a source recognises (a broken one too: it becomes an error row)
    assert [p.name for p in expand_recordings(str(recordings))] == ["broken", "site0", "site1"]
    bad = recordings / "bad.txt"
    bad.write_text("../elsewhere\n")
    with pytest.raises(FormatError, match="outside") as err:
        expand_recordings(bad)
    # the command line has no allow_outside: the message says what a CLI user can do (session 13 review)
    assert "allow_outside" not in str(err.value) and "glob" in str(err.value)
    with pytest.raises(FileNotFoundError):
        expand_recordings(str(recordings / "nothing*"))


@pytest.mark.slow
def test_ray_cluster_gives_the_same_table(recordings, tmp_path):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)  # a local cluster, started here
    try:
        on_ray = calibrate_many([str(recordings / "site*")], tmp_path / "r", executor="ray")
        from xcalib.calib.parallel import resolve_workers

        task = ray.remote(resolve_workers)  # a Ray worker runs one process (nested pools fall back)
        assert ray.get([task.remote("auto"), task.remote(2)]) == [1, 1]
    finally:
        ray.shutdown()
    serial = calibrate_many([str(recordings / "site*")], tmp_path / "s", executor="serial")
    assert _rows(on_ray) == _rows(serial) and on_ray.n_success == 2


def test_cli_calibrate_many(recordings, tmp_path):
    from xcalib.cli import main

    code = main(["calibrate-many", str(recordings / "site0"), "--out", str(tmp_path / "c"), "--executor", "serial"])
    assert code == 0 and (tmp_path / "c" / "index.html").is_file()
