"""``xcalib export`` and ``xcalib validate --runtime onnx`` on a small synthetic cache."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("torch")

from _deploy_helpers import loaded_matcher  # noqa: E402

from xcalib.cli import main  # noqa: E402


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    from xcalib.data.synth import write_site

    root = tmp_path_factory.mktemp("cli")
    loaded_matcher("fastmatch", root / "w", seed=3)
    write_site(root / "site", 0, 0, 4, seed=5)
    return root


def test_export_json_and_validate_runtime_onnx(setup, capsys):
    root = setup
    rc = main(["export", "--model", "fastmatch", "--weights", str(root / "w"), "--site", "synthetic",
               "--format", "onnx", "--out", str(root / "onnx"), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["parity_ok"] is True and out["max_parity_error"] <= 1e-4
    assert out["output_dir"].endswith("fastmatch_synthetic") and out["site"] == "synthetic"
    if "--runtime" not in _validate_help(capsys):
        pytest.fail("xcalib validate has no --runtime option")
    common = ["validate", "--model", "fastmatch", "--hdf5", str(root / "site" / "test.h5"), "--site", "synthetic",
              "--json"]
    assert main(common + ["--weights", str(root / "w")]) == 0
    torch_rep = json.loads(capsys.readouterr().out)
    assert main(common + ["--runtime", "onnx", "--onnx-dir", str(root / "onnx")]) == 0
    onnx_rep = json.loads(capsys.readouterr().out)
    a, b = torch_rep["results"]["fastmatch"], onnx_rep["results"]["fastmatch"]
    assert onnx_rep["runtime"] == "onnx" and a["n_cameras_with_match"] == b["n_cameras_with_match"] > 0
    for k in ("top1", "top3", "mrr"):
        assert abs(a[k] - b[k]) <= 0.003, (k, a[k], b[k])  # within 0.3 percentage points


def _validate_help(capsys) -> str:
    main(["validate", "--help"])
    return capsys.readouterr().out


def test_validate_runtime_bad_usage(setup, capsys):
    h5 = str(setup / "site" / "test.h5")
    assert main(["validate", "--model", "fastmatch", "--hdf5", h5, "--runtime", "tensorrt"]) == 2
    assert main(["validate", "--model", "fastmatch", "--hdf5", h5, "--runtime", "onnx"]) == 2
    capsys.readouterr()


def test_export_bad_input(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path / "home"))
    rc = main(["export", "--model", "fastmatch", "--site", "nowhere", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert rc == 1 and "no weights for model 'fastmatch' at site 'nowhere'" in err
    assert not any(tmp_path.glob("fastmatch_*"))
    rc = main(["export", "--model", "fastmatch", "--format", "tflite", "--out", str(tmp_path)])
    assert rc == 2


def test_export_help_shows_example(capsys):
    assert main(["export", "--help"]) == 0
    assert "Example: xcalib export" in capsys.readouterr().out
