"""KITTI object-detection format: calib files, label_2 rows, velodyne ``.bin`` and whole folders.

Frames and directions (KITTI devkit conventions, made explicit):

* ``Tr_velo_to_cam`` [4,4]: Velodyne (LiDAR) frame -> *unrectified* camera-0 frame.
* ``R0_rect`` [3,3]: unrectified camera-0 -> rectified camera-0 frame.
* ``P2`` [3,4]: rectified camera-0 frame -> camera-2 pixels. ``P2 = K2 [I | t_offset]`` with
  ``t_offset = K2^-1 P2[:, 3]`` (metres, about -6 cm along x for the left colour camera): P2's
  4th column is *not* zero, it is the translation from rectified camera 0 to camera 2.
* label_2 ``location`` is the bottom-centre of the box in the rectified camera-0 frame,
  ``dimensions`` are (h, w, l) metres and ``rotation_y`` rotates about the camera +y axis.

xcalib's extrinsics of camera ``i`` are therefore
``T_cam_lidar = Translate(t_offset_i) @ R0_rect @ Tr_velo_to_cam`` (LiDAR -> rectified
camera ``i``) and ``K_i @ T_cam_lidar[:3] == P_i @ R0_rect @ Tr_velo_to_cam`` exactly.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..geometry.boxes import box7_corners, box7_to_extents, boxes2d_from_points, check_boxes3d
from ..geometry.camera import MAX_PIXELS, CameraIntrinsics
from ..geometry.projection import project_points
from ..geometry.transforms import invert_transform, make_transform
from ..types import Frame
from ..io.files import atomic_write, read_text
from ._checks import as_matrix, checked_rotation
from ._media import image_size, load_rgb

__all__ = [
    "KittiCalibration", "KittiLabels", "load_kitti_calibration", "parse_kitti_calibration",
    "write_kitti_calibration", "format_kitti_calibration", "load_kitti_labels",
    "parse_kitti_labels", "read_velodyne_bin", "camera_boxes_to_lidar", "lidar_boxes_to_camera",
    "box7_to_protocol", "project_box7", "KittiFrames", "kitti_frames", "find_kitti_records",
    "KittiRecord",
]

log = logging.getLogger("xcalib.formats.kitti")

# Accepted key spellings -> canonical key (object-detection, raw-sequence and tool variants).
_KEY_ALIASES = {
    "P0": "P0", "P1": "P1", "P2": "P2", "P3": "P3",
    "P_rect_00": "P0", "P_rect_01": "P1", "P_rect_02": "P2", "P_rect_03": "P3",
    "R0_rect": "R0_rect", "R_rect": "R0_rect", "R0": "R0_rect", "R_rect_00": "R0_rect",
    "Tr_velo_to_cam": "Tr_velo_to_cam", "Tr_velo_cam": "Tr_velo_to_cam", "velo_to_cam": "Tr_velo_to_cam",
    "Tr_imu_to_velo": "Tr_imu_to_velo", "Tr_imu_velo": "Tr_imu_to_velo", "imu_to_velo": "Tr_imu_to_velo",
    "Tr_velo_to_cam_0": "Tr_velo_to_cam", "Tr_cam_to_road": "Tr_cam_to_road",
    "R": "R", "T": "T",  # raw-sequence calib_velo_to_cam.txt
}


# ------------------------------------------------------------------------------ calibration
@dataclass(frozen=True)
class KittiCalibration:
    """The matrices of one KITTI calib file (see the module docstring for every direction).

    P: projection matrices ``{0: P0, ..., 3: P3}`` [3,4] (rectified camera 0 -> camera i
    pixels); absent ones are missing from the dict. R0_rect [3,3] (camera 0 -> rectified
    camera 0). Tr_velo_to_cam [4,4] (LiDAR -> camera 0) or None when the file has none.
    Tr_imu_to_velo [4,4] (IMU -> LiDAR) or None. ``path``: the file it came from.
    """

    P: dict[int, np.ndarray]
    R0_rect: np.ndarray = field(default_factory=lambda: np.eye(3))
    Tr_velo_to_cam: np.ndarray | None = None
    Tr_imu_to_velo: np.ndarray | None = None
    path: str | None = None

    # --------------------------------------------------------------- per camera
    def _P(self, cam: int) -> np.ndarray:
        if cam not in self.P:
            raise FormatError(self.path, f"camera {cam} requested but the file has P{sorted(self.P)}",
                              f"P{cam}")
        return self.P[cam]

    def K(self, cam: int = 2) -> np.ndarray:
        """[3,3] camera matrix of camera ``cam`` (the left 3x3 of ``P<cam>``)."""
        return self._P(cam)[:, :3].copy()

    def intrinsics(self, cam: int = 2, width: int | None = None, height: int | None = None) -> CameraIntrinsics:
        """``CameraIntrinsics`` of camera ``cam`` (rectified images: no distortion)."""
        return CameraIntrinsics.from_matrix(self.K(cam), None, width=width, height=height)

    def t_offset(self, cam: int = 2) -> np.ndarray:
        """[3] metres: translation rectified camera 0 -> rectified camera ``cam``, ``K^-1 P[:,3]``."""
        P = self._P(cam)
        return np.linalg.solve(P[:, :3], P[:, 3])

    @property
    def T_rect_velo(self) -> np.ndarray:
        """[4,4] LiDAR -> rectified camera 0: ``R0_rect @ Tr_velo_to_cam``."""
        if self.Tr_velo_to_cam is None:
            raise FormatError(self.path, "the calibration has no LiDAR->camera transform", "Tr_velo_to_cam")
        return make_transform(self.R0_rect, np.zeros(3)) @ self.Tr_velo_to_cam

    def T_cam_lidar(self, cam: int = 2) -> np.ndarray:
        """[4,4] LiDAR -> rectified camera ``cam``: ``Translate(t_offset(cam)) @ R0_rect @ Tr_velo_to_cam``."""
        return make_transform(np.eye(3), self.t_offset(cam)) @ self.T_rect_velo

    def projection(self, cam: int = 2) -> np.ndarray:
        """[3,4] LiDAR points -> camera ``cam`` pixels: ``P_cam @ R0_rect @ Tr_velo_to_cam``."""
        return self._P(cam) @ self.T_rect_velo

    def with_T_cam_lidar(self, T_cam_lidar, cam: int = 2) -> "KittiCalibration":
        """A copy whose ``Tr_velo_to_cam`` is chosen so that ``T_cam_lidar(cam)`` equals the given
        [4,4] (LiDAR -> rectified camera ``cam``): ``Tr = inv(R0_rect) @ Translate(-t_offset) @ T``.
        P0..P3, R0_rect and Tr_imu_to_velo are kept (e.g. to write an estimate as a KITTI file)."""
        from ..geometry.transforms import as_transform

        T = as_transform(T_cam_lidar, "T_cam_lidar")
        R0_inv = make_transform(np.linalg.inv(self.R0_rect), np.zeros(3))  # exact even for 7-digit files
        Tr = R0_inv @ make_transform(np.eye(3), -self.t_offset(cam)) @ T
        return KittiCalibration(P=dict(self.P), R0_rect=self.R0_rect, Tr_velo_to_cam=Tr,
                                Tr_imu_to_velo=self.Tr_imu_to_velo, path=None)

    def to_calibration_result(self, cam: int = 2, image_size: tuple[int, int] | None = None,
                              camera_name: str | None = None):
        """``CalibrationResult`` (success, ground truth) of camera ``cam``; image_size = (W, H).
        ``meta["kitti"]`` keeps P0..P3 / R0_rect / Tr_imu_to_velo so a KITTI export can reuse them."""
        from ..calib.result import CalibrationResult

        T = self.T_cam_lidar(cam)
        w, h = image_size if image_size is not None else (None, None)
        kmeta = {"camera": cam, "P": {str(i): P.tolist() for i, P in self.P.items()},
                 "R0_rect": self.R0_rect.tolist(),
                 "Tr_imu_to_velo": None if self.Tr_imu_to_velo is None else self.Tr_imu_to_velo.tolist()}
        return CalibrationResult(
            success=True, intrinsics=self.intrinsics(cam, w, h), rotation=T[:3, :3], translation=T[:3, 3],
            camera_name=camera_name or f"image_{cam}", image_size=image_size, method="kitti",
            message=f"KITTI calibration {self.path or ''}".strip(), meta={"kitti": kmeta},
        )

    @classmethod
    def from_calibration_result(cls, result) -> "KittiCalibration":
        """KITTI matrices of a ``CalibrationResult``: the original P0..P3 / R0_rect when
        ``result.meta["kitti"]`` has them and K still matches P<cam>, else ``P0..P3 = [K|0]``,
        ``R0_rect = I``; ``Tr_velo_to_cam`` such that ``T_cam_lidar(cam) == result.extrinsics``."""
        if result.intrinsics is None:
            raise ValueError("kitti: the calibration has no camera intrinsics (P2 needs K)")
        km = (result.meta or {}).get("kitti")
        if isinstance(km, dict) and "P" in km:
            cam = int(km.get("camera", 2))
            P = {int(i): np.asarray(v, dtype=np.float64).reshape(3, 4) for i, v in km["P"].items()}
            if cam in P and np.allclose(P[cam][:, :3], result.intrinsics.K, atol=1e-9):
                Ti = km.get("Tr_imu_to_velo")
                base = cls(P=P, R0_rect=np.asarray(km.get("R0_rect", np.eye(3)), dtype=np.float64).reshape(3, 3),
                           Tr_imu_to_velo=None if Ti is None else np.asarray(Ti, dtype=np.float64).reshape(4, 4))
                return base.with_T_cam_lidar(result.extrinsics, cam)
        P2 = np.hstack([result.intrinsics.K, np.zeros((3, 1))])
        return cls(P={i: P2.copy() for i in range(4)}, R0_rect=np.eye(3), Tr_velo_to_cam=result.extrinsics)


def _split_line(line: str) -> tuple[str | None, list[str]]:
    if ":" in line:
        key, _, rest = line.partition(":")
        return key.strip(), rest.split()
    return None, line.split()


def parse_kitti_calibration(text: str, path=None, *, repair: bool = False) -> KittiCalibration:
    """Parse the text of a KITTI calib file (see :func:`load_kitti_calibration`)."""
    raw: dict[str, list[str]] = {}
    keyless: list[list[str]] = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        key, vals = _split_line(line)
        if key is None:
            keyless.append(vals)
            continue
        canon = _KEY_ALIASES.get(key)
        if canon is None:
            log.debug("%s: ignoring unknown calib key %r (line %d)", path, key, lineno)
            continue
        if canon in raw:
            raise FormatError(path, f"key given twice (line {lineno})", key)
        raw[canon] = vals
    if not raw and len(keyless) == 1:
        # mmdetection3d demo variant: one key-less line = P2 as [3,4] or [4,4].
        raw["P2"] = keyless[0]
    elif keyless and not raw:
        raise FormatError(path, f"expected 'KEY: numbers' lines (P0..P3, R0_rect, Tr_velo_to_cam), "
                                f"got {len(keyless)} lines without keys")

    def nums(key: str) -> list[float]:
        try:
            return [float(v) for v in raw[key]]
        except ValueError:
            raise FormatError(path, f"non-numeric value in {raw[key]!r}", key) from None

    P: dict[int, np.ndarray] = {}
    for i in range(4):
        k = f"P{i}"
        if k in raw:
            Pi = as_matrix(nums(k), (3, 4), path, k, alt_shapes=[(4, 4)])
            _check_projection(Pi, path, k)
            P[i] = Pi
    if not P:
        raise FormatError(path, "no projection matrix found (need at least P2)", "P2")
    R0 = np.eye(3)
    if "R0_rect" in raw:
        R0 = checked_rotation(as_matrix(nums("R0_rect"), (3, 3), path, "R0_rect", alt_shapes=[(4, 4)]),
                              path, "R0_rect", repair=repair)
    Tr = None
    if "Tr_velo_to_cam" in raw:
        Tr = _rigid(nums("Tr_velo_to_cam"), path, "Tr_velo_to_cam", repair)
    elif "R" in raw and "T" in raw:  # raw-sequence calib_velo_to_cam.txt
        R = checked_rotation(as_matrix(nums("R"), (3, 3), path, "R"), path, "R", repair=repair)
        Tr = make_transform(R, _translation(as_matrix(nums("T"), (3,), path, "T"), path, "T"))
    Timu = _rigid(nums("Tr_imu_to_velo"), path, "Tr_imu_to_velo", repair) if "Tr_imu_to_velo" in raw else None
    return KittiCalibration(P=P, R0_rect=R0, Tr_velo_to_cam=Tr, Tr_imu_to_velo=Timu,
                            path=None if path is None else str(path))


#: Bound of a plausible calibration file: translations (m) beyond it are corrupt data or wrong units
#: (camera-LiDAR rigs are metres apart); pixel values: ``geometry.camera.MAX_PIXELS``.
MAX_TRANSLATION_M = 1.0e4


def _translation(t: np.ndarray, path, key: str) -> np.ndarray:
    if np.abs(t).max() > MAX_TRANSLATION_M:
        raise FormatError(path, f"translation {np.array2string(np.asarray(t), precision=4)} m is beyond "
                                f"{MAX_TRANSLATION_M:g} m (corrupt data or wrong units)", key)
    return t


def _rigid(values, path, key: str, repair: bool) -> np.ndarray:
    M = as_matrix(values, (3, 4), path, key, alt_shapes=[(4, 4)])
    R = checked_rotation(M[:, :3], path, key, repair=repair)
    return make_transform(R, _translation(M[:, 3], path, key))


def _check_projection(P: np.ndarray, path, key: str) -> None:
    K = P[:, :3]
    if abs(K[0, 1]) > 1e-9 or np.any(np.abs(K[1:, 0]) > 1e-9) or abs(K[2, 1]) > 1e-9 or abs(K[2, 2] - 1) > 1e-9:
        raise FormatError(path, "expected P = K [I | t] with K = [[fx,0,cx],[0,fy,cy],[0,0,1]]; "
                                f"got left 3x3 {np.array2string(K, precision=4)}", key)
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise FormatError(path, f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}", key)
    if max(K[0, 0], K[1, 1], abs(K[0, 2]), abs(K[1, 2])) > MAX_PIXELS:
        raise FormatError(path, f"fx={K[0, 0]:g}, fy={K[1, 1]:g}, cx={K[0, 2]:g}, cy={K[1, 2]:g}: beyond "
                                f"{MAX_PIXELS:g} px (corrupt data)", key)
    _translation(np.linalg.solve(K, P[:, 3]), path, key + " (its offset K^-1 P[:, 3])")


def load_kitti_calibration(path, *, repair: bool = False) -> KittiCalibration:
    """Read a KITTI calib file.

    Accepts the object-detection layout (``P0..P3``, ``R0_rect``, ``Tr_velo_to_cam``,
    ``Tr_imu_to_velo``; ``Tr_velo_cam``/``R_rect`` spellings), raw-sequence keys
    (``P_rect_0i``, ``R_rect_00``, ``R``/``T``), [4,4] instead of [3,4] matrices and a single
    key-less line holding P2 (mmdetection3d demo). ``repair`` re-orthonormalises rotations
    that are off by at most 1e-3. Errors: ``FormatError`` naming the file and key.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"KITTI calib file not found: {path}")
    if path.suffix == ".pkl":
        return _calib_from_mmdet3d(path, repair)
    return parse_kitti_calibration(read_text(path, what="KITTI calib file"), path, repair=repair)


def _fmt(v: float) -> str:
    return repr(float(v))


def format_kitti_calibration(calib: KittiCalibration) -> str:
    """KITTI calib text (shortest exact float repr, so a read-back is bit-identical)."""
    lines = []
    for i in range(4):
        if i in calib.P:
            lines.append(f"P{i}: " + " ".join(_fmt(v) for v in calib.P[i].reshape(-1)))
    lines.append("R0_rect: " + " ".join(_fmt(v) for v in calib.R0_rect.reshape(-1)))
    if calib.Tr_velo_to_cam is not None:
        lines.append("Tr_velo_to_cam: " + " ".join(_fmt(v) for v in calib.Tr_velo_to_cam[:3].reshape(-1)))
    if calib.Tr_imu_to_velo is not None:
        lines.append("Tr_imu_to_velo: " + " ".join(_fmt(v) for v in calib.Tr_imu_to_velo[:3].reshape(-1)))
    return "\n".join(lines) + "\n"


def write_kitti_calibration(calib: KittiCalibration, path) -> Path:
    """Write ``calib`` as a KITTI calib txt file; returns the path."""
    return atomic_write(path, [format_kitti_calibration(calib).encode()])


# ----------------------------------------------------------------------------------- labels
@dataclass
class KittiLabels:
    """label_2 rows of one frame (DontCare rows included; see ``care``).

    types [N] str; truncated [N]; occluded [N] int; alpha [N] rad; bboxes_2d [N,4] pixels
    (x1,y1,x2,y2) in image 2; dimensions [N,3] (h, w, l) metres; location [N,3] bottom-centre
    in the rectified camera-0 frame (metres); rotation_y [N] rad about camera +y; score [N]
    (NaN when the file has none).
    """

    types: np.ndarray
    truncated: np.ndarray
    occluded: np.ndarray
    alpha: np.ndarray
    bboxes_2d: np.ndarray
    dimensions: np.ndarray
    location: np.ndarray
    rotation_y: np.ndarray
    score: np.ndarray
    path: str | None = None

    def __len__(self) -> int:
        return int(len(self.types))

    @property
    def care(self) -> np.ndarray:
        """[N] bool: rows that describe an object with a 3D box (not ``DontCare``)."""
        return self.types != "DontCare"

    def subset(self, mask) -> "KittiLabels":
        m = np.asarray(mask)
        return KittiLabels(self.types[m], self.truncated[m], self.occluded[m], self.alpha[m],
                           self.bboxes_2d[m], self.dimensions[m], self.location[m], self.rotation_y[m],
                           self.score[m], self.path)

    def boxes_camera(self) -> np.ndarray:
        """[N,7] (x, y, z, h, w, l, ry): KITTI camera-frame boxes as written in the file."""
        return np.hstack([self.location, self.dimensions, self.rotation_y[:, None]])

    def boxes_lidar(self, calib: KittiCalibration) -> np.ndarray:
        """[N,7] box7 in the LiDAR frame (see :func:`camera_boxes_to_lidar`)."""
        return camera_boxes_to_lidar(self.boxes_camera(), calib)


def parse_kitti_labels(text: str, path=None) -> KittiLabels:
    """Parse label_2 text: 15 fields per row (+ optional score)."""
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) not in (15, 16):
            raise FormatError(path, f"line {lineno}: expected 15 fields (type trunc occl alpha x1 y1 x2 y2 "
                                    f"h w l x y z ry) [+ score], got {len(parts)}", f"line {lineno}")
        rows.append(parts)
    n = len(rows)
    if n == 0:
        z = np.zeros((0,))
        return KittiLabels(np.zeros((0,), dtype=object).astype(str), z, z.astype(np.int64), z,
                           np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 3)), z, z,
                           None if path is None else str(path))
    try:
        num = np.array([[float(v) for v in r[1:15]] + [float(r[15]) if len(r) == 16 else np.nan] for r in rows])
    except ValueError as exc:
        raise FormatError(path, f"non-numeric label field ({exc})") from None
    if not np.all(np.isfinite(num[:, :14])):
        raise FormatError(path, "label has NaN/Inf fields")
    widths = sorted({len(r) for r in rows})
    if len(widths) > 1:
        i = next(k for k, r in enumerate(rows) if len(r) != len(rows[0]))
        raise FormatError(path, f"rows have {widths} fields (row 1: {len(rows[0])}, row {i + 1}: {len(rows[i])}); "
                                "a missing or extra number shifts the columns", f"row {i + 1}")
    _check_label_ranges(num, path)
    types = np.array([r[0] for r in rows])
    b2 = num[:, 3:7]
    bad = (b2[:, 2] < b2[:, 0]) | (b2[:, 3] < b2[:, 1])
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise FormatError(path, f"row {i + 1}: 2D box must have x1 <= x2 and y1 <= y2, got {b2[i].tolist()}", "bbox")
    care = types != "DontCare"
    if np.any(care & np.any(num[:, 7:10] <= 0, axis=1)):
        i = int(np.flatnonzero(care & np.any(num[:, 7:10] <= 0, axis=1))[0])
        raise FormatError(path, f"row {i + 1} ({types[i]}): dimensions (h, w, l) must be positive, "
                                f"got {num[i, 7:10].tolist()}", "dimensions")
    return KittiLabels(types=types, truncated=num[:, 0], occluded=num[:, 1].astype(np.int64), alpha=num[:, 2],
                       bboxes_2d=b2, dimensions=num[:, 7:10], location=num[:, 10:13], rotation_y=num[:, 13],
                       score=num[:, 14], path=None if path is None else str(path))


def _check_label_ranges(num: np.ndarray, path) -> None:
    """Columns that a shifted row breaks: truncated in [-1, 1], occluded an integer in -1..3,
    alpha / rotation_y in [-2 pi, 2 pi] (alpha -10 = unknown)."""
    checks = (("truncated", num[:, 0], (num[:, 0] >= -1) & (num[:, 0] <= 1)),
              ("occluded", num[:, 1], (num[:, 1] == np.round(num[:, 1])) & (num[:, 1] >= -1) & (num[:, 1] <= 3)),
              ("alpha", num[:, 2], (np.abs(num[:, 2]) <= 2 * np.pi + 1e-6) | (num[:, 2] == -10)),
              ("rotation_y", num[:, 13], (np.abs(num[:, 13]) <= 2 * np.pi + 1e-6) | (num[:, 13] == -10)),
              # beyond these a value is corrupt, not a box (as float32 1e300 would become inf)
              ("bbox", np.abs(num[:, 3:7]).max(axis=1), np.abs(num[:, 3:7]).max(axis=1) <= MAX_PIXELS),
              ("dimensions / location (m)", np.abs(num[:, 7:13]).max(axis=1),
               np.abs(num[:, 7:13]).max(axis=1) <= MAX_TRANSLATION_M))
    for name, col, ok in checks:
        if not np.all(ok):
            i = int(np.flatnonzero(~ok)[0])
            raise FormatError(path, f"row {i + 1}: {name} = {float(col[i]):g} is out of range (a missing or extra number "
                                    "shifts the columns)", name)


def load_kitti_labels(path) -> KittiLabels:
    """Read a label_2 file (``FormatError`` naming the file and line on bad rows); a ``.pkl``
    is read as an mmdetection3d KITTI info file (its ``instances``)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"KITTI label file not found: {path}")
    if path.suffix == ".pkl":
        return _labels_from_mmdet3d(path)
    return parse_kitti_labels(read_text(path, what="KITTI label file"), path)


# mmdetection3d KITTI class ids (bbox_label); -1 = DontCare.
_MMDET3D_KITTI_CLASSES = ("Pedestrian", "Cyclist", "Car", "Van", "Truck", "Person_sitting", "Tram", "Misc")


def _mmdet3d_kitti_info(path: Path) -> dict:
    from ._pickle import load_pickle_restricted

    d = load_pickle_restricted(path)
    try:
        info = d["data_list"][0] if isinstance(d, dict) else d[0]
        info["images"], info["lidar_points"]
    except (KeyError, IndexError, TypeError):
        raise FormatError(path, "expected an mmdetection3d info pickle with data_list[0].images and "
                                ".lidar_points", "data_list") from None
    return info


def _calib_from_mmdet3d(path: Path, repair: bool) -> KittiCalibration:
    """KittiCalibration from an mmdetection3d KITTI info pickle: P<i> = images.CAM<i>.cam2img,
    R0_rect = images.R0_rect, Tr_velo_to_cam / Tr_imu_to_velo from lidar_points."""
    info = _mmdet3d_kitti_info(path)
    imgs, lp = info["images"], info["lidar_points"]
    P = {}
    for i in range(4):
        cam = imgs.get(f"CAM{i}")
        if isinstance(cam, dict) and "cam2img" in cam:
            P[i] = as_matrix(cam["cam2img"], (3, 4), path, f"images.CAM{i}.cam2img", alt_shapes=[(4, 4)])
            _check_projection(P[i], path, f"images.CAM{i}.cam2img")
    if 2 not in P:
        cams = sorted(str(k)[:40] for k in imgs)[:8] if isinstance(imgs, dict) else []
        raise FormatError(path, "no camera-2 projection: `xcalib convert` reads mmdetection3d KITTI infos (CAM2); "
                                f"this one holds cameras {cams} (a nuScenes / Waymo info? open it as a frame "
                                "source: xcalib calibrate / xcalib bag write --camera NAME)", "images.CAM2.cam2img")
    R0 = np.eye(3)
    if "R0_rect" in imgs:
        R0 = checked_rotation(as_matrix(imgs["R0_rect"], (3, 3), path, "images.R0_rect", alt_shapes=[(4, 4)]),
                              path, "images.R0_rect", repair=repair)
    Tr = _rigid(lp["Tr_velo_to_cam"], path, "lidar_points.Tr_velo_to_cam", repair) if "Tr_velo_to_cam" in lp else None
    Ti = _rigid(lp["Tr_imu_to_velo"], path, "lidar_points.Tr_imu_to_velo", repair) if "Tr_imu_to_velo" in lp else None
    return KittiCalibration(P=P, R0_rect=R0, Tr_velo_to_cam=Tr, Tr_imu_to_velo=Ti, path=str(path))


def _labels_from_mmdet3d(path: Path) -> KittiLabels:
    """KittiLabels from the ``instances`` of an mmdetection3d KITTI info pickle (bbox_3d is
    camera-frame [x, y, z, l, h, w, ry]; bbox_label -1 = DontCare)."""
    info = _mmdet3d_kitti_info(path)
    lines = []
    for j, inst in enumerate(info.get("instances", [])):
        try:
            lab = int(inst["bbox_label"])
            x1, y1, x2, y2 = (float(v) for v in inst["bbox"])
            x, y, z, l, h, w, ry = (float(v) for v in inst["bbox_3d"])
        except (KeyError, TypeError, ValueError):
            raise FormatError(path, "expected bbox_label, bbox [4] and bbox_3d [7]", f"instances[{j}]") from None
        name = "DontCare" if lab < 0 else (_MMDET3D_KITTI_CLASSES[lab] if lab < len(_MMDET3D_KITTI_CLASSES)
                                           else f"class{lab}")
        vals = [inst.get("truncated", 0.0), inst.get("occluded", 0), inst.get("alpha", -10.0),
                x1, y1, x2, y2, h, w, l, x, y, z, ry]
        lines.append(name + " " + " ".join(repr(float(v)) for v in vals))
    return parse_kitti_labels("\n".join(lines), path)


# ------------------------------------------------------------------------- box conversion
def camera_boxes_to_lidar(boxes_cam, calib: KittiCalibration) -> np.ndarray:
    """KITTI camera boxes [N,7] (x, y, z bottom-centre in rectified camera 0, h, w, l, ry) ->
    LiDAR-frame box7 [N,7] (cx, cy, cz geometric centre, dx=l, dy=w, dz=h, yaw about LiDAR +z).

    Exact for the centre (through ``inv(R0_rect @ Tr_velo_to_cam)``); the heading is the
    object's length axis ``(cos ry, 0, -sin ry)`` rotated into the LiDAR frame and projected on
    its x-y plane (the sub-degree tilt between camera y and LiDAR z is dropped).
    """
    b = np.asarray(boxes_cam, dtype=np.float64).reshape(-1, 7)
    T = invert_transform(calib.T_rect_velo)  # rectified camera 0 -> LiDAR
    centre_cam = b[:, :3] - np.stack([np.zeros(len(b)), b[:, 3] / 2.0, np.zeros(len(b))], axis=1)
    centre = centre_cam @ T[:3, :3].T + T[:3, 3]
    heading_cam = np.stack([np.cos(b[:, 6]), np.zeros(len(b)), -np.sin(b[:, 6])], axis=1)
    heading = heading_cam @ T[:3, :3].T
    yaw = np.arctan2(heading[:, 1], heading[:, 0])
    return np.hstack([centre, b[:, 5:6], b[:, 4:5], b[:, 3:4], yaw[:, None]])


def lidar_boxes_to_camera(boxes7, calib: KittiCalibration) -> np.ndarray:
    """Inverse of :func:`camera_boxes_to_lidar`: LiDAR box7 [N,7] -> KITTI camera boxes [N,7]."""
    b = check_boxes3d(boxes7)
    if b.shape[1] != 7:
        raise ValueError(f"boxes7: expected shape [N, 7], got {b.shape}")
    T = calib.T_rect_velo
    centre = b[:, :3] @ T[:3, :3].T + T[:3, 3]
    heading = np.stack([np.cos(b[:, 6]), np.sin(b[:, 6]), np.zeros(len(b))], axis=1) @ T[:3, :3].T
    ry = np.arctan2(-heading[:, 2], heading[:, 0])
    loc = centre + np.stack([np.zeros(len(b)), b[:, 5] / 2.0, np.zeros(len(b))], axis=1)
    return np.hstack([loc, b[:, 5:6], b[:, 4:5], b[:, 3:4], ry[:, None]])


def box7_to_protocol(boxes7) -> np.ndarray:
    """box7 [N,7] -> protocol [N,6] extents (xmin, ymin, zmin, xmax, ymax, zmax): the
    axis-aligned box enclosing each yawed box (LiDAR frame, metres); see
    :func:`xcalib.geometry.boxes.box7_to_extents`."""
    return box7_to_extents(boxes7)


def project_box7(boxes7, K, T_cam_lidar, image_size: tuple[int, int] | None = None,
                 min_depth: float = 0.1) -> np.ndarray:
    """Enclosing 2D rectangles [N,4] (pixels) of LiDAR-frame box7 corners projected through
    ``K @ T_cam_lidar[:3]``; corners behind ``min_depth`` metres are dropped, all-behind -> NaN
    row; clipped to ``image_size`` = (W, H) when given."""
    corners = box7_corners(boxes7)  # [N,8,3]
    n = len(corners)
    if n == 0:
        return np.zeros((0, 4))
    T = np.asarray(T_cam_lidar, dtype=np.float64)
    uv, _ = project_points(corners.reshape(-1, 3), K, T[:3, :3], T[:3, 3], min_depth=min_depth)
    boxes = boxes2d_from_points(uv.reshape(n, 8, 2))
    if image_size is not None:
        w, h = image_size
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0, w)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0, h)
    return boxes


# ------------------------------------------------------------------------------ point clouds
def read_velodyne_bin(path, num_features: int | None = None) -> np.ndarray:
    """Read a KITTI-style float32 ``.bin`` -> [P, F] float32 (x, y, z metres in the LiDAR frame,
    then intensity...). ``num_features`` defaults to 4 (KITTI); the file size must divide by it.
    (Thin wrapper over :func:`xcalib.io.pointcloud.read_point_cloud`.)"""
    from ..io.pointcloud import read_point_cloud

    return read_point_cloud(path, columns=4 if num_features is None else int(num_features)).points


# ----------------------------------------------------------------------------------- folders
@dataclass(frozen=True)
class KittiRecord:
    """Paths of one KITTI frame (image/velodyne/label may be None)."""

    frame_id: str
    calib: Path
    image: Path | None = None
    velodyne: Path | None = None
    label: Path | None = None


def _first(*cands: Path) -> Path | None:
    for c in cands:
        if c.is_file():
            return c
    return None


def find_kitti_records(root) -> list[KittiRecord]:
    """Frames of a KITTI folder, sorted by id. Layouts: ``[training/]{calib,image_2,label_2,
    velodyne}/<id>.*``; flat ``<id>.bin`` with ``<id>_calib.txt|<id>.txt``, ``<id>_label.txt|
    <id>_gt.txt``, ``<id>_image.png|<id>.png``; a single ``calib.txt`` (+ ``label_2.txt``)."""
    root = Path(root)
    if not root.is_dir():
        if root.is_file():
            raise FormatError(root, "expected a KITTI folder, got a file (use load_kitti_calibration for calib files)")
        raise FileNotFoundError(f"KITTI folder not found: {root}")
    for sub in ("training", "testing"):
        if (root / sub / "calib").is_dir():
            root = root / sub
            break
    recs: list[KittiRecord] = []
    if (root / "calib").is_dir():
        for c in sorted((root / "calib").glob("*.txt")):
            i = c.stem
            img = _first(*(root / d / f"{i}{e}" for d in ("image_2", "image_0") for e in (".png", ".jpg")))
            recs.append(KittiRecord(i, c, img, _first(root / "velodyne" / f"{i}.bin",
                                                      root / "velodyne_reduced" / f"{i}.bin"),
                                    _first(root / "label_2" / f"{i}.txt")))
        return recs
    for b in sorted(root.glob("*.bin")):
        i = b.stem
        pkl = _first(root / f"{i}.pkl")
        calib = _first(root / f"{i}_calib.txt", root / f"{i}.txt", root / "calib.txt")
        label = _first(root / f"{i}_label.txt", root / f"{i}_gt.txt", root / f"{i}_label_2.txt")
        if pkl is not None and (calib is None or load_kitti_calibration(calib).Tr_velo_to_cam is None):
            calib, label = pkl, label or pkl  # mmdetection3d demo: full calibration + labels in the pkl
        if calib is None:
            continue
        recs.append(KittiRecord(i, calib, _first(root / f"{i}_image.png", root / f"{i}.png", root / f"{i}.jpg"),
                                b, label))
    if not recs and (root / "calib.txt").is_file():
        recs.append(KittiRecord(root.name, root / "calib.txt", _first(root / "image_2.png", root / "image.png"),
                                _first(root / "velodyne.bin"), _first(root / "label_2.txt", root / "label.txt")))
    if not recs:
        raise FormatError(root, "no KITTI frames found: expected calib/<id>.txt (+ image_2/, label_2/, "
                                "velodyne/), <id>.bin with <id>_calib.txt or <id>.txt, or calib.txt")
    return recs


class KittiFrames(Sequence):
    """Lazy ``Sequence[Frame]`` over a KITTI folder (each item is read when indexed).

    Each :class:`~xcalib.types.Frame` has image 2 (RGB), the velodyne cloud [P,4] (x, y, z,
    reflectance), the label rows that are not DontCare as ``bboxes_2d`` [K,4] and LiDAR-frame
    ``bboxes_3d`` (box7 [K,7] by default, protocol extents [K,6] with ``box_format="extents"``),
    ``match_matrix`` = identity (row i of the label gives 2D box i and 3D box i),
    ``intrinsics`` from P2 and ``extrinsics`` = ``KittiCalibration.T_cam_lidar(2)``.
    ``meta``: ``types`` (= ``classes_2d`` = ``classes_3d``), ``box7`` [K,7] float64,
    ``kitti_calibration``, ``label_path``, ``dontcare_boxes_2d``.
    """

    def __init__(self, root, ids=None, *, box_format: str = "box7", camera: int = 2,
                 load_image: bool = True, load_points: bool = True, repair: bool = False):
        if box_format not in ("box7", "extents"):
            raise ValueError(f"box_format must be 'box7' or 'extents', got {box_format!r}")
        self.root = Path(root)
        recs = find_kitti_records(self.root)
        if ids is not None:
            want = [str(i) if not isinstance(i, (int, np.integer)) else f"{int(i):06d}" for i in ids]
            have = {r.frame_id: r for r in recs}
            missing = [w for w in want if w not in have]
            if missing:
                raise KeyError(f"KITTI folder {self.root}: frame id(s) {missing} not found; "
                               f"available: {sorted(have)[:10]}{'...' if len(have) > 10 else ''}")
            recs = [have[w] for w in want]
        self.records = recs
        self.box_format, self.camera = box_format, camera
        self.load_image, self.load_points, self.repair = load_image, load_points, repair

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return self.load(self.records[index])

    @property
    def ids(self) -> list[str]:
        return [r.frame_id for r in self.records]

    def load(self, rec: KittiRecord) -> Frame:
        calib = load_kitti_calibration(rec.calib, repair=self.repair)
        image = np.zeros((0, 0, 3), dtype=np.uint8)
        size = None
        if rec.image is not None:
            if self.load_image:
                image = load_rgb(rec.image)
                size = (image.shape[1], image.shape[0])
            else:
                size = image_size(rec.image)
        elif self.load_image:
            raise FormatError(rec.calib, f"frame {rec.frame_id}: no image file found next to the calib file")
        points = np.zeros((0, 4), dtype=np.float32)
        if rec.velodyne is not None and self.load_points:
            points = read_velodyne_bin(rec.velodyne)
        elif self.load_points:
            raise FormatError(rec.calib, f"frame {rec.frame_id}: no velodyne .bin found next to the calib file")
        has_tr = calib.Tr_velo_to_cam is not None
        extr = calib.T_cam_lidar(self.camera) if has_tr else None
        b2, b3 = np.zeros((0, 4)), np.zeros((0, 7 if self.box_format == "box7" else 6))
        b7 = np.zeros((0, 7))
        types = np.zeros((0,), dtype=str)
        dontcare = np.zeros((0, 4))
        if rec.label is not None:
            labels = load_kitti_labels(rec.label)
            dontcare = labels.bboxes_2d[~labels.care]
            objs = labels.subset(labels.care)
            types = objs.types
            b2 = objs.bboxes_2d
            if len(objs) and not has_tr:
                raise FormatError(rec.calib, "labels need Tr_velo_to_cam to move boxes to the LiDAR frame",
                                  "Tr_velo_to_cam")
            if len(objs):
                b7 = objs.boxes_lidar(calib)
                b3 = b7 if self.box_format == "box7" else box7_to_protocol(b7)
        k = len(b2)
        return Frame(
            image=image, point_cloud=np.ascontiguousarray(points, dtype=np.float32),
            bboxes_2d=b2.astype(np.float32), bboxes_3d=b3.astype(np.float32),
            camera_name=f"image_{self.camera}", frame_key=rec.frame_id,
            match_matrix=np.eye(k, dtype=bool) if rec.label is not None else None,
            intrinsics=calib.intrinsics(self.camera, *(size or (None, None))), extrinsics=extr,
            point_fields=("x", "y", "z", "intensity"),
            meta={"types": types.tolist(), "classes_2d": types.tolist(), "classes_3d": types.tolist(),
                  "box7": b7.astype(np.float64), "kitti_calibration": calib, "label_path": rec.label,
                  "dontcare_boxes_2d": dontcare, "source": "kitti", "image_path": rec.image,
                  "velodyne_path": rec.velodyne},
        )


def kitti_frames(root, ids=None, **kwargs) -> KittiFrames:
    """A KITTI folder as a lazy ``Sequence[Frame]`` with ground-truth calibration (see
    :class:`KittiFrames`; ``ids`` = frame ids as strings or ints, e.g. ``[1, 2]`` -> 000001)."""
    return KittiFrames(root, ids, **kwargs)




def is_kitti_root(path) -> bool:
    """True for a folder :func:`kitti_frames` can read (calib/ dir, [training/]calib/, or
    ``<id>.bin`` with a calib txt / mmdetection3d pkl next to it)."""
    p = Path(path)
    if not p.is_dir():
        return False
    if (p / "calib").is_dir() or (p / "training" / "calib").is_dir():
        return True
    if (p / "calib.txt").is_file() and (p / "label_2.txt").is_file():
        return True
    for b in p.glob("*.bin"):
        i = b.stem
        if any((p / n).is_file() for n in (f"{i}_calib.txt", f"{i}.txt", f"{i}.pkl")):
            return True
    return False


def _kitti_camera(camera) -> int:
    """``2`` / ``"2"`` / ``"image_2"`` / ``"P2"`` / ``"cam2"`` -> 2 (KITTI cameras 0-3)."""
    text = str(camera).strip().lower()
    for prefix in ("image_", "image", "cam_", "cam", "p"):
        if text.startswith(prefix) and text[len(prefix):].isdigit():
            text = text[len(prefix):]
            break
    if not text.isdigit() or int(text) not in (0, 1, 2, 3):
        raise ValueError(f"KITTI camera {camera!r}: expected 0-3 (or image_0 ... image_3)")
    return int(text)


def open_kitti_source(path, *, camera=None, **kwargs) -> KittiFrames:
    """A KITTI folder as a frame source (``camera``: 0-3 or ``image_2``; default 2)."""
    return KittiFrames(path, kwargs.pop("ids", None), camera=2 if camera is None else _kitti_camera(camera), **kwargs)


def _register() -> None:
    from ..io.sources import register_source

    register_source("kitti", is_kitti_root, open_kitti_source,
                    description="KITTI object folder (calib/, image_2/, velodyne/, label_2/)", priority=30)


_register()
