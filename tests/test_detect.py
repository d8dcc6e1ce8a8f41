"""xcalib.detect: the ONNX camera detector (shipped YOLOX-Nano and user layouts), label-free LiDAR
boxes on synthetic clouds with known boxes, `xcalib detect` writing a bag that `calibrate` reads,
and bad detector files refused with FormatError."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.conftest import shared_path
from xcalib.detect.camera import decode_yolox, grid_cells, nms
from xcalib.detect.lidar import LidarDetectConfig, build_background, fit_ground, is_static_recording, lidar_boxes
from xcalib.errors import FormatError

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")


# ----------------------------------------------------------------------------- camera: post-processing
def test_decode_yolox_and_nms():
    in_h, in_w = 64, 96
    n = grid_cells(in_h, in_w)
    raw = np.zeros((n, 5 + 3))
    raw[:, 2:4] = np.log(4.0)  # 4 strides wide
    # cell (x=2, y=1) of stride 8 is row 1 * 12 + 2 = 14; offset 0.5 -> centre (20, 12) px, size 32 px
    raw[14, :2] = 0.5
    out = decode_yolox(raw, in_h, in_w)
    assert np.allclose(out[14, :4], [20, 12, 32, 32])
    first16 = (in_h // 8) * (in_w // 8)  # first cell of stride 16: centre (0 + 0) * 16, size 64
    assert np.allclose(out[first16, :4], [0, 0, 64, 64])
    boxes = np.array([[0, 0, 10, 10], [1, 1, 10, 10], [20, 20, 30, 30]], float)
    keep = nms(boxes, np.array([0.5, 0.9, 0.3]), 0.45)
    assert keep.tolist() == [1, 2]  # the overlapping lower score is suppressed


def _const_model(path, out: np.ndarray, in_shape=(1, 3, 64, 64), in_type=None):
    """An ONNX 'detector' returning a constant tensor (its image input is ignored)."""
    from onnx import TensorProto, helper, numpy_helper

    node = helper.make_node("Constant", [], ["output"], value=numpy_helper.from_array(out.astype(np.float32)))
    g = helper.make_graph([node], "g", [helper.make_tensor_value_info("images", in_type or TensorProto.FLOAT,
                                                                      list(in_shape))],
                          [helper.make_tensor_value_info("output", TensorProto.FLOAT, list(out.shape))])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 13)])
    m.ir_version = 8
    onnx.save(m, str(path))
    return path


def test_user_yolov8_layout_is_decoded_into_image_pixels(tmp_path):
    from xcalib.detect.camera import Detector2DConfig, load_detector

    cells = grid_cells(96, 96)  # 189
    out = np.zeros((1, 4 + 80, cells))
    out[0, :4, 5] = [48, 48, 24, 24]  # cx, cy, w, h in input pixels
    out[0, 4 + 2, 5] = 0.9            # COCO class 2 = car
    out[0, :4, 6] = [10, 10, 12, 12]
    out[0, 4 + 9, 6] = 0.95           # traffic light: not a traffic class, dropped
    det = load_detector(_const_model(tmp_path / "v8.onnx", out, (1, 3, 96, 96)), Detector2DConfig(min_box_px=2))
    assert det.layout == "yolov8" and det.fixed_hw == (96, 96)
    d = det(np.zeros((96, 192, 3), np.uint8))  # scale 0.5, centred: input = image / 2 + (0, 24) px
    assert d.class_names == ("car",) and np.allclose(d.boxes, [[72, 24, 120, 72]]) and np.isclose(d.scores[0], 0.9)


def test_bad_detector_files_are_refused(tmp_path):
    from onnx import TensorProto

    from xcalib.detect.camera import load_detector

    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"\x08\x07this is not a protobuf" * 10)
    with pytest.raises(FormatError, match="garbage.onnx"):
        load_detector(garbage)
    with pytest.raises(FormatError, match="expected an .onnx"):
        (tmp_path / "model.pt").write_bytes(b"x")
        load_detector(tmp_path / "model.pt")
    # a segmentation-like output [1, 3, 64, 64]: not a detector layout
    with pytest.raises(FormatError, match="graph.output"):
        load_detector(_const_model(tmp_path / "seg.onnx", np.zeros((1, 3, 64, 64))))
    # [1, N, 85] with N matching no grid of the input
    with pytest.raises(FormatError, match="no supported layout"):
        load_detector(_const_model(tmp_path / "n.onnx", np.zeros((1, 1000, 85))))
    # a grey-scale input
    with pytest.raises(FormatError, match=r"\[1, 3, H, W\]"):
        load_detector(_const_model(tmp_path / "g.onnx", np.zeros((1, 84, 84)), in_shape=(1, 1, 64, 64)))
    with pytest.raises(FormatError, match="float32"):
        load_detector(_const_model(tmp_path / "u8.onnx", np.zeros((1, 84, 84)), in_type=TensorProto.UINT8))


def test_external_data_outside_the_model_folder_is_refused(tmp_path):
    from onnx import TensorProto, helper

    from xcalib.detect.camera import load_detector

    w = helper.make_tensor("w", TensorProto.FLOAT, [1], [0.0])
    w.data_location = TensorProto.EXTERNAL
    w.ClearField("float_data")
    w.external_data.add(key="location", value="../../etc/passwd")
    node = helper.make_node("Identity", ["w"], ["output"])
    g = helper.make_graph([node], "g", [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 64, 64])],
                          [helper.make_tensor_value_info("output", TensorProto.FLOAT, [1, 84, 84])], initializer=[w])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 13)])
    (tmp_path / "m").mkdir()
    p = tmp_path / "m" / "ext.onnx"
    p.write_bytes(m.SerializeToString())
    with pytest.raises(FormatError, match="outside the model's folder"):
        load_detector(p)


def test_shipped_detector_on_a_real_image_matches_the_reference_run():
    import cv2

    from xcalib.detect.camera import Detector2DConfig, load_detector

    img_path = shared_path("a9_sample", "frame_0000", "image.png")
    ref_path = shared_path("real_detections", "yolox_nano_1280", "a9", "frame_0000.json")
    det = load_detector(None, Detector2DConfig(score_min=0.3, classes=(), min_box_px=0))
    d = det(cv2.imread(str(img_path))[..., ::-1].copy())
    ref = [r for r in json.loads(ref_path.read_text())["detections"] if r["score"] >= 0.3]
    assert det.layout == "yolox" and len(d) == len(ref) > 5
    rb = np.array([[r["x1"], r["y1"], r["x2"], r["y2"]] for r in ref])
    assert np.abs(np.sort(d.boxes, 0) - np.sort(rb, 0)).max() < 0.5  # the reference script's boxes, to rounding
    assert sorted(d.class_names) == sorted(r["class"] for r in ref)


# ----------------------------------------------------------------------------- LiDAR: synthetic clouds
def _box_surface(rng, c, size, yaw, n):
    """Points on the 4 sides and the top of a box (bottom on z = c_z - h/2)."""
    l, w, h = size
    u = rng.uniform(-0.5, 0.5, (n, 3))
    face = rng.integers(0, 5, n)
    u[face == 0, 0], u[face == 1, 0] = 0.5, -0.5
    u[face == 2, 1], u[face == 3, 1] = 0.5, -0.5
    u[face == 4, 2] = 0.5
    p = u * [l, w, h]
    cs, sn = np.cos(yaw), np.sin(yaw)
    return np.column_stack([p[:, 0] * cs - p[:, 1] * sn, p[:, 0] * sn + p[:, 1] * cs, p[:, 2]]) + c


def _scene(rng, objects, *, tilt_deg=2.0, sensor_h=1.8, clutter=True):
    """Ground tilted about y by ``tilt_deg`` below a sensor, objects standing on it; returns
    (cloud [P, 3], true box7 [M, 7])."""
    t = np.tan(np.radians(tilt_deg))
    g = rng.uniform(-40, 40, (30000, 2))
    ground = np.column_stack([g, -sensor_h + t * g[:, 0] + rng.normal(0, 0.03, len(g))])
    pts, truth = [ground], []
    for (x, y, l, w, h, yaw) in objects:
        z0 = -sensor_h + t * x
        pts.append(_box_surface(rng, (x, y, z0 + h / 2), (l, w, h), yaw, 600))
        truth.append((x, y, z0 + h / 2, l, w, h, yaw))
    if clutter:
        pts.append(_box_surface(rng, (0, 30, -sensor_h + 1.5), (40, 0.3, 3.0), 0.0, 3000))  # a wall
        pts.append(_box_surface(rng, (-15, -15, -sensor_h + 3.0), (0.3, 0.3, 6.0), 0.0, 300))  # a pole
        pts.append(_box_surface(rng, (10, -20, -sensor_h + 4.5), (3, 3, 1.5), 0.0, 500))  # a canopy
    return np.concatenate(pts).astype(np.float32), np.array(truth)


OBJECTS = [(8, 3, 4.5, 1.8, 1.5, 0.3), (-12, 6, 4.2, 1.9, 1.6, -1.2), (15, -6, 10.0, 2.5, 3.2, 0.05),
           (-5, -10, 0.6, 0.6, 1.75, 0.0), (25, 12, 4.6, 1.8, 1.5, 1.0)]


def _yaw_gap(a, b):
    d = (a - b) % np.pi
    return np.minimum(d, np.pi - d)


def test_lidar_boxes_find_the_objects_and_drop_the_clutter():
    rng = np.random.default_rng(0)
    cloud, truth = _scene(rng, OBJECTS)
    ground = fit_ground(cloud)
    assert np.degrees(np.arccos(ground.normal[2])) == pytest.approx(2.0, abs=0.3)
    boxes = lidar_boxes(cloud, LidarDetectConfig(mode="moving"))
    D = np.linalg.norm(truth[:, None, :2] - boxes[None, :, :2], axis=2)
    found = D.min(1) < 0.5
    assert found.mean() >= 0.8  # recall
    j = D.argmin(1)[found]
    assert np.median(D.min(1)[found]) < 0.15  # centre error, m
    big = found & (truth[:, 3] > 2)  # yaw and size of the vehicles
    jb = D.argmin(1)[big]
    assert np.all(_yaw_gap(boxes[jb, 6], truth[big, 6]) < np.radians(5))
    assert np.allclose(boxes[jb, 3:5], truth[big, 3:5], atol=0.3)
    assert np.allclose(boxes[j, 5], truth[found, 5], atol=0.3)
    assert len(boxes) == found.sum()  # wall, pole and canopy are not objects


def test_static_lidar_background_model_removes_what_never_moves():
    rng = np.random.default_rng(1)
    parked = (-12, 6, 4.2, 1.9, 1.6, -1.2)
    clouds, truths = [], []
    for k in range(6):  # one car drives by along x, one car is parked the whole time
        cloud, truth = _scene(rng, [parked, (-20 + 8 * k, -4, 4.5, 1.8, 1.5, 0.0)], clutter=True)
        clouds.append(cloud)
        truths.append(truth)
    cfg = LidarDetectConfig(mode="static", background_fraction=0.8)
    assert is_static_recording(clouds, cfg)
    ground = fit_ground(np.concatenate(clouds[:2]), cfg)
    bg = build_background(clouds, cfg, ground=ground)
    for cloud, truth in zip(clouds, truths):
        boxes = lidar_boxes(cloud, cfg, ground=ground, background=bg)
        assert len(boxes) == 1 and np.linalg.norm(boxes[0, :2] - truth[1, :2]) < 0.3  # only the moving car
    moved = [_scene(rng, [], clutter=False)[0] + np.float32([60 * k, 0, 0]) for k in range(2)]
    assert not is_static_recording(moved, cfg)


# ----------------------------------------------------------------------------- CLI: detect -> bag -> calibrate
def test_detect_cli_writes_a_bag_that_calibrate_reads(tmp_path, capsys):
    from xcalib.cli import main
    from xcalib.io.bags import BagFrames, bag_info, write_bag
    from xcalib.io.frames import read_frames

    seq = read_frames(shared_path("a9_sample"))
    raw = write_bag(tmp_path / "raw.mcap", [seq[i] for i in range(2)], detections=False)
    assert not any("Detection" in t.msgtype for t in bag_info(raw).topics)
    assert main(["calibrate", str(raw), "--out", str(tmp_path / "r0")]) == 1
    assert "--detect" in capsys.readouterr().err  # the error names the way out
    out = tmp_path / "det.mcap"
    assert main(["detect", str(raw), "--out", str(out), "--lidar-mode", "moving"]) == 0
    bf = BagFrames(out)
    src = BagFrames(raw, detections=False)
    assert len(bf) == 2 and bf.report.max_dt_s == src.report.max_dt_s
    for key in ("lidar_stamp_ns", "camera_stamp_ns"):  # the recording's stamps to the nanosecond
        assert [f.meta[key] for f in bf] == [f.meta[key] for f in src]
    f = bf[0]
    assert f.num_2d > 3 and f.num_3d > 3 and f.bboxes_3d.shape[1] == 7
    assert np.array_equal(f.point_cloud, src[0].point_cloud)
    rc = main(["calibrate", str(out), "--out", str(tmp_path / "r1"), "--max-overlays", "0", "--frames", "0:1"])
    assert rc in (0, 1) and (tmp_path / "r1" / "calibration.json").is_file()  # read and judged (1 frame)
    assert main(["detect", str(raw), "--out", str(out)]) == 2  # exists, no --force


def test_layering_detect_imports_nothing_above_it():
    import subprocess
    import sys

    code = ("import sys, xcalib.detect; print(sorted(m for m in ('xcalib.calib', 'xcalib.cli', 'xcalib.site', "
            "'xcalib.models', 'torch', 'onnxruntime') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"  # onnxruntime only when a detector is loaded


class _FakeDetector:
    """A stand-in camera detector: one fixed box per image."""

    path = __import__("pathlib").Path("fake.onnx")
    layout = "fake"

    def __init__(self):
        self.calls = 0

    def __call__(self, image):
        from xcalib.detect.camera import Detections2D

        self.calls += 1
        return Detections2D(np.array([[1, 2, 30, 40]], np.float32), np.array([0.9], np.float32),
                            np.array([2]), ("car",))


def test_detected_frames_replace_the_boxes_once_and_keep_the_sensors():
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.detect import DetectConfig, DetectedFrames, LidarDetectConfig

    frames = generate_frames(sample_site(3, width=320, height=200, focal_px=300), 2, seed=0)
    fake = _FakeDetector()
    det = DetectedFrames(frames, DetectConfig(lidar=LidarDetectConfig(mode="moving")), detector=fake).run()
    assert det.mode == "moving" and len(det) == 2 and fake.calls == 2 and det.replaced == 2  # synthetic labels
    f = det[1]
    assert fake.calls == 2  # boxes kept, not detected again
    assert np.array_equal(f.bboxes_2d, [[1, 2, 30, 40]]) and f.match_matrix is None and f.bboxes_3d.shape[1] == 7
    assert np.array_equal(f.point_cloud, frames[1].point_cloud) and f.detections.classes_2d == ("car",)
    assert det.counts() == (2, sum(len(det[i].bboxes_3d) for i in range(2))) and det.counts()[1] > 0


def test_detect_help_and_usage_errors(tmp_path, capsys):
    from xcalib.cli import main

    assert main(["detect", "--help"]) == 0
    assert "Example: xcalib detect" in capsys.readouterr().out
    assert main(["detect", str(tmp_path), "--out", str(tmp_path / "x.txt")]) == 2  # not a bag name
    assert main(["detect", str(tmp_path), "--out", str(tmp_path / "x.mcap"), "--lidar-mode", "flying"]) == 2
