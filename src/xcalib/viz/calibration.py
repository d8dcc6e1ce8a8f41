"""Calibration overlays: LiDAR points (coloured by depth) and 3D boxes projected on the image.

Projection honours the intrinsics' OpenCV distortion (box edges are sampled, so they bend as
the lens bends them). Images are RGB uint8 [H,W,3]; the output has the input's size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry.boxes import as_box7, box7_corners, check_boxes2d
from ..geometry.camera import CameraIntrinsics
from ..geometry.camera_models import CameraModel
from ..geometry.projection import project_points
from .matching import _to_uint8
from ..options import Options, document, resolve

__all__ = ["draw_calibration_overlay", "CalibrationOverlayOptions", "BOX_EDGES"]

# corner index pairs of the 12 box edges (box7_corners order: bottom face, then top face)
BOX_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4],
                      [0, 4], [1, 5], [2, 6], [3, 7]])


def _pose_args(calibration, projection, intrinsics, rotation, translation):
    if calibration is not None:
        return calibration.intrinsics, calibration.rotation, calibration.translation
    if projection is not None:
        P = np.asarray(projection, dtype=np.float64)
        if P.shape != (3, 4):
            raise ValueError(f"projection: expected a 3x4 matrix, got shape {P.shape}")
        # P = K [R|t] -> K R via RQ; a plain P is drawn without distortion
        import scipy.linalg

        Kq, Rq = scipy.linalg.rq(P[:, :3])
        S = np.diag(np.sign(np.diag(Kq)))
        Kq, Rq = Kq @ S, S @ Rq
        t = np.linalg.solve(Kq, P[:, 3])
        if np.linalg.det(Rq) < 0:
            Rq, t = -Rq, -t
        Kq = Kq / Kq[2, 2]
        return CameraIntrinsics.from_matrix(Kq), Rq, t
    if intrinsics is None or rotation is None or translation is None:
        raise ValueError("draw_calibration_overlay: give calibration=, projection= (3x4), or intrinsics= with "
                         "rotation= and translation=")
    if isinstance(intrinsics, (CameraIntrinsics, CameraModel)):  # a wide-angle model: drawn through it
        intr = intrinsics
    else:
        intr = CameraIntrinsics.from_matrix(intrinsics)
    return intr, np.asarray(rotation, float), np.asarray(translation, float)


def _project(points: np.ndarray, intr, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(uv [N,2] px, depth [N] m) of LiDAR-frame points: depth is Z for a pinhole camera, the range
    for a wide-angle camera model (whose image also holds points with Z <= 0; NaN pixels outside
    its valid region)."""
    uv, z = project_points(points, intr, R, t)
    if isinstance(intr, CameraModel) and not intr.is_pinhole:
        pc = np.asarray(points, dtype=np.float64)[:, :3] @ np.asarray(R, float).T + np.asarray(t, float)
        z = np.where(np.isfinite(uv).all(1), np.linalg.norm(pc, axis=1), np.nan)
    return uv, z


def _colormap(values: np.ndarray) -> np.ndarray:
    """Values in [0,1] -> RGB uint8 [N,3] (TURBO)."""
    import cv2

    v = np.clip(values * 255, 0, 255).astype(np.uint8).reshape(-1, 1)
    return cv2.applyColorMap(v, cv2.COLORMAP_TURBO).reshape(-1, 3)[:, ::-1]


REPORT_MAX_POINTS = 60000  # LiDAR points xcalib's own reports draw (the function default is the reference's 6000)


@dataclass(frozen=True)
class CalibrationOverlayOptions(Options):
    """What :func:`draw_calibration_overlay` draws and how (the defaults in one place; the
    function documents each): the pose (``calibration``, or ``projection``, or ``intrinsics`` +
    ``rotation`` + ``translation``), ``bboxes_3d``, ``bboxes_2d``, ``pairs``, ``max_points``,
    ``max_depth`` (m; None: the 95th percentile), ``point_radius`` (px), ``title``."""

    calibration: Any = None
    projection: Any = None
    intrinsics: Any = None
    rotation: Any = None
    translation: Any = None
    bboxes_3d: Any = None
    bboxes_2d: Any = None
    pairs: Any = None
    max_points: int = 6000
    max_depth: float | None = None
    point_radius: int = 2
    title: str | None = None


@document(CalibrationOverlayOptions)
def draw_calibration_overlay(image, point_cloud=None, *, options: CalibrationOverlayOptions | None = None,
                             **overrides: Any) -> np.ndarray:
    """Draw points coloured by camera depth (near = blue, far = red), projected 3D boxes (orange
    wireframes), 2D boxes (green) and matches (a line from each 2D box centre to its projected
    3D box centre, both labelled with the pair number) on a copy of ``image``.

    Pose from ``calibration`` (a CalibrationResult), a 3x4 ``projection`` (no distortion), or
    ``intrinsics`` + ``rotation`` + ``translation`` (LiDAR -> camera). ``pairs`` [n,2] are
    (2D index, 3D index). Returns RGB uint8 of the image's size. The keyword settings are the
    fields of :class:`CalibrationOverlayOptions` (or one whole as ``options=``).
    """
    o = resolve(CalibrationOverlayOptions, options, overrides, where="draw_calibration_overlay")
    calibration, projection, intrinsics, rotation, translation = o.calibration, o.projection, o.intrinsics, \
        o.rotation, o.translation
    bboxes_3d, bboxes_2d, pairs, max_points, max_depth, point_radius, title = o.bboxes_3d, o.bboxes_2d, o.pairs, \
        o.max_points, o.max_depth, o.point_radius, o.title
    import cv2

    intr, R, t = _pose_args(calibration, projection, intrinsics, rotation, translation)
    img = _to_uint8(image)
    out = np.ascontiguousarray(img.copy())
    Hh, W = out.shape[:2]
    if point_cloud is not None and len(point_cloud):
        pts = np.asarray(point_cloud)[:, :3]
        if len(pts) > max_points:
            pts = pts[:: int(np.ceil(len(pts) / max_points))]
        uv, z = _project(pts, intr, R, t)
        ok = (z > 0.5) & np.all(np.isfinite(uv), 1) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < Hh)
        uv, z = uv[ok], z[ok]
        if len(z):
            zmax = max_depth or float(np.percentile(z, 95))
            zmin = float(np.percentile(z, 2))
            col = _colormap((z - zmin) / max(zmax - zmin, 1e-6))
            order = np.argsort(-z)  # far first, near on top
            ui = uv[order].astype(np.int32)
            r = max(int(point_radius) - 1, 0)
            for du in range(-r, r + 1):  # square dots, vectorised per offset
                for dv in range(-r, r + 1):
                    uu = np.clip(ui[:, 0] + du, 0, W - 1)
                    vv = np.clip(ui[:, 1] + dv, 0, Hh - 1)
                    out[vv, uu] = col[order]
    centres3 = {}
    if bboxes_3d is not None and len(np.asarray(bboxes_3d)):
        b7 = as_box7(bboxes_3d)
        corners = box7_corners(b7)  # [M,8,3]
        s = np.linspace(0, 1, 8)
        seg = corners[:, BOX_EDGES[:, 0], None] * (1 - s)[None, None, :, None] + \
            corners[:, BOX_EDGES[:, 1], None] * s[None, None, :, None]  # [M,12,8,3]
        uv, z = _project(seg.reshape(-1, 3), intr, R, t)
        uv = uv.reshape(len(b7), 12, 8, 2)
        z = z.reshape(len(b7), 12, 8)
        for j in range(len(b7)):
            if not np.all(z[j] > 0.5):
                continue
            lines = [np.round(uv[j, e]).astype(np.int32).reshape(-1, 1, 2) for e in range(12)]
            cv2.polylines(out, lines, False, (255, 140, 0), 2, cv2.LINE_AA)
            cuv, cz = _project(b7[j:j + 1, :3], intr, R, t)
            if cz[0] > 0.5:
                centres3[j] = cuv[0]
    b2 = None
    if bboxes_2d is not None and len(np.asarray(bboxes_2d)):
        b2 = check_boxes2d(bboxes_2d)
        for x1, y1, x2, y2 in b2:
            cv2.rectangle(out, (int(x1), int(y1)), (int(x2), int(y2)), (0, 220, 0), 2)
    if pairs is not None and b2 is not None:
        for n, (i, j) in enumerate(np.asarray(pairs, dtype=np.int64).reshape(-1, 2)):
            c2 = ((b2[i, 0] + b2[i, 2]) / 2, (b2[i, 1] + b2[i, 3]) / 2)
            p2 = (int(c2[0]), int(c2[1]))
            cv2.circle(out, p2, 5, (0, 220, 0), -1)
            if j in centres3 and np.all(np.isfinite(centres3[j])):
                p3 = (int(centres3[j][0]), int(centres3[j][1]))
                cv2.line(out, p2, p3, (255, 255, 0), 2, cv2.LINE_AA)
                cv2.circle(out, p3, 5, (255, 140, 0), -1)
            cv2.putText(out, str(n), (int(b2[i, 0]) + 3, int(b2[i, 1]) + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                        (255, 255, 255), 2, cv2.LINE_AA)
    if title:
        cv2.putText(out, title, (12, 32), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (0, 0, 0), 4, cv2.LINE_AA)
        cv2.putText(out, title, (12, 32), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2, cv2.LINE_AA)
    return out
