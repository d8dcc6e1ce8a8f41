"""CLI: xcalib match / validate / train on tiny data with tiny weights."""

from __future__ import annotations

import json

import pytest
import torch

from _matching_frames import TINY, make_frames
from xcalib.cli import main
from xcalib.engine.matcher import Matcher
from xcalib.io.frames import write_frame_folder
from xcalib.io.hdf5 import write_cache
from xcalib.models import create_model


@pytest.fixture
def tiny_site(tmp_path, monkeypatch):
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path / "home"))
    torch.manual_seed(0)
    Matcher(create_model("fastmatch", TINY["fastmatch"]), device="cpu").save_pretrained(
        tmp_path / "home" / "sites" / "tiny")
    frames = make_frames(3, 4)
    for f in frames:
        f.camera_name = "cam"
    cache = write_cache(tmp_path / "test.h5", frames, camera_names=["cam"])
    return tmp_path, cache, frames


def test_match_cli_json_on_cache_and_frame_folder(tiny_site, capsys):
    tmp, cache, frames = tiny_site
    assert main(["match", str(cache), "--index", "1", "--site", "tiny", "--json", "--assignment", "hungarian"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["model"] == "fastmatch" and out["num_2d"] == frames[1].num_2d
    assert len({m["index_3d"] for m in out["matches"]}) == len(out["matches"])  # one-to-one
    write_frame_folder(tmp / "folder", frames, camera="cam")
    assert main(["match", str(tmp / "folder"), "--site", "tiny"]) == 0
    assert "fastmatch" in capsys.readouterr().out
    assert main(["match", str(cache), "--index", "7", "--site", "tiny"]) == 2  # usage error


def test_validate_cli_writes_reference_report_schema(tiny_site, capsys):
    tmp, cache, _ = tiny_site
    rep = tmp / "report.json"
    assert main(["validate", "--model", "fastmatch", "--hdf5", str(cache), "--site", "tiny",
                 "--output", str(rep), "--json"]) == 0
    r = json.loads(rep.read_text())["results"]["fastmatch"]
    for k in ("top1", "top3", "mrr", "n_frames", "n_cameras_with_match", "latency_ms_p50", "latency_ms_p95",
              "throughput_fps_mean", "wall_seconds"):
        assert k in r
    assert r["n_frames"] == 3 and 0 <= r["top1"] <= r["top3"] <= 1


def test_unknown_site_fails_with_how_to(tiny_site, capsys):
    _, cache, _ = tiny_site
    assert main(["match", str(cache), "--site", "elsewhere"]) == 1
    assert "xcalib train" in capsys.readouterr().err


def test_train_cli_installs_site_weights(tiny_site, tmp_path, capsys):
    _, cache, _ = tiny_site
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(json.dumps(TINY["fastmatch"]))
    assert main(["train", "--model", "fastmatch", "--train-data", str(cache), "--val-data", str(cache),
                 "--config", str(cfg), "--epochs", "1", "--warmup-epochs", "0", "--output-dir",
                 str(tmp_path / "run"), "--site", "newsite", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["installed"].endswith("sites/newsite/fastmatch.pth")
    assert Matcher.from_pretrained("fastmatch", site="newsite").model_name == "fastmatch"
