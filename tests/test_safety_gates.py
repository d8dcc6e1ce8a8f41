"""No silent overwrite (--force gates) and whole-or-nothing trainer / frame-folder outputs."""

from __future__ import annotations

import json

import pytest
import torch

from _deploy_helpers import loaded_matcher
from _matching_frames import TINY, make_frames
from xcalib.cli import main
from xcalib.engine import trainer as trainer_mod
from xcalib.engine.checkpoint import read_config
from xcalib.io import frames as frames_mod
from xcalib.io.frames import read_frames, write_frame_folder
from xcalib.io.hdf5 import write_cache


def _refused(capsys, rc: int, path) -> None:
    err = capsys.readouterr().err
    assert rc != 0 and str(path) in err and "--force" in err


def test_train_output_dir_needs_force(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "best.pth").write_bytes(b"previous run")
    rc = main(["train", "--model", "fastmatch", "--train-data", str(tmp_path / "none.h5"), "--output-dir", str(run)])
    _refused(capsys, rc, run / "best.pth")
    assert (run / "best.pth").read_bytes() == b"previous run"


def test_bootstrap_out_needs_force(tmp_path, capsys):
    out = tmp_path / "boot"
    out.mkdir()
    (out / "fastmatch.pt").write_bytes(b"old")
    rc = main(["bootstrap", str(tmp_path / "none"), "--site", "x", "--out", str(out)])
    _refused(capsys, rc, out)
    assert (out / "fastmatch.pt").read_bytes() == b"old"


def test_export_and_export_onnx_need_force(tmp_path, capsys):
    pytest.importorskip("onnxruntime")
    loaded_matcher("fastmatch", tmp_path / "w", seed=1)
    folder = tmp_path / "onnx" / "fastmatch_synthetic"
    folder.mkdir(parents=True)
    (folder / "manifest.json").write_text("{}")
    rc = main(["export", "--model", "fastmatch", "--weights", str(tmp_path / "w"), "--site", "synthetic",
               "--out", str(tmp_path / "onnx")])
    _refused(capsys, rc, folder)
    rc = main(["export-onnx", "--model", "fastmatch", "--weights", str(tmp_path / "w"), "--output", str(folder)])
    _refused(capsys, rc, folder)
    assert (folder / "manifest.json").read_text() == "{}"


def test_best_yaml_is_written_before_best_pth_and_stale_best_removed(tmp_path, monkeypatch):
    torch.manual_seed(0)
    frames = make_frames(2, 4)
    cache = write_cache(tmp_path / "c.h5", frames)
    out = tmp_path / "run"
    out.mkdir()
    (out / "best.pth").write_bytes(b"a previous run's weights")
    (out / "best.yaml").write_text("d_model: 999\n")
    seen = []
    orig = trainer_mod.save_weights

    def spy(net, path, **kw):  # at the moment the weights are written, the yaml must be this run's
        seen.append((path.exists(), read_config(path.with_suffix(".yaml")) == dict(net.config)))
        return orig(net, path, **kw)

    monkeypatch.setattr(trainer_mod, "save_weights", spy)
    best = trainer_mod.train("fastmatch", cache, cache, config=TINY["fastmatch"], epochs=1, output_dir=out,
                             device="cpu", progress=False)
    assert seen == [(False, True)]  # stale best.pth gone, yaml already current
    assert best.is_file() and read_config(out / "best.yaml") == dict(trainer_mod.read_checkpoint(best)["config"])


def test_write_frame_folder_is_whole_or_absent(tmp_path, monkeypatch):
    frames = make_frames(2, 3)
    calls = []
    orig = frames_mod.write_pcd

    def failing(*a, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise OSError("disk full")
        return orig(*a, **kw)

    monkeypatch.setattr(frames_mod, "write_pcd", failing)
    with pytest.raises(OSError, match="disk full"):
        write_frame_folder(tmp_path / "ff", frames)
    assert list(tmp_path.iterdir()) == []  # neither a partial folder nor a temp left
    monkeypatch.setattr(frames_mod, "write_pcd", orig)
    manifest = write_frame_folder(tmp_path / "ff", frames)
    assert manifest == tmp_path / "ff" / "manifest.json" and len(list(read_frames(tmp_path / "ff"))) == 2
    assert len(json.loads(manifest.read_text())["frames"]) == 2 and [p.name for p in tmp_path.iterdir()] == ["ff"]
