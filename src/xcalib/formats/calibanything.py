"""CalibAnything / OpenCalib calibration files.

Four files, one direction each (proved on the sample files in ``tests/test_formats_calibanything.py``):

* ``lucid_calib.json`` — ``extrinsic_params`` give the **camera pose in the LiDAR frame**
  (camera -> LiDAR, ``T_lidar_cam``): ``(px, py, pz)`` metres is the camera origin in LiDAR
  coordinates and ``R_lidar_cam = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (degrees; extrinsic x-y-z
  rotations, scipy ``"xyz"``), OpenCV optical camera axes (``camera_coordinate: OPTICAL``).
  The optional ``quaternion`` (x, y, z, w) is the same ``R_lidar_cam``. The Euler angles are
  authoritative: CalibAnything's own converter uses them, and in the shipped sample the
  quaternion is off by 0.64 deg (roll +0.4, yaw +0.5 deg; pitch identical). A quaternion more
  than ``quaternion_tol_deg`` (1 deg) away from the Euler angles is a conflict (FormatError).
  Distortion ``k1..k6, p1, p2`` is OpenCV's rational model.
* CalibAnything v2 ``calib.json`` — ``T_lidar_to_cam`` [4,4] is LiDAR -> camera (the initial /
  working extrinsic), ``T_lidar_to_cam_gt`` the same direction (ground truth when
  ``available``); ``cam_K`` is [3,3] or a KITTI-style [3,4] ``P`` (its 4th column
  ``K^-1 P[:,3]`` is folded into the translation); ``cam_dist`` = OpenCV (k1, k2, p1, p2[, k3]).
* CalibAnything v1 ``calib.txt`` — ``K:`` 9 numbers, ``D:`` OpenCV distortion, ``T:`` [3,4]
  LiDAR -> camera.
* OpenCalib ``<lidar>-to-<camera>-extrinsic.json`` (``param.sensor_calib`` [4,4] LiDAR ->
  camera) with ``<camera>-intrinsic.json`` (``param.cam_K``, ``cam_dist``, ``img_dist_w/h``).

Every reader returns a :class:`~xcalib.calib.result.CalibrationResult` whose ``rotation`` /
``translation`` are xcalib's ``T_cam_lidar`` (LiDAR -> camera).
"""

from __future__ import annotations

import json
import secrets
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..calib.result import CalibrationResult
from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics
from ..geometry.rotations import matrix_to_quaternion, rotation_angle
from ..geometry.transforms import invert_transform, make_transform
from ..io.files import atomic_write, read_text
from ..io.files import load_json as _load_json_file
from ._checks import as_float, as_matrix, checked_quaternion, checked_rotation, plausible_camera, require
from ._result import calibration_record, opencv_distortion, require_intrinsics, split_opencv_distortion

__all__ = [
    "LUCID_EULER_SEQ", "lucid_pose_to_T_cam_lidar", "T_cam_lidar_to_lucid_pose", "read_lucid_calib",
    "lucid_calib_dict", "write_lucid_calib", "read_calib_json", "calib_json_dict", "write_calib_json",
    "read_calib_txt", "write_calib_txt", "read_opencalib", "write_opencalib", "lucid_to_calib_json",
    "calib_json_to_lucid", "load_json",
]

#: scipy Euler sequence of ``lucid_calib.json``: extrinsic x, y, z = ``Rz(yaw) Ry(pitch) Rx(roll)``.
LUCID_EULER_SEQ = "xyz"
_QUAT_TOL_DEG = 1.0

# Defaults of CalibAnything v2 calib.json fields that are not calibration (their sample values).
_CALIB_JSON_DEFAULTS: dict[str, Any] = {
    "img_folder": "images", "mask_folder": "processed_masks", "pc_folder": "pc",
    "img_format": ".png", "pc_format": ".pcd", "file_name": [],
    "params": {"min_plane_point_num": 2000, "cluster_tolerance": 0.25, "search_num": 4000,
               "search_range": {"rot_deg": 5, "trans_m": 0.5}, "point_range": {"top": 0.0, "bottom": 1.0},
               "down_sample": {"is_valid": False, "voxel_m": 0.05},
               "thread": {"is_multi_thread": True, "num_thread": 8}},
}


def load_json(path) -> Any:
    """Parse a JSON file; FormatError naming it when it is not JSON."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"calibration file not found: {path}")
    return _load_json_file(path, what="calibration file")


def _write_json(path, obj) -> Path:
    return atomic_write(path, [(json.dumps(obj, indent=2) + "\n").encode()])


# ------------------------------------------------------------------------- lucid pose maths
def lucid_pose_to_T_cam_lidar(roll: float, pitch: float, yaw: float, px: float, py: float, pz: float) -> np.ndarray:
    """lucid pose (degrees; camera origin in the LiDAR frame, metres) -> ``T_cam_lidar`` [4,4]
    (LiDAR -> camera), the inverse of ``T_lidar_cam = [Rz(yaw) Ry(pitch) Rx(roll) | p]``."""
    R_lidar_cam = Rotation.from_euler(LUCID_EULER_SEQ, [roll, pitch, yaw], degrees=True).as_matrix()
    return invert_transform(make_transform(R_lidar_cam, [px, py, pz]))


def T_cam_lidar_to_lucid_pose(T_cam_lidar) -> dict[str, float]:
    """``T_cam_lidar`` [4,4] (LiDAR -> camera) -> lucid ``{roll, pitch, yaw (deg), px, py, pz (m),
    quaternion {x, y, z, w}}`` describing the camera pose in the LiDAR frame."""
    T_lc = invert_transform(T_cam_lidar)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # gimbal lock: the matrix is still exact
        roll, pitch, yaw = Rotation.from_matrix(T_lc[:3, :3]).as_euler(LUCID_EULER_SEQ, degrees=True)
    q = matrix_to_quaternion(T_lc[:3, :3])
    return {"roll": float(roll), "pitch": float(pitch), "yaw": float(yaw),
            "px": float(T_lc[0, 3]), "py": float(T_lc[1, 3]), "pz": float(T_lc[2, 3]),
            "quaternion": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}}


# ------------------------------------------------------------------------------ lucid files
def read_lucid_calib(path, *, quaternion_tol_deg: float = _QUAT_TOL_DEG, repair: bool = False,
                     data: dict | None = None) -> CalibrationResult:
    """Read ``lucid_calib.json`` -> ``CalibrationResult`` (``T_cam_lidar``, LiDAR -> camera).

    The Euler angles win; the quaternion, when present, must agree within
    ``quaternion_tol_deg`` (FormatError otherwise; the disagreement is kept in
    ``meta["quaternion_disagreement_deg"]``). ``repair`` normalises a quaternion whose norm is
    off by more than 1e-3. ``data``: the parsed JSON (then ``path`` only names it in errors).
    """
    d = load_json(path) if data is None else data
    intr_d = require(d, "intrinsic_params", path, kind=dict)
    ext_d = require(d, "extrinsic_params", path, kind=dict)
    ip = "intrinsic_params."
    ep = "extrinsic_params."
    fx, fy, cx, cy = (as_float(require(intr_d, k, path, ip), path, ip + k) for k in ("fx", "fy", "cx", "cy"))
    model = str(intr_d.get("camera_model", "normal")).lower()
    if model not in ("normal", "pinhole", "opencv"):
        raise FormatError(path, f"unsupported camera model {intr_d.get('camera_model')!r}; expected "
                                "'normal' (pinhole with OpenCV distortion)", ip + "camera_model")
    dist = opencv_distortion({k: as_float(intr_d[k], path, ip + k) for k in
                              ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6") if k in intr_d})
    width = intr_d.get("width", intr_d.get("image_width"))
    height = intr_d.get("height", intr_d.get("image_height"))
    try:
        intr = CameraIntrinsics(fx, fy, cx, cy, dist, width, height)
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), "intrinsic_params") from None
    plausible_camera(intr, path, "intrinsic_params")
    coord = str(ext_d.get("camera_coordinate", "OPTICAL")).upper()
    if coord != "OPTICAL":
        raise FormatError(path, f"camera_coordinate {ext_d.get('camera_coordinate')!r} is not supported; "
                                "expected OPTICAL (x right, y down, z forward)", ep + "camera_coordinate")
    ang = [as_float(require(ext_d, k, path, ep), path, ep + k) for k in ("roll", "pitch", "yaw")]
    pos = [as_float(require(ext_d, k, path, ep), path, ep + k) for k in ("px", "py", "pz")]
    T = lucid_pose_to_T_cam_lidar(*ang, *pos)
    meta: dict[str, Any] = {"format": "lucid_calib", "camera": intr_d.get("camera", "")}
    for k in ("translation_error", "plane_translation_error", "rotation_error", "reprojection_error"):
        if k in ext_d:
            meta[k] = ext_d[k]
    if "quaternion" in ext_d:
        qd = require(ext_d, "quaternion", path, ep, kind=dict)
        qv = [as_float(require(qd, k, path, ep + "quaternion."), path, ep + f"quaternion.{k}") for k in "xyzw"]
        norm = float(np.linalg.norm(qv))
        if norm > 1e-9 and abs(norm - 1.0) > 1e-3 and not repair:
            raise FormatError(path, f"quaternion norm is {norm:.6f}, expected 1 (pass repair=True / --repair "
                                    "to normalise it)", ep + "quaternion")
        R_q = checked_quaternion(qv, path, ep + "quaternion")
        gap = rotation_angle(R_q, T[:3, :3].T, degrees=True)
        meta["quaternion_disagreement_deg"] = gap
        if gap > quaternion_tol_deg:
            raise FormatError(path, f"quaternion and roll/pitch/yaw disagree by {gap:.3f} deg (tolerance "
                                    f"{quaternion_tol_deg} deg); which one is right is ambiguous: fix the "
                                    "file or drop one of them", ep + "quaternion")
    return calibration_record(intr, T, method="lucid_calib", camera_name=str(intr_d.get("camera", "")),
                              meta=meta)


def lucid_calib_dict(result: CalibrationResult, camera: str | None = None) -> dict:
    """``lucid_calib.json`` content of ``result`` (see the module docstring for the directions)."""
    intr = require_intrinsics(result, "lucid_calib.json")
    dist = split_opencv_distortion(intr)
    ip: dict[str, Any] = {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy,
                          "k1": dist["k1"], "k2": dist["k2"], "p1": dist["p1"], "p2": dist["p2"],
                          "camera": camera if camera is not None else result.camera_name,
                          "k3": dist["k3"], "k4": dist["k4"], "k5": dist["k5"], "k6": dist["k6"],
                          "camera_model": "normal"}
    if intr.width is not None and intr.height is not None:
        ip["width"], ip["height"] = intr.width, intr.height
    ep = T_cam_lidar_to_lucid_pose(result.extrinsics)
    for k, v in (("reprojection_error", result.reproj_error_px),):
        if np.isfinite(v):
            ep[k] = float(v)
    ep["camera_coordinate"] = "OPTICAL"
    return {"intrinsic_params": ip, "extrinsic_params": ep}


def write_lucid_calib(result: CalibrationResult, path, *, camera: str | None = None) -> Path:
    """Write ``result`` as ``lucid_calib.json`` (camera pose in the LiDAR frame, degrees)."""
    return _write_json(path, lucid_calib_dict(result, camera))


# ----------------------------------------------------------------------- CalibAnything v2
def _opencv_matrix(node, path, field: str, shape, alt_shapes=()) -> np.ndarray:
    data = require(node, "data", path, field + ".") if isinstance(node, dict) else node
    return as_matrix(data, shape, path, field, alt_shapes=alt_shapes)


def _K_and_offset(M: np.ndarray, path, field: str) -> tuple[np.ndarray, np.ndarray]:
    K = M[:, :3]
    if abs(K[0, 1]) > 1e-9 or np.any(np.abs(K[1:, 0]) > 1e-9) or abs(K[2, 1]) > 1e-9 or abs(K[2, 2] - 1) > 1e-9:
        raise FormatError(path, f"expected K = [[fx,0,cx],[0,fy,cy],[0,0,1]], got {M[:, :3].tolist()}", field)
    off = np.linalg.solve(K, M[:, 3]) if M.shape[1] == 4 else np.zeros(3)
    return K, off


def _distortion_list(node, path, field: str) -> np.ndarray | None:
    data = node.get("data", []) if isinstance(node, dict) else node
    try:
        d = np.asarray(data, dtype=np.float64).reshape(-1) if data is not None else np.zeros(0)
    except (TypeError, ValueError):
        raise FormatError(path, f"expected a list of numbers, got {data!r:.60}", field) from None
    if not np.all(np.isfinite(d)):
        raise FormatError(path, "distortion has NaN/Inf entries", field)
    if d.size == 0 or not np.any(d):
        return None
    if d.size not in (4, 5, 8, 12, 14):
        raise FormatError(path, f"expected 4, 5 or 8 OpenCV coefficients (k1 k2 p1 p2 [k3 ...]), got {d.size}", field)
    return d


def _rigid4(node, path, field: str, repair: bool) -> np.ndarray:
    if _n(node) == 12:
        M = np.vstack([_opencv_matrix(node, path, field, (3, 4)), [0, 0, 0, 1]])
    else:
        M = _opencv_matrix(node, path, field, (4, 4), alt_shapes=[(3, 4)])
    if not np.allclose(M[3], [0, 0, 0, 1], atol=1e-9):
        raise FormatError(path, f"last row must be [0, 0, 0, 1], got {M[3].tolist()}", field)
    R = checked_rotation(M[:3, :3], path, field, repair=repair)
    return make_transform(R, M[:3, 3])


def _n(node) -> int:
    data = node.get("data", []) if isinstance(node, dict) else node
    try:
        return int(np.asarray(data, dtype=np.float64).size)
    except (TypeError, ValueError):
        return -1


def read_calib_json(path, *, use_gt: bool = False, repair: bool = False) -> CalibrationResult:
    """Read a CalibAnything v2 ``calib.json`` -> ``CalibrationResult``.

    The result holds ``T_lidar_to_cam`` (LiDAR -> camera; with a [3,4] ``cam_K`` its offset
    ``K^-1 P[:,3]`` is added to the translation), or ``T_lidar_to_cam_gt`` with ``use_gt``.
    ``meta["T_cam_lidar_gt"]`` is the ground truth [4,4] (LiDAR -> camera, offset included) when
    ``available``, else None; the scene fields (file_name, folders, params) are kept in meta.
    """
    path = Path(path)
    d = load_json(path)
    Kn = require(d, "cam_K", path)
    KM = _opencv_matrix(Kn, path, "cam_K", (3, 3)) if _n(Kn) == 9 else _opencv_matrix(Kn, path, "cam_K", (3, 4))
    K, off = _K_and_offset(KM, path, "cam_K")
    dist = _distortion_list(d.get("cam_dist", {}), path, "cam_dist")
    try:
        intr = CameraIntrinsics.from_matrix(K, dist)
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), "cam_K") from None
    plausible_camera(intr, path, "cam_K / cam_dist")
    shift = make_transform(np.eye(3), off)
    T_init = shift @ _rigid4(require(d, "T_lidar_to_cam", path), path, "T_lidar_to_cam", repair)
    gt_node = d.get("T_lidar_to_cam_gt")
    T_gt = None
    if isinstance(gt_node, dict) and gt_node.get("available", True) and _n(gt_node) > 0:
        T_gt = shift @ _rigid4(gt_node, path, "T_lidar_to_cam_gt", repair)
    if use_gt and T_gt is None:
        raise FormatError(path, "use_gt=True but the ground truth is not available", "T_lidar_to_cam_gt")
    meta = {k: d[k] for k in _CALIB_JSON_DEFAULTS if k in d}
    meta.update({"format": "calib_json", "T_cam_lidar_gt": None if T_gt is None else T_gt.tolist(),
                 "T_cam_lidar_initial": T_init.tolist(), "P_offset": off.tolist()})
    return calibration_record(intr, T_gt if use_gt else T_init, method="calib_json", meta=meta)


def calib_json_dict(result: CalibrationResult, *, gt=None, template: dict | None = None) -> dict:
    """CalibAnything v2 ``calib.json`` content: ``T_lidar_to_cam`` = ``result`` (LiDAR -> camera),
    ``T_lidar_to_cam_gt`` = ``gt`` [4,4] (same direction) or unavailable; other fields from
    ``template`` (e.g. ``result.meta`` of a read calib.json) or CalibAnything's defaults."""
    intr = require_intrinsics(result, "calib.json")
    src = {**_CALIB_JSON_DEFAULTS, **{k: v for k, v in (template or result.meta).items() if k in _CALIB_JSON_DEFAULTS}}
    d = split_opencv_distortion(intr)
    dist = [d["k1"], d["k2"], d["p1"], d["p2"], d["k3"]]
    if any(d[k] for k in ("k4", "k5", "k6")):
        dist += [d["k4"], d["k5"], d["k6"]]
    out: dict[str, Any] = {
        "cam_K": {"rows": 3, "cols": 3, "data": intr.K.tolist()},
        "cam_dist": {"cols": len(dist), "data": dist},
        "T_lidar_to_cam": {"rows": 4, "cols": 4, "data": result.extrinsics.tolist()},
        "T_lidar_to_cam_gt": ({"available": True, "rows": 4, "cols": 4, "data": np.asarray(gt, dtype=float).tolist()}
                              if gt is not None else {"available": False, "rows": 0, "cols": 0, "data": []}),
    }
    out.update({k: src[k] for k in _CALIB_JSON_DEFAULTS})
    return out


def write_calib_json(result: CalibrationResult, path, *, gt=None, template: dict | None = None) -> Path:
    """Write ``result`` as a CalibAnything v2 ``calib.json`` (see :func:`calib_json_dict`)."""
    return _write_json(path, calib_json_dict(result, gt=gt, template=template))


def lucid_to_calib_json(lucid_path, out_path, *, template: dict | None = None, **kw) -> Path:
    """Convert ``lucid_calib.json`` to CalibAnything v2 ``calib.json`` (distortion kept)."""
    return write_calib_json(read_lucid_calib(lucid_path, **kw), out_path, template=template)


def calib_json_to_lucid(calib_path, out_path, *, use_gt: bool = False, camera: str = "") -> Path:
    """Convert CalibAnything v2 ``calib.json`` to ``lucid_calib.json``."""
    return write_lucid_calib(read_calib_json(calib_path, use_gt=use_gt), out_path, camera=camera)


# ----------------------------------------------------------------------- CalibAnything v1
def read_calib_txt(path, *, repair: bool = False) -> CalibrationResult:
    """Read CalibAnything v1 ``calib.txt`` (``K:`` [3,3], ``D:`` OpenCV, ``T:`` [3,4] LiDAR -> camera)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"calibration file not found: {path}")
    vals: dict[str, list[str]] = {}
    for line in read_text(path, what="calib.txt").splitlines():
        if ":" in line:
            k, _, rest = line.partition(":")
            vals[k.strip()] = rest.split()
    for k in ("K", "T"):
        if k not in vals:
            raise FormatError(path, f"missing line '{k}:' (found {sorted(vals) or 'none'})", k)

    def nums(k):
        try:
            return [float(v) for v in vals[k]]
        except ValueError:
            raise FormatError(path, f"non-numeric values {vals[k]}", k) from None

    K, _ = _K_and_offset(as_matrix(nums("K"), (3, 3), path, "K"), path, "K")
    dist = _distortion_list(nums("D"), path, "D") if "D" in vals else None
    Tm = as_matrix(nums("T"), (3, 4), path, "T", alt_shapes=[(4, 4)])
    T = make_transform(checked_rotation(Tm[:, :3], path, "T", repair=repair), Tm[:, 3])
    try:
        intr = CameraIntrinsics.from_matrix(K, dist)
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), "K") from None
    return calibration_record(intr, T, method="calib_txt", meta={"format": "calib_txt"})


def write_calib_txt(result: CalibrationResult, path) -> Path:
    """Write CalibAnything v1 ``calib.txt`` (exact float repr)."""
    intr = require_intrinsics(result, "calib.txt")
    d = intr.dist_coeffs if intr.distortion is not None else np.zeros(5)
    lines = ["K: " + " ".join(repr(float(v)) for v in intr.K.ravel()),
             "D: " + " ".join(repr(float(v)) for v in d),
             "T: " + " ".join(repr(float(v)) for v in result.extrinsics[:3].ravel())]
    path = Path(path)
    return atomic_write(path, [("\n".join(lines) + "\n").encode()])


# ------------------------------------------------------------------------------ OpenCalib
def _single_block(d, path) -> tuple[str, dict]:
    if not isinstance(d, dict) or len(d) != 1 or not isinstance(next(iter(d.values())), dict):
        raise FormatError(path, "expected one top-level object named '<sensor>-intrinsic' or "
                                "'<lidar>-to-<camera>-extrinsic'")
    return next(iter(d.items()))


def read_opencalib(extrinsic_path, intrinsic_path=None, *, repair: bool = False) -> CalibrationResult:
    """Read an OpenCalib ``*-extrinsic.json`` (``param.sensor_calib`` [4,4], LiDAR -> camera) and
    optionally its camera's ``*-intrinsic.json`` (found next to it when not given)."""
    extrinsic_path = Path(extrinsic_path)
    name, blk = _single_block(load_json(extrinsic_path), extrinsic_path)
    param = require(blk, "param", extrinsic_path, name + ".")
    T = _rigid4(require(param, "sensor_calib", extrinsic_path, name + ".param."), extrinsic_path,
                f"{name}.param.sensor_calib", repair)
    cam = blk.get("target_sensor_name", "")
    lidar = blk.get("sensor_name", "")
    embedded = blk.get(_EMBEDDED_INTRINSIC) if intrinsic_path is None else None
    if intrinsic_path is None and cam:
        cand = extrinsic_path.with_name(f"{cam}-intrinsic.json")
        intrinsic_path = cand if cand.is_file() else None
    intr = None
    if isinstance(embedded, dict) and len(embedded) == 1:  # written by xcalib: the pair id decides
        loaded = _single_block(load_json(intrinsic_path), intrinsic_path) if intrinsic_path is not None else None
        if loaded is None or loaded[1].get(_PAIR) != blk.get(_PAIR):  # the file is from another write
            intr = _opencalib_intrinsics(*next(iter(embedded.items())), extrinsic_path)
        else:
            intr = _opencalib_intrinsics(*loaded, Path(intrinsic_path))
    elif intrinsic_path is not None:
        ipath = Path(intrinsic_path)
        intr = _opencalib_intrinsics(*_single_block(load_json(ipath), ipath), ipath)
    return calibration_record(intr, T, method="opencalib", camera_name=cam,
                              meta={"format": "opencalib", "lidar_name": lidar})


_PAIR = "xcalib_pair"
_EMBEDDED_INTRINSIC = "xcalib_intrinsic"


def _opencalib_intrinsics(iname: str, iblk, ipath: Path) -> CameraIntrinsics:
    if not isinstance(iblk, dict):
        raise FormatError(ipath, "expected a JSON object", iname)
    ip = require(iblk, "param", ipath, iname + ".")
    K, _ = _K_and_offset(_opencv_matrix(require(ip, "cam_K", ipath, iname + ".param."), ipath,
                                        f"{iname}.param.cam_K", (3, 3)), ipath, f"{iname}.param.cam_K")
    dist = _distortion_list(ip.get("cam_dist", {}), ipath, f"{iname}.param.cam_dist")
    try:
        return CameraIntrinsics.from_matrix(K, dist, width=ip.get("img_dist_w"), height=ip.get("img_dist_h"))
    except (TypeError, ValueError) as exc:
        raise FormatError(ipath, str(exc), f"{iname}.param") from None


def write_opencalib(result: CalibrationResult, out_dir, *, lidar: str = "lidar",
                    camera: str | None = None) -> tuple[Path, Path | None]:
    """Write OpenCalib ``<lidar>-to-<camera>-extrinsic.json`` (+ ``<camera>-intrinsic.json`` when the
    result has intrinsics) into ``out_dir``; returns both paths."""
    out_dir = Path(out_dir)
    camera = camera or result.camera_name or "camera"
    ext_name = f"{lidar}-to-{camera}-extrinsic"
    ext = {ext_name: {"sensor_name": lidar, "target_sensor_name": camera, "device_type": "relational",
                      "param_type": "extrinsic",
                      "param": {"time_lag": 0, "sensor_calib": {"rows": 4, "cols": 4, "type": 6, "continuous": True,
                                                                "data": result.extrinsics.tolist()}}}}
    pair = secrets.token_hex(8)  # both files carry it; the extrinsic file also embeds the intrinsics, so a
    ext[ext_name][_PAIR] = pair   # write killed between the two renames is never read as a mixed pair
    iblock = None
    if result.intrinsics is not None:
        intr = result.intrinsics
        dist = intr.dist_coeffs.tolist()
        param: dict[str, Any] = {
            "cam_K": {"rows": 3, "cols": 3, "type": 6, "continuous": True, "data": intr.K.tolist()},
            "cam_dist": {"rows": 1, "cols": len(dist), "type": 6, "continuous": True, "data": [dist]}}
        if intr.width is not None and intr.height is not None:
            param = {"img_dist_w": intr.width, "img_dist_h": intr.height, **param}
        iname = f"{camera}-intrinsic"
        iblock = {iname: {"sensor_name": camera, "target_sensor_name": camera, "device_type": "camera",
                          "param_type": "intrinsic", "param": param, _PAIR: pair}}
        ext[ext_name][_EMBEDDED_INTRINSIC] = iblock
    ep = _write_json(out_dir / f"{ext_name}.json", ext)
    ip = _write_json(out_dir / f"{iname}.json", iblock) if iblock is not None else None
    return ep, ip
