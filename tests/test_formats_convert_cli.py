"""``xcalib convert`` end to end (in-process)."""

from __future__ import annotations

import json

import numpy as np
from conftest import shared_path

from xcalib.cli import main
from xcalib.formats.export import read_calibration
from xcalib.geometry import euler_to_matrix

KITTI = ("P2: 700.0 0 600.0 45.0 0 700.0 180.0 0.2 0 0 1 0.003\n"
         "R0_rect: 1 0 0 0 1 0 0 0 1\n"
         "Tr_velo_to_cam: {}\n")


def _kitti(tmp_path, R, t=(0.1, -0.2, -0.3)):
    vals = np.hstack([R, np.reshape(t, (3, 1))]).ravel()
    p = tmp_path / "calib.txt"
    p.write_text(KITTI.format(" ".join(repr(float(v)) for v in vals)))
    return p


def test_convert_kitti_to_lucid_and_back(tmp_path, capsys):
    R = euler_to_matrix([-1.5, 0.01, -1.6])
    src = _kitti(tmp_path, R)
    assert main(["convert", str(src), "--to", "lucid", "--out", str(tmp_path / "l.json"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["from"] == "kitti" and out["written"] == [str(tmp_path / "l.json")]
    a, b = read_calibration(src), read_calibration(tmp_path / "l.json")
    np.testing.assert_allclose(b.extrinsics, a.extrinsics, atol=1e-9)
    # the P2 offset K^-1 P2[:,3] is folded into the translation
    assert abs(a.translation[0] - (0.1 + (45.0 - 600.0 * 0.003) / 700.0)) < 1e-12


def test_convert_repair_and_errors(tmp_path, capsys):
    src = _kitti(tmp_path, euler_to_matrix([0.1, 0.2, 0.3]) * (1 + 2e-4))
    assert main(["convert", str(src), "--to", "json", "--out", str(tmp_path / "c.json")]) == 1
    err = capsys.readouterr().err
    assert "Tr_velo_to_cam" in err and "--repair" in err
    assert main(["convert", str(src), "--to", "json", "--out", str(tmp_path / "c.json"), "--repair"]) == 0
    R = read_calibration(tmp_path / "c.json").rotation
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert main(["convert", str(src), "--to", "waymo"]) == 2
    assert main(["convert", str(tmp_path / "missing.txt"), "--to", "kitti"]) == 1


def test_convert_real_lucid_sample(tmp_path, capsys):
    lucid = shared_path("calibanything", "format_examples", "lucid_calib.json")
    assert main(["convert", str(lucid), "--to", "calib_json", "--out", str(tmp_path / "calib.json")]) == 0
    d = json.loads((tmp_path / "calib.json").read_text())
    ref = json.loads(shared_path("calibanything", "format_examples",
                                 "plextechSC_output_daytimetraffic_cam03_calib.json").read_text())
    np.testing.assert_allclose(d["T_lidar_to_cam"]["data"], ref["T_lidar_to_cam"]["data"], atol=1e-12)
    assert d["cam_dist"]["data"][:2] == [-0.056582, 0.091158]  # unlike their converter, distortion is kept
