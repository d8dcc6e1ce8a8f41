"""``CalibrationResult``: the camera<-LiDAR extrinsics and how well they explain the data."""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CalibrationFailedError
from ..geometry.camera import CameraIntrinsics
from ..geometry.camera_models import calibration_camera_from_dict
from ..geometry.projection import project_points, projection_matrix
from ..geometry.transforms import make_transform, pose_error as _pose_error
from .config import CalibConfig
from .diagnostics import CalibDiagnostics, bound95

__all__ = ["CalibrationResult"]


@dataclass
class CalibrationResult:
    """Estimated extrinsics ``T_cam_lidar`` (LiDAR frame -> OpenCV camera frame).

    rotation [3,3], translation [3] (metres): ``X_cam = R X_lidar + t``. ``pairs`` holds the
    one-to-one matches per frame as int arrays [n,2] of (2D index, 3D index) in each frame's
    own numbering. Residuals are in pixels (box-edge disagreement) and IoU of projected 3D
    boxes vs their matched 2D boxes. ``rotation_std_deg`` / ``translation_std_m`` are 1-sigma
    uncertainty estimates ([3] each: about/along the camera x, y, z axes). A failed result
    (``success=False``) has ``rotation`` / ``translation`` None (as the reference), and its pose
    views (``extrinsics``, ``projection``, ``pose_error``, ``project``) raise
    :class:`xcalib.errors.CalibrationFailedError` (a ``RuntimeError`` and a ``ValueError``).
    ``config`` is the
    ``CalibConfig`` that produced the result and ``diagnostics`` what the calibration computed
    on the way (bring-up pose, uncertainty parts, misfit checks, per-frame residuals); both are
    None for results read from other tools' files. ``boxes_source``: who made the boxes the pose
    was fitted to, when a detector of xcalib's did (``xcalib.types.OWN_DETECTIONS``, set with the
    detection coverage by ``xcalib.detect.explain_refusal``; written to and read from xcalib's
    calibration.json); "" otherwise and for results read from other tools' files.
    """

    success: bool
    intrinsics: CameraIntrinsics | None = None
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None
    message: str = ""
    n_correspondences: int = 0
    n_inliers: int = 0
    reproj_error_px: float = float("inf")
    residual_px_median: float = float("nan")
    iou_median: float = float("nan")
    iou_mean: float = float("nan")
    rotation_std_deg: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    translation_std_m: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    pairs: list[np.ndarray] = field(default_factory=list)
    frame_keys: list[str] = field(default_factory=list)
    camera_name: str = ""
    image_size: tuple[int, int] | None = None
    accepted: bool = True
    buffer_reproj_px: float = float("nan")
    method: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    config: CalibConfig | None = None
    diagnostics: CalibDiagnostics | None = None
    boxes_source: str = ""

    def __post_init__(self) -> None:
        if self.success and (self.rotation is None or self.translation is None):
            raise ValueError("CalibrationResult: a successful result needs a rotation and a translation")
        if self.rotation is not None:
            self.rotation = np.asarray(self.rotation, dtype=np.float64).reshape(3, 3)
        if self.translation is not None:
            self.translation = np.asarray(self.translation, dtype=np.float64).reshape(3)
        self.rotation_std_deg = np.asarray(self.rotation_std_deg, dtype=np.float64).reshape(3)
        self.translation_std_m = np.asarray(self.translation_std_m, dtype=np.float64).reshape(3)
        self.pairs = [np.asarray(p, dtype=np.int64).reshape(-1, 2) for p in self.pairs]

    # ----------------------------------------------------------------- views
    def _require_pose(self, what: str) -> None:
        if self.rotation is None or self.translation is None:
            raise CalibrationFailedError(f"{what}: the calibration failed ({self.message or 'no pose'}); "
                                         "there is no pose")

    @property
    def extrinsics(self) -> np.ndarray:
        """[4,4] ``T_cam_lidar``."""
        self._require_pose("extrinsics")
        return make_transform(self.rotation, self.translation)

    @property
    def K(self) -> np.ndarray:
        if self.intrinsics is None:
            raise ValueError("CalibrationResult has no intrinsics")
        return self.intrinsics.K

    @property
    def projection(self) -> np.ndarray:
        """[3,4] ``P = K [R|t]`` (LiDAR-frame points -> pixels, distortion excluded). A wide-angle
        camera model (``kannala_brandt``, ``unified``, ``ucm``, ``eucm``, ``double_sphere``) has no
        such matrix: ValueError naming the model (use :meth:`project`, or the ``intrinsics``)."""
        self._require_pose("projection")
        if not self.has_projection_matrix:
            raise ValueError(f"projection: a {self.intrinsics.name} camera is not K [R|t] (its lens is no pinhole "
                             "with distortion); project with result.project(points) or the camera model in "
                             "result.intrinsics")
        return projection_matrix(self.K, self.rotation, self.translation)

    @property
    def has_projection_matrix(self) -> bool:
        """Whether ``projection`` (K [R|t]) describes the camera: a pinhole camera (with or without
        OpenCV distortion, which it leaves out); False for a wide-angle model and without intrinsics."""
        return isinstance(self.intrinsics, CameraIntrinsics) or \
            getattr(self.intrinsics, "name", None) in ("pinhole", "pinhole_radtan")

    def _projection_note(self) -> str | None:
        """calibration.json's ``projection_note``: why ``projection`` is null for a wide-angle model."""
        if self.intrinsics is None or self.has_projection_matrix:
            return None
        return (f"no K [R|t] for a {self.intrinsics.name} camera: project LiDAR points with the camera model in "
                f"'intrinsics' (model '{self.intrinsics.name}') and 'extrinsics_T_cam_lidar' "
                "(xcalib.CalibrationResult.project)")

    @property
    def bound95(self) -> tuple[float, float]:
        """(deg, m): the radii within which the rotation and the translation error lie with 95 %
        probability, from the reported per-axis 1-sigma (``uncertainty.bound95``; inf: unbounded)."""
        return bound95(self.rotation_std_deg), bound95(self.translation_std_m)

    @property
    def coarse(self) -> bool:
        """A success whose 95 % bound exceeds ``config.fine_rot_bound_deg`` / ``fine_trans_bound_m``
        (1 deg / 0.5 m by default): determined, but not 95 % sure within that line; a starting
        point, not a pose for fusion. False for a refusal (it has no pose) and for a fine success."""
        if not self.success:
            return False
        cfg = self.config or CalibConfig()
        r, t = self.bound95
        return bool(not (r <= cfg.fine_rot_bound_deg and t <= cfg.fine_trans_bound_m))

    def precision_line(self) -> str:
        """"fine ..." / "COARSE ...": the 95 % bound against the fine line (``coarse``); "" for a refusal."""
        if not self.success:
            return ""
        cfg = self.config or CalibConfig()
        r, t = self.bound95
        head = f"95 % bound {r:.2f} deg / {t:.2f} m"
        if not self.coarse:
            return f"fine: {head} (within {cfg.fine_rot_bound_deg:g} deg / {cfg.fine_trans_bound_m:g} m)"
        beyond = [w for w, out in ((f"the rotation beyond {cfg.fine_rot_bound_deg:g} deg", not r <= cfg.fine_rot_bound_deg),
                                   (f"the translation beyond {cfg.fine_trans_bound_m:g} m",
                                    not t <= cfg.fine_trans_bound_m)) if out]
        return (f"COARSE: {head}, {' and '.join(beyond)} -- a starting "
                "point, not a pose for fusing the sensors; add frames with other objects at other places and depths")

    @property
    def time_offset_s(self) -> float | None:
        """Camera time minus LiDAR time (s) the 3D boxes were moved by (estimated or fixed); None: none."""
        return None if self.diagnostics is None else self.diagnostics.selfcal.time_offset_s

    @property
    def time_offset_std_s(self) -> float | None:
        """1-sigma (s) of an estimated time offset."""
        return None if self.diagnostics is None else self.diagnostics.selfcal.time_offset_std_s

    @property
    def intrinsics_given(self) -> CameraIntrinsics | None:
        """The intrinsics passed in (``intrinsics`` are those used: estimated where refined)."""
        if self.diagnostics is None or self.diagnostics.selfcal.intrinsics_given is None:
            return self.intrinsics
        return calibration_camera_from_dict(self.diagnostics.selfcal.intrinsics_given)

    @property
    def focal_scale(self) -> float:
        """Focal length used / given (1.0: the given one kept)."""
        return 1.0 if self.diagnostics is None else float(self.diagnostics.selfcal.focal_scale)

    @property
    def focal_scale_std(self) -> float | None:
        """1-sigma (relative) of the focal scale where it was measured."""
        return None if self.diagnostics is None else self.diagnostics.selfcal.focal_scale_std

    @property
    def n_pairs(self) -> int:
        return int(sum(len(p) for p in self.pairs))

    def pose_error(self, gt_extrinsics) -> tuple[float, float]:
        """(rotation error in degrees, translation error in metres) against a [4,4]/[3,4] truth;
        :class:`CalibrationFailedError` (a RuntimeError) for a failed result."""
        if not self.success:
            raise CalibrationFailedError(f"calibration failed ({self.message}); there is no pose to compare")
        return _pose_error(self.extrinsics, gt_extrinsics)

    def project(self, points_3d):
        """LiDAR-frame points [N,>=3] -> (uv [N,2] pixels with distortion, depth [N] metres)."""
        self._require_pose("project")
        if self.intrinsics is None:
            raise ValueError("CalibrationResult has no intrinsics")
        return project_points(points_3d, self.intrinsics, self.rotation, self.translation)

    # ------------------------------------------------------------------ I/O
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (arrays as nested lists)."""
        return {
            "format": "xcalib-calibration-v1",
            "success": bool(self.success),
            "message": self.message,
            "method": self.method,
            "camera_name": self.camera_name,
            "image_size": None if self.image_size is None else list(self.image_size),
            "intrinsics": None if self.intrinsics is None else self.intrinsics.to_dict(),
            "rotation": None if self.rotation is None else self.rotation.tolist(),
            "translation": None if self.translation is None else self.translation.tolist(),
            "extrinsics_T_cam_lidar": None if self.rotation is None else self.extrinsics.tolist(),
            "projection": None if not self.has_projection_matrix or self.rotation is None else self.projection.tolist(),
            # a wide-angle model: projection is null, and this says why (pinhole results: no such key)
            **({"projection_note": self._projection_note()} if self._projection_note() else {}),
            "n_correspondences": int(self.n_correspondences),
            "n_inliers": int(self.n_inliers),
            "reproj_error_px": _num(self.reproj_error_px),
            "residual_px_median": _num(self.residual_px_median),
            "iou_median": _num(self.iou_median),
            "iou_mean": _num(self.iou_mean),
            "rotation_std_deg": [_num(v) for v in self.rotation_std_deg],
            "translation_std_m": [_num(v) for v in self.translation_std_m],
            "accepted": bool(self.accepted),
            "bound95": [_num(v) for v in self.bound95],  # derived (deg, m); not read back
            "coarse": self.coarse,  # derived: the 95 % bound beyond config.fine_*_bound; not read back
            "buffer_reproj_px": _num(self.buffer_reproj_px),
            "frame_keys": list(self.frame_keys),
            "pairs": [p.tolist() for p in self.pairs],
            "meta": self.meta,
            "config": None if self.config is None else self.config.to_dict(),
            "diagnostics": None if self.diagnostics is None else self.diagnostics.to_dict(),
            # who made the boxes (only when a detector of xcalib's did: other results' files unchanged)
            **({"boxes_source": self.boxes_source} if self.boxes_source else {}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CalibrationResult":
        intr = d.get("intrinsics")
        return cls(
            success=bool(d["success"]),
            intrinsics=None if intr is None else calibration_camera_from_dict(intr),
            rotation=None if d.get("rotation") is None else np.asarray(d["rotation"], dtype=np.float64),
            translation=None if d.get("translation") is None else np.asarray(d["translation"], dtype=np.float64),
            message=d.get("message", ""),
            n_correspondences=int(d.get("n_correspondences", 0)),
            n_inliers=int(d.get("n_inliers", 0)),
            reproj_error_px=_unnum(d.get("reproj_error_px"), float("inf")),
            residual_px_median=_unnum(d.get("residual_px_median")),
            iou_median=_unnum(d.get("iou_median")),
            iou_mean=_unnum(d.get("iou_mean")),
            rotation_std_deg=[_unnum(v) for v in d.get("rotation_std_deg", [None] * 3)],
            translation_std_m=[_unnum(v) for v in d.get("translation_std_m", [None] * 3)],
            pairs=[np.asarray(p, dtype=np.int64).reshape(-1, 2) for p in d.get("pairs", [])],
            frame_keys=list(d.get("frame_keys", [])),
            camera_name=d.get("camera_name", ""),
            image_size=None if d.get("image_size") is None else tuple(d["image_size"]),
            accepted=bool(d.get("accepted", True)),
            buffer_reproj_px=_unnum(d.get("buffer_reproj_px")),
            method=d.get("method", ""),
            meta=dict(d.get("meta", {})),
            config=None if d.get("config") is None else CalibConfig.from_dict(d["config"]),
            diagnostics=None if d.get("diagnostics") is None else CalibDiagnostics.from_dict(d["diagnostics"]),
            boxes_source=str(d.get("boxes_source") or ""),
        )

    def save(self, path: str | Path, *, overwrite: bool = True) -> Path:
        """Write ``.json`` (everything, exact float repr) or ``.npz`` (the reference's arrays
        rotation, translation, projection, K, reproj_error_px, n_inliers, plus extrinsics,
        dist_coeffs, success, n_correspondences and a JSON blob; a failed result's pose arrays
        are NaN), atomically (unique temp file beside ``path``, then rename).
        ``overwrite=False`` refuses an existing file."""
        import io

        from ..io.files import atomic_write

        path = Path(path)
        if path.suffix == ".npz":
            buf = io.BytesIO()
            posed = self.rotation is not None and self.translation is not None
            # a wide-angle camera model has no K + OpenCV distortion: NaN there (its model is in json)
            nan5 = None if isinstance(self.intrinsics, (CameraIntrinsics, type(None))) else np.full(5, np.nan)
            np.savez(buf, rotation=self.rotation if posed else np.full((3, 3), np.nan),
                     translation=self.translation if posed else np.full(3, np.nan),
                     extrinsics=self.extrinsics if posed else np.full((4, 4), np.nan),
                     K=self.K if self.intrinsics is not None else np.full((3, 3), np.nan),
                     dist_coeffs=nan5 if nan5 is not None else (self.intrinsics.dist_coeffs if self.intrinsics is not None
                                                                  else np.zeros(5)),
                     projection=self.projection if self.intrinsics is not None and posed and nan5 is None
                     else np.full((3, 4), np.nan),
                     reproj_error_px=np.float64(self.reproj_error_px), n_inliers=np.int64(self.n_inliers),
                     n_correspondences=np.int64(self.n_correspondences), success=np.bool_(self.success),
                     json=np.frombuffer(json.dumps(self.to_dict()).encode(), dtype=np.uint8))
            data = buf.getvalue()
        else:
            data = json.dumps(self.to_dict(), indent=2).encode()
        return atomic_write(path, [data], overwrite=overwrite)

    @classmethod
    def load(cls, path: str | Path) -> "CalibrationResult":
        """Read a ``.json`` / ``.npz`` written by :meth:`save`, validated: the rotation must be
        orthonormal (det +1), every number finite, the translation within ``MAX_TRANSLATION_M``, and
        an npz's arrays must agree with its JSON. Anything else is a FormatError naming the field."""
        from ..errors import FormatError
        from ..io.files import MAX_TEXT_BYTES, read_text

        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"calibration file not found: {path}")
        try:
            if path.suffix == ".npz":
                d, arrays = _read_npz(path)
            else:
                d, arrays = json.loads(read_text(path, max_bytes=MAX_TEXT_BYTES, what="calibration file")), None
        except FormatError:
            raise
        except (json.JSONDecodeError, OSError, ValueError, RecursionError, MemoryError, KeyError, EOFError,
                zipfile.BadZipFile, NotImplementedError) as exc:
            raise FormatError(path, f"not a readable xcalib calibration ({type(exc).__name__}: {str(exc)[:200]})") from None
        if not isinstance(d, dict):
            raise FormatError(path, f"expected a JSON object, got {type(d).__name__}")
        for key in ("success", "rotation", "translation"):
            if key not in d:
                raise FormatError(path, "missing key: not an xcalib calibration (the calibration.json of xcalib "
                                        "calibrate; another format: xcalib convert FILE --to json --out calibration.json)",
                                  key)
        if not isinstance(d["success"], bool):
            raise FormatError(path, f"expected true or false, got {d['success']!r:.40}", "success")
        if d["success"] and (d["rotation"] is None or d["translation"] is None):
            raise FormatError(path, "a successful calibration needs a rotation and a translation", "rotation")
        try:
            res = cls.from_dict(d)
            _validate_pose(res, path)
        except FormatError:
            raise
        except (TypeError, ValueError, KeyError, AttributeError, OverflowError, IndexError) as exc:
            raise FormatError(path, f"malformed field ({type(exc).__name__}: {str(exc)[:200]})") from None
        if arrays is not None:
            _check_npz_agrees(res, arrays, path)
        return res

    def _n_used(self) -> int:
        sel = None if self.diagnostics is None else getattr(self.diagnostics, "selection", None)
        return sel.n_frames_used if sel is not None and sel.n_frames_given else len(self.pairs)

    def frames_line(self) -> str:
        """"N of M used (K of L distinct objects ...)": which frames of the recording the
        calibration used (``diagnostics.selection``); "" when not recorded."""
        sel = None if self.diagnostics is None else getattr(self.diagnostics, "selection", None)
        if sel is None or not sel.n_frames_given:
            return ""
        how = {"tracks": "by track id", "positions": "tracked by 3D position"}.get(sel.object_identity, "")
        chosen = "" if sel.n_frames_used == sel.n_frames_given else \
            f"; the informative frames, up to max_frames={sel.max_frames}"
        return (f"{sel.n_frames_used} of {sel.n_frames_given} used ({sel.n_objects_used} of {sel.n_objects} distinct "
                f"objects{', ' + how if how else ''}{chosen})")

    def summary(self) -> str:
        """A few human-readable lines."""
        if not self.success:
            return f"calibration FAILED: {self.message}"
        from ..geometry.rotations import matrix_to_euler

        rpy = matrix_to_euler(self.rotation, "xyz", degrees=True)
        lines = [
            f"calibration OK ({self.method or 'xcalib'}): {self.n_pairs} matched pairs over {self._n_used()} frame(s)",
            f"  t (m)         = [{self.translation[0]:+.3f}, {self.translation[1]:+.3f}, {self.translation[2]:+.3f}]",
            f"  R (xyz deg)   = [{rpy[0]:+.2f}, {rpy[1]:+.2f}, {rpy[2]:+.2f}]",
            f"  residual      = {self.residual_px_median:.2f} px median, IoU median {self.iou_median:.3f}",
            f"  1-sigma       = rot {np.array2string(self.rotation_std_deg, precision=3)} deg, "
            f"trans {np.array2string(self.translation_std_m, precision=3)} m",
            f"  precision     = {self.precision_line()}",
        ]
        sc = None if self.diagnostics is None else self.diagnostics.selfcal
        if sc is not None and sc.focal_estimated:
            lines.append(f"  focal length  = fx {sc.fx_used:.2f}, fy {sc.fy_used:.2f} px (x{sc.focal_scale:.4f} of the "
                         f"given, 1-sigma {100 * (sc.focal_scale_std or 0):.2f} %)")
        if sc is not None and sc.principal_shift_px is not None:
            lines.append(f"  principal pt  = cx {sc.cx_used:.1f}, cy {sc.cy_used:.1f} px (moved "
                         f"{sc.principal_shift_px[0]:+.1f}, {sc.principal_shift_px[1]:+.1f} px)")
        if sc is not None and sc.time_offset_s is not None:
            sd = "" if sc.time_offset_std_s is None else f", 1-sigma {1e3 * sc.time_offset_std_s:.1f} ms"
            lines.append(f"  time offset   = {1e3 * sc.time_offset_s:+.1f} ms camera - LiDAR ({sc.time_offset_source}{sd})")
        line = self.frames_line()
        if line:
            lines.append(f"  frames        = {line}")
        bf = None if self.diagnostics is None else getattr(self.diagnostics, "box_fit", None)
        if bf and "sides" in bf:
            lines.append(f"  box model     = {bf.get('outline') or 'corners'} outlines; 2D boxes inside them by "
                         f"{100 * bf['sides']:+.1f} % (sides), {100 * bf['top']:+.1f} % (top), "
                         f"{100 * bf['bottom']:+.1f} % (bottom) of their size")
        ob = bf.get("objects") if bf else None
        if ob and "tau" in ob:
            tau = ob["tau"]
            lines.append(f"  own outlines  = {ob.get('n_objects', 0)} objects differ by 1-sigma {100 * tau.get('left', 0):.1f} % "
                         f"(sides), {100 * tau.get('top', 0):.1f} % (top), {100 * tau.get('bottom', 0):.1f} % (bottom); "
                         + (f"fitted with the pose (moved {ob['pose_shift'][0]:.2f} deg / {ob['pose_shift'][1]:.2f} m)"
                            if ob.get("applied", True) else "the pose did not move beyond its noise: kept"))
        if self.message:
            lines.append(f"  note: {self.message}")
        return "\n".join(lines)


#: Largest |translation| (metres) a calibration file may hold (camera-LiDAR rigs are metres apart).
MAX_TRANSLATION_M = 1000.0
#: max |R R^T - I| / |det R - 1| accepted when loading a saved rotation.
LOAD_ROTATION_TOL = 1e-6
_NPZ_MAX_BYTES = 64 << 20


def _read_npz(path: Path) -> tuple[dict, dict]:
    """(JSON dict, {name: array}) of a calibration npz; member sizes are checked before inflating."""
    from ..errors import FormatError
    from ..io.files import open_regular

    with open_regular(path, what="calibration npz") as fh:
        with np.load(fh, allow_pickle=False) as z:
            if not hasattr(z, "zip"):
                raise FormatError(path, "not an npz archive")
            total = sum(i.file_size for i in z.zip.infolist())
            if total > _NPZ_MAX_BYTES:
                raise FormatError(path, f"archive inflates to {total} bytes; a calibration is < {_NPZ_MAX_BYTES}",
                                  "npz")
            if "json" not in z.files:
                raise FormatError(path, "missing the 'json' array; not an xcalib calibration npz", "json")
            arrays = {k: z[k] for k in z.files}
    blob = arrays.pop("json")
    if blob.dtype != np.uint8:
        raise FormatError(path, f"expected uint8 bytes, got {blob.dtype}", "json")
    try:
        d = json.loads(blob.tobytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not UTF-8 JSON ({exc.reason})", "json") from None
    return d, arrays


def validate_loaded(res: "CalibrationResult", path) -> None:
    """FormatError naming ``path`` unless ``res`` holds a rotation (orthonormal, det +1), finite
    numbers and a translation within ``MAX_TRANSLATION_M`` (what every reader must return)."""
    _validate_pose(res, path)


def _validate_pose(res: "CalibrationResult", path) -> None:
    from ..errors import FormatError
    from ..geometry.rotations import orthonormality_error

    R, t = res.rotation, res.translation
    if R is None or t is None:  # a failed result has no pose
        if (R is None) != (t is None):
            raise FormatError(path, "rotation and translation must both be null or both be given", "rotation")
        R, t = np.eye(3), np.zeros(3)
    if not np.all(np.isfinite(R)):
        raise FormatError(path, "rotation has NaN/Inf entries", "rotation")
    err = orthonormality_error(R)
    if err > LOAD_ROTATION_TOL:
        raise FormatError(path, f"not a rotation matrix: error {err:.2e} (max |R R^T - I|, |det - 1|) exceeds "
                                f"{LOAD_ROTATION_TOL:.0e}", "rotation")
    if not np.all(np.isfinite(t)):
        raise FormatError(path, "translation has NaN/Inf entries", "translation")
    if np.abs(t).max() > MAX_TRANSLATION_M:
        raise FormatError(path, f"translation {t.tolist()} m exceeds {MAX_TRANSLATION_M:g} m: not a camera-LiDAR "
                                "extrinsic", "translation")
    for name in ("rotation_std_deg", "translation_std_m"):
        v = getattr(res, name)
        if np.any(np.isinf(v)) or np.any(v < 0):
            raise FormatError(path, f"expected non-negative finite values or null, got {v.tolist()}", name)
    for k, p in enumerate(res.pairs):
        if len(p) and p.min() < 0:
            raise FormatError(path, "pair indices must be >= 0", f"pairs[{k}]")
    if res.intrinsics is not None and res.image_size is not None:
        w, h = res.image_size
        if not (0 < int(w) <= 100_000 and 0 < int(h) <= 100_000):
            raise FormatError(path, f"image size {w}x{h} out of range", "image_size")


def _check_npz_agrees(res: "CalibrationResult", arrays: dict, path) -> None:
    from ..errors import FormatError

    if res.rotation is None:  # a failed result: NaN pose arrays
        want = {}
    else:
        want = {"rotation": res.rotation, "translation": res.translation, "extrinsics": res.extrinsics}
    if res.intrinsics is not None:
        want["K"] = res.intrinsics.K
    for name, value in want.items():
        if name not in arrays:
            raise FormatError(path, "missing array", name)
        a = arrays[name]
        if a.shape != value.shape or a.dtype.kind != "f" or not np.allclose(a, value, rtol=1e-12, atol=1e-12):
            raise FormatError(path, f"array {name} disagrees with the JSON blob (which one is right is ambiguous)",
                              name)


def _num(v):
    v = float(v)
    return v if np.isfinite(v) else None


def _unnum(v, default=float("nan")):
    return default if v is None else float(v)
