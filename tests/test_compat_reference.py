"""The reference package's documented usage (reference-behaviour.md §1, 4, 5, 6), written here
from that description, run against xcalib: one test per item of issue 15, plus one per row of
the migration table in docs/compat.md (deliberate differences)."""

from __future__ import annotations

import inspect
import json
import sys

import numpy as np
import pytest
import torch

from _matching_frames import TINY, make_frame, make_frames, small_site, tiny_matcher
import xcalib
from xcalib import CalibrationResult, Matcher, MatchResult
from xcalib.cli import main
from xcalib.errors import CalibrationFailedError

INTR = xcalib.CameraIntrinsics(700.0, 700.0, 320.0, 240.0, width=640, height=480)
T_CAM_LIDAR = np.array([[0.0, -1, 0, 0], [0, 0, -1, 0.2], [1, 0, 0, -0.1], [0, 0, 0, 1]])  # x fwd, y left, z up


def _saved(tmp_path, model="fastmatch"):
    d = tmp_path / f"w_{model}"
    tiny_matcher(model=model).save_pretrained(d)
    return d


def _gt_pose(site) -> CalibrationResult:
    T = site.T_cam_lidar
    return CalibrationResult(success=True, intrinsics=site.intrinsics, rotation=T[:3, :3], translation=T[:3, 3])


# ------------------------------------------------------------------ item 12: constructor
def test_item12_matcher_constructor_reference_form(tmp_path):
    d = _saved(tmp_path)
    cfg = dict(TINY["fastmatch"])
    m = Matcher("fastmatch", cfg, d / "fastmatch.pth", "cpu")  # positional weights_path, device
    assert m.model_name == "fastmatch" and str(m.device) == "cpu" and m.weights_path == d / "fastmatch.pth"
    m2 = Matcher(model_name="fastmatch", config={**cfg, "weights_path": str(d / "fastmatch.pth"), "device": "cpu"})
    assert all(torch.equal(a, b) for a, b in zip(m.model.state_dict().values(), m2.model.state_dict().values()))
    assert m.prepare_cfg is m.crop_config and m.prepare_cfg.crop_size == cfg.get("crop_size", m.prepare_cfg.crop_size)
    with pytest.raises(ValueError, match="no weights_path"):
        Matcher("fastmatch", cfg)  # the reference refuses a silently random model
    with pytest.raises(KeyError):
        Matcher("no_such_model", {}, d / "fastmatch.pth")
    assert Matcher("fastmatch", cfg, allow_random=True).weights_path is None  # xcalib's explicit opt-in


# ------------------------------------------------------------------ item 11: match positional order
def test_item11_match_positional_order_and_pair():
    m = tiny_matcher()
    f = make_frame(0)
    r = m.match(f.image, f.point_cloud, f.bboxes_2d, f.bboxes_3d, 1, 0.0, True, "off")  # 7th: return_latency
    assert isinstance(r, MatchResult) and r.latency_ms > 0
    assert [p for p in inspect.signature(Matcher.match).parameters][6:10] == [
        "match_threshold", "return_latency", "validate", "assignment"]
    assert inspect.signature(Matcher.match).parameters["assignment"].kind is inspect.Parameter.KEYWORD_ONLY
    r2 = m.pair(f.image, f.point_cloud, f.bboxes_2d, f.bboxes_3d, 1, 0.0, False, "off")
    assert np.array_equal(r.similarity, r2.similarity)


# ------------------------------------------------------------------ item 13: match_frame, defaults
def test_item13_match_frame_overlay_defaults_and_device():
    m = tiny_matcher()
    f = make_frame(1)
    scores, ms = m.match_frame(m.prepare(*f.inputs()))  # the reference's FrameData form
    assert isinstance(scores, np.ndarray) and scores.shape == (f.num_2d, f.num_3d) and ms >= 0
    assert isinstance(m.match_frame(f, validate="off"), MatchResult)  # xcalib's Frame form
    p = inspect.signature(xcalib.draw_matching_overlay).parameters
    assert p["output_height"].default == 420
    assert inspect.signature(xcalib.draw_calibration_overlay).parameters["max_points"].default == 6000
    img = xcalib.draw_matching_overlay(f.image, f.point_cloud, f.bboxes_2d, f.bboxes_3d, [(0, 0, 0.9)])
    assert img.dtype == np.uint8 and img.shape[0] >= 420
    fields = {fl.name: fl for fl in MatchResult.__dataclass_fields__.values()}
    assert fields["device"].default == ""


# ------------------------------------------------------------------ item 8: visualization module
def test_item08_visualization_module():
    from xcalib.visualization import draw_calibration_overlay, draw_matching_overlay

    assert draw_matching_overlay is xcalib.draw_matching_overlay
    assert draw_calibration_overlay is xcalib.draw_calibration_overlay
    f = make_frame(2)
    T = T_CAM_LIDAR
    out = draw_calibration_overlay(f.image, f.point_cloud, intrinsics=INTR, rotation=T[:3, :3], translation=T[:3, 3],
                                   bboxes_3d=f.bboxes_3d)
    assert out.shape == f.image.shape and not np.array_equal(out, f.image)


# ------------------------------------------------------------------ item 6: save_pretrained .pth
def test_item06_save_pretrained_pth_and_directories_load_pt_or_pth(tmp_path):
    m = tiny_matcher()
    paths = m.save_pretrained(tmp_path / "a")
    assert paths["weights"] == tmp_path / "a" / "fastmatch.pth" and paths["config"].name == "fastmatch.yaml"
    payload = torch.load(paths["weights"], weights_only=True)
    assert {"model_name", "package_version", "model_state_dict"} <= set(payload)
    # a directory with a .pt (older xcalib, shipped weights) loads too
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "fastmatch.pth").rename(tmp_path / "b" / "fastmatch.pt")
    (tmp_path / "a" / "fastmatch.yaml").rename(tmp_path / "b" / "fastmatch.yaml")
    again = Matcher.from_pretrained("fastmatch", weights=tmp_path / "b", device="cpu")
    assert all(torch.equal(a, b) for a, b in zip(m.model.state_dict().values(), again.model.state_dict().values()))
    again.save_pretrained(tmp_path / "b", overwrite=True)  # .pth replaces the .pt: one set of weights per folder
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["fastmatch.pth", "fastmatch.sha256", "fastmatch.yaml"]


# ------------------------------------------------------------------ item 3: Matcher.train(device=)
def test_item03_matcher_train_accepts_device(tmp_path):
    m = tiny_matcher(model="crlite")
    tr = make_frames(3, 1, n_obj=2)
    best = m.train(tr, tr[:1], output_dir=tmp_path, epochs=1, device="cpu", frames_per_batch=2, progress=False)
    assert best.name == "best.pth" and m.weights_path == best and not m.model.training


# ------------------------------------------------------------------ item 2: xcalib.train
def test_item02_train_reference_signature_defaults_and_best_pth(tmp_path):
    p = inspect.signature(xcalib.train).parameters
    want = {"epochs": 10, "lr": 1e-4, "weight_decay": 1e-4, "optimizer": "adamw", "warmup_epochs": 0,
            "scheduler": "none", "min_lr": 1e-5, "label_smoothing": 0.05, "output_dir": "runs/train",
            "device": "auto", "seed": 42, "pairwise_batch_size": 64}
    assert {k: p[k].default for k in want} == want
    for k in ("model_name", "site", "temperature", "stage1_weight", "stage2_weight", "limit_train_frames"):
        assert k in p
    best = xcalib.train("crlite", make_frames(3, 1, n_obj=2), make_frames(2, 2, n_obj=2), model_name="crlite",
                        config=TINY["crlite"], site="synthetic", epochs=1, temperature=0.1, stage2_weight=0.5,
                        output_dir=tmp_path / "run", device="cpu", progress=False, frames_per_batch=2)
    assert best.name == "best.pth"
    ck = torch.load(best, weights_only=True)
    assert "model_state_dict" in ck and ck["train_args"]["temperature"] == pytest.approx(0.1)
    assert ck["train_args"]["stage2_weight"] == 0.5 and ck["train_args"]["optimizer"] == "adamw"
    with pytest.raises(ValueError, match="model_name"):
        xcalib.train("crlite", [], None, model_name="fastmatch")


# ------------------------------------------------------------------ item 5: Matcher.calibrate one frame
def test_item05_calibrate_one_frame_options_and_validation():
    site = small_site()
    from xcalib.data.synth import generate_frames

    f = generate_frames(site, 1, seed=3, render_images=False)[0]
    m = tiny_matcher()
    bad = f.point_cloud.copy()
    bad[0, 0] = np.nan
    with pytest.raises(xcalib.ProtocolError):
        m.calibrate(f.image, bad, f.bboxes_2d, f.bboxes_3d, site.intrinsics)
    loose = m.calibrate(f.image, f.point_cloud, f.bboxes_2d, f.bboxes_3d, site.intrinsics,
                        match_threshold=0.0, ransac_reproj_px=1e6, validate="off")
    if loose.success:  # every matched pair is within 1e6 px
        assert loose.n_inliers == loose.n_correspondences
    else:
        assert loose.rotation is None and loose.message
    # the inlier count itself, on the true pose and the true pairs
    from xcalib.calib.single import inlier_count

    gt = _gt_pose(site)
    gt.pairs = [np.argwhere(f.match_matrix)]
    n = len(gt.pairs[0])
    assert n >= 3
    assert inlier_count(*f.inputs(), gt, 1e6) == n and inlier_count(*f.inputs(), gt, 1e-9) == 0


# ------------------------------------------------------------------ item 10: CalibrationResult
def test_item10_calibration_result_names_failure_and_npz(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.2, 0.3]
    ok = CalibrationResult(success=True, intrinsics=INTR, rotation=T[:3, :3], translation=T[:3, 3],
                           n_inliers=7, reproj_error_px=1.5)
    assert ok.pose_error(gt_extrinsics=T) == pytest.approx((0.0, 0.0))
    uv, depth = ok.project(points_3d=np.array([[0.0, 0.0, 10.0]]))
    assert uv.shape == (1, 2) and depth[0] == pytest.approx(10.3)
    z = np.load(ok.save(tmp_path / "c.npz"))
    assert {"rotation", "translation", "projection", "K", "reproj_error_px", "n_inliers"} <= set(z.files)
    assert float(z["reproj_error_px"]) == 1.5 and int(z["n_inliers"]) == 7
    failed = CalibrationResult(success=False, intrinsics=INTR, message="too few pairs")
    assert failed.rotation is None and failed.translation is None
    with pytest.raises(RuntimeError, match="too few pairs"):
        failed.pose_error(gt_extrinsics=T)
    with pytest.raises(CalibrationFailedError):
        failed.extrinsics
    back = CalibrationResult.load(failed.save(tmp_path / "f.npz"))
    assert not back.success and back.rotation is None
    with pytest.raises(ValueError, match="needs a rotation"):  # a success without a pose is refused
        CalibrationResult(success=True, intrinsics=INTR)


# ------------------------------------------------------------------ item 7: load_dataset frames
def test_item07_load_dataset_frames_are_reference_shaped(tmp_path):
    from xcalib.io.hdf5 import write_cache

    frames = make_frames(2, 4)
    for f in frames:
        f.intrinsics, f.extrinsics = INTR, T_CAM_LIDAR
    (tmp_path / "site").mkdir()
    write_cache(tmp_path / "site" / "test.h5", frames, camera_names=["cam"])
    with xcalib.load_dataset(tmp_path / "site", split="test") as ds:
        assert len(ds) == 2
        fr = ds[0]
        assert set(fr.intrinsics) == {fr.camera_name} and fr.intrinsics[fr.camera_name].shape == (3, 3)
        assert np.allclose(fr.extrinsics[fr.camera_name], frames[0].extrinsics)
        out = fr.for_camera(fr.camera_name)
        assert len(out) == 4 and out[2].shape == frames[0].bboxes_2d.shape
        assert fr.match_matrix.shape == frames[0].match_matrix.shape
        assert len(fr.frame.camera_view(fr.camera_name)) == 5  # xcalib's form, with the match matrix
        m = tiny_matcher()
        assert isinstance(m.match_frame(fr, validate="off"), MatchResult)
    with pytest.raises(ValueError, match="never downloads"):
        xcalib.load_dataset("a9_dataset_r02_s01", repo_id="UArizona/xcalib-a9")


# ------------------------------------------------------------------ item 1: one-shot session
def test_item01_oneshot_reference_usage():
    from xcalib.data.synth import generate_frames

    site = small_site()
    frames = generate_frames(site, 3, seed=1, render_images=False)
    m = tiny_matcher()
    s = m.oneshot(site.intrinsics, accept_confidence=0.0, max_center_dist_px=64, bank_capacity=4096,
                  calib_buffer=500, calib_reproj_px=8, replay_frames=16, min_frames=50)  # no scheduled attempts
    assert s.match_threshold == 0.7 and s.bank is s.buffer and s.calib_session is s.pose
    assert s.best_reproj_px == float("inf")
    reps = [s.observe(f.image, f.point_cloud, f.bboxes_2d, f.bboxes_3d, validate="off") for f in frames[:2]]
    assert [r.frame_id for r in reps] == [0, 1] and reps[-1].n_banked == 0 and reps[-1].bank_size == 0
    warm = s.calibrate(min_pairs=4, disambiguate=True, gate_factor=2.0, min_frames=3)
    assert not warm.accepted and not s.is_calibrated and "warming up" in warm.reason
    assert warm.result is not None and warm.success == warm.result.success
    assert warm.n_correspondences == warm.result.n_correspondences and np.isnan(warm.buffer_reproj_px) != warm.success
    assert (warm.projection is None) != warm.success
    s.set_calibration(_gt_pose(site))
    r = s.observe(frames[0].image, frames[0].point_cloud, frames[0].bboxes_2d, frames[0].bboxes_3d, validate="off")
    assert r.n_banked > 0 and r.bank_size >= r.n_banked
    p = inspect.signature(s.adapt).parameters
    assert p["steps"].default == 50 and {"batch_size", "temperature", "replay_weight", "min_bank"} <= set(p)
    rep = s.adapt(2, lr=1e-3, batch_size=64, temperature=0.1, mode="adapter", replay_weight=1.0, min_bank=1)
    assert rep.steps == 2 and rep.n_bank_pairs == rep.n_pairs and m.model.temperature == 0.1


# ------------------------------------------------------------------ item 4: build
def test_item04_build_paths_and_result_fields(tmp_path, monkeypatch):
    pytest.importorskip("onnx")
    m = Matcher.from_pretrained("fastmatch", weights=_saved(tmp_path), device="cpu")
    res = m.build("onnx", tmp_path / "out", verify=False)
    assert res.output_dir == tmp_path / "out" and (tmp_path / "out" / "manifest.json").is_file()
    assert [f.name for f in __import__("dataclasses").fields(res)][:6] == [
        "target", "model", "output_dir", "artifacts", "parity", "logs"]
    monkeypatch.chdir(tmp_path)
    res2 = m.build("onnx", verify=False)  # the reference's default ./onnx/<model>/
    assert res2.output_dir == __import__("pathlib").Path("onnx") / "fastmatch"
    assert res2.parity_ok is False and res2.parity == {}  # deliberate: unchecked parity is not "ok"


# ------------------------------------------------------------------ item 9: CLI
def test_item09_cli_reference_commands(tmp_path, capsys, monkeypatch):
    w = _saved(tmp_path)
    assert main(["demo", "--n-image", "2", "--n-lidar", "3", "--device", "cpu", "--site", "x", "--weights", str(w),
                 "--model", "fastmatch"]) == 0
    out = capsys.readouterr().out
    assert "similarity shape: (2, 3)" in out and "latency" in out
    assert main(["export-onnx", "--model", "fastmatch", "--repo", "org/repo"]) == 1
    assert "xcalib bootstrap" in capsys.readouterr().err
    monkeypatch.setenv("PATH", str(tmp_path))  # no trtexec anywhere -> exit 1 (2: usage errors)
    monkeypatch.setattr("xcalib.deploy.trt.SEARCH_DIRS", (), raising=False)
    assert main(["build-trt", "--model", "fastmatch", "--site", "x", "--trtexec", str(tmp_path / "nope")]) == 1
    pytest.importorskip("onnxruntime")
    assert main(["export-onnx", "--model", "fastmatch", "--weights", str(w), "--output", str(tmp_path / "o")]) == 0
    assert "worst parity" in capsys.readouterr().out and (tmp_path / "o" / "manifest.json").is_file()


# ------------------------------------------------------------------ migration table (docs/compat.md)
def test_migration_crlite_scores_are_probabilities():
    m = tiny_matcher(model="crlite")
    f = make_frame(5, n_obj=5)
    s = m.match(*f.inputs(), validate="off").similarity
    assert np.all(((s >= 0) & (s <= 1)) | (s == -1))
    assert not np.all(np.isclose(s.max(axis=1), 1.0))  # not min-max normalised per row


def test_migration_sparse_box_warning():
    f = make_frame(6, n_obj=2)
    b3 = np.vstack([f.bboxes_3d, [[200.0, 0, 0, 2, 2, 2]]]).astype(np.float32)  # far: no point inside
    codes = {v.code for v in xcalib.validate_frame_inputs(f.image, f.point_cloud, f.bboxes_2d, b3)}
    assert "bboxes_3d.sparse" in codes


def test_migration_no_hub_downloads(tmp_path, monkeypatch):
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path))
    assert inspect.signature(Matcher.from_pretrained).parameters["site"].default == "synthetic"
    with pytest.raises(ValueError, match="never downloads"):
        Matcher.from_pretrained("fastmatch", repo_id="UArizona/xcalib")
    with pytest.raises(FileNotFoundError, match="xcalib bootstrap"):
        Matcher.from_pretrained("crlite", site="a9_dataset_r02_s01")
    with pytest.raises(ValueError, match="never downloads"):
        xcalib.load_dataset("a9_dataset_r02_s01", token="t")


def test_migration_strict_loading(tmp_path):
    from xcalib.engine.checkpoint import WeightsMismatchError

    d = _saved(tmp_path)
    with pytest.raises(WeightsMismatchError, match="shape mismatch"):
        Matcher("fastmatch", {**TINY["fastmatch"], "embed_dim": 24}, d / "fastmatch.pth", "cpu")


def test_migration_onnx_layout(tmp_path):
    pytest.importorskip("onnx")
    m = Matcher.from_pretrained("fastmatch", weights=_saved(tmp_path), device="cpu")
    res = m.build("onnx", tmp_path / "o", verify=False)
    man = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert set(man["graphs"]) >= {"image_embed", "lidar_embed"} and not (tmp_path / "o" / "stage1.onnx").exists()
    assert res.parity_ok is False  # parity not checked is never reported as OK
    pytest.importorskip("onnxruntime")
    f = make_frame(7)
    om = Matcher.from_onnx(tmp_path / "o")
    r = om.match(*f.inputs(), validate="off")
    assert np.allclose(r.similarity, m.match(*f.inputs(), validate="off").similarity, atol=1e-4)


def test_migration_oneshot_options_without_effect():
    from xcalib.data.synth import generate_frames

    site = small_site()
    frames = generate_frames(site, 3, seed=2, render_images=False)
    runs = []
    for opts in ({}, {"max_center_dist_px": 1.0, "bank_capacity": 1, "calib_buffer": 1, "calib_reproj_px": 0.1}):
        s = tiny_matcher().oneshot(site.intrinsics, **opts)
        s.set_calibration(_gt_pose(site))
        reps = [s.observe_frame(f, validate="off") for f in frames]
        runs.append(([(r.n_matches, r.n_pseudo_pairs, r.n_banked, r.bank_size) for r in reps],
                     [t.positive.tolist() for t in s.pseudo_labels()]))
    assert runs[0] == runs[1] and runs[0][0][-1][3] > 0
    assert s.reference_options["bank_capacity"] == 1 and s.accept_confidence == 0.0


def test_migration_train_config_values(tmp_path):
    p = inspect.signature(xcalib.train).parameters
    assert all(p[k].default is None for k in ("temperature", "stage1_weight", "stage2_weight"))
    states = []
    for k, pbs in enumerate((1, 64)):
        best = xcalib.train("crlite", make_frames(3, 1, n_obj=2), None, config=TINY["crlite"], epochs=1,
                            pairwise_batch_size=pbs, output_dir=tmp_path / str(k), device="cpu", progress=False,
                            frames_per_batch=3, seed=0)
        ck = torch.load(best, weights_only=True)
        assert ck["train_args"]["temperature"] == pytest.approx(TINY["crlite"].get("temperature", 0.07))
        states.append(ck["model_state_dict"])
    assert all(torch.equal(states[0][k], states[1][k]) for k in states[0])
