"""ONNX export (parity, manifest, folders, bad input) and the ONNX Runtime matcher."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
torch = pytest.importorskip("torch")

from _deploy_helpers import crowded_frame, loaded_matcher  # noqa: E402

from xcalib.deploy.build import BuildResult, random_inputs, state_hash, synthetic_inputs  # noqa: E402
from xcalib.deploy.errors import (EnvelopeError, ExportError, OnnxFolderError,  # noqa: E402
                                  RandomWeightsError)
from xcalib.deploy.ort_runtime import OnnxMatcher  # noqa: E402
from xcalib.engine.matcher import Matcher  # noqa: E402

MODELS = ["fastmatch", "crlite", "crlite_vit_exp1"]  # pairwise, hybrid, cosine families


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    """{model: (matcher, BuildResult)} exported once for the module."""
    root = tmp_path_factory.mktemp("deploy")
    out = {}
    for name in MODELS:
        m = loaded_matcher(name, root / f"w_{name}", point_cloud_size=128)  # small crops: quick tests
        out[name] = (m, m.build("onnx", root / "onnx", site="siteA", site_folder=True))
    return out


@pytest.mark.parametrize("name", MODELS)
def test_parity_random_and_synthetic(exports, name):
    m, res = exports[name]
    assert isinstance(res, BuildResult) and res.target == "onnx" and res.parity_checked
    assert res.parity_ok, res.parity
    cases = {k.split("[")[-1].rstrip("]") for k in res.parity}
    assert cases == {"random", "synthetic"}
    assert "similarity[synthetic]" in res.parity and "image_embed/img_embed[random]" in res.parity
    assert max(res.parity.values()) <= 1e-4
    assert res.output_dir.name == f"{name}_siteA"


def test_manifest_contents(exports):
    m, res = exports["crlite"]
    man = json.loads((res.output_dir / "manifest.json").read_text())
    assert man["model"] == "crlite" and man["site"] == "siteA" and man["family"] == "hybrid"
    assert man["opset"] == 20 and man["weights_sha256"] == state_hash(m.model)
    assert man["config"]["top_k"] == m.config["top_k"] and man["host"]["fill_value"] == -1.0
    assert set(man["graphs"]) == {"image_embed", "lidar_embed", "pair_score"}
    ins = [t["name"] for t in man["graphs"]["image_embed"]["inputs"]]
    assert ins[0] == "image_crops" and man["graphs"]["image_embed"]["inputs"][0]["shape"][0] == "N"
    assert man["graphs"]["pair_score"]["role"] == "stage2" and man["parity_ok"] is True
    assert man["xcalib_version"]


def test_synthetic_parity_inputs_have_distinct_centres():
    from xcalib.data.crops import CropConfig

    for inp in (random_inputs(CropConfig(), 5, 7), synthetic_inputs(CropConfig(point_cloud_size=64))):
        c2 = (inp.boxes_2d[:, :2] + inp.boxes_2d[:, 2:]) / 2
        assert len(np.unique(c2.round(3), axis=0)) == len(c2) >= 2
        assert len(np.unique(inp.boxes_3d[:, :3].round(3), axis=0)) == inp.num_3d >= 2


@pytest.fixture(scope="module")
def synth_frame():
    from xcalib.data.synth import generate_frames, sample_site

    return generate_frames(sample_site(3), 1, seed=3)[0]


@pytest.mark.parametrize("name", MODELS)
def test_ort_match_equals_torch(exports, synth_frame, name):
    m, res = exports[name]
    om = Matcher.from_onnx(res.output_dir, model=name, site="siteA")
    assert isinstance(om, OnnxMatcher) and om.device.startswith("onnxruntime")
    frame = synth_frame
    a = m.match_frame(frame, top_k=2)
    b = om.match_frame(frame, top_k=2)
    np.testing.assert_allclose(b.similarity, a.similarity, atol=1e-5)
    np.testing.assert_array_equal(b.kept_2d_indices, a.kept_2d_indices)
    np.testing.assert_array_equal(b.top_indices, a.top_indices)
    assert [(i, j) for i, j, _ in b.matches] == [(i, j) for i, j, _ in a.matches]
    h = om.match_frame(frame, assignment="hungarian")
    assert h.assignment == "hungarian" and len(h.matches) <= min(h.similarity.shape)


def test_import_and_match_without_torch(exports, tmp_path):
    _, res = exports["fastmatch"]
    code = f"""
import sys, numpy as np
import xcalib, xcalib.deploy
from xcalib.deploy import OnnxMatcher
assert xcalib.OnnxMatcher is OnnxMatcher
m = OnnxMatcher({str(res.output_dir)!r})
rng = np.random.default_rng(0)
img = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
pts = rng.uniform([5, -5, -1], [30, 5, 1], (5000, 3)).astype(np.float32)
b2 = np.array([[10, 10, 60, 80], [200, 100, 260, 200]], np.float32)
b3 = np.array([[5, -5, -1, 15, 0, 1], [15, 0, -1, 30, 5, 1]], np.float32)
r = m.match(img, pts, b2, b3, validate="off")
assert r.similarity.shape == (2, 2), r.similarity.shape
print("torch" in sys.modules)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("name", ["fastmatch", "crlite"])
def test_envelope_chunking_80_detections(exports, name):
    _, res = exports[name]
    image, pts, b2, b3 = crowded_frame(80)
    free = OnnxMatcher(res.output_dir)
    env = OnnxMatcher(res.output_dir, envelope="protocol")
    calls: dict[str, list[int]] = {}
    for g, sess in env.sessions.items():  # record every batch size the graphs see
        class Spy:
            def __init__(self, s, g):
                self.s, self.g = s, g

            def run(self, outs, feeds):
                calls.setdefault(self.g, []).append(len(next(iter(feeds.values()))))
                return self.s.run(outs, feeds)

            def get_outputs(self):
                return self.s.get_outputs()
        env.sessions[g] = Spy(sess, g)
    a = free.match(image, pts, b2, b3, validate="off")
    b = env.match(image, pts, b2, b3, validate="off")
    assert a.similarity.shape == (80, 80)
    np.testing.assert_allclose(b.similarity, a.similarity, atol=1e-5)
    np.testing.assert_array_equal(b.top_indices, a.top_indices)
    assert calls["image_embed"] == [32, 32, 16] and calls["lidar_embed"] == [32, 32, 16]
    pair_max = 320 if name == "crlite" else 1024
    assert max(calls["pair_score"]) <= pair_max and sum(calls["pair_score"]) > pair_max


def test_envelope_guard_refuses_oversized_calls(exports, monkeypatch):
    import xcalib.deploy.ort_runtime as ortmod

    _, res = exports["fastmatch"]
    env = OnnxMatcher(res.output_dir, envelope="protocol")
    monkeypatch.setattr(ortmod, "run_chunked", lambda fn, feeds, limit: fn(feeds))  # as if chunking were skipped
    feeds = {"image_crops": np.zeros((40, 3, 32, 32), np.float32), "boxes_2d": np.zeros((40, 4), np.float32),
             "image_wh": np.ones((40, 2), np.float32)}
    with pytest.raises(EnvelopeError, match="image_embed.*40 rows exceed the envelope maximum 32"):
        env.run_graph("image_embed", feeds)


def test_two_sites_do_not_overwrite(tmp_path):
    m = loaded_matcher("fastmatch", tmp_path / "w")
    ra = m.build("onnx", tmp_path / "o", site="a", verify=False, site_folder=True)
    rb = m.build("onnx", tmp_path / "o", site="b", verify=False, site_folder=True)
    assert ra.output_dir != rb.output_dir
    assert (ra.output_dir / "manifest.json").is_file() and (rb.output_dir / "manifest.json").is_file()
    # without a site the folder name carries the weights hash
    rc = m.build("onnx", tmp_path / "o", verify=False, site_folder=True)
    assert rc.output_dir.name == f"fastmatch_local-{state_hash(m.model)[:8]}"
    # parity not checked -> not OK (never vacuously True)
    assert not ra.parity_checked and ra.parity_ok is False and ra.notes


def test_parity_ok_is_never_vacuous():
    r = BuildResult("onnx", "m", "s", Path("."))
    assert r.parity_ok is False
    r.parity_checked = True
    assert r.parity_ok is False  # checked but empty
    r.parity = {"x[random]": 5e-5}
    assert r.parity_ok is True
    r.parity["y[synthetic]"] = 2e-4
    assert r.parity_ok is False


def test_random_weights_refused(tmp_path):
    torch.manual_seed(0)
    m = Matcher("fastmatch", device="cpu", allow_random=True)
    with pytest.raises(RandomWeightsError, match="never loaded"):
        m.build("onnx", tmp_path, site_folder=True)
    r = m.build("onnx", tmp_path, allow_random=True, verify=False, site_folder=True)
    assert r.site == "random" and (tmp_path / "fastmatch_random" / "manifest.json").is_file()


def test_exp4_dense_graph_export(tmp_path):
    """exp4's sparse per-frame kNN GNN is exported in dense form and checked against the model."""
    m = loaded_matcher("crlite_vit_exp4", tmp_path / "w", point_cloud_size=64)
    res = m.build("onnx", tmp_path / "o", site="s", site_folder=True)
    assert res.parity_ok, res.parity
    om = OnnxMatcher(res.output_dir)
    assert om.host["joint_embedding"] is True
    image, pts, b2, b3 = crowded_frame(40, seed=2)
    for n in (1, 2, 3, 6, 40):  # fewer detections than k neighbours, and more
        a = m.match(image, pts, b2[:n], b3[:n], validate="off")
        b = om.match(image, pts, b2[:n], b3[:n], validate="off")
        np.testing.assert_allclose(b.similarity, a.similarity, atol=1e-5)
    env = OnnxMatcher(res.output_dir, envelope="protocol")
    with pytest.raises(EnvelopeError, match="jointly.*40 image detections"):
        env.match(image, pts, b2, b3, validate="off")


def test_unknown_model_has_no_plan():
    from xcalib.deploy.onnx_export import family_of

    with pytest.raises(ExportError, match="no ONNX export plan"):
        family_of("no_such_model")


def test_fastpath_flag_restored(tmp_path):
    m = loaded_matcher("fastmatch", tmp_path / "w")
    for flag in (True, False):
        torch.backends.mha.set_fastpath_enabled(flag)
        m.build("onnx", tmp_path / "o", site="x", verify=False, site_folder=True)
        assert torch.backends.mha.get_fastpath_enabled() is flag
    torch.backends.mha.set_fastpath_enabled(True)
    assert m.model.training is False and str(m.device) == "cpu"


def test_bad_folders_name_the_file(exports, tmp_path):
    import shutil

    _, res = exports["fastmatch"]
    d = tmp_path / "copy"
    shutil.copytree(res.output_dir, d)
    with pytest.raises(OnnxFolderError, match=r"manifest\.json.*model 'fastmatch'.*'crlite' was requested"):
        OnnxMatcher(d, model="crlite")
    with pytest.raises(OnnxFolderError, match=r"site 'siteA'.*'siteB' was requested"):
        OnnxMatcher(d, site="siteB")
    g = d / "lidar_embed.onnx"
    data = bytearray(g.read_bytes())
    data[len(data) // 2: len(data) // 2 + 64] = b"\x00" * 64
    g.write_bytes(bytes(data))
    with pytest.raises(OnnxFolderError, match=r"lidar_embed\.onnx.*corrupted"):
        OnnxMatcher(d)
    g.write_bytes(b"not an onnx graph")
    with pytest.raises(OnnxFolderError, match=r"lidar_embed\.onnx.*onnxruntime cannot load"):
        OnnxMatcher(d, verify_files=False)
    (d / "manifest.json").unlink()
    with pytest.raises(OnnxFolderError, match=r"manifest\.json.*not an ONNX folder"):
        OnnxMatcher(d)
    # an export root with one folder per model/site resolves by model and site
    om = OnnxMatcher(res.output_dir.parent, model="fastmatch", site="siteA")
    assert om.folder == res.output_dir
