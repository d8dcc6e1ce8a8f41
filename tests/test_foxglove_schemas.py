"""The review file's messages (``review.mcap``: foxglove.CompressedImage, ImageAnnotations,
CameraCalibration, PointCloud, FrameTransforms as JSON) valid against Foxglove's schemas (issue 30).

Two checks: against the field definitions of the published ``@foxglove/schemas`` 2.1.0 JSON
schemas written out here (required fields, JSON types, nested types; always run), and against
the published package itself with ``jsonschema`` when it is installed (npm: ``npm install
@foxglove/schemas`` in or above the repository, or ``XCALIB_FOXGLOVE_SCHEMAS`` = the package
folder); skipped cleanly when absent."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

from xcalib.calib.result import CalibrationResult
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.site import calibrate_site
from xcalib.types import Frame
from xcalib.viz.review import write_review_mcap

# -------------------------------------------------- the published definitions (@foxglove/schemas 2.1.0)
# type name -> {field: (JSON type, nested type or None, required)}; "array" fields name their item type
TIME = {"sec": ("integer", None, False), "nsec": ("integer", None, False)}
COLOR = {k: ("number", None, True) for k in "rgba"}
POINT2 = {k: ("number", None, True) for k in "xy"}
VECTOR3 = {k: ("number", None, True) for k in "xyz"}
QUATERNION = {k: ("number", None, True) for k in "xyzw"}
POSE = {"position": ("object", "Vector3", True), "orientation": ("object", "Quaternion", True)}
PACKED_FIELD = {"name": ("string", None, True), "offset": ("integer", None, True), "type": ("integer", None, True)}
KEY_VALUE = {"key": ("string", None, True), "value": ("string", None, True)}
POINTS_ANNOTATION = {"timestamp": ("object", "Time", True), "type": ("integer", None, True),
                     "points": ("array", "Point2", True), "outline_color": ("object", "Color", True),
                     "outline_colors": ("array", "Color", True), "fill_color": ("object", "Color", True),
                     "thickness": ("number", None, True), "metadata": ("array", "KeyValuePair", False)}
CIRCLE = {"timestamp": ("object", "Time", True), "position": ("object", "Point2", True),
          "diameter": ("number", None, True), "thickness": ("number", None, True),
          "fill_color": ("object", "Color", True), "outline_color": ("object", "Color", True),
          "metadata": ("array", "KeyValuePair", False)}
TEXT = {"timestamp": ("object", "Time", True), "position": ("object", "Point2", True), "text": ("string", None, True),
        "font_size": ("number", None, True), "text_color": ("object", "Color", True),
        "background_color": ("object", "Color", True), "metadata": ("array", "KeyValuePair", False)}
FRAME_TRANSFORM = {"timestamp": ("object", "Time", True), "parent_frame_id": ("string", None, True),
                   "child_frame_id": ("string", None, True), "translation": ("object", "Vector3", True),
                   "rotation": ("object", "Quaternion", True)}
TYPES = {
    "Time": TIME, "Color": COLOR, "Point2": POINT2, "Vector3": VECTOR3, "Quaternion": QUATERNION, "Pose": POSE,
    "PackedElementField": PACKED_FIELD, "KeyValuePair": KEY_VALUE, "PointsAnnotation": POINTS_ANNOTATION,
    "CircleAnnotation": CIRCLE, "TextAnnotation": TEXT, "FrameTransform": FRAME_TRANSFORM,
    "foxglove.CompressedImage": {"timestamp": ("object", "Time", True), "frame_id": ("string", None, True),
                                 "data": ("string", None, True), "format": ("string", None, True)},
    "foxglove.CameraCalibration": {"timestamp": ("object", "Time", True), "frame_id": ("string", None, True),
                                   "width": ("integer", None, True), "height": ("integer", None, True),
                                   "distortion_model": ("string", None, True), "D": ("array", "number", True),
                                   "K": ("array", "number", True), "R": ("array", "number", True),
                                   "P": ("array", "number", True)},
    "foxglove.PointCloud": {"timestamp": ("object", "Time", True), "frame_id": ("string", None, True),
                            "pose": ("object", "Pose", True), "point_stride": ("integer", None, True),
                            "fields": ("array", "PackedElementField", True), "data": ("string", None, True)},
    "foxglove.FrameTransforms": {"transforms": ("array", "FrameTransform", True)},
    "foxglove.ImageAnnotations": {"timestamp": ("object", "Time", False), "metadata": ("array", "KeyValuePair", False),
                                  "circles": ("array", "CircleAnnotation", True),
                                  "points": ("array", "PointsAnnotation", True),
                                  "texts": ("array", "TextAnnotation", True)},
}
_JSON = {"integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
         "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
         "string": lambda v: isinstance(v, str), "object": lambda v: isinstance(v, dict),
         "array": lambda v: isinstance(v, list)}
FIXED = {"foxglove.CameraCalibration": {"K": 9, "R": 9, "P": 12}}  # fixed-length arrays of the schema


def _check(msg, type_name: str, where: str) -> list[str]:
    """Problems of ``msg`` against ``TYPES[type_name]`` (unknown fields, missing required ones,
    wrong JSON types), recursively."""
    spec = TYPES[type_name]
    errs = [f"{where}.{k}: not a field of {type_name}" for k in msg if k not in spec]
    for k, (jtype, sub, required) in spec.items():
        if k not in msg:
            if required:
                errs.append(f"{where}.{k}: required by {type_name}, missing")
            continue
        v = msg[k]
        if not _JSON[jtype](v):
            errs.append(f"{where}.{k}: {type(v).__name__}, {type_name} wants {jtype}")
        elif jtype == "object" and sub:
            errs += _check(v, sub, f"{where}.{k}")
        elif jtype == "array" and sub in _JSON:
            errs += [f"{where}.{k}[{i}]: not a {sub}" for i, x in enumerate(v) if not _JSON[sub](x)]
        elif jtype == "array" and sub:
            errs += [e for i, x in enumerate(v) for e in _check(x, sub, f"{where}.{k}[{i}]")]
    for k, n in FIXED.get(type_name, {}).items():
        if k in msg and len(msg[k]) != n:
            errs.append(f"{where}.{k}: {len(msg[k])} values, {type_name} wants {n}")
    return errs


# -------------------------------------------------- a small site and its review file
K = CameraIntrinsics(fx=800.0, fy=800.0, cx=320.0, cy=240.0, width=640, height=480)
T = np.array([[0, -1, 0, 0.1], [0, 0, -1, 0.2], [1, 0, 0, -0.3], [0, 0, 0, 1]], dtype=np.float64)


def _frames(n=2):
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        cloud = np.column_stack([rng.uniform(5, 30, 500), rng.uniform(-8, 8, 500), rng.uniform(-1.5, 1, 500)])
        b3 = np.array([[10.0 + i, -1.0, -0.8, 4.5, 1.8, 1.5, 0.1], [20.0, 3.0, -0.8, 4.2, 1.8, 1.6, -0.2]], np.float32)
        b2 = np.array([[200, 200, 300, 260], [350, 210, 400, 240]], np.float32)
        img = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
        out.append(Frame(img, cloud.astype(np.float32), b2, b3, frame_key=f"{i:04d}", intrinsics=K,
                         meta={"lidar_stamp_ns": 1_700_000_000_000_000_000 + i * 100_000_000}))
    return out


@pytest.fixture(scope="module")
def review_messages(tmp_path_factory):
    from mcap.reader import make_reader

    def ok(frames, intrinsics, progress=None, **_):
        return CalibrationResult(success=True, intrinsics=intrinsics, rotation=T[:3, :3], translation=T[:3, 3],
                                 camera_name="front", pairs=[np.array([[0, 0], [1, 1]])] * len(frames),
                                 rotation_std_deg=np.full(3, 0.1), translation_std_m=np.full(3, 0.02))

    def refused(frames, intrinsics, progress=None, **_):
        return CalibrationResult(success=False, camera_name="side", message="too few detections")

    out = tmp_path_factory.mktemp("fox")
    site, loaded = calibrate_site({"front": _frames()}, calibrate=ok, lidar_frame="velodyne")
    site2, loaded2 = calibrate_site({"side": _frames()}, calibrate=refused)
    msgs = []
    for s, ld, name in ((site, loaded, "a.mcap"), (site2, loaded2, "b.mcap")):
        path = write_review_mcap(out / name, s, ld)
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            assert all(c.message_encoding == "json" for c in summary.channels.values())
            for schema, ch, m in reader.iter_messages():
                assert schema.encoding == "jsonschema"
                msgs.append((schema.name, ch.topic, json.loads(m.data)))
    return msgs


def test_review_messages_match_the_published_foxglove_definitions(review_messages):
    names = {n for n, _, _ in review_messages}
    assert names == {"foxglove.CompressedImage", "foxglove.ImageAnnotations", "foxglove.CameraCalibration",
                     "foxglove.PointCloud", "foxglove.FrameTransforms"}
    errors = [e for name, topic, msg in review_messages for e in _check(msg, name, topic)]
    assert errors == []
    # the checker itself finds what is wrong
    bad = {"timestamp": {"sec": 1.5, "nsec": 0}, "frame_id": "cam", "format": "jpeg", "colour": 1}
    assert sorted(_check(bad, "foxglove.CompressedImage", "m")) == [
        "m.colour: not a field of foxglove.CompressedImage", "m.data: required by foxglove.CompressedImage, missing",
        "m.timestamp.sec: float, Time wants integer"]



def test_camera_calibration_distortion_has_the_models_length(review_messages):
    """plumb_bob carries 5 coefficients, rational_polynomial 8 (ROS; Foxglove's camera model reads
    them by position): a camera without distortion gets 5 zeros, not an empty D."""
    cals = [m for name, _, m in review_messages if name == "foxglove.CameraCalibration"]
    assert cals
    for m in cals:
        assert len(m["D"]) == {"plumb_bob": 5, "rational_polynomial": 8}[m["distortion_model"]], m["D"]

def _published_schemas() -> dict | None:
    """The JSON schemas of the installed npm package ``@foxglove/schemas`` (``dist/jsonschema``),
    by title (``foxglove.X``); None when it is not installed."""
    cands = [Path(os.environ["XCALIB_FOXGLOVE_SCHEMAS"])] if os.environ.get("XCALIB_FOXGLOVE_SCHEMAS") else []
    here = Path(__file__).resolve().parent
    cands += [p / "node_modules" / "@foxglove" / "schemas" for p in (here, *here.parents)]
    for pkg in cands:
        js = pkg / "dist" / "jsonschema" / "index.js"
        if js.is_file():
            out = {}
            for body in re.split(r"\nexports\.\w+ = ", js.read_text())[1:]:
                body = body.strip().rstrip(";")
                if body.startswith("{"):
                    sch = json.loads(body)
                    out[sch["title"]] = sch
            return out
    return None


def test_review_messages_validate_against_the_installed_foxglove_package(review_messages):
    jsonschema = pytest.importorskip("jsonschema")
    schemas = _published_schemas()
    if schemas is None:
        pytest.skip("@foxglove/schemas (npm) not installed; set XCALIB_FOXGLOVE_SCHEMAS to its folder")
    for name, topic, msg in review_messages:
        jsonschema.validate(msg, schemas[name])  # raises ValidationError naming the field
    # and the definitions written above are the package's
    for name in ("foxglove.CompressedImage", "foxglove.CameraCalibration", "foxglove.PointCloud",
                 "foxglove.ImageAnnotations", "foxglove.FrameTransforms", "foxglove.FrameTransform",
                 "foxglove.PointsAnnotation"):
        mine = TYPES[name if name in TYPES else name.split(".")[1]]
        assert set(schemas[name]["properties"]) == set(mine)
        assert set(schemas[name]["required"]) == {k for k, v in mine.items() if v[2]}
