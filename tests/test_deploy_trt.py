"""TensorRT builds through trtexec: lookup, command lines (fake trtexec), staleness checks."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

pytest.importorskip("onnxruntime")
torch = pytest.importorskip("torch")

from _deploy_helpers import loaded_matcher  # noqa: E402

from xcalib.deploy import trt  # noqa: E402
from xcalib.deploy.errors import (OnnxFolderError, StaleOnnxError, TrtBuildError,  # noqa: E402
                                  TrtexecNotFoundError)
from xcalib.deploy.manifest import GraphInfo, TensorInfo  # noqa: E402

FAKE = """#!/bin/sh
# fake trtexec: record the arguments, write the engine named by --saveEngine
echo "$@" >> "{log}"
for a in "$@"; do
  case "$a" in --saveEngine=*) echo engine > "${{a#--saveEngine=}}";; esac
done
exit {rc}
"""


def _fake_trtexec(d: Path, rc: int = 0) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    p = d / "trtexec"
    p.write_text(FAKE.format(log=d / "calls.txt", rc=rc))
    p.chmod(p.stat().st_mode | stat.S_IEXEC)
    return p


@pytest.fixture
def matcher(tmp_path):
    return loaded_matcher("fastmatch", tmp_path / "w")


def test_not_found_names_where_it_looked(tmp_path, monkeypatch, matcher):
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.setattr(trt, "SEARCH_DIRS", (str(tmp_path / "nope1"), str(tmp_path / "nope2")))
    with pytest.raises(TrtexecNotFoundError) as ei:
        trt.find_trtexec()
    msg = str(ei.value)
    assert "$PATH" in msg and "nope1/trtexec" in msg and "nope2/trtexec" in msg
    with pytest.raises(TrtexecNotFoundError, match="given path"):
        trt.find_trtexec(tmp_path / "missing" / "trtexec")
    with pytest.raises(TrtexecNotFoundError):  # checked before any export: no folder is written
        matcher.build("trt", tmp_path / "engines", site_folder=True)
    assert not (tmp_path / "engines").exists()


def test_search_dirs_order(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    fake = _fake_trtexec(tmp_path / "opt")
    monkeypatch.setattr(trt, "SEARCH_DIRS", (str(tmp_path / "usr"), str(tmp_path / "opt")))
    assert trt.find_trtexec() == fake
    assert trt.SEARCH_DIRS == (str(tmp_path / "usr"), str(tmp_path / "opt"))
    assert trt.find_trtexec(tmp_path / "opt") == fake  # a directory works as the explicit path


def test_command_line_profiles_and_precision():
    g = GraphInfo("pair_score.onnx", "0" * 64, [TensorInfo("img_embed", ["B", 256]), TensorInfo("lid_embed", ["B", 256])],
                  [TensorInfo("logit", ["B"])], "B", "stage2")
    cmd = trt.trtexec_command("/x/trtexec", Path("o/pair_score.onnx"), Path("e/pair_score.fp16.engine"), g,
                              precision="fp16", extra_args=["--verbose", "--memPoolSize=workspace:1024"])
    assert cmd[:3] == ["/x/trtexec", "--onnx=o/pair_score.onnx", "--saveEngine=e/pair_score.fp16.engine"]
    assert "--minShapes=img_embed:1x256,lid_embed:1x256" in cmd
    assert "--optShapes=img_embed:80x256,lid_embed:80x256" in cmd
    assert "--maxShapes=img_embed:320x256,lid_embed:320x256" in cmd
    assert cmd[-3:] == ["--fp16", "--verbose", "--memPoolSize=workspace:1024"]
    assert not any(a.startswith("--fp16") or a == "--int8" for a in
                   trt.trtexec_command("t", Path("a"), Path("b"), g, precision="fp32"))
    assert "--int8" in trt.trtexec_command("t", Path("a"), Path("b"), g, precision="int8")
    with pytest.raises(ValueError, match="precision"):
        trt.trtexec_command("t", Path("a"), Path("b"), g, precision="fp8")


def test_build_with_fake_trtexec(tmp_path, monkeypatch, matcher):
    fake = _fake_trtexec(tmp_path / "bin")
    monkeypatch.setenv("PATH", f"{fake.parent}{os.pathsep}{os.environ['PATH']}")
    res = matcher.build("trt", tmp_path / "engines", site="s1", precision="fp16", extra_trt_args=["--verbose"],
                        verify=False, site_folder=True)
    assert res.target == "trt" and res.precision == "fp16" and res.output_dir.name == "fastmatch_s1"
    engines = sorted(p.name for p in res.artifacts if p.suffix == ".engine")
    assert engines == ["image_embed.fp16.engine", "lidar_embed.fp16.engine", "pair_score.fp16.engine"]
    calls = (fake.parent / "calls.txt").read_text().splitlines()
    assert len(calls) == 3 and all("--fp16" in c and c.endswith("--verbose") for c in calls)
    img = next(c for c in calls if "image_embed.onnx" in c)
    assert "--minShapes=image_crops:1x3x32x32,boxes_2d:1x4,image_wh:1x2" in img
    assert "--maxShapes=image_crops:32x3x32x32" in img
    lid = next(c for c in calls if "lidar_embed.onnx" in c)
    assert "--optShapes=lidar_crops:12x64x3" in lid
    pair = next(c for c in calls if "pair_score.onnx" in c)
    assert ":1024x" in pair and ":96x" in pair  # pairwise envelope (calibrefine / fastmatch)
    assert len(res.logs) == 3 and all(p.is_file() for p in res.logs)
    # a second build reuses the current ONNX graphs (same weights hash)
    res2 = matcher.build("trt", tmp_path / "engines", site="s1", precision="fp32", verify=False, site_folder=True)
    assert any("reused current ONNX" in n for n in res2.notes)
    assert "--fp16" not in (fake.parent / "calls.txt").read_text().splitlines()[-1]
    # weights changed -> the stale graphs are re-exported, never reused
    with torch.no_grad():
        next(matcher.model.parameters()).add_(0.5)
    res3 = matcher.build("trt", tmp_path / "engines", site="s1", verify=False, site_folder=True)
    assert any("re-exported" in n and "other weights" in n for n in res3.notes)


def test_stale_or_foreign_onnx_dir_is_an_error(tmp_path, monkeypatch, matcher):
    fake = _fake_trtexec(tmp_path / "bin")
    onnx_res = matcher.build("onnx", tmp_path / "onnx", site="s1", verify=False, site_folder=True)
    with pytest.raises(OnnxFolderError, match=r"manifest\.json.*site 's1', not 's2'"):
        matcher.build("trt", tmp_path / "e", site="s2", onnx_dir=onnx_res.output_dir, trtexec=fake, site_folder=True)
    other = loaded_matcher("fastmatch", tmp_path / "w2", seed=1)
    with pytest.raises(StaleOnnxError, match=r"manifest\.json.*other weights"):
        other.build("trt", tmp_path / "e", site="s1", onnx_dir=tmp_path / "onnx", trtexec=fake, site_folder=True)
    crl = loaded_matcher("crlite", tmp_path / "w3", point_cloud_size=64)
    with pytest.raises(OnnxFolderError, match=r"model 'fastmatch', not 'crlite'"):
        crl.build("trt", tmp_path / "e", site="s1", onnx_dir=onnx_res.output_dir, trtexec=fake, site_folder=True)
    ok = matcher.build("trt", tmp_path / "e", site="s1", onnx_dir=tmp_path / "onnx", trtexec=fake, precision="int8", site_folder=True)
    assert any("int8" in n for n in ok.notes) and len([a for a in ok.artifacts if a.suffix == ".engine"]) == 3


def test_trtexec_failure_names_the_log(tmp_path, matcher):
    fake = _fake_trtexec(tmp_path / "bin", rc=3)
    with pytest.raises(TrtBuildError, match=r"code 3.*log: .*image_embed\.fp16\.log"):
        matcher.build("trt", tmp_path / "e", site="s1", trtexec=fake, verify=False, site_folder=True)


def test_export_trt_says_trtexec_is_missing_before_loading_the_model(tmp_path, monkeypatch, capsys):
    """`xcalib export --format trt` without TensorRT: exit 1 naming trtexec, before the model is
    loaded (no torch import, no wait)."""
    from xcalib.cli import main
    from xcalib.engine import matcher as matcher_mod

    def _never(*a, **k):
        raise AssertionError("the model was loaded first")

    monkeypatch.setattr(matcher_mod.Matcher, "from_pretrained", classmethod(_never))
    rc = main(["export", "--model", "crlite", "--format", "trt", "--out", str(tmp_path / "engines"),
               "--trtexec", str(tmp_path / "missing" / "trtexec")])
    assert rc == 1
    err = capsys.readouterr().err
    assert "trtexec" in err and "loaded first" not in err and not (tmp_path / "engines").exists()
