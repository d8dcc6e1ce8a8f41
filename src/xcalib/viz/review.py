"""A Foxglove-viewable ``.mcap`` review file of a site calibration (the ``mcap`` library, JSON
channels with the ``foxglove.*`` JSON schemas).

Per camera ``<cam>``: ``/<cam>/image`` (``foxglove.CompressedImage``, JPEG),
``/<cam>/annotations`` (``foxglove.ImageAnnotations``: LiDAR points projected with the
calibration, coloured by depth (blue near, red far); the projected 3D boxes (orange); the 2D
detections (green); a one-line key of these colours in the image's top-left corner),
``/<cam>/calibration`` (``foxglove.CameraCalibration``, the camera's optical frame). Shared:
``/lidar/points`` (``foxglove.PointCloud``, the LiDAR frame: the whole cloud unless ``max_points``
is given) and ``/tf`` (``foxglove.FrameTransforms``: LiDAR -> each calibrated camera's optical
frame). Frame names are the site's (a recording's own ``header.frame_id``s when it had them);
messages keep the recording's stamps (a bag's header stamps, else the frames' LiDAR times),
so the file opens beside the source recording; frames without times get 1 s + 0.1 s x i (i: the
frame's index). The frames: up to ``max_frames`` spread evenly over the whole recording, first and
last included (:func:`review_indices`), so a long recording is reviewed end to end in bounded size.
Written to a temporary name and renamed.
"""

from __future__ import annotations

import base64
import json
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..geometry.boxes import as_box7, box7_corners
from ..geometry.rotations import matrix_to_quaternion
from ..geometry.transforms import invert_transform
from ..formats.ros import ros_name
from ..io.files import sweep_stale, tmp_prefix
from ..io.images import encode_jpeg
from ..site.calibration import optical_frame

__all__ = ["write_review_mcap", "review_indices", "REVIEW_SCHEMAS"]

_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_P2 = {"type": "object", "properties": {k: {"type": "number"} for k in "xy"}}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in "rgba"}}
_NUMS = {"type": "array", "items": {"type": "number"}}


def _obj(**props) -> dict:
    return {"type": "object", "properties": props}


REVIEW_SCHEMAS = {
    "foxglove.CompressedImage": _obj(timestamp=_TIME, frame_id={"type": "string"},
                                     data={"type": "string", "contentEncoding": "base64"}, format={"type": "string"}),
    "foxglove.CameraCalibration": _obj(timestamp=_TIME, frame_id={"type": "string"}, width={"type": "integer"},
                                       height={"type": "integer"}, distortion_model={"type": "string"}, D=_NUMS,
                                       K=_NUMS, R=_NUMS, P=_NUMS),
    "foxglove.ImageAnnotations": _obj(
        circles={"type": "array", "items": _obj()},
        points={"type": "array", "items": _obj(timestamp=_TIME, type={"type": "integer"},
                                               points={"type": "array", "items": _P2}, outline_color=_COLOR,
                                               outline_colors={"type": "array", "items": _COLOR},
                                               fill_color=_COLOR, thickness={"type": "number"})},
        texts={"type": "array", "items": _obj(timestamp=_TIME, position=_P2, text={"type": "string"},
                                              font_size={"type": "number"}, text_color=_COLOR,
                                              background_color=_COLOR)}),
    "foxglove.PointCloud": _obj(timestamp=_TIME, frame_id={"type": "string"},
                                pose=_obj(position=_VEC3, orientation=_QUAT), point_stride={"type": "integer"},
                                fields={"type": "array", "items": _obj(name={"type": "string"},
                                                                       offset={"type": "integer"},
                                                                       type={"type": "integer"})},
                                data={"type": "string", "contentEncoding": "base64"}),
    "foxglove.FrameTransforms": _obj(transforms={"type": "array", "items": _obj(
        timestamp=_TIME, parent_frame_id={"type": "string"}, child_frame_id={"type": "string"},
        translation=_VEC3, rotation=_QUAT)}),
}
for _name, _schema in REVIEW_SCHEMAS.items():
    _schema["title"] = _name
    _schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"

_POINTS, _LINE_LOOP, _LINE_LIST = 1, 2, 4  # foxglove.PointsAnnotationType
_FLOAT32 = 7  # foxglove.NumericType
_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


def _t(ns: int) -> dict:
    return {"sec": int(ns // 1_000_000_000), "nsec": int(ns % 1_000_000_000)}


def _color(r, g, b, a=1.0) -> dict:
    return {"r": float(r), "g": float(g), "b": float(b), "a": float(a)}


def _depth_color(d: np.ndarray) -> list[dict]:
    x = np.clip((d - 2.0) / 60.0, 0.0, 1.0)
    return [_color(v, 0.3, 1.0 - v) for v in x]


class _Out:
    def __init__(self, writer):
        self.w, self.schemas, self.channels = writer, {}, {}

    def add(self, topic: str, schema: str, ns: int, msg: dict) -> None:
        if schema not in self.schemas:
            self.schemas[schema] = self.w.register_schema(schema, "jsonschema",
                                                          json.dumps(REVIEW_SCHEMAS[schema]).encode())
        if topic not in self.channels:
            self.channels[topic] = self.w.register_channel(topic, "json", self.schemas[schema])
        self.w.add_message(self.channels[topic], ns, json.dumps(msg).encode(), ns)


def _annotations(ns: int, frame, result, max_points: int) -> dict:
    pts = []
    b2 = np.asarray(frame.bboxes_2d, dtype=np.float64).reshape(-1, 4)
    for x1, y1, x2, y2 in b2:
        pts.append({"timestamp": _t(ns), "type": _LINE_LOOP, "thickness": 2.0, "outline_color": _color(0.1, 0.9, 0.2),
                    "points": [{"x": x1, "y": y1}, {"x": x2, "y": y1}, {"x": x2, "y": y2}, {"x": x1, "y": y2}],
                    "outline_colors": [], "fill_color": _color(0, 0, 0, 0)})
    if result is not None and result.success:
        cloud = np.asarray(frame.point_cloud, dtype=np.float64)[:, :3]
        step = max(1, len(cloud) // max_points)
        uv, depth = result.project(cloud[::step])
        h, w = frame.image.shape[:2]
        ok = np.isfinite(uv).all(axis=1) & (depth > 0.5) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) \
            & (uv[:, 1] < h)
        pts.append({"timestamp": _t(ns), "type": _POINTS, "thickness": 2.0, "outline_color": _color(1, 1, 1),
                    "points": [{"x": float(u), "y": float(v)} for u, v in uv[ok]],
                    "outline_colors": _depth_color(depth[ok]), "fill_color": _color(0, 0, 0, 0)})
        if frame.num_3d:
            corners = box7_corners(as_box7(np.asarray(frame.bboxes_3d)))
            cuv, cd = result.project(corners.reshape(-1, 3))
            cuv, cd = cuv.reshape(-1, 8, 2), cd.reshape(-1, 8)
            for k in range(len(corners)):
                if np.all(cd[k] > 0.5) and np.isfinite(cuv[k]).all():
                    seg = [{"x": float(cuv[k, e, 0]), "y": float(cuv[k, e, 1])} for a, b in _EDGES for e in (a, b)]
                    pts.append({"timestamp": _t(ns), "type": _LINE_LIST, "thickness": 1.5, "points": seg,
                                "outline_color": _color(1.0, 0.55, 0.0), "outline_colors": [],
                                "fill_color": _color(0, 0, 0, 0)})
    key = ("green: 2D detections" + ("; orange: 3D boxes; dots: LiDAR points, blue near to red far; both projected "
                                       "with the calibration" if result is not None and result.success else
                                       "; no pose: nothing projected"))
    texts = [{"timestamp": _t(ns), "position": {"x": 8.0, "y": 20.0}, "text": key, "font_size": 16.0,
              "text_color": _color(1, 1, 1), "background_color": _color(0, 0, 0, 0.6)}]
    return {"circles": [], "points": pts, "texts": texts}


def _calibration(ns: int, cam: str, result, frame, warned: set | None = None) -> dict | None:
    """foxglove.CameraCalibration in the optical frame ``cam``: ``plumb_bob`` / ``rational_polynomial``
    for a pinhole camera, ``kannala_brandt`` (k1-k4, OpenCV's fisheye, as Foxglove defines it) for a
    Kannala-Brandt one; None for a model it cannot express (unified, UCM, EUCM, double sphere): no
    message rather than a wrong pinhole one, with one warning per camera (``warned`` holds the
    cameras already warned about)."""
    intr = result.intrinsics if result.intrinsics is not None else frame.intrinsics
    h, w = frame.image.shape[:2]
    if getattr(intr, "name", "") == "kannala_brandt":
        d, K = [float(v) for v in intr.k], np.asarray(intr.K, dtype=np.float64)
        model = "kannala_brandt"
    elif not hasattr(intr, "dist_coeffs"):  # a CameraModel other than CameraIntrinsics
        if warned is None or cam not in warned:
            import logging

            logging.getLogger("xcalib.viz.review").warning(
                "%s: no foxglove.CameraCalibration message: it cannot express a %s camera (plumb_bob, "
                "rational_polynomial and kannala_brandt only)", cam, intr.name)
            if warned is not None:
                warned.add(cam)
        return None
    else:
        # no distortion: plumb_bob with 5 zeros, as ROS writes it (an empty D is not a plumb_bob model)
        d = [0.0] * 5 if intr.distortion is None else [float(v) for v in intr.distortion]
        K = np.asarray(intr.K, dtype=np.float64)
        model = "rational_polynomial" if len(d) > 5 else "plumb_bob"
    return {"timestamp": _t(ns), "frame_id": cam, "width": int(w), "height": int(h),
            "distortion_model": model, "D": d,
            "K": K.reshape(-1).tolist(), "R": np.eye(3).reshape(-1).tolist(),
            "P": np.hstack([K, np.zeros((3, 1))]).reshape(-1).tolist()}


def _cloud(ns: int, frame, lidar_frame: str, max_points: int | None) -> dict:
    pts = np.asarray(frame.point_cloud, dtype=np.float32)[:, :3]
    if max_points:
        pts = pts[:: max(1, -(-len(pts) // max_points))]
    pts = np.ascontiguousarray(pts)
    return {"timestamp": _t(ns), "frame_id": lidar_frame,
            "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
            "point_stride": 12, "fields": [{"name": n, "offset": 4 * i, "type": _FLOAT32} for i, n in enumerate("xyz")],
            "data": base64.b64encode(pts.tobytes()).decode()}


def _transforms(ns: int, site) -> dict:
    items = []
    for c in site.cameras:
        if not c.result.success:
            continue
        T = invert_transform(c.result.extrinsics)
        q = matrix_to_quaternion(T[:3, :3])
        items.append({"timestamp": _t(ns), "parent_frame_id": ros_name(site.lidar_frame, "lidar"),
                      "child_frame_id": ros_name(c.child_frame, "camera_optical_frame"),
                      "translation": {k: float(v) for k, v in zip("xyz", T[:3, 3])},
                      "rotation": {k: float(v) for k, v in zip("xyzw", q)}})
    return {"transforms": items}


def review_indices(n: int, k: int) -> list[int]:
    """The frames a review file holds: ``k`` of ``n`` indices spread evenly over the whole
    sequence (the first and the last included), every one when ``k <= 0`` or ``k >= n``."""
    if n <= 0:
        return []
    if k <= 0 or k >= n:
        return list(range(n))
    return [int(i) for i in np.unique(np.linspace(0, n - 1, k).round().astype(int))]


def _stamps(frames: Sequence, pick: Sequence[int], period_s: float) -> tuple[list[int], bool]:
    """Per picked frame the LiDAR stamp (ns) of the recording: a bag's header stamp, else the frame's
    ``lidar_time_s``; (synthetic 1 s + period x index, False) when any is missing or they do not increase."""
    from ..io.bags import recorded_stamp_ns

    out = []
    for i in pick:
        f = frames[i]
        ns = recorded_stamp_ns(f, "lidar")
        if ns is None and f.lidar_time_s is not None and np.isfinite(f.lidar_time_s) and f.lidar_time_s > 0:
            ns = int(round(float(f.lidar_time_s) * 1e9))
        out.append(None if ns is None else int(ns))
    if pick and all(v is not None and v > 0 for v in out) and all(b > a for a, b in zip(out, out[1:])):
        return out, True
    return [1_000_000_000 + int(round(i * period_s * 1e9)) for i in pick], False


def _camera_stamp(frame, lidar_ns: int, recorded: bool) -> int:
    from ..io.bags import recorded_stamp_ns

    ns = recorded_stamp_ns(frame, "camera")
    return int(ns) if recorded and ns is not None and int(ns) > 0 else lidar_ns


def write_review_mcap(path, site, frames_by_camera: dict[str, Sequence], *, max_frames: int = 8,
                      max_points: int | None = None, period_s: float = 0.1) -> Path:
    """Write the review file of ``site`` (a :class:`xcalib.site.SiteCalibration`) over up to
    ``max_frames`` frames of each camera spread evenly over the whole sequence (:func:`review_indices`;
    0: every frame; frame ``i`` of each camera = the same LiDAR sweep).
    ``max_points``: decimate the cloud to about that many points (None: the whole cloud); the
    points projected into the images are decimated to 5000 per image."""
    from mcap.writer import Writer

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path.parent, path.name)  # temps of killed writers
    fd, tmp = tempfile.mkstemp(prefix=tmp_prefix(path.name), suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            w = Writer(f)
            w.start(profile="", library="xcalib")
            out = _Out(w)
            pick = review_indices(min(len(v) for v in frames_by_camera.values()), max_frames)
            first_cam = next(iter(frames_by_camera.values()))
            stamps, recorded = _stamps(first_cam, pick, period_s)
            t0 = stamps[0] if stamps else 1_000_000_000
            out.add("/tf", "foxglove.FrameTransforms", t0, _transforms(t0, site))
            warned: set = set()  # cameras whose model CameraCalibration cannot express: said once
            for i, ns in zip(pick, stamps):
                out.add("/lidar/points", "foxglove.PointCloud", ns,
                        _cloud(ns, first_cam[i], ros_name(site.lidar_frame, "lidar"), max_points))
                for cam, frames in frames_by_camera.items():
                    topic = "/" + ros_name(cam, "camera")  # a name from a recording: a valid topic
                    frame, cc = frames[i], site.camera(cam)
                    res, optical = cc.result, ros_name(cc.child_frame, "camera_optical_frame")
                    if frame.image.size == 0:
                        continue
                    cs = _camera_stamp(frame, ns, recorded)
                    out.add(f"{topic}/image", "foxglove.CompressedImage", cs,
                            {"timestamp": _t(cs), "frame_id": optical, "format": "jpeg",
                             "data": base64.b64encode(encode_jpeg(frame.image, 85)).decode()})
                    out.add(f"{topic}/annotations", "foxglove.ImageAnnotations", cs,
                            _annotations(cs, frame, res, 5000))
                    calib = (_calibration(cs, optical, res, frame, warned)
                             if res.intrinsics is not None or frame.intrinsics is not None else None)
                    if calib is not None:
                        out.add(f"{topic}/calibration", "foxglove.CameraCalibration", cs, calib)
            w.finish()
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
