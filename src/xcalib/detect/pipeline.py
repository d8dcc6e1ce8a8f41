"""Detections for frames that have none: the camera detector on each image, label-free LiDAR
boxes on each cloud (:class:`DetectedFrames`, a lazy ``Sequence[Frame]``)."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..types import OWN_DETECTIONS, Frame, FrameDetections
from .camera import Detector2D, Detector2DConfig, load_detector
from .lidar import Background, GroundPlane, LidarDetectConfig, build_background, fit_ground, is_static_recording, \
    lidar_boxes

__all__ = ["DetectConfig", "DetectedFrames", "detect_frame", "open_sensors", "STATIC_MIN_FRAMES"]

log = logging.getLogger(__name__)
Progress = Callable[[str, int, int], None]
STATIC_MIN_FRAMES = 30  # auto mode: a background model needs at least this many clouds of a static LiDAR


@dataclass(frozen=True)
class DetectConfig:
    """``camera``: the 2D detector's settings; ``lidar``: the LiDAR extraction's;
    ``detector_2d``: path of the user's ONNX detector (None: the shipped YOLOX-Nano);
    ``classes_2d``: its class names in output order (None: COCO for 80 classes)."""

    camera: Detector2DConfig = field(default_factory=Detector2DConfig)
    lidar: LidarDetectConfig = field(default_factory=LidarDetectConfig)
    detector_2d: str | None = None
    classes_2d: tuple[str, ...] | None = None


def _clouds(seq: Sequence[Frame], limit: int):
    idx = np.unique(np.linspace(0, len(seq) - 1, min(limit, len(seq))).round().astype(int))
    for i in idx:
        yield seq[int(i)].point_cloud


def detect_frame(frame: Frame, detector: Detector2D, config: LidarDetectConfig, *,
                 ground: GroundPlane | None = None, background: Background | None = None) -> Frame:
    """``frame`` with its 2D boxes from ``detector`` (every camera of a multi-camera frame) and
    its 3D boxes (box7) from the cloud; labels, match matrix, tracks and velocities dropped."""
    meta = dict(frame.meta)
    if frame.images:
        boxes, per_det, scores, names = [], [], [], []
        for cam, img in frame.images.items():
            d = detector(img)
            boxes.append(d.boxes)
            per_det += [cam] * len(d)
            scores += d.scores.tolist()
            names += list(d.class_names)
        b2 = np.concatenate(boxes) if boxes else np.zeros((0, 4), np.float32)
    else:
        d = detector(frame.image)
        b2, per_det, scores, names = d.boxes, None, d.scores.tolist(), list(d.class_names)
    b3 = lidar_boxes(frame.point_cloud, config, ground=ground, background=background)
    made = FrameDetections(OWN_DETECTIONS, tuple(scores), tuple(names), str(detector.path.name),
                           "static" if background else "moving")
    return dataclasses.replace(frame, bboxes_2d=b2.astype(np.float32), bboxes_3d=b3, match_matrix=None,
                               camera_per_det=per_det, track_ids_3d=None, velocities_3d=None, meta=meta,
                               detections=made)


class DetectedFrames(Sequence):
    """``source`` frames with xcalib's own detections in place of the source's (lazy; each
    frame's boxes are computed once and kept, the images and clouds are re-read).

    ``mode`` (after construction): ``static`` (background model over the recording) or
    ``moving``; ``background`` / ``ground``: the static LiDAR's models; ``replaced``: how many
    frames had boxes of their own (replaced)."""

    def __init__(self, source: Sequence[Frame], config: DetectConfig | None = None, *,
                 detector: Detector2D | None = None, progress: Progress | None = None):
        self.source, self.config = source, config or DetectConfig()
        self.detector = detector or load_detector(self.config.detector_2d, self.config.camera, self.config.classes_2d)
        for k in ("intrinsics", "camera", "camera_names", "source_name", "report", "tf_T_cam_lidar"):
            if hasattr(source, k):
                setattr(self, k, getattr(source, k))
        lc = self.config.lidar
        self.background: Background | None = None
        self.ground: GroundPlane | None = None
        mode = lc.mode
        if mode == "auto":
            static = len(source) >= STATIC_MIN_FRAMES and is_static_recording(
                [source[0].point_cloud, source[len(source) - 1].point_cloud], lc)
            mode = "static" if static else "moving"
        self.mode = mode
        if mode == "static":
            if progress:
                progress("background model", 0, 1)
            self.ground = fit_ground(np.concatenate([c[:, :3] for c in _clouds(source, 4)]), lc)
            self.background = build_background(_clouds(source, lc.background_frames), lc, ground=self.ground)
            if progress:
                progress("background model", 1, 1)
        self._boxes: dict[int, tuple] = {}
        self.replaced = 0  # frames whose source had boxes of its own (replaced by these)

    def __len__(self) -> int:
        return len(self.source)

    def _detect(self, i: int) -> Frame:
        src = self.source[i]
        self.replaced += bool(src.num_2d or src.num_3d)
        f = detect_frame(src, self.detector, self.config.lidar, ground=self.ground, background=self.background)
        self._boxes[i] = (f.bboxes_2d, f.bboxes_3d, f.camera_per_det, f.detections)
        return f

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = range(len(self))[index]
        if i not in self._boxes:
            return self._detect(i)
        b2, b3, per_det, det = self._boxes[i]
        f = self.source[i]
        return dataclasses.replace(f, bboxes_2d=b2, bboxes_3d=b3, match_matrix=None, camera_per_det=per_det,
                                   track_ids_3d=None, velocities_3d=None, meta=dict(f.meta), detections=det)

    def run(self, progress: Progress | None = None) -> DetectedFrames:
        """Detect in every frame now (``progress("detect", done, total)``); returns self."""
        n = len(self)
        for i in range(n):
            if i not in self._boxes:
                self._detect(i)
            if progress:
                progress("detect", i + 1, n)
        return self

    def counts(self) -> tuple[int, int]:
        """(2D boxes, 3D boxes) found so far."""
        return (sum(len(v[0]) for v in self._boxes.values()), sum(len(v[1]) for v in self._boxes.values()))


def open_sensors(source, camera: str | None = None, frames=None, **options) -> Sequence[Frame]:
    """``source`` (any frame source) opened for detection: a bag is read without its detection
    topics (its images, CameraInfo and clouds only; ``options`` go to the bag reader, e.g.
    ``tolerance_s``, ``intrinsics``); any other source as it is (its own boxes are replaced by
    :class:`DetectedFrames`). Shared by ``xcalib detect``, ``calibrate --detect`` and
    ``calibrate-many --detect``."""
    from ..io.sources import find_source, open_source

    if find_source(source).name == "bag":
        options = {**options, "detections": False}
    else:
        options = {}
    return open_source(source, camera=camera, frames=frames, **options)
