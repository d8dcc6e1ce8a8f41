"""ROS messages <-> numpy: PointCloud2, Image, CompressedImage, CameraInfo, vision_msgs
detections (ROS 1 and ROS 2 layouts), tf. Readers raise FormatError naming the bag, topic and
field; writers build messages of a given rosbags typestore."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...errors import FormatError
from ...geometry.camera import CameraIntrinsics
from ..images import decode_image, encode_image

__all__ = ["cloud_from_msg", "make_pointcloud2", "CloudLayout", "image_from_msg", "make_image", "make_compressed",
           "intrinsics_from_msg", "camera_model_from_msg", "Fisheye", "make_camera_info", "boxes2d_from_msg", "make_detection2d_array",
           "boxes3d_from_msg", "make_detection3d_array", "transforms_from_msg", "make_tf_message",
           "make_header", "stamp_ns"]

# sensor_msgs/PointField datatypes
_PF_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_PF_CODES = {v: k for k, v in _PF_DTYPES.items()}
_DIST_MODELS = {"plumb_bob": (4, 5), "rational_polynomial": (8, 12, 14)}


def _err(where, problem: str, fld: str | None = None) -> FormatError:
    """``where`` = (bag path, topic[, message index]): the error names the bag, the topic, the
    message (its index on the topic, in log order) and the message field ``fld``."""
    at = []
    if len(where) > 2 and where[2] is not None:
        at.append(f"message {where[2]}")
    if fld:
        at.append(f"field {fld}")
    return FormatError(where[0], (", ".join(at) + ": " if at else "") + problem, field=where[1])


def stamp_ns(header, where=None) -> int:
    """A header's stamp in integer nanoseconds (``where``: a nanosecond part outside
    0..999999999 is a FormatError)."""
    st = header.stamp
    ns = int(st.nanosec)
    if where is not None and not 0 <= ns < 1_000_000_000:
        raise _err(where, f"stamp nanoseconds {ns} outside 0..999999999", "header.stamp.nanosec")
    return int(st.sec) * 1_000_000_000 + ns


def make_header(store, stamp: int, frame_id: str):
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    t = Time(sec=int(stamp // 1_000_000_000), nanosec=int(stamp % 1_000_000_000))
    if "seq" in Header.__dataclass_fields__:
        return Header(seq=0, stamp=t, frame_id=frame_id)
    return Header(stamp=t, frame_id=frame_id)


# ----------------------------------------------------------------------------- PointCloud2
def _cloud_dtype(msg, where) -> np.dtype:
    """The numpy record type a PointCloud2's fields declare, each field checked against the
    point: known datatype, count >= 1, inside ``point_step``, no two fields sharing bytes, x/y/z
    floating point and present once."""
    names, formats, offsets, spans = [], [], [], []
    endian = ">" if msg.is_bigendian else "<"
    step = int(msg.point_step)
    if step <= 0 or step > 1 << 16:
        raise _err(where, f"point_step {step} outside 1..65536", "point_step")
    for k, f in enumerate(msg.fields):
        fname = str(f.name)
        code = _PF_DTYPES.get(int(f.datatype))
        if code is None:
            raise _err(where, f"field {fname!r} has unknown PointField datatype {f.datatype}", f"fields[{k}].datatype")
        size = np.dtype(code).itemsize
        off, count = int(f.offset), int(f.count)
        if count < 0 or count * size > step:
            raise _err(where, f"field {fname!r} count {count} does not fit point_step {step}", f"fields[{k}].count")
        count = max(1, count)
        if off < 0 or off + count * size > step:
            raise _err(where, f"field {fname!r} ({count} x {size} bytes at offset {off}) ends past point_step "
                              f"{step}", f"fields[{k}].offset")
        for lo, hi, other in spans:
            if off < hi and lo < off + count * size:
                raise _err(where, f"field {fname!r} (bytes {off}-{off + count * size - 1}) overlaps field "
                                  f"{other!r} (bytes {lo}-{hi - 1})", f"fields[{k}].offset")
        spans.append((off, off + count * size, fname))
        if fname in ("x", "y", "z"):
            if fname in names:
                raise _err(where, f"field {fname!r} declared twice", f"fields[{k}].name")
            if code not in ("f4", "f8") or count != 1:
                raise _err(where, f"coordinate field {fname!r} must be one FLOAT32 or FLOAT64, got datatype "
                                  f"{f.datatype} x {count}", f"fields[{k}].datatype")
        for c in range(count):
            name = fname if count == 1 else f"{fname}_{c}"
            if not name or name in names:
                continue  # unnamed padding or a repeated (non-coordinate) name: skipped
            names.append(name)
            formats.append(endian + code)
            offsets.append(off + c * size)
    missing = [a for a in "xyz" if a not in names]
    if missing:
        raise _err(where, f"PointCloud2 has no field(s) {missing}; fields: {names}", "fields")
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})


#: Points farther than this are refused as corrupt (a wrong layout or endianness), as other readers do.
MAX_COORD_M = 1.0e5


def cloud_from_msg(msg, where) -> tuple[np.ndarray, tuple[str, ...], int]:
    """PointCloud2 (any field layout and endianness, organised or not, point and row padding) ->
    ``(points float32 [N, C] with x, y, z first, field names, number of non-finite points dropped)``.

    Every field the decoding relies on is checked against the data: the layout (see
    ``_cloud_dtype``), ``row_step`` >= ``width * point_step``, ``height * row_step`` == the data
    length, and the coordinates: beyond ``MAX_COORD_M`` or denormal-small (data of the other
    endianness than ``is_bigendian`` says) is a FormatError; NaN / Inf points are dropped and
    counted."""
    dt = _cloud_dtype(msg, where)
    h, w, step, row = int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if h < 0 or w < 0:
        raise _err(where, f"height {h} / width {w} negative", "height")
    if row < w * step:
        raise _err(where, f"row_step {row} is less than width {w} x point_step {step}: does not fit",
                   "row_step")
    if data.size != h * row:
        raise _err(where, f"PointCloud2 data has {data.size} bytes; height {h} x row_step {row} "
                          f"(width {w} x point_step {step}) = {h * row} bytes does not fit", "data")
    rows = data.reshape(h, row)[:, : w * step] if h * row else np.zeros((h, 0), np.uint8)
    arr = np.ascontiguousarray(rows).reshape(-1).view(dt) if h * w else np.zeros(0, dt)
    names = ["x", "y", "z"] + [n for n in dt.names if n not in ("x", "y", "z")]
    xyz = np.stack([arr[n].astype(np.float64) for n in "xyz"], axis=1) if len(arr) else np.zeros((0, 3))
    finite = np.isfinite(xyz).all(axis=1)
    good = xyz[finite]
    if good.size:
        big = np.abs(good).max()
        if big > MAX_COORD_M:
            raise _err(where, f"coordinates up to {big:.3g} m (> {MAX_COORD_M:g} m): corrupt data, a wrong "
                              f"field layout or is_bigendian={bool(msg.is_bigendian)} wrong", "data")
        nz = good[good != 0]
        if nz.size and np.mean(np.abs(nz) < 1e-30) > 0.5:
            raise _err(where, f"most coordinates are below 1e-30 m: the data are not of the endianness "
                              f"is_bigendian={bool(msg.is_bigendian)} declares (or the layout is wrong)",
                       "is_bigendian")
    pts = np.stack([arr[n][finite].astype(np.float32) for n in names], axis=1) if len(arr) \
        else np.zeros((0, len(names)), np.float32)
    return np.ascontiguousarray(pts), tuple(names), int((~finite).sum())


@dataclass(frozen=True)
class CloudLayout:
    """How a PointCloud2 lays out its points: ``datatypes`` (numpy codes per field; None: float32),
    byte order, ``height`` (> 1: an organised cloud), padding bytes after each point and each row."""

    datatypes: tuple | list | None = None
    big_endian: bool = False
    height: int = 1
    point_padding: int = 0
    row_padding: int = 0


def make_pointcloud2(store, points, fields, stamp: int, frame_id: str, layout: CloudLayout | None = None, **changes):
    """A PointCloud2 of ``points`` [N, C] (fields named ``fields``) laid out as ``layout`` (default:
    :class:`CloudLayout`) with ``changes`` (its field names, e.g. ``height=4``) applied; an
    organised cloud needs N divisible by its height."""
    lay = replace(layout or CloudLayout(), **changes)
    datatypes, big_endian, height, point_padding, row_padding = lay.datatypes, lay.big_endian, lay.height, \
        lay.point_padding, lay.row_padding
    pts = np.asarray(points)
    codes = list(datatypes or ["f4"] * pts.shape[1])
    endian = ">" if big_endian else "<"
    offsets = np.cumsum([0] + [np.dtype(c).itemsize for c in codes])
    step = int(offsets[-1]) + point_padding
    dt = np.dtype({"names": list(fields), "formats": [endian + c for c in codes], "offsets": offsets[:-1].tolist(),
                   "itemsize": step})
    if len(pts) % height:
        raise ValueError(f"{len(pts)} points do not fill {height} rows")
    width = len(pts) // height
    rec = np.zeros(len(pts), dtype=dt)
    for i, name in enumerate(fields):
        rec[name] = pts[:, i]
    raw = rec.view(np.uint8).reshape(height, width * step)
    raw = np.hstack([raw, np.zeros((height, row_padding), np.uint8)])
    PF = store.types["sensor_msgs/msg/PointField"]
    pf = [PF(name=n, offset=int(o), datatype=_PF_CODES[c], count=1) for n, o, c in zip(fields, offsets, codes)]
    return store.types["sensor_msgs/msg/PointCloud2"](
        header=make_header(store, stamp, frame_id), height=height, width=width, fields=pf, is_bigendian=big_endian,
        point_step=step, row_step=width * step + row_padding, data=raw.reshape(-1), is_dense=True)


# ----------------------------------------------------------------------------- images
def _to_rgb8(a: np.ndarray, channels: int, order: str) -> np.ndarray:
    if a.dtype != np.uint8:
        a = ((a.astype(np.uint32) + 128) // 257).astype(np.uint8)
    if channels == 1:
        return np.repeat(a[:, :, None] if a.ndim == 2 else a, 3, axis=2)
    a = a[:, :, :3]
    return np.ascontiguousarray(a[:, :, ::-1] if order.startswith("bgr") else a)


_ENCODINGS = {  # encoding -> (numpy sample type, channels)
    "rgb8": ("u1", 3), "bgr8": ("u1", 3), "rgba8": ("u1", 4), "bgra8": ("u1", 4), "mono8": ("u1", 1),
    "8UC1": ("u1", 1), "8UC3": ("u1", 3), "rgb16": ("u2", 3), "bgr16": ("u2", 3), "mono16": ("u2", 1),
    "16UC1": ("u2", 1), "16UC3": ("u2", 3),
}


def image_from_msg(msg, where) -> np.ndarray:
    """sensor_msgs/Image (rgb8, bgr8, rgba8, bgra8, mono8, rgb16, bgr16, mono16, 8UC1/3, 16UC1/3)
    or CompressedImage (jpeg/png) -> [H, W, 3] uint8 RGB (16-bit scaled by 1/257)."""
    if hasattr(msg, "format"):  # CompressedImage
        try:
            return decode_image(np.asarray(msg.data, dtype=np.uint8).tobytes(), source=f"{where[0]} [{where[1]}]")
        except FormatError:
            raise _err(where, f"CompressedImage ({msg.format!r}) does not decode as JPEG/PNG") from None
    enc = str(msg.encoding)
    if enc not in _ENCODINGS:
        raise _err(where, f"unsupported image encoding {enc!r}; supported: {', '.join(_ENCODINGS)}")
    code, ch = _ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    size = np.dtype(code).itemsize
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if step < w * ch * size or data.size < h * step:
        raise _err(where, f"image data has {data.size} bytes; {h} rows x step {step} for {w}x{h} {enc} "
                                  "does not fit")
    rows = np.ascontiguousarray(data[: h * step].reshape(h, step)[:, : w * ch * size])
    a = rows.view((">" if msg.is_bigendian else "<") + code).reshape(h, w, ch)
    return _to_rgb8(a, ch, enc)


def make_image(store, rgb, stamp: int, frame_id: str):
    a = np.ascontiguousarray(rgb, dtype=np.uint8)
    return store.types["sensor_msgs/msg/Image"](
        header=make_header(store, stamp, frame_id), height=a.shape[0], width=a.shape[1], encoding="rgb8",
        is_bigendian=0, step=a.shape[1] * 3, data=a.reshape(-1))


def make_compressed(store, rgb, stamp: int, frame_id: str, fmt: str = "png"):
    data = encode_image(rgb, ".png" if fmt == "png" else ".jpg")
    return store.types["sensor_msgs/msg/CompressedImage"](
        header=make_header(store, stamp, frame_id), format=fmt, data=np.frombuffer(data, dtype=np.uint8))


# ----------------------------------------------------------------------------- CameraInfo
def _field(msg, *names):
    for n in names:
        if hasattr(msg, n):
            return np.asarray(getattr(msg, n), dtype=np.float64).reshape(-1)
    return np.zeros(0)


@dataclass(frozen=True)
class Fisheye:
    """An ``equidistant`` CameraInfo (OpenCV fisheye: K, k1-k4, image size) and the pinhole
    camera ``K_new`` (no distortion, same size) its images and 2D boxes are rectified to."""

    K: np.ndarray
    D: np.ndarray
    size: tuple[int, int]
    K_new: np.ndarray

    @property
    def intrinsics(self) -> CameraIntrinsics:
        k = self.K_new
        return CameraIntrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], None, *self.size)

    @property
    def camera_model(self):
        """The fisheye camera itself (``kannala_brandt``), to calibrate in the fisheye image."""
        from ...geometry.camera_models import KannalaBrandt

        k = self.K
        return KannalaBrandt(k[0, 0], k[1, 1], k[0, 2], k[1, 2], *self.size, tuple(float(v) for v in self.D))

    def rectify_image(self, rgb: np.ndarray) -> np.ndarray:
        import cv2

        m1, m2 = cv2.fisheye.initUndistortRectifyMap(self.K, self.D, np.eye(3), self.K_new, self.size, cv2.CV_32FC1)
        return cv2.remap(rgb, m1, m2, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def rectify_boxes(self, boxes: np.ndarray, per_edge: int = 16) -> np.ndarray:
        """2D boxes of the fisheye image -> the rectified image: the box around ``per_edge``
        points along each edge, undistorted (a box's straight edges are curves after
        rectification), clipped to the image."""
        import cv2

        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        if len(b) == 0:
            return np.zeros((0, 4), np.float32)
        s = np.linspace(0.0, 1.0, per_edge)
        out = []
        for x1, y1, x2, y2 in b:
            xs, ys = x1 + s * (x2 - x1), y1 + s * (y2 - y1)
            pts = np.concatenate([np.stack([xs, np.full_like(xs, y1)], 1), np.stack([xs, np.full_like(xs, y2)], 1),
                                  np.stack([np.full_like(ys, x1), ys], 1), np.stack([np.full_like(ys, x2), ys], 1)])
            und = cv2.fisheye.undistortPoints(pts.reshape(-1, 1, 2), self.K, self.D, R=np.eye(3), P=self.K_new)
            u = und.reshape(-1, 2)
            out.append([u[:, 0].min(), u[:, 1].min(), u[:, 0].max(), u[:, 1].max()])
        r = np.asarray(out)
        r[:, [0, 2]] = np.clip(r[:, [0, 2]], 0, self.size[0])
        r[:, [1, 3]] = np.clip(r[:, [1, 3]], 0, self.size[1])
        return r.astype(np.float32)


def camera_model_from_msg(msg, where) -> CameraIntrinsics | Fisheye:
    """CameraInfo -> intrinsics with distortion and image size (plumb_bob, rational_polynomial),
    or a :class:`Fisheye` (``equidistant``: xcalib's camera model is OpenCV's pinhole with
    radial/tangential distortion, so fisheye images are rectified to a pinhole camera). Other
    models are refused."""
    K = _field(msg, "k", "K")
    D = _field(msg, "d", "D")
    R = _field(msg, "r", "R")
    model = str(msg.distortion_model or "plumb_bob")
    if K.size != 9 or not np.all(np.isfinite(K)) or K[0] <= 0 or K[4] <= 0:
        raise _err(where, f"CameraInfo K is not a calibrated 3x3 matrix ({K.tolist()}); pass --intrinsics", "k")
    if abs(K[1]) > 1e-6 * K[0] or K[3] != 0 or K[6] != 0 or K[7] != 0 or abs(K[8] - 1) > 1e-9:
        raise _err(where, f"CameraInfo K must be [fx 0 cx; 0 fy cy; 0 0 1] (no skew, K[8] = 1), got {K.tolist()}",
                   "k")
    if model not in _DIST_MODELS and model != "equidistant":
        raise _err(where, f"unsupported distortion_model {model!r}; supported: plumb_bob, rational_polynomial, "
                          "equidistant", "distortion_model")
    if not np.all(np.isfinite(D)):
        raise _err(where, f"distortion coefficients are not finite: {D.tolist()}", "d")
    if R.size not in (0, 9) or not np.all(np.isfinite(R)):
        raise _err(where, f"R (rectification) must be 9 finite numbers, got {R.tolist()}", "r")
    if R.size == 9 and np.abs(R.reshape(3, 3) - np.eye(3)).max() > 1e-9 and np.any(R):
        raise _err(where, "CameraInfo R (rectification) is not identity: a stereo-rectified camera_info is "
                          "not a plain camera calibration", "r")
    w, h = int(msg.width), int(msg.height)
    if not (0 <= w <= 100_000 and 0 <= h <= 100_000) or (w == 0) != (h == 0):
        raise _err(where, f"image size {w}x{h} is not a camera's", "width")
    if model == "equidistant":
        return _fisheye(K, D, w, h, where)
    dist = D if D.size and np.any(D) else None
    if dist is not None and dist.size not in _DIST_MODELS[model] and dist.size != 5:
        raise _err(where, f"{model} with {dist.size} coefficients; expected {_DIST_MODELS[model]}", "d")
    try:
        intr = CameraIntrinsics(K[0], K[4], K[2], K[5], dist, w or None, h or None)
        intr.check_plausible()
    except ValueError as exc:
        raise _err(where, str(exc), "k" if "distortion" not in str(exc) else "d") from None
    return intr


def _fisheye(K, D, w: int, h: int, where) -> Fisheye:
    import cv2

    if D.size != 4 or not np.all(np.isfinite(D)) or np.abs(D).max() > 1e3:
        raise _err(where, f"equidistant needs 4 finite coefficients k1-k4 (|k| <= 1e3), got {D.tolist()}", "d")
    if w <= 0 or h <= 0:
        raise _err(where, "equidistant CameraInfo needs width and height (the images are rectified)", "width")
    try:
        CameraIntrinsics(K[0], K[4], K[2], K[5], None, w, h).check_plausible()
    except ValueError as exc:
        raise _err(where, str(exc), "k") from None
    Km = K.reshape(3, 3)
    K_new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(Km, D, (w, h), np.eye(3), balance=0.0)
    if not np.all(np.isfinite(K_new)) or K_new[0, 0] <= 0 or K_new[1, 1] <= 0:
        raise _err(where, f"equidistant coefficients {D.tolist()} give no usable rectified camera", "d")
    return Fisheye(Km, D.astype(np.float64), (w, h), np.asarray(K_new, dtype=np.float64))


def intrinsics_from_msg(msg, where) -> CameraIntrinsics:
    """The pinhole intrinsics of a CameraInfo (an equidistant one: those of its rectified images)."""
    m = camera_model_from_msg(msg, where)
    return m.intrinsics if isinstance(m, Fisheye) else m


def make_camera_info(store, intr: CameraIntrinsics, stamp: int, frame_id: str, width: int, height: int):
    """A CameraInfo of ``intr``: ``plumb_bob`` / ``rational_polynomial``, or ``equidistant`` for a
    ``kannala_brandt`` camera model (its k1-k4; the fisheye image as it is). A camera model that
    CameraInfo cannot express (unified, UCM, EUCM, double sphere) is a ValueError naming it, never
    written as another model."""
    model = None
    if not isinstance(intr, CameraIntrinsics):  # a camera model (xcalib.geometry.camera_models)
        name = getattr(intr, "name", type(intr).__name__)
        if name == "kannala_brandt":
            model, d = "equidistant", np.asarray(intr.k, dtype=np.float64)
        elif getattr(intr, "is_pinhole", False):
            intr = intr.to_intrinsics()
        else:
            raise ValueError(f"make_camera_info: a ROS CameraInfo cannot express a {name} camera (plumb_bob, "
                             f"rational_polynomial and equidistant only); write its intrinsics as a Kalibr camchain "
                             f"or an xcalib intrinsics JSON (xcalib.formats.cameras)")
    if model is None:
        d = np.zeros(5) if intr.distortion is None else np.asarray(intr.distortion, dtype=np.float64)
        if d.size == 4:
            d = np.concatenate([d, [0.0]])
        model = "plumb_bob" if d.size == 5 else "rational_polynomial"
    CI = store.types["sensor_msgs/msg/CameraInfo"]
    upper = "K" in CI.__dataclass_fields__
    K = np.asarray(intr.K, dtype=np.float64).reshape(-1)
    P = np.hstack([intr.K, np.zeros((3, 1))]).reshape(-1)
    roi = store.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    mats = {"D": d, "K": K, "R": np.eye(3).reshape(-1), "P": P}
    mats = mats if upper else {k.lower(): v for k, v in mats.items()}
    return CI(header=make_header(store, stamp, frame_id), height=int(height), width=int(width),
              distortion_model=model, binning_x=0, binning_y=0, roi=roi, **mats)


# ----------------------------------------------------------------------------- detections
def boxes2d_from_msg(msg, where=None) -> tuple[np.ndarray, list[str]]:
    """Detection2DArray (ROS 1 or ROS 2 layout) -> ``(boxes [K, 4] x1 y1 x2 y2 float32, ids)``;
    non-finite centres / sizes and negative sizes are a FormatError (``where``: bag, topic,
    message index)."""
    rows, ids = [], []
    for i, det in enumerate(msg.detections):
        c = det.bbox.center
        cx, cy = (c.position.x, c.position.y) if hasattr(c, "position") else (c.x, c.y)
        sx, sy = float(det.bbox.size_x), float(det.bbox.size_y)
        v = np.array([cx, cy, sx, sy], dtype=np.float64)
        if where is not None:
            if not np.all(np.isfinite(v)) or np.abs(v).max() > 1e6:
                raise _err(where, f"detection {i}: bbox center/size {v.tolist()} not finite or beyond 1e6 px",
                           f"detections[{i}].bbox")
            if sx < 0 or sy < 0:
                raise _err(where, f"detection {i}: negative bbox size ({sx:g}, {sy:g})", f"detections[{i}].bbox.size")
        rows.append([cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2])
        ids.append(str(getattr(det, "id", "")))
    return np.asarray(rows, dtype=np.float64).reshape(-1, 4).astype(np.float32), ids


def make_detection2d_array(store, boxes, stamp: int, frame_id: str, ids=None):
    """Detection2DArray of ``boxes`` [K, 4] (pixels); ``ids`` (ROS 2 layout only) per box."""
    T = store.types
    hdr = make_header(store, stamp, frame_id)
    ros2 = "id" in T["vision_msgs/msg/Detection2D"].__dataclass_fields__
    dets = []
    for i, (x1, y1, x2, y2) in enumerate(np.asarray(boxes, dtype=np.float64).reshape(-1, 4)):
        cx, cy, sx, sy = (x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1
        if ros2:
            center = T["vision_msgs/msg/Pose2D"](position=T["vision_msgs/msg/Point2D"](x=cx, y=cy), theta=0.0)
            bbox = T["vision_msgs/msg/BoundingBox2D"](center=center, size_x=sx, size_y=sy)
            dets.append(T["vision_msgs/msg/Detection2D"](header=hdr, results=[], bbox=bbox,
                                                         id="" if ids is None else str(ids[i])))
        else:
            center = T["geometry_msgs/msg/Pose2D"](x=cx, y=cy, theta=0.0)
            bbox = T["vision_msgs/msg/BoundingBox2D"](center=center, size_x=sx, size_y=sy)
            img = make_image(store, np.zeros((0, 0, 3), np.uint8), stamp, frame_id)
            dets.append(T["vision_msgs/msg/Detection2D"](header=hdr, results=[], bbox=bbox, source_img=img))
    return T["vision_msgs/msg/Detection2DArray"](header=hdr, detections=dets)


#: 3D box centres farther than this (metres) are refused as corrupt.
MAX_BOX_CENTER_M = 1.0e4


def boxes3d_from_msg(msg, where, max_tilt_deg: float = 1.0) -> tuple[np.ndarray, list[str]]:
    """Detection3DArray -> ``(box7 [M, 7] float64 (cx, cy, cz, l, w, h, yaw), ids)``; boxes turned
    about x or y by more than ``max_tilt_deg`` are refused (xcalib's boxes turn about z only), so
    are non-finite values, sizes <= 0, centres beyond ``MAX_BOX_CENTER_M`` and orientations that
    are no rotation (NaN, zero or a norm far from 1)."""
    rows, ids = [], []
    for i, det in enumerate(msg.detections):
        p, q, s = det.bbox.center.position, det.bbox.center.orientation, det.bbox.size
        pos = np.array([p.x, p.y, p.z], dtype=np.float64)
        size = np.array([s.x, s.y, s.z], dtype=np.float64)
        qv = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(size))):
            raise _err(where, f"detection {i}: non-finite centre {pos.tolist()} or size {size.tolist()}",
                       f"detections[{i}].bbox")
        if np.any(size <= 0):
            raise _err(where, f"detection {i}: box size {size.tolist()} must be > 0", f"detections[{i}].bbox.size")
        if np.abs(pos).max() > MAX_BOX_CENTER_M or size.max() > MAX_BOX_CENTER_M:
            raise _err(where, f"detection {i}: centre {pos.tolist()} / size beyond {MAX_BOX_CENTER_M:g} m",
                       f"detections[{i}].bbox.center")
        n = np.linalg.norm(qv) if np.all(np.isfinite(qv)) else np.nan
        if not np.isfinite(n) or abs(n - 1.0) > 0.1:
            raise _err(where, f"detection {i}: orientation {qv.tolist()} is not a unit quaternion (norm {n:.3g})",
                       f"detections[{i}].bbox.center.orientation")
        qv = qv / n
        tilt = np.degrees(2 * np.arcsin(min(1.0, float(np.hypot(qv[0], qv[1])))))
        if tilt > max_tilt_deg:
            raise _err(where, f"detection {i}: the box is turned {tilt:.1f} deg about x/y; xcalib's 3D "
                              "boxes turn about z only", f"detections[{i}].bbox.center.orientation")
        yaw = 2.0 * np.arctan2(qv[2], qv[3])
        yaw = (yaw + np.pi) % (2 * np.pi) - np.pi if abs(yaw) > np.pi else yaw
        rows.append([*pos, *size, yaw])
        ids.append(str(getattr(det, "id", "")))
    return np.asarray(rows, dtype=np.float64).reshape(-1, 7), ids


def make_detection3d_array(store, box7, stamp: int, frame_id: str, ids=None):
    """Detection3DArray of box7 rows [M, 7] (LiDAR frame, metres, yaw about z)."""
    T = store.types
    hdr = make_header(store, stamp, frame_id)
    ros2 = "id" in T["vision_msgs/msg/Detection3D"].__dataclass_fields__
    dets = []
    for i, (x, y, z, l, w, h, yaw) in enumerate(np.asarray(box7, dtype=np.float64).reshape(-1, 7)):
        pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                                           orientation=T["geometry_msgs/msg/Quaternion"](
                                               x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2))))
        bbox = T["vision_msgs/msg/BoundingBox3D"](center=pose, size=T["geometry_msgs/msg/Vector3"](x=l, y=w, z=h))
        if ros2:
            dets.append(T["vision_msgs/msg/Detection3D"](header=hdr, results=[], bbox=bbox,
                                                         id="" if ids is None else str(ids[i])))
        else:
            cloud = make_pointcloud2(store, np.zeros((0, 3), np.float32), ("x", "y", "z"), stamp, frame_id)
            dets.append(T["vision_msgs/msg/Detection3D"](header=hdr, results=[], bbox=bbox, source_cloud=cloud))
    return T["vision_msgs/msg/Detection3DArray"](header=hdr, detections=dets)


# ----------------------------------------------------------------------------- tf
def transforms_from_msg(msg, where=None) -> list[tuple[str, str, np.ndarray, int]]:
    """TFMessage -> ``[(parent, child, T_parent_child [4, 4], stamp_ns)]`` (the child's pose in the
    parent: maps child-frame points into the parent frame); a non-finite translation or a
    rotation that is no unit quaternion is a FormatError (``where``: bag, topic, message)."""
    from ...geometry.rotations import quaternion_to_matrix

    out = []
    for i, t in enumerate(msg.transforms):
        tr, r = t.transform.translation, t.transform.rotation
        qv = np.array([r.x, r.y, r.z, r.w], dtype=np.float64)
        tv = np.array([tr.x, tr.y, tr.z], dtype=np.float64)
        n = np.linalg.norm(qv) if np.all(np.isfinite(qv)) else np.nan
        if where is not None and (not np.isfinite(n) or abs(n - 1.0) > 1e-3 or not np.all(np.isfinite(tv))
                                  or np.abs(tv).max() > MAX_BOX_CENTER_M):
            raise _err(where, f"transform {i}: rotation {qv.tolist()} (norm {n:.4g}) / translation {tv.tolist()} "
                              "is not a rigid transform", f"transforms[{i}].transform")
        T = np.eye(4)
        T[:3, :3] = quaternion_to_matrix(qv)
        T[:3, 3] = [tr.x, tr.y, tr.z]
        out.append((str(t.header.frame_id).lstrip("/"), str(t.child_frame_id).lstrip("/"), T, stamp_ns(t.header)))
    return out


def make_tf_message(store, transforms, stamp: int):
    """TFMessage of ``[(parent, child, T_parent_child)]``."""
    from ...geometry.rotations import matrix_to_quaternion

    T = store.types
    items = []
    for parent, child, M in transforms:
        M = np.asarray(M, dtype=np.float64)
        q = matrix_to_quaternion(M[:3, :3])
        tf = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=float(M[0, 3]), y=float(M[1, 3]), z=float(M[2, 3])),
            rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
        items.append(T["geometry_msgs/msg/TransformStamped"](header=make_header(store, stamp, parent),
                                                            child_frame_id=child, transform=tf))
    return T["tf2_msgs/msg/TFMessage"](transforms=items)
