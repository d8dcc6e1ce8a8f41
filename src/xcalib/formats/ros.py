"""ROS calibration files: ``camera_info`` YAML (camera_calibration_parsers layout) and a static
transform YAML for tf2.

Directions: the static transform follows tf2 — ``parent_frame`` (``header.frame_id``) is the
LiDAR frame, ``child_frame`` the camera's **optical** frame (REP 103 ``*_optical_frame``: x right,
y down, z forward), and translation + rotation (x, y, z, w) are the child's pose in the parent,
i.e. ``T_lidar_cam = inv(T_cam_lidar)`` mapping camera points into the LiDAR frame (what
``static_transform_publisher --frame-id lidar --child-frame-id camera_optical_frame`` expects).
``write_ros`` writes ``<path>`` (camera_info) and ``<stem>_tf.yaml`` next to it.

Also: ``static_transform_command`` (a runnable ROS 2 line, plain numbers), ``write_tf_static`` /
``read_tf_static`` (a ``tf2_msgs/TFMessage`` YAML), ``write_urdf`` / ``read_urdf`` (the body
frame ``<camera>_link``, x forward / y left / z up, joined to the LiDAR, and the fixed
``<camera>_link -> <camera>_optical_frame`` rotation; ``T_cam_lidar`` is always the optical frame's).
"""

from __future__ import annotations

import logging
import re
import secrets
from pathlib import Path
from typing import Any

import numpy as np

from ..calib.result import CalibrationResult
from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics
from ..geometry.rotations import matrix_to_quaternion
from ..geometry.transforms import invert_transform, make_transform
from ..io.files import MAX_TEXT_BYTES, atomic_write, read_text
from ._checks import as_float, as_matrix, checked_quaternion, require, require_numbers
from ._result import calibration_record, require_intrinsics

__all__ = ["camera_info_dict", "camera_info_size", "static_transform_dict", "write_ros", "read_ros", "read_camera_info",
           "read_static_transform", "tf_path_for", "static_transform_args", "static_transform_command",
           "static_transform_ros1_args", "static_transform_ros1_command", "body_link",
           "urdf_joints", "write_urdf", "read_urdf", "tf_static_dict", "write_tf_static", "read_tf_static",
           "R_BODY_OPTICAL", "ros_name", "printable"]

log = logging.getLogger("xcalib.formats.ros")


_NOT_ROS = re.compile(r"[^A-Za-z0-9_./-]+")


def ros_name(text, default: str = "frame") -> str:
    """A ROS frame / link / topic token derived from data (a camera name, a topic, a frame id read
    from a recording): characters other than letters, digits, ``_ . - /`` become ``_``, no
    leading or repeated ``/`` (tf2 frame ids have none), and it starts with a letter or ``_`` (never
    ``-``: no name reads as a command-line option). Names that are already valid (``velodyne``,
    ``cam/front``, ``os1-lidar``) come back unchanged."""
    s = _NOT_ROS.sub("_", str(text))
    s = re.sub(r"/+", "/", s).strip("/")
    if not s:
        return default
    return s if (s[0].isalpha() or s[0] == "_") else "x" + s


def printable(text, max_len: int = 400) -> str:
    """``text`` on one line for a comment in a generated script or file: newlines, carriage
    returns, other control and bidirectional-override characters are written as ``\\xNN`` /
    ``\\uNNNN`` escapes, so a name can never end the comment or hide what follows it."""
    out = []
    for ch in str(text)[:max_len]:
        if ch.isprintable() and ch not in "\\":
            out.append(ch)
        else:
            o = ord(ch)
            out.append(f"\\x{o:02x}" if o < 0x100 else f"\\u{o:04x}" if o < 0x10000 else f"\\U{o:08x}")
    return "".join(out)


def _yaml():
    import yaml

    return yaml


def _mat(rows: int, cols: int, data) -> dict:
    return {"rows": rows, "cols": cols, "data": [float(v) for v in np.asarray(data).reshape(-1)]}


def camera_info_size(intr: CameraIntrinsics, image_size=None) -> tuple[int, int]:
    """``(width, height)`` for a CameraInfo: the intrinsics' own, else ``image_size`` (the images');
    ``ValueError`` when neither is known (``camera_calibration_parsers`` refuses a YAML without them)."""
    if intr.width is not None and intr.height is not None:
        return int(intr.width), int(intr.height)
    if image_size is not None:
        w, h = (int(v) for v in image_size)
        if w > 0 and h > 0:
            return w, h
    raise ValueError("a CameraInfo YAML needs image_width and image_height, and neither the intrinsics nor the "
                     "calibration hold the image size (xcalib convert: pass --image-size WIDTHxHEIGHT)")


def camera_info_dict(intr: CameraIntrinsics, camera_name: str = "camera", image_size=None) -> dict[str, Any]:
    """``camera_info`` YAML content as ``camera_calibration_parsers`` reads it: every key it
    requires (``image_width``/``image_height`` from the intrinsics, else ``image_size`` (width,
    height) of the images; ``ValueError`` when neither is known), distortion model plumb_bob for
    <= 5 coefficients, else rational_polynomial. A camera model (``xcalib.geometry.camera_models``)
    is written as itself: ``equidistant`` for Kannala-Brandt; a model CameraInfo cannot express
    (unified, UCM, EUCM, double sphere) is an ``UnsupportedModelError`` (a ValueError) naming the
    formats that can, never a pinhole CameraInfo of its fx, fy, cx, cy."""
    w, h = camera_info_size(intr, image_size)
    if not isinstance(intr, CameraIntrinsics):
        import yaml

        from .cameras import camera_text

        return yaml.safe_load(camera_text(intr.with_image_size(w, h), "camera_info", camera_name=camera_name))
    d = np.zeros(5) if intr.distortion is None else np.asarray(intr.distortion, dtype=np.float64)
    if d.size < 5:
        d = np.concatenate([d, np.zeros(5 - d.size)])
    model = "plumb_bob" if d.size == 5 else "rational_polynomial"
    out: dict[str, Any] = {"image_width": w, "image_height": h}
    out.update(camera_name=camera_name, camera_matrix=_mat(3, 3, intr.K), distortion_model=model,
               distortion_coefficients=_mat(1, d.size, d), rectification_matrix=_mat(3, 3, np.eye(3)),
               projection_matrix=_mat(3, 4, np.hstack([intr.K, np.zeros((3, 1))])))
    return out


def static_transform_dict(T_cam_lidar, parent_frame: str = "lidar", child_frame: str = "camera_optical_frame") -> dict:
    """Static transform YAML content: the pose of ``child_frame`` (camera, optical) in
    ``parent_frame`` (LiDAR), ``T_lidar_cam = inv(T_cam_lidar)``, plus the equivalent command."""
    T = invert_transform(T_cam_lidar)
    t, q = T[:3, 3], matrix_to_quaternion(T[:3, :3])
    return {"header": {"frame_id": parent_frame}, "child_frame_id": child_frame,
            "transform": {"translation": {"x": float(t[0]), "y": float(t[1]), "z": float(t[2])},
                          "rotation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}},
            "comment": f"pose of {child_frame} in {parent_frame}: maps {child_frame} points into {parent_frame}",
            "command": static_transform_command(T, parent_frame, child_frame)}


def _num(v) -> str:
    """A plain decimal literal that round-trips (``repr(float)``: no ``np.float64(...)``)."""
    return repr(float(v))


def static_transform_args(T_parent_child, parent_frame: str, child_frame: str) -> list[str]:
    """ROS 2 ``static_transform_publisher`` arguments (named form, humble and later) publishing
    ``child_frame``'s pose in ``parent_frame``: ``--x --y --z --qx --qy --qz --qw --frame-id
    --child-frame-id``, numbers as plain decimals."""
    T = np.asarray(T_parent_child, dtype=np.float64)
    t, q = T[:3, 3], matrix_to_quaternion(T[:3, :3])
    out = []
    for k, v in zip(("x", "y", "z", "qx", "qy", "qz", "qw"), [*t, *q]):
        out += [f"--{k}", _num(v)]
    return out + ["--frame-id", parent_frame, "--child-frame-id", child_frame]


def static_transform_command(T_parent_child, parent_frame: str, child_frame: str) -> str:
    """A runnable ``ros2 run tf2_ros static_transform_publisher ...`` line (shell-quoted)."""
    import shlex

    args = static_transform_args(T_parent_child, parent_frame, child_frame)
    return "ros2 run tf2_ros static_transform_publisher " + " ".join(shlex.quote(a) for a in args)


def static_transform_ros1_args(T_parent_child, parent_frame: str, child_frame: str) -> list[str]:
    """ROS 1 ``static_transform_publisher`` arguments (positional: ``x y z qx qy qz qw frame_id
    child_frame_id``; ROS 2 also accepts this form)."""
    T = np.asarray(T_parent_child, dtype=np.float64)
    t, q = T[:3, 3], matrix_to_quaternion(T[:3, :3])
    return [_num(v) for v in [*t, *q]] + [parent_frame, child_frame]


def static_transform_ros1_command(T_parent_child, parent_frame: str, child_frame: str) -> str:
    """A runnable ROS 1 ``rosrun tf2_ros static_transform_publisher ...`` line (shell-quoted)."""
    import shlex

    args = static_transform_ros1_args(T_parent_child, parent_frame, child_frame)
    return "rosrun tf2_ros static_transform_publisher " + " ".join(shlex.quote(a) for a in args)


# REP 103: a camera's body frame (x forward, y left, z up) -> its optical frame (x right, y down,
# z forward). Columns = the optical axes in body coordinates.
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _origin(T) -> str:
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, dtype=np.float64)
    rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")  # URDF: fixed-axis roll, pitch, yaw
    return (f'<origin xyz="{" ".join(_num(v) for v in T[:3, 3])}" '
            f'rpy="{" ".join(_num(v) for v in rpy)}"/>')


def body_link(optical: str) -> str:
    """The REP 103 body link of an optical frame: ``x_optical_frame`` / ``x_optical`` -> ``x_link``."""
    for suffix in ("_optical_frame", "_optical"):
        if optical.endswith(suffix) and len(optical) > len(suffix):
            return optical[: -len(suffix)] + "_link"
    return optical + "_link"


def urdf_joints(T_cam_lidar, lidar_link: str, camera: str, optical: str | None = None) -> str:
    """URDF snippet: ``lidar_link -> <camera>_link`` (body frame, REP 103) and the fixed
    ``<camera>_link -> <camera>_optical_frame`` rotation; the optical frame is xcalib's camera
    frame (``T_cam_lidar`` maps LiDAR points into it). ``optical``: the optical frame's name
    (the recording's image ``header.frame_id``; its body link is named by :func:`body_link`)."""
    T_lidar_optical = invert_transform(T_cam_lidar)
    T_body_optical = make_transform(R_BODY_OPTICAL, np.zeros(3))
    T_lidar_body = T_lidar_optical @ invert_transform(T_body_optical)
    lidar_link = ros_name(lidar_link, "lidar")  # names from a recording: valid tf names only
    optical = ros_name(optical or f"{ros_name(camera, 'camera')}_optical_frame", "camera_optical_frame")
    body = body_link(optical)
    return "\n".join([
        f'  <link name="{body}"/>',
        f'  <link name="{optical}"/>',
        f'  <joint name="{lidar_link}_to_{body}" type="fixed">',
        f'    <parent link="{lidar_link}"/>', f'    <child link="{body}"/>', f"    {_origin(T_lidar_body)}",
        "  </joint>",
        f'  <joint name="{body}_to_{optical}" type="fixed">',
        f'    <parent link="{body}"/>', f'    <child link="{optical}"/>', f"    {_origin(T_body_optical)}",
        "  </joint>"])


def write_urdf(result: CalibrationResult, path, *, lidar_link: str = "lidar") -> Path:
    """A URDF file (``<robot>`` with the LiDAR link and the camera's body and optical joints)."""
    from ..io.files import atomic_write

    name = ros_name(result.camera_name or "camera", "camera")
    text = (f'<?xml version="1.0"?>\n<robot name="xcalib_{name}">\n  <link name="{ros_name(lidar_link, "lidar")}"/>\n'
            f"{urdf_joints(result.extrinsics, lidar_link, name)}\n</robot>\n")
    return atomic_write(Path(path), [text.encode()])


def _urdf_origin(joint, path: Path) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    o = joint.find("origin")
    xyz = [0.0, 0.0, 0.0] if o is None else o.get("xyz", "0 0 0").split()
    rpy = [0.0, 0.0, 0.0] if o is None else o.get("rpy", "0 0 0").split()
    try:
        t, a = np.array(xyz, dtype=np.float64), np.array(rpy, dtype=np.float64)
    except ValueError:
        raise FormatError(path, f"joint {joint.get('name')!r}: origin is not numeric", "origin") from None
    if t.shape != (3,) or a.shape != (3,) or not (np.all(np.isfinite(t)) and np.all(np.isfinite(a))):
        raise FormatError(path, f"joint {joint.get('name')!r}: origin needs 3 finite xyz and 3 rpy", "origin")
    return make_transform(Rotation.from_euler("xyz", a).as_matrix(), t)


def read_urdf(path, camera: str | None = None) -> CalibrationResult:
    """A URDF's fixed joints -> ``T_cam_lidar`` of the ``*_optical_frame`` link (``camera`` picks
    one when there are several) relative to the tree's root link (the LiDAR)."""
    import xml.etree.ElementTree as ET

    path = Path(path)
    try:
        root = ET.fromstring(read_text(path, max_bytes=MAX_TEXT_BYTES, what="URDF file"))
    except (OSError, ET.ParseError, RecursionError, ValueError) as exc:
        if isinstance(exc, FormatError):
            raise
        raise FormatError(path, f"not readable URDF XML ({exc})") from None
    parent_of = {}
    for j in root.iter("joint"):
        p, c = j.find("parent"), j.find("child")
        if p is None or c is None:
            raise FormatError(path, f"joint {j.get('name')!r} needs <parent> and <child>", "joint")
        parent_of[c.get("link")] = (p.get("link"), _urdf_origin(j, path))
    opticals = sorted(k for k in parent_of if k.endswith("_optical_frame"))
    want = [o for o in opticals if camera is None
            or o in (f"{camera}_optical_frame", f"{ros_name(camera, 'camera')}_optical_frame")]
    if len(want) != 1:
        raise FormatError(path, f"expected one *_optical_frame link{'' if camera is None else ' of ' + camera}; "
                                f"found {opticals}", "link")
    link, T, seen = want[0], np.eye(4), set()
    while link in parent_of and link not in seen:
        seen.add(link)
        parent, T_pc = parent_of[link]
        T, link = T_pc @ T, parent
    name = want[0][: -len("_optical_frame")]
    return calibration_record(None, invert_transform(T), method="urdf", camera_name=name,
                              meta={"format": "urdf", "parent_frame": link})


def tf_static_dict(edges) -> dict:
    """``tf2_msgs/TFMessage`` YAML content (what ``ros2 topic echo /tf_static`` prints) of
    ``[(parent, child, T_parent_child)]``."""
    items = []
    for parent, child, T in edges:
        T = np.asarray(T, dtype=np.float64)
        q = matrix_to_quaternion(T[:3, :3])
        items.append({"header": {"frame_id": parent}, "child_frame_id": child,
                      "transform": {"translation": {k: float(v) for k, v in zip("xyz", T[:3, 3])},
                                    "rotation": {k: float(v) for k, v in zip("xyzw", q)}}})
    return {"transforms": items}


def write_tf_static(result: CalibrationResult, path, *, parent_frame: str = "lidar") -> Path:
    """One-transform tf_static YAML: LiDAR -> ``<camera>_optical_frame``."""
    from ..io.files import atomic_write

    child = f"{ros_name(result.camera_name or 'camera', 'camera')}_optical_frame"
    d = tf_static_dict([(ros_name(parent_frame, "lidar"), child, invert_transform(result.extrinsics))])
    return atomic_write(Path(path), [_yaml().safe_dump(d, sort_keys=False).encode()])


def read_tf_static(path, child: str | None = None) -> CalibrationResult:
    """tf_static YAML (``transforms: [...]``) -> the ``*_optical_frame`` (or ``child``) transform."""
    path = Path(path)
    d = _load_yaml(path)
    items = d.get("transforms")
    if not isinstance(items, list) or not items:
        raise FormatError(path, "expected a non-empty list", "transforms")
    for i, it in enumerate(items):
        if not isinstance(it, dict):
            raise FormatError(path, "expected a mapping", f"transforms[{i}]")
    pick = [it for it in items if (child is None and str(it.get("child_frame_id", "")).endswith("optical_frame"))
            or it.get("child_frame_id") == child] or (items if len(items) == 1 else [])
    if len(pick) != 1:
        raise FormatError(path, f"expected one camera transform; children: "
                                f"{[it.get('child_frame_id') for it in items]}", "transforms")
    T, parent, ch = _transform_of(pick[0], path)
    name = ch[: -len("_optical_frame")] if ch.endswith("_optical_frame") else ch
    return calibration_record(None, invert_transform(T), method="tf_static", camera_name=name,
                              meta={"format": "tf_static", "parent_frame": parent, "child_frame": ch})


def tf_path_for(path) -> Path:
    """``<stem>_tf.yaml`` next to a camera_info YAML."""
    p = Path(path)
    return p.with_name(p.stem + "_tf.yaml")


def write_ros(result: CalibrationResult, path, *, parent_frame: str = "lidar",
              child_frame: str | None = None) -> tuple[Path, Path]:
    """Write ``camera_info`` YAML to ``path`` and the static transform to ``<stem>_tf.yaml``."""
    intr = require_intrinsics(result, "ros camera_info")
    name = result.camera_name or "camera"
    child = child_frame or f"{ros_name(name, 'camera')}_optical_frame"
    yaml = _yaml()
    path = Path(path)
    tf = tf_path_for(path)
    tf_dict = static_transform_dict(result.extrinsics, parent_frame, child)
    # Both files carry one pair id and camera_info also embeds the transform (extra keys ROS
    # parsers ignore). camera_info is renamed first: a write killed before the tf file's rename
    # leaves a tf file of another pair id, and read_ros then takes the embedded transform.
    pair = secrets.token_hex(8)
    info_d = camera_info_dict(intr, name, result.image_size)  # ValueError without an image size
    info = yaml.safe_dump({**info_d, PAIR_KEY: pair, EMBEDDED_TF: tf_dict},
                          sort_keys=False).encode()
    tfy = yaml.safe_dump({**tf_dict, PAIR_KEY: pair}, sort_keys=False).encode()
    atomic_write(path, [info])
    atomic_write(tf, [tfy])
    return path, tf


EMBEDDED_TF = "xcalib_static_transform"
PAIR_KEY = "xcalib_pair"


def _load_yaml(path: Path) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"ROS YAML file not found: {path}")
    yaml = _yaml()
    try:
        d = yaml.safe_load(read_text(path, max_bytes=MAX_TEXT_BYTES, what="YAML file"))
    except (yaml.YAMLError, RecursionError, ValueError, TypeError) as exc:
        if isinstance(exc, FormatError):
            raise
        raise FormatError(path, f"not valid YAML ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(d, dict):
        raise FormatError(path, f"expected a YAML mapping, got {type(d).__name__}")
    return d


def _matrix_data(d: dict, key: str, path: Path) -> list:
    """``d[key]["data"]``, all numbers, as many as the matrix's ``rows`` x ``cols`` say (a number
    dropped or added is a FormatError, not a shifted matrix)."""
    m = require(d, key, path)
    data = require_numbers(require(m, "data", path, key + "."), path, key + ".data")
    if not isinstance(data, list):
        raise FormatError(path, f"expected a list of numbers, got {type(data).__name__}", key + ".data")
    if isinstance(m, dict) and ("rows" in m or "cols" in m):
        rows = require_numbers(require(m, "rows", path, key + "."), path, key + ".rows", integral=True)
        cols = require_numbers(require(m, "cols", path, key + "."), path, key + ".cols", integral=True)
        if rows * cols != len(data):
            raise FormatError(path, f"{rows} x {cols} matrix holds {len(data)} numbers", key + ".data")
    return data


def read_camera_info(path) -> CameraIntrinsics:
    """Intrinsics from a ``camera_info`` YAML (camera_matrix; a non-trivial rectification is refused)."""
    path = Path(path)
    d = _load_yaml(path)
    K = as_matrix(_matrix_data(d, "camera_matrix", path), (3, 3), path, "camera_matrix.data")
    dist = None
    if "distortion_coefficients" in d:
        raw = _matrix_data(d, "distortion_coefficients", path)
        try:
            dist = np.asarray(raw, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise FormatError(path, f"expected a list of numbers, got {raw!r:.60}",
                              "distortion_coefficients.data") from None
        model = str(d.get("distortion_model", "plumb_bob"))
        if model not in ("plumb_bob", "rational_polynomial"):
            raise FormatError(path, f"unsupported distortion_model {model!r} (plumb_bob or rational_polynomial)",
                              "distortion_model")
    if "rectification_matrix" in d:
        Rr = as_matrix(_matrix_data(d, "rectification_matrix", path), (3, 3), path, "rectification_matrix.data")
        if np.abs(Rr - np.eye(3)).max() > 1e-9:
            raise FormatError(path, "rectification_matrix is not identity (stereo-rectified camera_info is "
                                    "not a plain LiDAR->camera calibration)", "rectification_matrix")
    for key in ("image_width", "image_height"):
        if d.get(key) is not None:
            require_numbers(d[key], path, key, integral=True)
    try:
        intr = CameraIntrinsics.from_matrix(K, dist, width=d.get("image_width") or None,
                                            height=d.get("image_height") or None)
        intr.check_plausible()
        return intr
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), "camera_matrix") from None


def _transform_of(d: dict, path: Path) -> tuple[np.ndarray, str, str]:
    tr = require(d, "transform", path)
    t = require(tr, "translation", path, "transform.")
    r = require(tr, "rotation", path, "transform.")
    tv = [as_float(require(t, k, path, "transform.translation."), path, f"transform.translation.{k}") for k in "xyz"]
    qv = [as_float(require(r, k, path, "transform.rotation."), path, f"transform.rotation.{k}") for k in "xyzw"]
    norm = float(np.linalg.norm(qv))
    if norm > 1e-9 and abs(norm - 1.0) > 1e-3:
        raise FormatError(path, f"rotation quaternion norm is {norm:.6f}, expected 1", "transform.rotation")
    R = checked_quaternion(qv, path, "transform.rotation")
    header = d.get("header") or {}
    if not isinstance(header, dict):
        raise FormatError(path, f"expected a mapping, got {type(header).__name__}", "header")
    parent = str(header.get("frame_id", ""))
    return make_transform(R, tv), parent, str(d.get("child_frame_id", ""))


def read_static_transform(path) -> tuple[np.ndarray, str, str]:
    """``(T_parent_child [4,4], parent_frame, child_frame)`` from a static transform YAML."""
    path = Path(path)
    return _transform_of(_load_yaml(path), path)


def read_ros(path, tf_path=None) -> CalibrationResult:
    """camera_info YAML + its ``<stem>_tf.yaml`` -> ``CalibrationResult`` (``T_cam_lidar`` =
    inv(pose of the camera optical frame in the LiDAR frame))."""
    path = Path(path)
    intr = read_camera_info(path)
    info = _load_yaml(path)
    tf = Path(tf_path) if tf_path is not None else tf_path_for(path)
    embedded = info.get(EMBEDDED_TF) if tf_path is None else None
    tf_d = _load_yaml(tf) if tf.is_file() else None
    if isinstance(embedded, dict) and (tf_d is None or tf_d.get(PAIR_KEY) != info.get(PAIR_KEY)):
        if tf_d is not None:  # the tf file belongs to another (interrupted) write: the pair is in camera_info
            log.warning("%s: %s is from another write (pair id); using the transform saved with camera_info",
                        path, tf.name)
        T_parent_child, parent, child = _transform_of(embedded, path)
    elif tf_d is None:
        raise FormatError(path, f"no static transform file {tf.name} next to the camera_info YAML")
    else:
        T_parent_child, parent, child = _transform_of(tf_d, tf)
    name = str(info.get("camera_name", ""))
    return calibration_record(intr, invert_transform(T_parent_child), method="ros", camera_name=name,
                              meta={"format": "ros", "parent_frame": parent, "child_frame": child})
