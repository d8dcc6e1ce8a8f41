"""Contact sheet: a PNG grid of frames with 2D boxes and LiDAR points projected by the GT calibration."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ...types import Frame

__all__ = ["contact_sheet", "draw_frame", "legend"]


def draw_frame(frame: Frame, *, max_points: int = 40000) -> np.ndarray:
    """One annotated RGB image: points coloured by depth (needs ``intrinsics`` + ``extrinsics``),
    matched 2D boxes green, unmatched 2D boxes red, projected matched 3D boxes (box7) yellow."""
    import cv2

    from ...geometry.boxes import box7_corners
    from ...geometry.projection import project_points

    img = np.ascontiguousarray(frame.image).copy()
    H, W = img.shape[:2]
    if frame.intrinsics is not None and frame.extrinsics is not None and len(frame.point_cloud):
        T = np.asarray(frame.extrinsics)
        pts = frame.point_cloud[:, :3]
        if len(pts) > max_points:
            pts = pts[np.random.default_rng(0).choice(len(pts), max_points, replace=False)]
        uv, depth = project_points(pts, frame.intrinsics, T[:3, :3], T[:3, 3])
        ok = np.isfinite(uv[:, 0]) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        if getattr(frame.intrinsics, "has_distortion", False):  # beyond the image's field the distortion polynomial folds back
            from ...geometry.projection import undistort_pixels

            Km = frame.intrinsics.K
            corners = undistort_pixels(np.array([[0, 0], [W, 0], [0, H], [W, H]], float), Km,
                                       frame.intrinsics.distortion)
            r_max = 1.05 * np.linalg.norm((corners - Km[:2, 2]) / np.diag(Km)[:2], axis=1).max()
            pc = pts @ T[:3, :3].T + T[:3, 3]
            with np.errstate(all="ignore"):
                ok &= np.linalg.norm(pc[:, :2] / pc[:, 2:3], axis=1) < r_max
        uv, depth = uv[ok].astype(np.int32), depth[ok]
        hue = np.clip(depth / 80.0 * 150, 0, 150).astype(np.uint8)
        hsv = np.stack([hue, np.full_like(hue, 255), np.full_like(hue, 255)], axis=1)[None]
        rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0]
        r = max(1, W // 900)
        for dx in range(-r, r + 1):
            for dy in range(-r, r + 1):
                img[np.clip(uv[:, 1] + dy, 0, H - 1), np.clip(uv[:, 0] + dx, 0, W - 1)] = rgb
        b7 = frame.meta.get("box7")
        if b7 is not None and frame.match_matrix is not None and len(b7):
            sel = np.flatnonzero(frame.match_matrix.any(axis=0))
            if len(sel):
                c = box7_corners(np.asarray(b7)[sel])
                uvc, dc = project_points(c.reshape(-1, 3), frame.intrinsics, T[:3, :3], T[:3, 3])
                uvc = uvc.reshape(-1, 8, 2)
                for k in range(len(sel)):
                    if np.all(np.isfinite(uvc[k])):
                        q = np.round(uvc[k]).astype(np.int32)
                        for a, b in ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4),
                                     (0, 4), (1, 5), (2, 6), (3, 7)):
                            cv2.line(img, tuple(map(int, q[a])), tuple(map(int, q[b])), (255, 230, 0), 1, cv2.LINE_AA)
    matched = frame.match_matrix.any(axis=1) if frame.match_matrix is not None else np.zeros(frame.num_2d, bool)
    th = max(2, W // 640)
    for k, b in enumerate(np.asarray(frame.bboxes_2d)):
        col = (0, 255, 0) if matched[k] else (255, 40, 40)
        cv2.rectangle(img, (int(b[0]), int(b[1])), (int(b[2]), int(b[3])), col, th)
    txt = f"{frame.frame_key}  K={frame.num_2d} M={frame.num_3d} P={len(frame.point_cloud)}"
    cv2.putText(img, txt, (12, 20 + 20 * th), cv2.FONT_HERSHEY_SIMPLEX, 0.6 * th, (255, 255, 255), th + 1, cv2.LINE_AA)
    return img


def legend(sheet_width: int, *, max_depth_m: float = 80.0) -> np.ndarray:
    """The key of :func:`draw_frame`'s colours, one RGB strip ``sheet_width`` wide: the box colours,
    the depth scale of the points (the hue :func:`draw_frame` uses, 0 to ``max_depth_m``) and the
    tile caption's letters."""
    import cv2

    h = 96
    strip = np.full((h, sheet_width, 3), 24, np.uint8)
    font, fs, white = cv2.FONT_HERSHEY_SIMPLEX, 0.5, (235, 235, 235)
    x = 12
    for col, text in (((0, 255, 0), "2D box matched to a 3D box"), ((255, 40, 40), "2D box without a 3D box"),
                      ((255, 230, 0), "its 3D box, projected with the true calibration")):
        cv2.rectangle(strip, (x, 12), (x + 26, 30), col, 2)
        cv2.putText(strip, text, (x + 34, 27), font, fs, white, 1, cv2.LINE_AA)
        x += 44 + cv2.getTextSize(text, font, fs, 1)[0][0]
    bar_w = min(360, max(120, sheet_width // 3))
    hue = np.linspace(0, 150, bar_w).astype(np.uint8)
    hsv = np.stack([hue, np.full_like(hue, 255), np.full_like(hue, 255)], axis=1)[None]
    strip[44:60, 12:12 + bar_w] = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0][None]
    cv2.putText(strip, f"LiDAR points by depth: 0 m (left) to {max_depth_m:g}+ m (right)", (24 + bar_w, 57), font,
                fs, white, 1, cv2.LINE_AA)
    cv2.putText(strip, "caption: frame key, K = 2D boxes, M = 3D boxes, P = LiDAR points", (12, 84), font, fs,
                white, 1, cv2.LINE_AA)
    return strip


def contact_sheet(frames: Sequence[Frame], path, *, cols: int = 3, tile_width: int = 640) -> Path:
    """Write a PNG grid of annotated frames (see :func:`draw_frame`), with a legend strip below it
    (:func:`legend`), to ``path``; returns the path."""
    import cv2

    frames = list(frames)
    if not frames:
        raise ValueError("contact_sheet: no frames given")
    tiles = []
    for f in frames:
        im = draw_frame(f)
        h = int(round(im.shape[0] * tile_width / im.shape[1]))
        tiles.append(cv2.resize(im, (tile_width, h), interpolation=cv2.INTER_AREA))
    th = max(t.shape[0] for t in tiles)
    rows = []
    for r in range(0, len(tiles), cols):
        row = [np.pad(t, ((0, th - t.shape[0]), (0, 0), (0, 0))) for t in tiles[r:r + cols]]
        row += [np.zeros((th, tile_width, 3), np.uint8)] * (cols - len(row))
        rows.append(np.hstack(row))
    sheet = np.vstack(rows + [legend(sheet_width=cols * tile_width)])
    from ...io.files import atomic_write
    from ...io.images import encode_image

    return atomic_write(path, [encode_image(sheet, ".png")])
