"""Normalise calibration inputs (Frames or tuples) into ``CalibFrame`` records.

Everything downstream of this module works on ``CalibFrame``: valid 2D boxes (pixels), box7
3D boxes (LiDAR frame, metres, yaw re-estimated from the points when the input had none) and
their corner "shapes" [M,8,3], plus index maps back to the caller's numbering.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from ..geometry.boxes import as_box7, box7_corners, check_boxes2d, check_boxes3d, valid_boxes2d
from ..geometry.camera import CameraIntrinsics
from ..geometry.camera_models import CameraModel, as_calibration_camera, calibration_camera_from_dict
from .boxshape import fit_yaw_to_points, lidar_angular_step, shapes_from_points
from .parallel import Workers, parallel_map

__all__ = ["CalibFrame", "as_intrinsics", "prepare_frames", "with_corner_outlines", "with_point_outlines",
           "YAW_OPEN_SIGMA", "lean_frames", "SCAN_STEP_KEY", "scan_step_of", "box_scores", "input_scores"]

#: ``Frame.meta`` key of the LiDAR scan step (:func:`~.boxmodel.lidar_angular_step`) of the frame's
#: whole cloud, set where the frame carries only part of its cloud (``xcalib.site.stream``: the
#: points near the 3D boxes); absent: the step is computed from the frame's points.
SCAN_STEP_KEY = "lidar_scan_step"


def scan_step_of(points, meta: dict | None) -> tuple[float, float] | None:
    """The scan step of a frame's cloud: ``meta[SCAN_STEP_KEY]`` when the frame carries it (the
    step of its whole cloud, which ``points`` may only be part of), else computed from ``points``."""
    if meta and SCAN_STEP_KEY in meta:
        s = meta[SCAN_STEP_KEY]
        return None if s is None else (float(s[0]), float(s[1]))
    return lidar_angular_step(points)


#: 1-sigma of a box outline whose yaw the points leave open, as a fraction of |length - width|
YAW_OPEN_SIGMA = 0.25


@dataclass
class CalibFrame:
    """One frame as the calibrator sees it.

    boxes2d [K,4] px (valid rows only), boxes3d box7 [M,7] LiDAR frame (metres, radians),
    corners [M,S,3] LiDAR frame: each 3D box's outline (its 8 corners, or the hull of its LiDAR
    points, see ``box_model``), box_corners [M,8,3] the 8 corners, from_points [M] bool: the outline
    is a point hull, yaw_ambiguous [M] bool: a yaw-less box whose heading the points do not tell
    (None: yaw given), outline_sigma_m [M] the outline's own 1-sigma (m; None: 0): a quarter of
    length minus width for the 8 corners of a box whose yaw is open (a point hull does not depend
    on it), which makes such a box count little in the fit while it still counts in matching and
    scoring. idx2d [K] / idx3d [M] map rows back to the input numbering.
    size = (width, height) px. points: [P,3] LiDAR-frame cloud or None (overlays, yaw).
    scores2d_input: the 2D detector's confidence per *input* 2D box (the caller's numbering, so
    it stays right when rows of ``boxes2d`` are dropped with their ``idx2d``; None: no scores);
    :func:`box_scores` gives them per row of ``boxes2d``.
    """

    key: str
    camera: str
    boxes2d: np.ndarray
    boxes3d: np.ndarray
    corners: np.ndarray
    idx2d: np.ndarray
    idx3d: np.ndarray
    size: tuple[int, int]
    box_corners: np.ndarray | None = None
    from_points: np.ndarray | None = None
    yaw_ambiguous: np.ndarray | None = None
    outline_sigma_m: np.ndarray | None = None
    points: np.ndarray | None = None
    image: np.ndarray | None = None
    gt: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    scores2d_input: np.ndarray | None = None

    @property
    def n2(self) -> int:
        return len(self.boxes2d)

    @property
    def n3(self) -> int:
        return len(self.boxes3d)


def as_intrinsics(intrinsics) -> CameraIntrinsics:
    """Accept ``CameraIntrinsics``, a 3x3 K, or a dict; raise ValueError otherwise. A camera model
    (``xcalib.geometry.camera_models``, or a dict with a ``model``) is kept as it is, except the
    pinhole ones, which become ``CameraIntrinsics``."""
    if isinstance(intrinsics, CameraIntrinsics):
        return intrinsics
    if isinstance(intrinsics, CameraModel):  # camera-model dispatch
        return as_calibration_camera(intrinsics)
    if isinstance(intrinsics, dict) and intrinsics.get("model") is not None:
        return calibration_camera_from_dict(intrinsics)
    if isinstance(intrinsics, dict):
        return CameraIntrinsics.from_dict(intrinsics)
    if intrinsics is None:
        raise ValueError("intrinsics: required (CameraIntrinsics, a 3x3 K matrix or a dict), got None")
    K = np.asarray(intrinsics, dtype=np.float64)
    if K.shape == (3, 4):  # a KITTI-style P: use its left 3x3 block
        K = K[:, :3]
    if K.shape != (3, 3):
        raise ValueError(f"intrinsics: expected CameraIntrinsics or a 3x3 matrix, got shape {K.shape}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"intrinsics: focal lengths must be positive pixels, got fx={K[0, 0]}, fy={K[1, 1]}")
    return CameraIntrinsics.from_matrix(K)


def _frame_fields(item, i: int):
    """(image, points, b2, b3, camera, key, gt, intrinsics, meta, detections) from a Frame or a tuple."""
    if hasattr(item, "bboxes_2d") and hasattr(item, "bboxes_3d"):
        return (getattr(item, "image", None), getattr(item, "point_cloud", None), item.bboxes_2d,
                item.bboxes_3d, getattr(item, "camera_name", "") or "", getattr(item, "frame_key", "") or f"{i:04d}",
                getattr(item, "extrinsics", None), getattr(item, "intrinsics", None), dict(getattr(item, "meta", {}) or {}),
                getattr(item, "detections", None))
    if isinstance(item, (tuple, list)) and len(item) == 4:
        image, pts, b2, b3 = item
        return image, pts, b2, b3, "", f"{i:04d}", None, None, {}, None
    raise TypeError(
        f"frames[{i}]: expected an xcalib.types.Frame or an (image, point_cloud, bboxes_2d, bboxes_3d) "
        f"tuple, got {type(item).__name__}"
    )


def _image_size(image, intr: CameraIntrinsics, meta: dict) -> tuple[int, int]:
    img = None if image is None else np.asarray(image)
    if img is not None and img.ndim >= 2 and img.shape[0] > 1 and img.shape[1] > 1:
        return int(img.shape[1]), int(img.shape[0])
    if "image_size" in meta and meta["image_size"] is not None:
        w, h = meta["image_size"]
        return int(w), int(h)
    if intr.width is not None and intr.height is not None:
        return intr.width, intr.height
    return int(round(2 * intr.cx)), int(round(2 * intr.cy))


#: the image may differ from the size the intrinsics declare by this share (a crop of a few rows)
_SIZE_SLACK = 0.1


def _check_declared_size(intr: CameraIntrinsics, size: tuple[int, int], key) -> None:
    """Refuse intrinsics that declare an image size (``width``/``height``) other than the frames'
    images by more than ``_SIZE_SLACK``: they belong to another camera or resolution (their focal
    length and principal point are in another pixel grid), and a pose fitted through them is wrong."""
    iw, ih = getattr(intr, "width", None), getattr(intr, "height", None)
    if not iw or not ih:
        return
    w, h = size
    if abs(w - iw) > _SIZE_SLACK * iw or abs(h - ih) > _SIZE_SLACK * ih:
        raise ValueError(f"intrinsics: they are for a {iw}x{ih} image, but frame {key}'s image is "
                         f"{w}x{h}: the intrinsics of another camera or resolution? Give this camera's intrinsics "
                         "(--intrinsics), scaled to the images' size")


def prepare_frames(frames: Sequence, intrinsics, *, reestimate_yaw: str | bool = "auto",
                   box_model: str = "auto", min_box_px: float = 2.0, workers: Workers = 1,
                   scores: bool = False) -> tuple[list[CalibFrame], CameraIntrinsics, str | None]:
    """Normalise ``frames`` -> (CalibFrames, intrinsics, problem message or None).

    The message is set (and the list may be partial) when frames come from different
    cameras. ``reestimate_yaw``: "auto" (yaw-less [M,6] boxes get their yaw from the points),
    "always" or "never" (True/False accepted). ``box_model``: "corners" (the 8 box corners), "points" (hull of the LiDAR points in
    each box; corners where too few) or "auto" (points for yaw-less [M,6] boxes when a cloud is
    given, corners otherwise). ``workers``: processes for the per-frame yaw fits and point hulls
    (the frames come back the same whatever the number). ``scores``: keep the 2D boxes' detector
    scores (``CalibFrame.scores2d_input``, see :func:`input_scores`; ``CalibConfig.detector_scores``). Raises ValueError for impossible
    intrinsics or malformed boxes.
    """
    if not isinstance(frames, (list, tuple)):
        frames = list(frames)
    if len(frames) == 0:
        raise ValueError("frames: expected at least one frame, got an empty sequence")
    raw = [_frame_fields(f, i) for i, f in enumerate(frames)]
    if intrinsics is None:
        cand = [r[7] for r in raw if r[7] is not None]
        if not cand:
            raise ValueError("intrinsics: not given and the frames carry none")
        intrinsics = cand[0]
    intr = as_intrinsics(intrinsics)
    out: list[CalibFrame] = []
    cams = {r[4] for r in raw if r[4]}
    problem = None
    if len(cams) > 1:
        problem = (f"frames from different cameras are mixed ({', '.join(sorted(cams))}); "
                   "calibrate one camera at a time")
    frame_intr = [(r[5], r[7]) for r in raw if r[7] is not None]
    other = next(((k, fi) for k, fi in frame_intr[1:] if fi != frame_intr[0][1]), None)
    if problem is None and other is not None:
        (k0, i0), (k1, i1) = frame_intr[0], other
        fx_cx = [f"fx {getattr(i, 'fx', float('nan')):g}, cx {getattr(i, 'cx', float('nan')):g}" for i in (i0, i1)]
        problem = (f"frames carry different camera intrinsics (frame {k0}: {fx_cx[0]}; frame {k1}: {fx_cx[1]}; "
                   "mixed cameras or recordings?); calibrate one camera of one recording at a time")
    if reestimate_yaw not in ("auto", "always", "never", True, False):
        raise ValueError(f"reestimate_yaw: expected 'auto', 'always' or 'never', got {reestimate_yaw!r}")
    if box_model not in ("auto", "corners", "points"):
        raise ValueError(f"box_model: expected 'auto', 'corners' or 'points', got {box_model!r}")
    scan_step = None
    rows = []
    for i, (image, pts, b2, b3, cam, key, gt, _fi, meta, made) in enumerate(raw):
        size = _image_size(image, intr, meta)
        _check_declared_size(intr, size, key if key is not None else i)
        intr.check_image_size(*size)
        b2 = check_boxes2d(b2, f"frames[{i}].bboxes_2d")[:, :4]
        b3 = check_boxes3d(b3, f"frames[{i}].bboxes_3d")
        m7 = meta.get("box7")
        if b3.shape[1] == 6 and m7 is not None and np.shape(m7) == (len(b3), 7):
            b3 = np.asarray(m7, dtype=np.float64)  # the detector's yawed boxes (synth, readers)
        if not np.all(np.isfinite(b3)):
            raise ValueError(f"frames[{i}].bboxes_3d: NaN/Inf values")
        ok2 = valid_boxes2d(b2) & ((b2[:, 2] - b2[:, 0]) >= min_box_px) & ((b2[:, 3] - b2[:, 1]) >= min_box_px)
        idx2 = np.flatnonzero(ok2)
        box7 = as_box7(b3) if len(b3) else np.zeros((0, 7))
        ok3 = np.all(box7[:, 3:6] > 1e-3, axis=1)
        idx3 = np.flatnonzero(ok3)
        box7 = box7[idx3]
        p = None
        if pts is not None:
            p = np.asarray(pts)
            if p.ndim != 2 or p.shape[1] < 3:
                raise ValueError(f"frames[{i}].point_cloud: expected shape [P, >=3], got {p.shape}")
            p = p[:, :3]
        had_yaw = b3.ndim == 2 and b3.shape[1] == 7
        redo = reestimate_yaw in (True, "always") or (reestimate_yaw == "auto" and not had_yaw)
        use_pts = box_model == "points" or (box_model == "auto" and not had_yaw)
        has_pts = p is not None and len(p) and len(box7)
        if use_pts and has_pts and scan_step is None:  # one LiDAR for all frames: its scan pattern once
            scan_step = scan_step_of(p, meta)
        rows.append((i, image, cam, key, gt, meta, b2[idx2].astype(np.float64), box7, idx2, idx3, p, size,
                     (bool(redo and has_pts), not had_yaw, bool(use_pts and has_pts)),
                     input_scores(meta, len(b2), i, made) if scores else None))
    # the per-frame outline work (yaw fits, point hulls) on up to ``workers`` processes (frames in order)
    shaped = parallel_map(_frame_outlines, [(r[7], r[10], r[12], scan_step) for r in rows],
                          workers if any(r[12][0] or r[12][2] for r in rows) else 1)
    for (i, image, cam, key, gt, meta, b2, box7, idx2, idx3, p, size, _, q), (box7, ambiguous, shapes, corners8,
                                                                             from_pts, extra) in zip(rows, shaped):
        meta = {**meta, **extra}
        out.append(CalibFrame(
            key=str(key), camera=cam, boxes2d=b2, boxes3d=box7,
            corners=shapes, box_corners=corners8, from_points=from_pts, yaw_ambiguous=ambiguous,
            outline_sigma_m=None if ambiguous is None else np.where(ambiguous & ~from_pts,
                                                                   YAW_OPEN_SIGMA * np.abs(box7[:, 3] - box7[:, 4]), 0.0),
            idx2d=idx2, idx3d=idx3,
            size=size, points=p, image=None if image is None else np.asarray(image),
            gt=None if gt is None else np.asarray(gt, dtype=np.float64), meta=meta, scores2d_input=q,
        ))
    return out, intr, problem


def input_scores(meta: dict | None, n: int, i: int = 0, detections=None) -> np.ndarray | None:
    """The 2D detector's score of each of a frame's ``n`` input 2D boxes, from ``meta["scores_2d"]``
    or the frame's ``detections.scores_2d`` (:class:`xcalib.types.FrameDetections`, as ``xcalib
    detect`` sets it), or None when the frame has none. Scores of another length than the boxes, or
    not finite, are not used (a warning names frame ``i`` and the problem): they cannot be told apart
    from another frame's."""
    q = (meta or {}).get("scores_2d")
    if q is None and detections is not None:
        q = detections.scores_2d
    if q is None:
        return None
    try:
        q = np.asarray(q, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        q = None
    problem = ("not numbers" if q is None else f"{len(q)} scores for {n} 2D boxes" if len(q) != n
               else "NaN/Inf values" if not np.all(np.isfinite(q)) else None)
    if problem is not None:
        import warnings

        warnings.warn(f"frames[{i}].meta scores_2d: {problem}; the frame's detector scores are not used", stacklevel=3)
        return None
    return q


def box_scores(fr: CalibFrame) -> np.ndarray | None:
    """The detector score of each row of ``fr.boxes2d`` (None: the frame has no scores)."""
    if fr.scores2d_input is None:
        return None
    return fr.scores2d_input[fr.idx2d]


def _frame_outlines(job):
    """One frame's 3D outlines (a task of ``prepare_frames``): job = (box7 [M,7], points [P,3] or
    None, (refit the yaw to the points, the boxes came without a yaw, outline from the points),
    scan step). Returns (box7, yaw_ambiguous or None, outlines [M,S,3], 8 corners [M,8,3],
    from_points [M], meta additions)."""
    box7, p, (refit, yawless, hulls), scan_step = job
    ambiguous, extra = None, {}
    if refit:
        yf = fit_yaw_to_points(box7, p)
        box7, ambiguous = yf.boxes7, yf.ambiguous
        extra = {"yaw_fitted": int(yf.fitted.sum()), "yaw_ambiguous": int(yf.ambiguous.sum())}
    elif yawless and len(box7):
        # yaw-less boxes and no cloud to tell their heading: every outline's yaw is open (its
        # corners can be a quarter-turn off), so it weighs as little as an ambiguous one -- with
        # no outline sigma, a 4-frame folder of such boxes gave a success 0.84 m off with a
        # reported 1-sigma of 0.08 m (issue 29's calibrate-many benchmark, synthetic site 34)
        ambiguous = np.ones(len(box7), dtype=bool)
        extra = {"yaw_unknown": int(len(box7))}
    corners8 = box7_corners(box7) if len(box7) else np.zeros((0, 8, 3))
    shapes, from_pts = corners8, np.zeros(len(box7), dtype=bool)
    if hulls:
        shapes, from_pts = shapes_from_points(box7, corners8, p, scan_step_rad=scan_step)
        extra = {**extra, "boxes_from_points": int(from_pts.sum())}
    return box7, ambiguous, shapes, corners8, from_pts, extra


def with_corner_outlines(frames: Sequence[CalibFrame]) -> list[CalibFrame] | None:
    """The frames with every point-hull outline replaced by its box's 8 corners, except boxes whose
    yaw the points leave ambiguous (their hull is the better outline, weighted as one whose yaw is
    open: among corners it is another model); None when no outline comes from points."""
    if not any(f.from_points is not None and f.from_points.any() for f in frames):
        return None
    out = []
    for f in frames:
        swap = np.zeros(f.n3, dtype=bool) if f.from_points is None else f.from_points.copy()
        if f.yaw_ambiguous is not None:
            swap &= ~f.yaw_ambiguous
        if not swap.any():
            out.append(f)
            continue
        S = max(f.corners.shape[1], 8)
        shapes = np.concatenate([f.corners, np.repeat(f.corners[:, :1], S - f.corners.shape[1], 1)], 1)
        shapes[swap] = np.concatenate([f.box_corners[swap], np.repeat(f.box_corners[swap][:, :1], S - 8, 1)], 1)
        hull = f.from_points & ~swap  # open yaw: a hull among corners is another model, counted little
        sig = np.where(hull, YAW_OPEN_SIGMA * np.abs(f.boxes3d[:, 3] - f.boxes3d[:, 4]),
                       0.0 if f.outline_sigma_m is None else f.outline_sigma_m)
        out.append(replace(f, corners=shapes, from_points=hull, outline_sigma_m=sig))
    return out


def lean_frames(frames: list[CalibFrame]) -> list[CalibFrame]:
    """The frames without their point cloud and image (the geometry the search and refinement
    use, pickled in kilobytes instead of megabytes for a worker process)."""
    from dataclasses import replace

    return [f if f.points is None and f.image is None else replace(f, points=None, image=None) for f in frames]


def with_point_outlines(frames: Sequence[CalibFrame], in_view: Sequence[np.ndarray]) -> list[CalibFrame] | None:
    """The frames with the outline of every 3D box flagged in ``in_view`` (per frame [M] bool: e.g.
    the boxes a pose projects into the image) replaced by the hull of its LiDAR points
    (``boxmodel.shapes_from_points``, grown by half a scan step); boxes with too few points keep
    their corners. For 3D boxes *with* a yaw: a camera detector draws the visible outline of an
    object, which the points follow and the box corners overshoot (PandaSet: detector boxes 11-13 %
    smaller than the rectangles around the cuboids' corners). None when no frame has a cloud or no
    box got a hull."""
    if not any(f.points is not None and len(f.points) for f in frames):
        return None
    scan_step = next((s for s in (scan_step_of(f.points, f.meta) for f in frames if f.points is not None
                                  and len(f.points)) if s is not None), None)
    out, any_hull = [], False
    for f, view in zip(frames, in_view):
        idx = np.flatnonzero(np.asarray(view, dtype=bool) & ~(f.from_points if f.from_points is not None
                                                              else np.zeros(f.n3, dtype=bool)))
        if f.points is None or not len(f.points) or not len(idx):
            out.append(f)
            continue
        hulls, used = shapes_from_points(f.boxes3d[idx], f.box_corners[idx], f.points, scan_step_rad=scan_step)
        if not used.any():
            out.append(f)
            continue
        any_hull = True
        S = max(f.corners.shape[1], hulls.shape[1])
        shapes = np.concatenate([f.corners, np.repeat(f.corners[:, :1], S - f.corners.shape[1], 1)], 1)
        hulls = np.concatenate([hulls, np.repeat(hulls[:, :1], S - hulls.shape[1], 1)], 1)
        shapes[idx[used]] = hulls[used]
        from_pts = np.zeros(f.n3, dtype=bool) if f.from_points is None else f.from_points.copy()
        from_pts[idx[used]] = True
        out.append(replace(f, corners=shapes, from_points=from_pts,
                           meta={**f.meta, "boxes_from_points": int(from_pts.sum())}))
    return out if any_hull else None
