"""Matching overlay: the camera image with its 2D boxes beside a bird's-eye view (BEV) of the
point cloud with its 3D boxes, matched pairs linked by lines coloured by score.

BEV axes follow the LiDAR frame seen from above (z toward the viewer): **+x up, +y left**, so
the picture is not mirrored (a right-handed frame stays right-handed). Metres are isotropic
(one scale for both axes); a grid, a scale bar and an axis glyph are drawn. 3D boxes are
footprints of box7 ([M,7], yaw drawn as a heading tick) or protocol boxes ([M,6], axis-aligned).
Images are RGB uint8.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry.boxes import as_box7, box2d_centers, box7_corners, check_boxes2d
from ..options import Options, document, resolve

__all__ = ["draw_matching_overlay", "MatchingOverlayOptions", "score_colors", "BevView", "bev_view"]

_BG = (24, 26, 30)
_GRID = (52, 56, 64)
_UNMATCHED = (150, 150, 150)
_WRONG = (255, 60, 60)
_WHITE = (240, 240, 240)
_HEADER = 40
_FOOTER = 40
_PAD = 12


def score_colors(s: np.ndarray) -> np.ndarray:
    """Normalised scores [N] in [0,1] -> RGB uint8 [N,3]: red (low) -> yellow -> green (high)."""
    s = np.clip(np.asarray(s, dtype=np.float64).reshape(-1), 0.0, 1.0)
    r = np.where(s < 0.5, 1.0, 2.0 * (1.0 - s))
    g = np.where(s < 0.5, 2.0 * s, 1.0)
    rgb = np.stack([r * 235 + 20, g * 200 + 35, np.full_like(s, 50.0)], axis=1)
    return np.clip(rgb, 0, 255).astype(np.uint8)


@dataclass
class BevView:
    """Metric window of a BEV pane: LiDAR x in [x_min, x_max] (up), y in [y_min, y_max] (left),
    ``scale`` pixels per metre, pane ``width`` x ``height`` pixels."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    scale: float
    width: int
    height: int

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """LiDAR-frame (x, y) [N,2] metres -> pane pixels (col, row) [N,2] float; +x up, +y left."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        xc, yc = (self.x_min + self.x_max) / 2, (self.y_min + self.y_max) / 2
        col = self.width / 2 - (xy[:, 1] - yc) * self.scale
        row = self.height / 2 - (xy[:, 0] - xc) * self.scale
        return np.stack([col, row], axis=1)


def bev_view(points_xy: np.ndarray, centres_xy: np.ndarray, width: int, height: int,
             bev_range: tuple[float, float, float, float] | None = None) -> BevView:
    """Window holding every 3D box centre (or, with no boxes, the 2-98th percentile of the
    points), padded by 8% of the span and at least 6 m.

    ``bev_range`` = (x_min, x_max, y_min, y_max) metres overrides it. Isotropic scale.
    """
    if bev_range is not None:
        x0, x1, y0, y1 = (float(v) for v in bev_range)
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"bev_range: expected (x_min, x_max, y_min, y_max) with max > min, got {bev_range}")
    else:
        if len(centres_xy):  # the boxes are what matters; points only frame an empty scene
            lo, hi = centres_xy.min(0), centres_xy.max(0)
        elif len(points_xy):
            lo, hi = np.percentile(points_xy, [2, 98], axis=0)
        else:
            lo, hi = np.array([-10.0, -10.0]), np.array([10.0, 10.0])
        span = np.maximum(hi - lo, 1e-3)
        mid = (lo + hi) / 2
        half = span / 2 + np.maximum(0.08 * span.max(), 6.0)
        x0, x1, y0, y1 = mid[0] - half[0], mid[0] + half[0], mid[1] - half[1], mid[1] + half[1]
    scale = min(height / (x1 - x0), width / (y1 - y0))
    return BevView(float(x0), float(x1), float(y0), float(y1), float(scale), int(width), int(height))


def _nice_step(span_m: float, target_lines: int = 6) -> float:
    raw = span_m / max(target_lines, 1)
    mag = 10 ** np.floor(np.log10(max(raw, 1e-9)))
    for m in (1, 2, 5, 10):
        if raw <= m * mag:
            return float(m * mag)
    return float(10 * mag)


def _text(img, s: str, org, color=_WHITE, scale: float = 0.5, thick: int = 1) -> None:
    import cv2

    x, y = int(org[0]), int(org[1])
    # dark halo from offset copies: a thicker stroke would advance each glyph further (OpenCV adds
    # the thickness to the advance) and leave a shifted ghost after the text
    for dx, dy in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1), (-1, 1), (1, -1)):
        cv2.putText(img, s, (x + dx, y + dy), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick, cv2.LINE_AA)
    cv2.putText(img, s, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, tuple(int(c) for c in color), thick, cv2.LINE_AA)


def _dashed_polygon(img, pts: np.ndarray, color, thick: int = 1, dash: float = 7.0) -> None:
    import cv2

    pts = np.asarray(pts, dtype=np.float64)
    for a, b in zip(pts, np.roll(pts, -1, axis=0)):
        n = max(int(np.linalg.norm(b - a) / dash), 1)
        s = np.linspace(0, 1, n + 1)
        seg = a[None] * (1 - s)[:, None] + b[None] * s[:, None]
        for k in range(0, n, 2):
            cv2.line(img, tuple(np.round(seg[k]).astype(int)), tuple(np.round(seg[k + 1]).astype(int)), color, thick,
                     cv2.LINE_AA)


def _as_matches(matches, match_threshold: float | None) -> np.ndarray:
    """MatchResult | [(i, j, score)] | [n,2] / [n,3] array -> float64 [n,3] (i, j, score)."""
    if matches is None:
        return np.zeros((0, 3))
    if hasattr(matches, "matches"):
        matches = matches.matches
    arr = np.asarray(list(matches) if not isinstance(matches, np.ndarray) else matches, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 3))
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        raise ValueError(f"matches: expected a MatchResult or (2D index, 3D index[, score]) rows, got shape {arr.shape}")
    if arr.shape[1] == 2:
        arr = np.hstack([arr, np.ones((len(arr), 1))])
    if match_threshold is not None:
        arr = arr[arr[:, 2] >= match_threshold]
    return arr


def _to_uint8(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image: expected [H,W,3] RGB, got shape {img.shape}")
    if img.dtype != np.uint8:
        img = np.clip(img * (255.0 if img.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    return img


def _draw_camera(pane, view: BevView, camera, width: int, height: int) -> None:
    """Camera centre and the rays through the left/right image edges (at cy), in the BEV."""
    import cv2

    if hasattr(camera, "rotation") and hasattr(camera, "intrinsics"):
        intr, R, t = camera.intrinsics, np.asarray(camera.rotation, float), np.asarray(camera.translation, float)
    else:
        intr, T = camera
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"camera: expected (intrinsics, T_cam_lidar [4,4]), got a transform of shape {T.shape}")
        R, t = T[:3, :3], T[:3, 3]
    if intr is None:
        return
    Kinv = np.linalg.inv(np.asarray(intr.K if hasattr(intr, "K") else intr, dtype=np.float64))
    centre = -R.T @ t  # camera centre in the LiDAR frame
    cy = float(np.asarray(intr.K if hasattr(intr, "K") else intr)[1, 2])
    rays = (R.T @ (Kinv @ np.array([[0.0, cy, 1.0], [float(width), cy, 1.0]]).T)).T
    c = view.to_pixels(centre[None, :2])[0]
    reach = 2.0 * max(view.width, view.height) / view.scale
    col = (255, 200, 0)
    for d in rays:
        d2 = d[:2] / max(np.linalg.norm(d[:2]), 1e-9)
        e = view.to_pixels((centre[:2] + reach * d2)[None])[0]
        cv2.line(pane, tuple(np.round(c).astype(int)), tuple(np.round(e).astype(int)), col, 1, cv2.LINE_AA)
    if 0 <= c[0] < view.width and 0 <= c[1] < view.height:
        cv2.circle(pane, tuple(np.round(c).astype(int)), 5, col, -1, cv2.LINE_AA)
        _text(pane, "camera", (c[0] + 7, c[1] + 14), col, 0.4)


REPORT_HEIGHT = 540  # px: the height xcalib's own reports draw at (the function default is the reference's 420)


@dataclass(frozen=True)
class MatchingOverlayOptions(Options):
    """What :func:`draw_matching_overlay` draws besides the frame and its matches, and how (the
    defaults in one place; the function documents each)."""

    output_height: int = 420
    match_threshold: float | None = None
    match_matrix: Any = None
    score_range: tuple[float, float] | None = None
    bev_range: tuple[float, float, float, float] | None = None
    max_points: int = 30000
    camera: Any = None
    title: str | None = None


@document(MatchingOverlayOptions)
def draw_matching_overlay(image, point_cloud, bboxes_2d, bboxes_3d, matches=None, *,
                          options: MatchingOverlayOptions | None = None, **overrides: Any) -> np.ndarray:
    """Image with 2D boxes (left) beside a BEV of the point cloud with 3D boxes (right).

    Args:
        image: [H,W,3] RGB. point_cloud: [P,>=3] LiDAR frame, metres (None: no points).
        bboxes_2d: [K,4] pixels. bboxes_3d: [M,6] protocol boxes or [M,7] box7 with yaw.
        matches: ``MatchResult``, (2D index, 3D index, score) rows, or [n,2] pairs (score 1),
            in the caller's numbering. Pairs below ``match_threshold`` are dropped.
        match_matrix: optional [K,M] bool ground truth; wrong pairs get a red cross and label.
        score_range: (low, high) mapped to red..green (default [0,1] when all scores are
            inside it, else their min..max).
        bev_range: (x_min, x_max, y_min, y_max) metres of the BEV window (default: automatic).
        camera: optional ``CalibrationResult`` or (``CameraIntrinsics``, ``T_cam_lidar`` [4,4]):
            draws the camera position and its horizontal field of view in the BEV.
        output_height, max_points, title: panel height (px), BEV points drawn, header text.
        The keyword settings are the fields of :class:`MatchingOverlayOptions` (``options=``).
    Returns:
        RGB uint8 [output_height + header + footer, W_total, 3]. Matched boxes and their link
        take the score colour; unmatched boxes are grey and dashed.
    """
    o = resolve(MatchingOverlayOptions, options, overrides, where="draw_matching_overlay")
    output_height, match_threshold, match_matrix, score_range = o.output_height, o.match_threshold, o.match_matrix, \
        o.score_range
    bev_range, max_points, camera, title = o.bev_range, o.max_points, o.camera, o.title
    import cv2

    img = _to_uint8(image)
    b2 = check_boxes2d(bboxes_2d) if bboxes_2d is not None and len(np.asarray(bboxes_2d)) else np.zeros((0, 4))
    b3 = np.asarray(bboxes_3d if bboxes_3d is not None else np.zeros((0, 6)), dtype=np.float64)
    b3 = b3.reshape(len(b3), -1) if b3.size else np.zeros((0, 6))
    has_yaw = b3.shape[1] == 7
    b7 = as_box7(b3) if len(b3) else np.zeros((0, 7))
    K, M = len(b2), len(b7)
    m = _as_matches(matches, match_threshold)
    if len(m):
        bad = (m[:, 0] < 0) | (m[:, 0] >= K) | (m[:, 1] < 0) | (m[:, 1] >= M)
        if np.any(bad):
            raise ValueError(f"matches: index out of range for {K} 2D and {M} 3D boxes: {m[bad][:3, :2].tolist()}")
    truth = None
    if match_matrix is not None:
        truth = np.asarray(match_matrix, dtype=bool)
        if truth.shape != (K, M):
            raise ValueError(f"match_matrix: expected shape ({K}, {M}), got {truth.shape}")

    # ---- scores -> colours
    scores = m[:, 2] if len(m) else np.zeros(0)
    if score_range is None:
        finite = scores[np.isfinite(scores)]
        if len(finite) == 0 or (finite.min() >= 0 and finite.max() <= 1):
            score_range = (0.0, 1.0)
        else:
            score_range = (float(finite.min()), float(max(finite.max(), finite.min() + 1e-6)))
    lo, hi = score_range
    colors = score_colors((scores - lo) / max(hi - lo, 1e-12)) if len(m) else np.zeros((0, 3), np.uint8)

    # ---- layout
    H = int(output_height)
    if H < 120:
        raise ValueError(f"output_height: expected >= 120 pixels, got {output_height}")
    sx = H / img.shape[0]
    left_w = max(int(round(img.shape[1] * sx)), 1)
    bev_w = max(int(round(0.9 * H)), 320)
    W = _PAD + left_w + _PAD + bev_w + _PAD
    canvas = np.empty((_HEADER + H + _FOOTER, W, 3), dtype=np.uint8)
    canvas[:] = _BG
    ox_l, oy = _PAD, _HEADER
    ox_r = _PAD + left_w + _PAD
    canvas[oy:oy + H, ox_l:ox_l + left_w] = cv2.resize(img, (left_w, H), interpolation=cv2.INTER_AREA)

    # ---- BEV pane
    pane = np.empty((H, bev_w, 3), dtype=np.uint8)
    pane[:] = (14, 15, 18)
    pts = np.zeros((0, 3))
    if point_cloud is not None and len(point_cloud):
        pts = np.asarray(point_cloud)[:, :3]
        if len(pts) > max_points:
            pts = pts[:: int(np.ceil(len(pts) / max_points))]
        pts = pts[np.all(np.isfinite(pts), axis=1)]
    view = bev_view(pts[:, :2], b7[:, :2], bev_w, H, bev_range)
    step = _nice_step(max(view.x_max - view.x_min, view.y_max - view.y_min))
    # grid lines at multiples of `step` metres (over the whole visible pane)
    half_x, half_y = H / 2 / view.scale, bev_w / 2 / view.scale
    xc, yc = (view.x_min + view.x_max) / 2, (view.y_min + view.y_max) / 2
    for gx in np.arange(np.ceil((xc - half_x) / step), np.floor((xc + half_x) / step) + 1) * step:
        r = int(round(view.to_pixels([[gx, yc]])[0, 1]))
        cv2.line(pane, (0, r), (bev_w - 1, r), _GRID, 1)
        _text(pane, f"x={gx + 0.0:g}", (4, r - 3), (120, 126, 140), 0.38)
    for gy in np.arange(np.ceil((yc - half_y) / step), np.floor((yc + half_y) / step) + 1) * step:
        c = int(round(view.to_pixels([[xc, gy]])[0, 0]))
        cv2.line(pane, (c, 0), (c, H - 1), _GRID, 1)
        _text(pane, f"y={gy + 0.0:g}", (c + 3, H - 6), (120, 126, 140), 0.38)
    if len(pts):
        cr = np.round(view.to_pixels(pts[:, :2])).astype(np.int64)
        ok = (cr[:, 0] >= 0) & (cr[:, 0] < bev_w) & (cr[:, 1] >= 0) & (cr[:, 1] < H)
        z = pts[ok, 2]
        if len(z):
            zl, zh = np.percentile(z, [5, 95])
            g = 70 + 150 * np.clip((z - zl) / max(zh - zl, 1e-6), 0, 1)  # brighter = higher
            col = np.stack([g * 0.85, g * 0.92, g], axis=1).astype(np.uint8)
            order = np.argsort(z)  # high points on top
            pane[cr[ok][order, 1], cr[ok][order, 0]] = col[order]
    # sensor origin
    o = view.to_pixels([[0.0, 0.0]])[0]
    if 0 <= o[0] < bev_w and 0 <= o[1] < H:
        oc = (int(o[0]), int(o[1]))
        cv2.drawMarker(pane, oc, (0, 200, 255), cv2.MARKER_TRIANGLE_UP, 12, 2)
        _text(pane, "LiDAR", (oc[0] + 8, oc[1] + 4), (0, 200, 255), 0.4)

    if camera is not None:
        _draw_camera(pane, view, camera, img.shape[1], img.shape[0])

    color3 = {int(j): tuple(int(c) for c in colors[n]) for n, j in enumerate(m[:, 1])} if len(m) else {}
    color2 = {int(i): tuple(int(c) for c in colors[n]) for n, i in enumerate(m[:, 0])} if len(m) else {}
    centre3 = view.to_pixels(b7[:, :2]) if M else np.zeros((0, 2))
    if M:
        foot = view.to_pixels(box7_corners(b7)[:, :4, :2].reshape(-1, 2)).reshape(M, 4, 2)
        for j in range(M):
            if j in color3:
                cv2.polylines(pane, [np.round(foot[j]).astype(np.int32)], True, color3[j], 2, cv2.LINE_AA)
            else:
                _dashed_polygon(pane, foot[j], _UNMATCHED, 1, dash=4.0)
            if has_yaw:  # heading tick: centre -> middle of the +x face (corners 0 and 3)
                front = (foot[j, 0] + foot[j, 3]) / 2
                cv2.line(pane, tuple(np.round(centre3[j]).astype(int)), tuple(np.round(front).astype(int)),
                         color3.get(j, _UNMATCHED), 1, cv2.LINE_AA)
            c = centre3[j]
            if 0 <= c[0] < bev_w and 0 <= c[1] < H:
                _text(pane, f"L{j}", (c[0] + 5, c[1] - 5), color3.get(j, _UNMATCHED), 0.4)
    # scale bar + axis glyph
    bar_m = step
    bar_px = int(round(bar_m * view.scale))
    cv2.line(pane, (10, 14), (10 + bar_px, 14), _WHITE, 2)
    _text(pane, f"{bar_m:g} m", (14 + bar_px, 19), _WHITE, 0.45)
    ax0 = (bev_w - 22, H - 26)
    cv2.arrowedLine(pane, ax0, (ax0[0], ax0[1] - 36), (255, 90, 90), 2, cv2.LINE_AA, tipLength=0.25)
    cv2.arrowedLine(pane, ax0, (ax0[0] - 36, ax0[1]), (90, 230, 90), 2, cv2.LINE_AA, tipLength=0.25)
    _text(pane, "+x", (ax0[0] - 8, ax0[1] - 42), (255, 90, 90), 0.45)
    _text(pane, "+y", (ax0[0] - 62, ax0[1] + 5), (90, 230, 90), 0.45)
    canvas[oy:oy + H, ox_r:ox_r + bev_w] = pane
    cv2.rectangle(canvas, (ox_r - 1, oy - 1), (ox_r + bev_w, oy + H), (90, 96, 110), 1)

    # ---- 2D boxes on the image pane
    if K:
        bb = b2 * sx + np.array([ox_l, oy, ox_l, oy])
        for i in range(K):
            x1, y1, x2, y2 = bb[i]
            if i in color2:
                cv2.rectangle(canvas, (int(x1), int(y1)), (int(x2), int(y2)), color2[i], 2, cv2.LINE_AA)
            else:
                _dashed_polygon(canvas, np.array([[x1, y1], [x2, y1], [x2, y2], [x1, y2]]), _UNMATCHED, 1, dash=5.0)
            _text(canvas, f"C{i}", (x1 + 2, max(y1 - 4, oy + 12)), color2.get(i, _UNMATCHED), 0.42)
    # ---- links
    n_wrong = 0
    for n, (i, j, s) in enumerate(m):
        i, j = int(i), int(j)
        p2 = box2d_centers(b2[i:i + 1])[0] * sx + np.array([ox_l, oy])
        p3 = centre3[j] + np.array([ox_r, oy])
        p3 = np.clip(p3, [ox_r, oy], [ox_r + bev_w - 1, oy + H - 1])
        c = tuple(int(v) for v in colors[n])
        cv2.line(canvas, tuple(np.round(p2).astype(int)), tuple(np.round(p3).astype(int)), c, 1, cv2.LINE_AA)
        cv2.circle(canvas, tuple(np.round(p2).astype(int)), 3, c, -1, cv2.LINE_AA)
        cv2.circle(canvas, tuple(np.round(p3).astype(int)), 3, c, -1, cv2.LINE_AA)
        if truth is not None and not truth[i, j]:
            n_wrong += 1
            cv2.drawMarker(canvas, tuple(np.round(p2).astype(int)), _WRONG, cv2.MARKER_TILTED_CROSS, 16, 3)
            cv2.drawMarker(canvas, tuple(np.round(p3).astype(int)), _WRONG, cv2.MARKER_TILTED_CROSS, 16, 3)

    # ---- header and footer
    head = title or "matching"
    unm2, unm3 = K - len(set(m[:, 0].astype(int).tolist())), M - len(set(m[:, 1].astype(int).tolist()))
    stats = f"{len(m)} pairs | unmatched: {unm2} camera, {unm3} LiDAR"
    if truth is not None:
        stats += f" | wrong vs ground truth: {n_wrong}"
    _text(canvas, head, (_PAD, 17), _WHITE, 0.55, 1)
    _text(canvas, stats, (_PAD, 35), (200, 205, 215), 0.45)
    _text(canvas, "camera image (2D boxes C#)", (ox_l + 4, oy + H + 16), (200, 205, 215), 0.42)
    _text(canvas, "LiDAR bird's-eye view, +x up / +y left (3D boxes L#)", (ox_r + 4, oy + H + 16),
          (200, 205, 215), 0.42)
    # colour bar: score low..high, then legend for unmatched / wrong
    fy = oy + H + 24
    bar_w = min(160, left_w // 3)
    ramp = score_colors(np.linspace(0, 1, bar_w))
    canvas[fy:fy + 10, ox_l:ox_l + bar_w] = ramp[None]
    _text(canvas, f"score {lo:.2g} .. {hi:.2g}", (ox_l + bar_w + 6, fy + 10), (200, 205, 215), 0.4)
    lx = ox_l + bar_w + 130
    _dashed_polygon(canvas, np.array([[lx, fy], [lx + 18, fy], [lx + 18, fy + 10], [lx, fy + 10]]), _UNMATCHED, 1, 4)
    _text(canvas, "unmatched", (lx + 24, fy + 10), _UNMATCHED, 0.4)
    if truth is not None:
        cv2.drawMarker(canvas, (lx + 120, fy + 5), _WRONG, cv2.MARKER_TILTED_CROSS, 10, 2)
        _text(canvas, "wrong", (lx + 130, fy + 10), _WRONG, 0.4)
    return canvas
