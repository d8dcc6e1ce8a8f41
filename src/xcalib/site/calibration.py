"""One LiDAR, many cameras: each camera calibrated against the LiDAR through the public
:func:`xcalib.calibrate`, gathered into one site calibration (a transform tree rooted at the
LiDAR frame, each edge with its uncertainty and verdict), with the agreement of cameras that
matched the same LiDAR objects.

Layer: above :mod:`xcalib.calib` (it calls ``calibrate``), below ``cli`` / ``viz``.
Frames: ``T_cam_lidar`` maps LiDAR points into the camera's OpenCV optical frame; the tree edge
``lidar -> <camera>_optical_frame`` stores the child's pose in the parent, ``T_lidar_cam``.
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ..calib.result import CalibrationResult
from ..errors import FormatError
from ..geometry.boxes import as_box7, box7_corners, boxes2d_from_points, iou_matrix
from ..geometry.camera import CameraIntrinsics
from ..geometry.camera_models import CameraModel, project_outline_rects
from ..geometry.projection import project_points
from ..geometry.rotations import rotation_angle
from ..geometry.transforms import invert_transform
from ..formats.ros import ros_name
from ..io.files import atomic_write, safe_name
from ..types import Frame

__all__ = ["SITE_FORMAT", "CameraCalibration", "CameraAgreement", "SiteCalibration", "calibrate_site",
           "optical_frame", "camera_folders", "is_frame_id"]

SITE_FORMAT = "xcalib-site-calibration-v1"


def optical_frame(camera: str) -> str:
    """The tf name of a camera's OpenCV optical frame (REP 103: ``<camera>_optical_frame``); a
    camera name read from a recording is made a valid ROS name first (:func:`ros_name`)."""
    return f"{ros_name(camera, 'camera')}_optical_frame"


def camera_folders(cameras: Sequence[str]) -> dict[str, str]:
    """camera name -> a file-name component for its outputs (folders, ``<x>_camera_info.yaml``):
    safe for the file system whatever the name holds (``/``, ``..``, newlines, controls; see
    :func:`xcalib.io.files.safe_name`), and distinct for distinct cameras (``-2``, ``-3``, ...
    where two names map to one token), so no output leaves its folder or replaces another's."""
    out: dict[str, str] = {}
    used: set[str] = set()
    for cam in cameras:
        if cam in out:
            continue
        base = safe_name(cam, max_len=80, default="camera")
        token, k = base, 2
        while token.lower() in used:
            token, k = f"{base}-{k}", k + 1
        used.add(token.lower())
        out[cam] = token
    return out


_FRAME_ID = re.compile(r"[A-Za-z_][A-Za-z0-9_./-]{0,199}")


def is_frame_id(name: str) -> bool:
    """A tf frame name xcalib writes as it is: letters, digits, ``_ . / -``, a letter or ``_`` first
    (a recording's ``header.frame_id`` that is not is replaced by the default name, with a warning)."""
    return isinstance(name, str) and _FRAME_ID.fullmatch(name) is not None


@dataclass(frozen=True)
class CameraCalibration:
    """One camera's result; ``ground_truth`` = the frames' common ``T_cam_lidar`` when they carry one."""

    camera: str
    result: CalibrationResult
    num_frames: int
    ground_truth: np.ndarray | None = None
    frame: str = ""  # the camera's tf frame (the recording's image header.frame_id); "" -> <camera>_optical_frame
    image_size: tuple[int, int] | None = None  # (width, height) of its images
    recorded: np.ndarray | None = None  # the recording's own T_cam_lidar (its tf between the two frames)

    @property
    def vs_recorded(self) -> tuple[float, float] | None:
        """(rotation deg, translation m) of the recording's tf from this calibration (None without
        one or when refused)."""
        if self.recorded is None or not self.result.success:
            return None
        return tuple(float(v) for v in self.result.pose_error(self.recorded))

    @property
    def child_frame(self) -> str:
        """The camera's optical frame in the tree: the recording's own name, else ``<camera>_optical_frame``."""
        return self.frame or optical_frame(self.camera)

    @property
    def verdict(self) -> Literal["calibrated", "refused"]:
        return "calibrated" if self.result.success else "refused"

    @property
    def error_vs_truth(self) -> tuple[float, float] | None:
        """(rotation deg, translation m) from ``ground_truth`` (None without one or when refused)."""
        if self.ground_truth is None or not self.result.success:
            return None
        return tuple(float(v) for v in self.result.pose_error(self.ground_truth))


@dataclass(frozen=True)
class CameraAgreement:
    """Two calibrated cameras that matched the same LiDAR objects (same frame, same 3D box):
    how many, the median IoU of each camera's projection of them with its matched 2D box, and the
    relative pose camera A -> camera B implied by the two calibrations (vs the ground truth's
    when both have one)."""

    camera_a: str
    camera_b: str
    shared_objects: int
    iou_a_median: float
    iou_b_median: float
    relative_rotation_deg: float
    baseline_m: float
    relative_error_deg: float | None = None
    relative_error_m: float | None = None

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class SiteCalibration:
    """All cameras of a site against one LiDAR: ``cameras`` (one entry each, calibrated or
    refused), ``agreements`` between camera pairs, the ``lidar_frame`` name of the tree root."""

    cameras: tuple[CameraCalibration, ...]
    agreements: tuple[CameraAgreement, ...] = ()
    lidar_frame: str = "lidar"
    source: str = ""
    meta: dict = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return any(c.result.success for c in self.cameras)

    def camera(self, name: str) -> CameraCalibration:
        for c in self.cameras:
            if c.camera == name:
                return c
        raise KeyError(f"no camera {name!r}; cameras: {[c.camera for c in self.cameras]}")

    def transforms(self) -> list[dict]:
        """The tree: one edge ``lidar_frame -> <camera>_optical_frame`` per camera."""
        out = []
        for c in self.cameras:
            r = c.result
            edge = {"parent": self.lidar_frame, "child": c.child_frame, "camera": c.camera,
                    "verdict": c.verdict, "message": r.message, "num_frames": c.num_frames,
                    "n_pairs": r.n_pairs}
            if r.success:
                edge.update(T_cam_lidar=r.extrinsics.tolist(), T_parent_child=invert_transform(r.extrinsics).tolist(),
                            rotation_std_deg=r.rotation_std_deg.tolist(), translation_std_m=r.translation_std_m.tolist(),
                            residual_px_median=r.residual_px_median, iou_median=r.iou_median)
            if c.recorded is not None:
                edge["recorded_T_cam_lidar"] = np.asarray(c.recorded).tolist()
                if c.vs_recorded is not None:
                    edge["recorded_tf_vs_calibration"] = {"rotation_deg": c.vs_recorded[0],
                                                          "translation_m": c.vs_recorded[1]}
            if c.error_vs_truth is not None:
                edge["error_vs_truth"] = {"rotation_deg": c.error_vs_truth[0], "translation_m": c.error_vs_truth[1]}
            out.append(edge)
        return out

    def to_dict(self) -> dict:
        return {"format": SITE_FORMAT, "lidar_frame": self.lidar_frame, "source": self.source,
                "frame_convention": "T_parent_child = pose of the child (camera OpenCV optical frame: x right, "
                                    "y down, z forward) in the parent (LiDAR); T_cam_lidar = its inverse",
                "transforms": self.transforms(), "agreements": [a.to_dict() for a in self.agreements],
                "cameras": {c.camera: c.result.to_dict() for c in self.cameras}}

    def save(self, path) -> Path:
        """``site_calibration.json`` (written atomically)."""
        return atomic_write(Path(path), [json.dumps(_plain(self.to_dict()), indent=1).encode()])

    @classmethod
    def load(cls, path) -> "SiteCalibration":
        p = Path(path)
        try:
            d = json.loads(p.read_text())
        except (OSError, ValueError) as exc:
            raise FormatError(p, f"not a readable site calibration ({exc})") from None
        if not isinstance(d, dict) or d.get("format") != SITE_FORMAT:
            raise FormatError(p, f"expected format {SITE_FORMAT!r}", "format")
        cams = []
        for edge in d.get("transforms", []):
            res = CalibrationResult.from_dict(d["cameras"][edge["camera"]])
            child = str(edge.get("child", ""))
            cams.append(CameraCalibration(edge["camera"], res, int(edge.get("num_frames", 0)),
                                          frame="" if child == optical_frame(edge["camera"]) else child,
                                          image_size=res.image_size,
                                          recorded=None if edge.get("recorded_T_cam_lidar") is None else
                                          np.asarray(edge["recorded_T_cam_lidar"], dtype=np.float64)))
        agr = tuple(CameraAgreement(**a) for a in d.get("agreements", []))
        return cls(tuple(cams), agr, str(d.get("lidar_frame", "lidar")), str(d.get("source", "")))


def _plain(v):
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return _plain(v.tolist())
    if isinstance(v, (np.floating, float)):
        return float(v) if np.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v


def _common_truth(frames: Sequence[Frame]) -> np.ndarray | None:
    gts = [f.extrinsics for f in frames if f.extrinsics is not None]
    if not gts or len(gts) != len(frames):
        return None
    first = np.asarray(gts[0], dtype=np.float64)
    if any(np.abs(np.asarray(g) - first).max() > 1e-6 for g in gts[1:]):
        return None  # e.g. two calibration days mixed: no single ground truth
    return first


def _projected_iou(frame: Frame, pair, result: CalibrationResult) -> float:
    i2, i3 = int(pair[0]), int(pair[1])
    corners = box7_corners(as_box7(np.asarray(frame.bboxes_3d)[i3:i3 + 1]))
    T = result.extrinsics
    if isinstance(result.intrinsics, CameraModel) and not result.intrinsics.is_pinhole:
        # a wide-angle camera: the outline of the box's edges in the model's own image (edges curve)
        box, _ = project_outline_rects(corners, T[:3, :3], T[:3, 3], result.intrinsics, (1, 1), clip=False,
                                       min_distance=0.1)
    else:
        uv, _ = project_points(corners.reshape(-1, 3), result.intrinsics.K, T[:3, :3], T[:3, 3], min_depth=0.1)
        box = boxes2d_from_points(uv.reshape(1, 8, 2))
    if not np.all(np.isfinite(box)):
        return 0.0
    return float(iou_matrix(box, np.asarray(frame.bboxes_2d)[i2:i2 + 1])[0, 0])


def _matched_objects(cal: CameraCalibration, frames: Sequence[Frame]) -> dict[tuple[int, bytes], float]:
    """(frame index, 3D box row bytes) -> IoU of that camera's projection with its 2D box."""
    out = {}
    for fi, pairs in enumerate(cal.result.pairs):
        if fi >= len(frames):
            break
        b3 = np.asarray(frames[fi].bboxes_3d, dtype=np.float32)
        for p in pairs:
            out[(fi, b3[int(p[1])].tobytes())] = _projected_iou(frames[fi], p, cal.result)
    return out


def _agreement(a: CameraCalibration, b: CameraCalibration, fa, fb) -> CameraAgreement | None:
    ma, mb = _matched_objects(a, fa), _matched_objects(b, fb)
    shared = sorted(set(ma) & set(mb))
    if not shared:
        return None
    T_ab = a.result.extrinsics @ invert_transform(b.result.extrinsics)  # camera B -> camera A
    err_deg = err_m = None
    if a.ground_truth is not None and b.ground_truth is not None:
        G = a.ground_truth @ invert_transform(b.ground_truth)
        err_deg = rotation_angle(T_ab[:3, :3], G[:3, :3])
        err_m = float(np.linalg.norm(T_ab[:3, 3] - G[:3, 3]))
    return CameraAgreement(a.camera, b.camera, len(shared), float(np.median([ma[k] for k in shared])),
                           float(np.median([mb[k] for k in shared])), rotation_angle(T_ab[:3, :3]),
                           float(np.linalg.norm(T_ab[:3, 3])), err_deg, err_m)


def _recorded_frame(name, what: str) -> str:
    """A recording's frame id as written, or "" (the default name) when it has none or it is not
    a plain tf name (it reaches shell lines, XML and Python launch files)."""
    if not name:
        return ""
    if not is_frame_id(str(name)):
        logging.getLogger(__name__).warning("%s: the recording's frame id %r is not a plain tf frame name; the "
                                            "default name is written instead", what, str(name)[:80])
        return ""
    return str(name)


def _distinct_frames(cams: list[CameraCalibration], lidar_frame: str) -> list[CameraCalibration]:
    """Cameras whose recorded frame name is shared with another camera or the LiDAR get the
    default ``<camera>_optical_frame`` (one tf frame cannot hold two poses), with a warning."""
    import dataclasses

    names = [c.child_frame for c in cams] + [lidar_frame]
    out = []
    for c in cams:
        if c.frame and names.count(c.frame) > 1:
            logging.getLogger(__name__).warning("camera %s: its frame id %r is shared with another sensor; "
                                                "writing %s instead", c.camera, c.frame, optical_frame(c.camera))
            c = dataclasses.replace(c, frame="")
        out.append(c)
    return out


def _default_calibrate(frames, intrinsics, progress):
    from ..calib.api import calibrate

    return calibrate(frames, intrinsics, progress=progress)


def calibrate_site(views: dict[str, Sequence[Frame]], intrinsics: dict[str, CameraIntrinsics | None] | None = None,
                   *, lidar_frame: str | None = None, source: str = "",
                   calibrate: Callable[..., CalibrationResult] | None = None,
                   progress: Callable[[str, int, int], None] | None = None,
                   camera_frames: dict[str, str] | None = None,
                   priors: dict[str, np.ndarray] | None = None) -> tuple[SiteCalibration, dict]:
    """Calibrate each camera's frames (``views``: camera name -> its frames, the same LiDAR)
    against the LiDAR with ``calibrate(frames, intrinsics, progress)`` (default: the public
    :func:`xcalib.calibrate` with its defaults). Returns ``(SiteCalibration, frames read per
    camera)``; a camera whose frames do not determine its pose is in the result as refused, with
    the reason. Frame names: ``lidar_frame`` / ``camera_frames[camera]`` when given, else the
    source's own (a bag's ``header.frame_id``s: ``lidar_frame_id`` / ``camera_frame_id`` of its
    view), else ``lidar`` / ``<camera>_optical_frame``. ``priors[camera]``: a starting pose passed
    to ``calibrate(..., prior=)`` for that camera (e.g. the recording's own tf)."""
    run = calibrate or _default_calibrate
    intrinsics = intrinsics or {}
    cams, loaded = [], {}
    for name, seq in views.items():
        frames = [seq[i] for i in range(len(seq))]
        loaded[name] = frames
        intr = intrinsics.get(name) or getattr(seq, "intrinsics", None) or (frames[0].intrinsics if frames else None)
        if intr is None:
            res = CalibrationResult(success=False, camera_name=name,
                                    message=f"camera {name}: no intrinsics (pass --intrinsics)")
        elif not frames:
            res = CalibrationResult(success=False, camera_name=name, message=f"camera {name}: no frames")
        else:
            stage = (lambda s, d, t, _n=name: progress(f"{_n}: {s}", d, t)) if progress else None
            res = run(frames, intr, stage, prior=priors[name]) if priors and name in priors else \
                run(frames, intr, stage)
            res.camera_name = res.camera_name or name
        size = next((f.image.shape[1::-1] for f in frames if np.asarray(f.image).ndim == 3
                     and f.image.shape[0] > 1), None)
        if size is None:  # streamed frames (xcalib.site.stream): the image's size is kept, not the image
            size = next((tuple(f.meta["image_size"]) for f in frames if np.asarray(f.image).size == 0
                         and (f.meta or {}).get("image_size") is not None), None)
        own = (camera_frames or {}).get(name) or _recorded_frame(getattr(seq, "camera_frame_id", None), name)
        rec = getattr(seq, "tf_T_cam_lidar", None)
        cams.append(CameraCalibration(name, res, len(frames), _common_truth(frames), frame=str(own),
                                      image_size=None if size is None else (int(size[0]), int(size[1])),
                                      recorded=None if rec is None else np.asarray(rec, dtype=np.float64)))
        if lidar_frame is None:
            lidar_frame = _recorded_frame(getattr(seq, "lidar_frame_id", None), "LiDAR") or None
    cams = _distinct_frames(cams, lidar_frame or "lidar")
    agreements = []
    for i in range(len(cams)):
        for j in range(i + 1, len(cams)):
            a, b = cams[i], cams[j]
            if a.result.success and b.result.success:
                ag = _agreement(a, b, loaded[a.camera], loaded[b.camera])
                if ag is not None:
                    agreements.append(ag)
    return SiteCalibration(tuple(cams), tuple(agreements), lidar_frame or "lidar", source), loaded
