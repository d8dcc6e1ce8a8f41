"""Small typed records that cross module boundaries (pure numpy, no torch)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .geometry.camera import CameraIntrinsics

__all__ = ["Frame", "FrameDetections", "MatchResult", "MatchSource", "DatasetFrame", "as_frame", "OWN_DETECTIONS"]

MatchSource = Literal["model", "fused", "geometry"]

#: ``Frame.detections.source`` of boxes made by xcalib's own detectors (``xcalib.detect``);
#: a bag written from such frames says so in its frame records, and the frames read back carry it.
OWN_DETECTIONS = "xcalib detect"


@dataclass(frozen=True)
class FrameDetections:
    """Which detector made a frame's boxes (``Frame.detections``; None when the source's own boxes
    or labels are used as they are).

    source: who made them (:data:`OWN_DETECTIONS` for ``xcalib.detect``, ``"synth detector"`` for
    the synthetic detector). scores_2d / classes_2d: the 2D detector's score and class of each 2D
    box, in the frame's order (None when not known; the calibration weighs the boxes by the scores
    with ``CalibConfig.detector_scores``). detector_2d: the 2D detector's file name; lidar_mode:
    ``"static"`` / ``"moving"`` (how ``xcalib.detect`` found the LiDAR boxes); "" when not known.
    """

    source: str
    scores_2d: tuple[float, ...] | None = None
    classes_2d: tuple[str, ...] | None = None
    detector_2d: str = ""
    lidar_mode: str = ""

    @classmethod
    def from_dict(cls, d: dict) -> FrameDetections:
        """From the dict of earlier versions (``Frame.meta["detections"] = {"source": ..., ...}``);
        keys other than the fields are ignored."""
        scores, classes = d.get("scores_2d"), d.get("classes_2d")
        return cls(source=str(d.get("source", "")),
                   scores_2d=None if scores is None else tuple(np.asarray(scores).reshape(-1).tolist()),
                   classes_2d=None if classes is None else tuple(classes),
                   detector_2d=str(d.get("detector_2d", "")), lidar_mode=str(d.get("lidar_mode", "")))


@dataclass
class Frame:
    """One time-synchronised camera + LiDAR frame.

    image: [H,W,3] uint8 RGB. point_cloud: [P,>=3] float32, LiDAR frame, metres (columns
    past x, y, z are kept, named by ``point_fields``). bboxes_2d: [K,4] float32 pixels.
    bboxes_3d: [M,6] float32 protocol boxes (or [M,7] box7 with yaw), LiDAR frame.
    match_matrix: optional [K,M] bool ground truth. intrinsics / extrinsics: optional camera
    intrinsics and ground-truth ``T_cam_lidar`` [4,4]. images / camera_per_det: multi-camera
    frames (each 2D box's source camera).

    Timing and tracks (optional; readers fill them where the format has them):
    lidar_time_s / camera_time_s: the LiDAR sweep time and the camera exposure time of this
    frame, seconds on one clock (``camera_time_s - lidar_time_s`` is the sensors' time offset).
    track_ids_3d: [M] int64 track id per 3D box (stable across frames; -1 = none).
    velocities_3d: [M,3] float64 velocity per 3D box, LiDAR frame, m/s.

    detections: which detector made the boxes (:class:`FrameDetections`), None for a source's own
    boxes. A frame built with the earlier ``meta={"detections": {...}}`` dict gets it from there
    (the dict leaves ``meta``, and wins over the field: ``dataclasses.replace(frame, meta={...,
    "detections": {...}})`` sets it as before).
    """

    image: np.ndarray
    point_cloud: np.ndarray
    bboxes_2d: np.ndarray
    bboxes_3d: np.ndarray
    camera_name: str = ""
    frame_key: str = ""
    match_matrix: np.ndarray | None = None
    intrinsics: CameraIntrinsics | None = None
    extrinsics: np.ndarray | None = None
    images: dict[str, np.ndarray] | None = None
    camera_per_det: list[str] | None = None
    point_fields: tuple[str, ...] = ("x", "y", "z")
    meta: dict[str, Any] = field(default_factory=dict)
    lidar_time_s: float | None = None
    camera_time_s: float | None = None
    track_ids_3d: np.ndarray | None = None
    velocities_3d: np.ndarray | None = None
    detections: FrameDetections | None = None

    def __post_init__(self) -> None:
        det = self.meta.get("detections") if isinstance(self.meta, dict) else None
        if isinstance(det, dict):  # the earlier convention: one place for it now, the typed field
            self.meta = {k: v for k, v in self.meta.items() if k != "detections"}
            self.detections = FrameDetections.from_dict(det)

    @property
    def num_2d(self) -> int:
        return int(len(self.bboxes_2d))

    @property
    def num_3d(self) -> int:
        return int(len(self.bboxes_3d))

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.image.shape[1]), int(self.image.shape[0])

    def inputs(self):
        """``(image, point_cloud, bboxes_2d, bboxes_3d)`` as ``Matcher.match`` takes them."""
        return self.image, self.point_cloud, self.bboxes_2d, self.bboxes_3d

    def for_camera(self, name: str):
        """The reference's 4 values: (image, point_cloud, bboxes_2d, bboxes_3d) of camera ``name``'s
        detections (all 3D boxes). :meth:`camera_view` adds the filtered match matrix."""
        return self.camera_view(name)[:4]

    def camera_view(self, name: str):
        """(image, point_cloud, bboxes_2d, bboxes_3d, match_matrix) of one camera's detections
        (the match matrix keeps that camera's rows; None without ground truth)."""
        if self.images is not None and name not in self.images and name != self.camera_name:
            raise KeyError(f"frame {self.frame_key!r} has no camera {name!r}; cameras: {sorted(self.images)}")
        image = self.images[name] if self.images and name in self.images else self.image
        if self.camera_per_det is None:
            keep = np.ones(self.num_2d, dtype=bool)
        else:
            keep = np.array([c == name for c in self.camera_per_det], dtype=bool)
        mm = None if self.match_matrix is None else self.match_matrix[keep]
        return image, self.point_cloud, self.bboxes_2d[keep], self.bboxes_3d, mm


@dataclass
class MatchResult:
    """Output of ``Matcher.match``.

    similarity: [K',M'] float32 scores of the kept detections (range per model).
    top_indices: [K'] int64 best column per kept row (index into the kept 3D boxes).
    matches: list of (2D index, 3D index, score) in the caller's original numbering.
    kept_2d_indices / kept_3d_indices: int64 maps from kept rows/columns to caller indices.
    geometry_iou: [K',M'] IoU of each 2D box with the 3D box projected through the matcher's
    calibration when the scores were fused, else None. fusion_weight: weight w of that
    geometry (0 = model scores alone). Fused scores keep the model's range and meaning
    ("match probability", mapped to [-1, 1] for cosine models): sigmoid((1-w) logit(p_model) +
    w logit(clip(IoU, eps, 1-eps))) (see ``xcalib.engine.fusion``).
    source: which path produced the matches: "model" (the model's scores), "fused" (model and
    the site calibration's projection) or "geometry" (geometric consensus over the frame's
    boxes, :mod:`xcalib.calib.consensus`: similarity = projection IoU, matches one-to-one).
    """

    similarity: np.ndarray
    top_indices: np.ndarray
    matches: list[tuple[int, int, float]]
    kept_2d_indices: np.ndarray
    kept_3d_indices: np.ndarray
    latency_ms: float = 0.0
    model: str = ""
    device: str = ""
    assignment: str = "argmax"
    geometry_iou: np.ndarray | None = None
    fusion_weight: float = 0.0
    source: MatchSource = "model"

    def as_pairs(self) -> np.ndarray:
        """Matches as an int64 array [n, 2] of (2D index, 3D index)."""
        if not self.matches:
            return np.zeros((0, 2), dtype=np.int64)
        return np.array([(i, j) for i, j, _ in self.matches], dtype=np.int64)

    def full_similarity(self, num_2d: int, num_3d: int, fill: float = np.nan) -> np.ndarray:
        """Similarity scattered back to the caller's [K, M] numbering (dropped rows = ``fill``)."""
        out = np.full((num_2d, num_3d), fill, dtype=np.float32)
        if self.similarity.size:
            out[np.ix_(self.kept_2d_indices, self.kept_3d_indices)] = self.similarity
        return out


@dataclass
class DatasetFrame:
    """A frame as the reference's ``load_dataset`` yields it: ``intrinsics`` / ``extrinsics`` are
    ``{camera: 3x3 K}`` / ``{camera: 4x4 T_cam_lidar}`` dicts over the frame's cameras, and
    :meth:`for_camera` returns 4 values. ``frame`` is the same data as an xcalib :class:`Frame`
    (typed intrinsics with distortion and image size, extras); ``Matcher.match_frame``,
    ``Matcher.calibrate`` and ``xcalib.train`` accept either (:func:`as_frame`)."""

    frame: Frame

    def __getattr__(self, name: str):  # frame_key, image, point_cloud, boxes, images, ...
        if name == "frame":
            raise AttributeError(name)
        return getattr(self.frame, name)

    def _per_camera(self, key: str, value):
        got = dict(self.frame.meta.get(key) or {})
        if not got and value is not None:
            got = {self.frame.camera_name: value}
        return got

    @property
    def intrinsics(self) -> dict[str, np.ndarray]:
        """{camera: [3,3] K} of the frame's cameras with intrinsics."""
        return {c: np.asarray(k.K if isinstance(k, CameraIntrinsics) else k, dtype=np.float64)
                for c, k in self._per_camera("intrinsics_by_camera", self.frame.intrinsics).items()}

    @property
    def extrinsics(self) -> dict[str, np.ndarray]:
        """{camera: [4,4] LiDAR -> camera ground truth} of the frame's cameras with one."""
        return {c: np.asarray(t, dtype=np.float64)
                for c, t in self._per_camera("extrinsics_by_camera", self.frame.extrinsics).items()}

    def for_camera(self, name: str):
        """(image, point_cloud, bboxes_2d, bboxes_3d) of camera ``name``: its image, its 2D boxes,
        all 3D boxes (``KeyError`` for an unknown camera)."""
        if name != self.frame.camera_name and name not in (self.frame.images or {}):
            raise KeyError(f"frame {self.frame.frame_key!r} has no camera {name!r}")
        return self.frame.for_camera(name)


def as_frame(item):
    """An xcalib :class:`Frame` from a ``Frame`` or a :class:`DatasetFrame` (others pass through)."""
    return item.frame if isinstance(item, DatasetFrame) else item
