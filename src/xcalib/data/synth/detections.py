"""Detections with exact ground truth: 2D boxes = visible projected extents, 3D boxes in the LiDAR frame.

Visibility comes from an object-id mask (convex hulls of the projected boxes painted far to near
at full image resolution), so labels are identical whether or not images are rendered. A fully
visible, untruncated object's noise-free 2D box is exactly the extent of its projected box7
corners (with the site's distortion); an occluded one's is clipped to its visible pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from typing import TYPE_CHECKING

import numpy as np

from ...geometry.boxes import box7_corners, box7_to_extents, extents_to_center_size
from ...geometry.camera_models import CameraModel, densify_box_edges
from ...geometry.camera_models.outline import outline_extremes
from ...geometry.projection import project_points, undistort_pixels
from .scene import CLASSES, SceneObjects, sample_sizes

if TYPE_CHECKING:  # annotations only: the site module renders with this one (no import cycle)
    from .site import Site

__all__ = ["Detections", "CameraView", "camera_view", "detect", "world_to_lidar_box7", "box7_to_protocol",
           "mirror_boxes"]

_NEAR = 0.3  # metres: objects with a corner closer to the camera plane are not imaged
_SHIFT = 4   # sub-pixel bits for OpenCV polygon fills


@dataclass
class CameraView:
    """Projection of a frame's objects: uv [N,8,2] px, depth [N,8] m, in_view [N] bool,
    order (far to near indices of in-view objects), mask [H,W] int32 (object index + 1, 0 = none),
    hulls (per object [n,2] int32 polygon in 1/16 px, or None)."""

    uv: np.ndarray
    depth: np.ndarray
    in_view: np.ndarray
    order: np.ndarray
    mask: np.ndarray
    hulls: list


@dataclass
class Detections:
    """One frame's labels. 2D: boxes [K,4] px, ids [K] (track id, -1 = false positive), classes,
    clean [K,4] (noise-free), visibility [K], truncation [K]. 3D (LiDAR frame): box7 [M,7],
    box7_gt [M,7] (noise-free), ids [M], classes, protocol [M,6], velocity [M,3] m/s. match [K,M] bool."""

    boxes_2d: np.ndarray
    ids_2d: np.ndarray
    classes_2d: list
    clean_2d: np.ndarray
    visibility_2d: np.ndarray
    truncation_2d: np.ndarray
    box7_3d: np.ndarray
    box7_gt_3d: np.ndarray
    ids_3d: np.ndarray
    classes_3d: list
    boxes_3d: np.ndarray
    match: np.ndarray
    view: CameraView | None = field(default=None, repr=False)
    velocity_3d: np.ndarray | None = None    # [M,3] LiDAR frame, m/s (0 for false positives)


def _project(site: Site, pts_world: np.ndarray):
    T = site.T_cam_world
    return project_points(pts_world.reshape(-1, 3), site.intrinsics, T[:3, :3], T[:3, 3])


def _max_normalised_radius(site: Site) -> float:
    """Largest |normalised coordinate| seen by the image (+30 %): beyond it distortion folds back."""
    if "max_r" not in site._cache:
        W, H = site.width, site.height
        c = np.array([[0, 0], [W, 0], [0, H], [W, H], [W / 2, 0], [0, H / 2]], dtype=np.float64)
        K = site.intrinsics.K
        und = undistort_pixels(c, K, site.intrinsics.distortion)
        xy = (und - K[:2, 2]) / np.array([K[0, 0], K[1, 1]])
        site._cache["max_r"] = 1.3 * float(np.linalg.norm(xy, axis=1).max())
    return site._cache["max_r"]


def camera_view(site: Site, objs: SceneObjects) -> CameraView:
    """Project every object and paint the object-id mask (far to near)."""
    W, H = site.width, site.height
    N = len(objs)
    corners = box7_corners(objs.box7) if N else np.zeros((0, 8, 3))
    if isinstance(site.intrinsics, CameraModel):
        uv, depth, in_view = _model_view(site, corners)
    else:
        uv, depth = _project(site, corners)
        uv, depth = uv.reshape(N, 8, 2), depth.reshape(N, 8)
        in_view = np.all(depth > _NEAR, axis=1)
    if getattr(site.intrinsics, "has_distortion", False) and N:
        pc = (corners.reshape(-1, 3) @ site.T_cam_world[:3, :3].T + site.T_cam_world[:3, 3]).reshape(N, 8, 3)
        with np.errstate(all="ignore"):
            r = np.linalg.norm(pc[..., :2] / np.maximum(pc[..., 2:3], 1e-9), axis=-1)
        in_view &= np.all(r < _max_normalised_radius(site), axis=1)
    mask = np.zeros((H, W), dtype=np.int32)
    hulls: list = [None] * N
    if N:
        lo = np.where(in_view[:, None], uv.min(axis=1), np.inf)
        hi = np.where(in_view[:, None], uv.max(axis=1), -np.inf)
        overlaps = in_view & (hi[:, 0] > 0) & (lo[:, 0] < W) & (hi[:, 1] > 0) & (lo[:, 1] < H)
        in_view = overlaps
        dist = np.linalg.norm(objs.box7[:, :3] - site.camera_position, axis=1)
        idx = np.flatnonzero(in_view)
        order = idx[np.argsort(-dist[idx], kind="stable")]
        import cv2

        for i in order:
            pts = np.round(uv[i] * (1 << _SHIFT)).astype(np.int32)
            hull = cv2.convexHull(pts)
            hulls[i] = hull
            cv2.fillConvexPoly(mask, hull, int(i) + 1, lineType=cv2.LINE_8, shift=_SHIFT)
    else:
        order = np.zeros(0, dtype=np.int64)
    return CameraView(uv=uv, depth=depth, in_view=in_view, order=order, mask=mask, hulls=hulls)


def _model_view(site: Site, corners: np.ndarray):
    """Under a camera model (wide-angle): the box edges projected densely (straight edges curve)
    and the points where each box's image is widest (``outline_extremes``, exact), uv [N,S,2], distance [N,S] (m) and in_view [N] (every point in the model's valid region and
    farther than ``_NEAR``)."""
    N = len(corners)
    T = site.T_cam_world
    # the edges densely (for the hull that paints the mask) and the exact extremes of u and v over
    # each box (the tight box of the projected solid, where a curved edge peaks between samples)
    dense = np.concatenate([densify_box_edges(corners), outline_extremes(corners, T[:3, :3], T[:3, 3],
                                                                         site.intrinsics)], axis=1) if N else corners
    S = dense.shape[1]
    pc = dense.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    uv, ok = site.intrinsics.project(pc)
    dist = np.linalg.norm(pc, axis=1)
    in_view = np.all((ok & (dist > _NEAR)).reshape(N, S), axis=1)
    return uv.reshape(N, S, 2), dist.reshape(N, S), in_view


def _visible_boxes(site: Site, view: CameraView):
    """Noise-free visible 2D boxes [N,4], visible fraction [N], truncation [N] (NaN = not imaged)."""
    import cv2

    W, H = site.width, site.height
    N = len(view.uv)
    boxes = np.full((N, 4), np.nan)
    vis = np.zeros(N)
    trunc = np.ones(N)
    if not N:
        return boxes, vis, trunc
    for i in np.flatnonzero(view.in_view):
        lo, hi = view.uv[i].min(axis=0), view.uv[i].max(axis=0)
        full = max((hi[0] - lo[0]) * (hi[1] - lo[1]), 1e-9)
        a = np.array([max(lo[0], 0.0), max(lo[1], 0.0), min(hi[0], W), min(hi[1], H)])
        clipped = max(a[2] - a[0], 0.0) * max(a[3] - a[1], 0.0)
        trunc[i] = 1.0 - clipped / full
        x0, y0 = int(math.floor(a[0])), int(math.floor(a[1]))
        x1, y1 = min(int(math.ceil(a[2])) + 1, W), min(int(math.ceil(a[3])) + 1, H)
        if x1 <= x0 or y1 <= y0:
            continue
        # pixels the object would cover alone (inside the image)
        solo = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
        hull = view.hulls[i] - np.array([x0 << _SHIFT, y0 << _SHIFT], dtype=np.int32)
        cv2.fillConvexPoly(solo, hull, 1, lineType=cv2.LINE_8, shift=_SHIFT)
        n_full = int(np.count_nonzero(solo))
        own = view.mask[y0:y1, x0:x1] == i + 1
        n_vis = int(np.count_nonzero(own))
        if n_full == 0 or n_vis == 0:
            continue
        vis[i] = n_vis / n_full
        if n_vis >= n_full:
            boxes[i] = a
            continue
        ys, xs = np.nonzero(own)
        m = np.array([xs.min() + x0 - 1.0, ys.min() + y0 - 1.0, xs.max() + x0 + 2.0, ys.max() + y0 + 2.0])
        boxes[i] = [max(a[0], m[0]), max(a[1], m[1]), min(a[2], m[2]), min(a[3], m[3])]
    return boxes, vis, trunc


def world_to_lidar_box7(site: Site, box7_world: np.ndarray) -> np.ndarray:
    """World box7 [N,7] -> box7 in the levelled LiDAR frame (yaw about LiDAR z)."""
    b = np.asarray(box7_world, dtype=np.float64).reshape(-1, 7)
    T = site.T_lidar_world
    out = b.copy()
    out[:, :3] = b[:, :3] @ T[:3, :3].T + T[:3, 3]
    out[:, 6] = (b[:, 6] - site.lidar_yaw + np.pi) % (2 * np.pi) - np.pi
    return out


def box7_to_protocol(box7: np.ndarray, convention: str = "extents") -> np.ndarray:
    """box7 [M,7] -> protocol [M,6]: the axis-aligned box enclosing each yawed box
    (``"extents"``: xmin..zmax, ``"center"``: cx, cy, cz, dx, dy, dz)."""
    if convention not in ("extents", "center"):
        raise ValueError(f"box_convention must be 'extents' or 'center', got {convention!r}")
    ext = box7_to_extents(np.asarray(box7, dtype=np.float64).reshape(-1, 7))
    return ext if convention == "extents" else extents_to_center_size(ext)


def _ground_point(site: Site, uv: np.ndarray) -> np.ndarray:
    """World ground points [n,3] seen at pixels uv [n,2] (NaN where the ray misses the ground)."""
    if isinstance(site.intrinsics, CameraModel):
        rays_c, _ = site.intrinsics.unproject(uv)
    else:
        K = site.intrinsics.K
        und = undistort_pixels(uv, K, site.intrinsics.distortion)
        rays_c = np.column_stack([(und - K[:2, 2]) / np.array([K[0, 0], K[1, 1]]), np.ones(len(uv))])
    R, C = site.T_world_cam[:3, :3], site.camera_position
    d = rays_c @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -C[2] / d[:, 2]
    t[~(t > 0)] = np.nan
    return C + t[:, None] * d


def _false_2d(site: Site, rng: np.random.Generator, n: int) -> np.ndarray:
    """n false-positive 2D boxes shaped like road users standing on visible ground."""
    if n <= 0:
        return np.zeros((0, 4))
    W, H = site.width, site.height
    uv = np.column_stack([rng.uniform(0, W, 4 * n), rng.uniform(0.2 * H, H, 4 * n)])
    g = _ground_point(site, uv)
    ok = np.isfinite(g[:, 0]) & (np.linalg.norm(g[:, :2] - site.camera_position[:2], axis=1) < 120)
    g = g[ok][:n]
    cls = rng.choice(list(CLASSES), size=len(g))
    size = sample_sizes(rng, cls)
    b7 = np.column_stack([g[:, :2], size[:, 2] / 2, size, rng.uniform(-np.pi, np.pi, len(g))])
    out = []
    if len(b7):
        c = box7_corners(b7)
        uvc, dep = _project(site, c)
        uvc, dep = uvc.reshape(-1, 8, 2), dep.reshape(-1, 8)
        for i in range(len(b7)):
            if np.all(dep[i] > _NEAR):
                lo, hi = uvc[i].min(axis=0), uvc[i].max(axis=0)
                out.append([max(lo[0], 0), max(lo[1], 0), min(hi[0], W), min(hi[1], H)])
    while len(out) < n:  # sky / missed ground: generic boxes
        w, h = rng.uniform(15, 200, 2)
        x, y = rng.uniform(0, W - w), rng.uniform(0, H - h)
        out.append([x, y, x + w, y + h])
    return np.asarray(out[:n], dtype=np.float64)


def mirror_boxes(boxes: np.ndarray, width: int) -> np.ndarray:
    """2D boxes [K,4] of an image mirrored left-right (u -> W - u)."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    return np.column_stack([width - b[:, 2], b[:, 1], width - b[:, 0], b[:, 3]])


def detect(site: Site, objs: SceneObjects, rng: np.random.Generator, *, view: CameraView | None = None,
           noise: dict | None = None, objs_3d: SceneObjects | None = None) -> Detections:
    """Camera and LiDAR detections with the site's (or ``noise``-overridden) noise levels.

    ``objs``: the scene at the camera time (2D boxes); ``objs_3d``: the scene at the LiDAR time
    (3D boxes; default ``objs``, i.e. synchronised sensors). Track ids tie the two together.
    """
    c = site.config
    nz = {k: getattr(c, k) for k in ("box_noise_px", "miss_rate_2d", "miss_rate_3d", "false_positive_rate_2d",
                                     "false_positive_rate_3d", "center_noise_m", "size_noise_frac",
                                     "yaw_noise_deg")}
    nz.update(noise or {})
    W, H = site.width, site.height
    view = camera_view(site, objs) if view is None else view
    N = len(objs)
    # ---------------------------------------------------------------- 2D
    boxes, vis, trunc = _visible_boxes(site, view)
    wh = boxes[:, 2:] - boxes[:, :2]
    with np.errstate(invalid="ignore"):
        ok2 = (np.isfinite(boxes[:, 0]) & (vis >= c.min_visible_fraction) & (trunc <= c.max_truncation)
               & (wh[:, 0] >= c.min_box_px) & (wh[:, 1] >= c.min_box_px))
    u_miss2 = rng.uniform(size=N)
    idx2 = np.flatnonzero(ok2 & (u_miss2 >= nz["miss_rate_2d"]))
    clean = boxes[idx2]
    noisy = clean + rng.normal(0.0, 1.0, clean.shape) * nz["box_noise_px"]
    n_fp2 = int(rng.poisson(nz["false_positive_rate_2d"] * max(len(idx2), 1))) if nz["false_positive_rate_2d"] > 0 else 0
    fp2 = _false_2d(site, rng, n_fp2)
    b2 = np.vstack([noisy, fp2]) if len(fp2) else noisy
    b2[:, [0, 2]] = np.clip(b2[:, [0, 2]], 0, W)
    b2[:, [1, 3]] = np.clip(b2[:, [1, 3]], 0, H)
    b2[:, 2] = np.maximum(b2[:, 2], np.minimum(b2[:, 0] + 1, W))
    b2[:, 0] = np.minimum(b2[:, 0], b2[:, 2] - 1)
    b2[:, 3] = np.maximum(b2[:, 3], np.minimum(b2[:, 1] + 1, H))
    b2[:, 1] = np.minimum(b2[:, 1], b2[:, 3] - 1)
    ids2 = np.concatenate([idx2, -np.ones(len(fp2), dtype=np.int64)])
    clean2 = np.vstack([clean, fp2]) if len(fp2) else clean
    vis2 = np.concatenate([vis[idx2], np.zeros(len(fp2))])
    tr2 = np.concatenate([trunc[idx2], np.zeros(len(fp2))])
    cls2 = [str(objs.classes[i]) for i in idx2] + ["false_positive"] * len(fp2)
    # ---------------------------------------------------------------- 3D
    o3 = objs if objs_3d is None else objs_3d
    N3 = len(o3)
    b7l = world_to_lidar_box7(site, o3.box7) if N3 else np.zeros((0, 7))
    rng3 = np.hypot(b7l[:, 0], b7l[:, 1])
    vmin, vmax = np.radians(c.lidar_vfov_deg)
    tilt = math.asin(float(np.clip(-site.R_lidar_sensor[2, 0], -1, 1)))  # forward-axis pitch down
    with np.errstate(invalid="ignore", divide="ignore"):
        elev = np.arctan2(b7l[:, 2], rng3)
    in_fov = (elev >= vmin - abs(tilt) - math.radians(5)) & (elev <= vmax + abs(tilt) + math.radians(5))
    ok3 = (rng3 <= c.detection_range_3d) & in_fov & (rng3 > max(1.0, float(c.lidar_blind_radius_m)))
    u_miss3 = rng.uniform(size=N3)
    idx3 = np.flatnonzero(ok3 & (u_miss3 >= nz["miss_rate_3d"]))
    gt3 = b7l[idx3]
    det3 = gt3.copy()
    det3[:, :3] += rng.normal(0, 1, (len(idx3), 3)) * nz["center_noise_m"]
    det3[:, 3:6] *= np.clip(1 + rng.normal(0, 1, (len(idx3), 3)) * nz["size_noise_frac"], 0.5, 1.5)
    det3[:, 6] += rng.normal(0, 1, len(idx3)) * math.radians(nz["yaw_noise_deg"])
    if c.box3d_yaw == "dropped":  # exported without yaw (A9): length along LiDAR x
        det3[:, 6] = 0.0
    n_fp3 = int(rng.poisson(nz["false_positive_rate_3d"] * max(len(idx3), 1))) if nz["false_positive_rate_3d"] > 0 else 0
    if n_fp3:
        r = rng.uniform(5, c.detection_range_3d, n_fp3)
        a = rng.uniform(-np.pi, np.pi, n_fp3)
        fcls = rng.choice(list(CLASSES), size=n_fp3)
        sz = sample_sizes(rng, fcls)
        ground_z = -site.lidar_position[2]
        fp3 = np.column_stack([r * np.cos(a), r * np.sin(a), ground_z + sz[:, 2] / 2, sz,
                               rng.uniform(-np.pi, np.pi, n_fp3)])
        det3, gt3 = np.vstack([det3, fp3]), np.vstack([gt3, fp3])
    det3[:, 6] = (det3[:, 6] + np.pi) % (2 * np.pi) - np.pi
    ids3 = np.concatenate([idx3, -np.ones(n_fp3, dtype=np.int64)])
    cls3 = [str(o3.classes[i]) for i in idx3] + ["false_positive"] * n_fp3
    # ------------------------------------------------------ shuffle + GT matches
    p2, p3 = rng.permutation(len(ids2)), rng.permutation(len(ids3))
    t2 = np.where(ids2[p2] >= 0, objs.ids[np.maximum(ids2[p2], 0)] if N else -1, -1)
    t3 = np.where(ids3[p3] >= 0, o3.ids[np.maximum(ids3[p3], 0)] if N3 else -1, -1)
    match = (t2[:, None] == t3[None, :]) & (t2[:, None] >= 0)
    vel_w = o3.velocity[idx3] if o3.velocity is not None else np.zeros((len(idx3), 3))
    vel3 = np.vstack([vel_w @ site.T_lidar_world[:3, :3].T, np.zeros((n_fp3, 3))])
    return Detections(
        boxes_2d=b2[p2], ids_2d=t2.astype(np.int64), classes_2d=[cls2[i] for i in p2], clean_2d=clean2[p2],
        visibility_2d=vis2[p2], truncation_2d=tr2[p2], box7_3d=det3[p3], box7_gt_3d=gt3[p3],
        ids_3d=t3.astype(np.int64), classes_3d=[cls3[i] for i in p3],
        boxes_3d=box7_to_protocol(det3[p3], c.box_convention), match=match, view=view, velocity_3d=vel3[p3])
