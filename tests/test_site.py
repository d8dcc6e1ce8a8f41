"""One LiDAR, many cameras: xcalib calibrate --camera A --camera B on the nuScenes sample; the
site calibration, its ROS files and the Foxglove review file."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest
from conftest import shared_path

from xcalib.cli import main
from xcalib.site import SiteCalibration

NUS = ("nuscenes", "mmdet3d_demo", "n015-2018-07-24-11-22-45+0800.pkl")
SCHEMAS = {"foxglove.FrameTransforms", "foxglove.PointCloud", "foxglove.CompressedImage",
           "foxglove.ImageAnnotations", "foxglove.CameraCalibration"}


@pytest.fixture(scope="module")
def nus_site(tmp_path_factory):
    pkl = shared_path(*NUS)
    out = tmp_path_factory.mktemp("nus") / "site"
    code = main(["calibrate", str(pkl), "--camera", "CAM_FRONT", "--camera", "CAM_FRONT_RIGHT", "--camera",
                 "CAM_FRONT_LEFT", "--out", str(out), "--max-overlays", "1"])
    return code, out


def test_site_calibration_per_camera_verdicts(nus_site):
    code, out = nus_site
    assert code == 1  # CAM_FRONT_LEFT sees 2 objects: refused, so the run is not a full success
    d = json.loads((out / "site_calibration.json").read_text())
    edges = {e["camera"]: e for e in d["transforms"]}
    assert {e["child"] for e in d["transforms"]} == {"CAM_FRONT_optical_frame", "CAM_FRONT_RIGHT_optical_frame",
                                                     "CAM_FRONT_LEFT_optical_frame"}
    assert edges["CAM_FRONT_LEFT"]["verdict"] == "refused" and "too few detections" in edges["CAM_FRONT_LEFT"]["message"]
    for cam in ("CAM_FRONT", "CAM_FRONT_RIGHT"):
        e = edges[cam]
        assert e["verdict"] == "calibrated" and e["parent"] == "lidar"
        assert e["error_vs_truth"]["rotation_deg"] < 0.3 and e["error_vs_truth"]["translation_m"] < 0.05
        assert max(e["rotation_std_deg"]) < 0.5 and np.allclose(
            np.linalg.inv(np.array(e["T_cam_lidar"])), np.array(e["T_parent_child"]))
    (ag,) = d["agreements"]
    assert {ag["camera_a"], ag["camera_b"]} == {"CAM_FRONT", "CAM_FRONT_RIGHT"} and ag["shared_objects"] >= 5
    assert ag["relative_error_deg"] < 0.3 and ag["iou_a_median"] > 0.7
    site = SiteCalibration.load(out / "site_calibration.json")
    assert [c.verdict for c in site.cameras] == ["calibrated", "calibrated", "refused"]
    assert (out / "CAM_FRONT" / "report.html").is_file() and "CAM_FRONT_LEFT" in (out / "report.html").read_text()


def test_site_ros_files(nus_site):
    import yaml

    _, out = nus_site
    tf = yaml.safe_load((out / "ros" / "tf_static.yaml").read_text())
    assert [t["child_frame_id"] for t in tf["transforms"]] == ["CAM_FRONT_optical_frame",
                                                                "CAM_FRONT_RIGHT_optical_frame"]
    lines = [ln for ln in (out / "ros" / "static_transforms.sh").read_text().splitlines() if ln.startswith("ros2")]
    assert len(lines) == 2
    for ln in lines:
        tok = shlex.split(ln.rstrip("&"))
        nums = [float(tok[i + 1]) for i, t in enumerate(tok) if t in ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw")]
        assert len(nums) == 7 and abs(np.linalg.norm(nums[3:]) - 1) < 1e-9
    assert "CAM_FRONT_LEFT: refused" in (out / "ros" / "static_transforms.sh").read_text()
    assert (out / "ros" / "CAM_FRONT_camera_info.yaml").is_file() and "CAM_FRONT_link" in (out / "ros" / "site.urdf").read_text()


def test_review_mcap_channels_and_schemas(nus_site):
    from mcap.reader import make_reader

    _, out = nus_site
    with open(out / "review.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        chans = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        assert set(chans.values()) == SCHEMAS and all(c.message_encoding == "json" for c in summary.channels.values())
        assert chans["/CAM_FRONT/annotations"] == "foxglove.ImageAnnotations" and chans["/tf"] == "foxglove.FrameTransforms"
        msgs = {ch.topic: json.loads(m.data) for _, ch, m in reader.iter_messages()}
    children = {t["child_frame_id"] for t in msgs["/tf"]["transforms"]}
    assert children == {"CAM_FRONT_optical_frame", "CAM_FRONT_RIGHT_optical_frame"}
    assert len(msgs["/CAM_FRONT/annotations"]["points"]) > 10
    assert not msgs["/CAM_FRONT_LEFT/annotations"]["points"][-1]["type"] == 1  # refused: no projected points
    assert msgs["/CAM_FRONT/calibration"]["frame_id"] == "CAM_FRONT_optical_frame"
