"""``xcalib demo`` end to end on a small synthetic site (+ a tiny "real" frame folder), its report
and summary, and how it degrades when a piece is missing."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from xcalib.cli import _demo, main
from xcalib.cli.demo_cmd import _write_tiny_frames
from xcalib.io import read_frames
from xcalib.protocol import validate_frame_inputs


def test_tiny_synthetic_frames_are_valid_and_consistent(tmp_path):
    ff = read_frames(_write_tiny_frames(tmp_path / "frames", num_frames=2))
    assert len(ff) == 2 and ff.intrinsics is not None
    for fr in ff:
        assert [v for v in validate_frame_inputs(*fr.inputs()) if v.severity == "error"] == []
        assert fr.match_matrix.shape == (fr.num_2d, fr.num_3d) and fr.extrinsics.shape == (4, 4)
        assert np.all(fr.bboxes_2d[:, 2] > fr.bboxes_2d[:, 0])


@pytest.fixture(scope="module")
def untrained_weights(tmp_path_factory):
    import torch

    from xcalib.engine.matcher import Matcher

    torch.manual_seed(0)
    d = tmp_path_factory.mktemp("weights")
    Matcher("fastmatch", device="cpu", allow_random=True).save_pretrained(d)
    return d


def _images_of(html: Path) -> list[Path]:
    return [html.parent / m for m in re.findall(r'<img src="([^"]+)"', html.read_text())]


@pytest.mark.slow
def test_demo_end_to_end(tmp_path, capsys, untrained_weights):
    from xcalib.engine.checkpoint import packaged_weights_dir

    shipped = (packaged_weights_dir() / "synthetic" / "fastmatch.pt").is_file()
    real = _write_tiny_frames(tmp_path / "real", num_frames=3)
    out = tmp_path / "demo"
    # 8 frames: 6 of this site fit the focal length x1.015 +- 2.4 %, too wide to rule out a 5 % error,
    # and are refused as not verifiable (focal_unverifiable); 8 fit +- 1.4 %
    argv = ["demo", "--out", str(out), "--n-frames", "8", "--real", str(real), "--json"]
    rc = main(argv if shipped else argv + ["--weights", str(untrained_weights)])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert json.loads((out / "summary.json").read_text())["calibrations"].keys() == summary["calibrations"].keys()
    # matching ran and was scored against the true matches (untrained weights: any accuracy)
    m = summary["matching"]
    assert m["ok"] and m["n_detections"] > 10 and 0.0 <= m["top1"] <= m["top3"] <= 1.0
    if shipped:  # the demo site is the one the shipped weights were trained for (unseen traffic)
        assert m["top1"] > 0.8
    # calibration with no labels and no guess recovers the synthetic pose
    syn = summary["calibrations"]["synthetic"]
    assert syn["success"] and syn["rotation_error_deg"] < 1.0 and syn["translation_error_m"] < 0.5
    assert syn["pair_precision"] > 0.9
    # the real-frame run is reported either way (tiny frames may be too few to calibrate)
    assert "real" in summary["calibrations"]
    # reports: index links both runs; every image a report shows exists
    index = (out / "index.html").read_text()
    assert 'href="synthetic/report.html"' in index
    imgs = _images_of(out / "synthetic" / "report.html")
    assert len(imgs) >= 4 and all(p.is_file() and p.stat().st_size > 1000 for p in imgs)
    assert any("matching" in p.name for p in imgs) and any(p.parent.name == "overlays" for p in imgs)
    assert (out / "synthetic" / "calibration.json").is_file()


def test_missing_weights_degrade_to_a_message(tmp_path):
    matcher, why = _demo.load_matcher("fastmatch", tmp_path / "nowhere.pt")
    assert matcher is None and "nowhere.pt" in why


def test_pair_accuracy_counts_true_and_false_pairs():
    class R:
        pairs = [np.array([[0, 0], [1, 2]]), np.zeros((0, 2), np.int64)]

    class F:
        def __init__(self, mm):
            self.match_matrix = mm

    mm0 = np.zeros((2, 3), bool)
    mm0[0, 0] = mm0[1, 1] = True
    mm1 = np.eye(2, dtype=bool)
    precision, recall = _demo.pair_accuracy(R(), [F(mm0), F(mm1)])
    assert precision == pytest.approx(0.5) and recall == pytest.approx(1 / 4)


def test_find_real_frames_prefers_the_explicit_folder(tmp_path):
    assert _demo.find_real_frames(tmp_path) == tmp_path


def test_the_default_demo_site_calibrates():
    """``make demo`` runs 20 frames of traffic seed 5 at site 0 (the defaults): that clean site must
    calibrate (a principal-point test at 3 sigmas refused it once: a false 38 px shift)."""
    from xcalib.calib.api import calibrate

    data = _demo.synthetic_site(20, 5)
    res = calibrate(data.frames, data.site.intrinsics)
    assert res.success, res.message
    rot, trans = res.pose_error(data.truth)
    assert rot < 0.5 and trans < 0.3
