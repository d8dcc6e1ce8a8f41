"""How much of the camera's detections the LiDAR's detections cover, at a pose: the attribution
of a refusal of a calibration made from xcalib's own detections (``calibrate --detect``).

When the label-free LiDAR boxes miss most of the objects the camera detector sees (a sparse,
far-reaching or high-mounted LiDAR: few points per object), no pose explains the boxes, and
the calibration's own verdict (a model misfit, an ambiguity, too few pairs) names a symptom.
:func:`detection_coverage` counts, at the best pose found, the 2D boxes that have a projected
LiDAR box over them; :meth:`DetectionCoverage.refusal` words what is missing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..geometry.boxes import as_box7, box7_corners, iou_matrix
from ..types import OWN_DETECTIONS

__all__ = ["DetectionCoverage", "detection_coverage", "explain_refusal", "COVERAGE_MIN"]

COVERAGE_MIN = 0.5  # below this share of 2D boxes with a LiDAR box, the LiDAR detections are named as the cause
_IOU_MIN = 0.3
_MIN_BOXES = 3  # fewer boxes of a kind than this: the calibration refuses before any search (calib.decision)


@dataclass(frozen=True)
class DetectionCoverage:
    """Counts over ``frames``: 2D boxes, 3D boxes, 3D boxes projecting into the image at the pose
    (None without a pose), 2D boxes with a projected 3D box of IoU >= 0.3 over them (None
    without a pose)."""

    frames: int
    boxes_2d: int
    boxes_3d: int
    in_view_3d: int | None
    covered_2d: int | None

    @property
    def share(self) -> float | None:
        """Share of the 2D boxes that have a LiDAR box (None without a pose or 2D boxes)."""
        if self.covered_2d is None or self.boxes_2d == 0:
            return None
        return self.covered_2d / self.boxes_2d

    def too_few(self) -> bool:
        """True when the LiDAR boxes cover less than ``COVERAGE_MIN`` of the camera's boxes
        (or there are fewer LiDAR boxes than half the camera's, with no pose to look at)."""
        if self.share is not None:
            return self.share < COVERAGE_MIN
        return self.boxes_3d < COVERAGE_MIN * self.boxes_2d

    def refusal(self) -> str:
        """What is missing, in words (for a refusal's message)."""
        f = max(1, self.frames)
        lidar = f"xcalib's LiDAR detector finds {self.boxes_3d / f:.1f} objects a frame"
        if self.in_view_3d is not None:
            lidar += f", {self.in_view_3d / f:.1f} of them in the camera's view"
        if self.share is not None:
            head = (f"too few LiDAR objects detected: {100 * self.share:.0f} % of the camera's {self.boxes_2d} boxes "
                    f"({self.boxes_2d / f:.1f} a frame) have a LiDAR box at the best pose found")
        else:
            head = (f"too few LiDAR objects detected: {self.boxes_3d} LiDAR boxes for the camera's {self.boxes_2d} "
                    "boxes")
        return (f"{head}; {lidar}. Its label-free boxes miss objects with few points (far, dark, or under a sparse or "
                "high-mounted LiDAR): give the recording's own 3D detections (Detection3DArray or Autoware "
                "DetectedObjects topics), more frames with near objects, or calibrate from labelled boxes")


    def found_too_few(self) -> bool:
        """True when xcalib's detectors found fewer than 3 boxes of a kind over all frames: no
        calibration can start, whatever the pose."""
        return self.boxes_2d < _MIN_BOXES or self.boxes_3d < _MIN_BOXES

    def found_too_few_refusal(self) -> str:
        """What the detectors found when it is too few to calibrate (for a refusal's message)."""
        f = self.frames
        what = []
        if self.boxes_2d < _MIN_BOXES:
            what.append(f"the camera detector (shipped YOLOX-Nano unless --detector-2d) found {self.boxes_2d} "
                        f"object(s) in {f} image(s): it sees traffic (person, bicycle, car, motorcycle, bus, "
                        "truck) in camera images, not synthetic renders; look at its boxes with `xcalib detect "
                        "SOURCE --out detected.mcap --score-min 0.2`")
        if self.boxes_3d < _MIN_BOXES:
            what.append(f"the label-free LiDAR detector found {self.boxes_3d} object(s) in {f} cloud(s): it keeps "
                        "traffic-sized clusters standing on the ground (try --lidar-mode moving or static)")
        return ("too few objects detected to calibrate (at least 3 camera and 3 LiDAR boxes over all frames): "
                + "; ".join(what) + ". Give more frames with traffic, or the recording's own detections")


def _project(b7: np.ndarray, T: np.ndarray, K: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """2D rectangles [M, 4] of the boxes in front of the camera and inside the image, and their
    indices."""
    if not len(b7):
        return np.zeros((0, 4)), np.zeros(0, np.int64)
    c = box7_corners(b7) @ T[:3, :3].T + T[:3, 3]
    front = np.all(c[..., 2] > 0.1, axis=1)
    c = c[front]
    uv = (c[..., :2] / c[..., 2:3]) * K[[0, 1], [0, 1]] + K[:2, 2]
    r = np.concatenate([uv.min(1), uv.max(1)], axis=1)
    inside = (r[:, 2] > 0) & (r[:, 0] < width) & (r[:, 3] > 0) & (r[:, 1] < height)
    r = r[inside]
    r[:, [0, 2]] = np.clip(r[:, [0, 2]], 0, width)
    r[:, [1, 3]] = np.clip(r[:, [1, 3]], 0, height)
    return r, np.nonzero(front)[0][inside]


def detection_coverage(frames: Sequence, T_cam_lidar=None, intrinsics=None) -> DetectionCoverage:
    """Coverage of ``frames``' 2D boxes by their 3D boxes projected with ``T_cam_lidar`` [4, 4]
    and ``intrinsics`` (pinhole; the frame's own when None); without a pose only the counts."""
    n2 = n3 = 0
    view = cov = 0
    T = None if T_cam_lidar is None else np.asarray(T_cam_lidar, dtype=np.float64)
    for f in frames:
        b2 = np.asarray(f.bboxes_2d, dtype=np.float64).reshape(-1, 4)
        b3 = f.bboxes_3d
        n2 += len(b2)
        n3 += 0 if b3 is None else len(b3)
        k = intrinsics or f.intrinsics
        if T is None or k is None or b3 is None or not len(b3):
            continue
        if k.width and k.height:
            w, h = int(k.width), int(k.height)
        else:  # the image's size (a streamed frame keeps only its size: ``image_size_of``)
            from ..io.sources import image_size_of

            size = image_size_of(f)
            if size is None:
                continue
            w, h = size
        rects, _ = _project(as_box7(b3), T, np.asarray(k.K, dtype=np.float64), w, h)
        view += len(rects)
        if len(b2) and len(rects):
            cov += int((iou_matrix(b2, rects).max(1) >= _IOU_MIN).sum())
    have_pose = T is not None
    return DetectionCoverage(len(frames), n2, n3, view if have_pose else None, cov if have_pose else None)


def explain_refusal(result, frames: Sequence, intrinsics=None):
    """A refused calibration ``result`` (a :class:`xcalib.calib.CalibrationResult`) made from
    xcalib's own detections, with what is missing named first when the LiDAR boxes cover too
    few of the camera's boxes at the refused pose (``diagnostics.refused_T``; the counts alone
    without one): ``"too few LiDAR objects detected: ... (the calibration's verdict: ...)"``.
    The coverage is kept in ``meta["detection_coverage"]`` (written to calibration.json) and
    ``boxes_source`` is :data:`xcalib.types.OWN_DETECTIONS`; a success, or a refusal with enough
    coverage, is returned with only these added."""
    import dataclasses

    T = getattr(getattr(result, "diagnostics", None), "refused_T", None) if not result.success else None
    if result.success:
        T = result.extrinsics
    cov = detection_coverage(frames, T, intrinsics)
    meta = {**(result.meta or {}), "detection_coverage": dataclasses.asdict(cov) | {"share": cov.share}}
    own = {"meta": meta, "boxes_source": OWN_DETECTIONS}
    if not result.success and cov.found_too_few():  # the calibration's own hint ("--detect makes them") misleads here
        return dataclasses.replace(result, message=cov.found_too_few_refusal(), **own)
    if result.success or not cov.too_few():
        return dataclasses.replace(result, **own)
    return dataclasses.replace(result, message=f"{cov.refusal()} (the calibration's verdict: {result.message})", **own)
