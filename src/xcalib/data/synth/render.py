"""Camera images: a static background rendered once per site, objects painted per frame.

Background: every pixel's ray (distortion removed exactly) is intersected with the ground plane
and samples a top-down texture of the site (asphalt, lane markings, stop lines, crosswalks,
sidewalks, grass), with distance blur and haze; rays above the horizon get sky and a tree line.
Objects: shadows, then Lambert-shaded textured box faces (windows, wheels, lights; clothes for
people) painted far to near — the same order as the object-id mask used for the labels.
"""

from __future__ import annotations

import math

from typing import TYPE_CHECKING

import numpy as np

from ...geometry.boxes import box7_corners
from ...geometry.camera_models import CameraModel
from .detections import CameraView, _project
from .scene import SceneObjects

if TYPE_CHECKING:  # annotations only: the site module renders with this one (no import cycle)
    from .site import Site

__all__ = ["render_background", "render_frame", "ground_texture"]

_RES = 0.1   # metres per ground-texture pixel
_SHIFT = 4
_GRASS = np.array([92, 112, 62], np.float32)
_HAZE = np.array([196, 206, 214], np.float32)


def _noise(rng, shape, scale: int) -> np.ndarray:
    """Smooth value noise in [-1, 1] of ``shape`` (H, W) with features of ``scale`` pixels."""
    import cv2

    h, w = shape
    small = rng.uniform(-1, 1, (max(h // scale, 2) + 1, max(w // scale, 2) + 1)).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


def ground_texture(site: Site):
    """(texture [N,N,3] uint8 RGB, half extent E in metres); pixel (col,row) = ((x+E)/res, (E-y)/res)."""
    if "ground_tex" in site._cache:
        return site._cache["ground_tex"]
    import cv2

    c = site.config
    rng = np.random.default_rng([site.seed, 4242])
    E = float(c.scene_half_length) + 25.0
    N = int(round(2 * E / _RES))
    n1 = _noise(rng, (N, N), 300)[..., None]
    n2 = _noise(rng, (N, N), 12)[..., None]
    n3 = rng.normal(0, 1, (N, N, 1)).astype(np.float32)
    tex = _GRASS + n1 * np.array([18, 16, 10], np.float32) + n2 * 8 + n3 * 5

    def P(x, y):
        return np.array([[(xx + E) / _RES * 16, (E - yy) / _RES * 16] for xx, yy in zip(x, y)], np.int32)

    def rect(x0, y0, x1, y1, col, layer):
        cv2.fillConvexPoly(layer, P([x0, x1, x1, x0], [y0, y0, y1, y1]), col, cv2.LINE_AA, _SHIFT)

    w, bw, sw = c.lane_width, c.bike_lane_width, c.sidewalk_width
    na, nb = site.lanes_a, site.lanes_b
    ra, rb = na * w + bw, nb * w + bw          # carriageway half widths
    ha, hb = ra + sw, rb + sw                   # incl. sidewalks
    layer = np.zeros((N, N, 3), np.uint8)
    side = (170, 166, 158)
    rect(-E, -ha, E, ha, side, layer)
    rect(-hb, -E, hb, E, side, layer)
    road = (78, 78, 80)
    rect(-E, -ra, E, ra, road, layer)
    rect(-rb, -E, rb, E, road, layer)
    m = layer.any(axis=2)
    shade = 1.0 + 0.06 * n1[..., 0] + 0.05 * n2[..., 0]
    tex[m] = layer[m].astype(np.float32) * shade[m, None] + n3[m] * 4
    tex = np.clip(tex, 0, 255).astype(np.uint8)
    # sidewalk joints and curbs
    for s in (-1, 1):
        for x in np.arange(-E, E, 1.8):
            if abs(x) > hb:
                rect(x, s * ra, x + 0.05, s * ha, (135, 132, 126), tex)
        for y in np.arange(-E, E, 1.8):
            if abs(y) > ha:
                rect(s * rb, y, s * hb, y + 0.05, (135, 132, 126), tex)
    white, yellow = (232, 232, 226), (222, 186, 60)
    # stains and patches on the asphalt
    for _ in range(int(4 * E / 10)):
        x, y = rng.uniform(-E, E), rng.uniform(-max(ra, rb), max(ra, rb))
        if rng.uniform() < 0.5:
            x, y = y, x
        col = tuple(int(v) for v in (np.array(road) * rng.uniform(0.7, 1.15)))
        cv2.ellipse(tex, (int((x + E) / _RES), int((E - y) / _RES)),
                    (int(rng.uniform(3, 25)), int(rng.uniform(3, 12))), float(rng.uniform(0, 180)), 0, 360, col, -1,
                    cv2.LINE_AA)
    for road_id, (n, r_half, h_other) in {"a": (na, ra, hb), "b": (nb, rb, ha)}.items():
        def R(a0, l0, a1, l1, col, road_id=road_id):
            # rectangle in (along, lateral) coordinates of this road
            if road_id == "a":
                rect(a0, l0, a1, l1, col, tex)
            else:
                rect(l0, a0, l1, a1, col, tex)
        for s in (-1, 1):
            a_from, a_to = (h_other, E) if s > 0 else (-E, -h_other)
            # double yellow centre line, edge lines, dashed lane dividers
            R(a_from, 0.1, a_to, 0.25, yellow)
            R(a_from, -0.25, a_to, -0.1, yellow)
            for sgn in (-1, 1):
                R(a_from, sgn * n * w - 0.08, a_to, sgn * n * w + 0.08, white)
                for i in range(1, n):
                    for a in np.arange(a_from, a_to, 9.0):
                        R(a, sgn * i * w - 0.07, min(a + 3.0, a_to), sgn * i * w + 0.07, white)
            # stop line across the lanes approaching the intersection from this side
            stop = s * (h_other + 0.6)
            lat = (0.0, n * w) if s > 0 else (-n * w, 0.0)
            R(stop - 0.25, lat[0], stop + 0.25, lat[1], white)
            # zebra crossing over this road where the other road's sidewalk continues
            mid = s * (h_other - sw / 2)
            for lat0 in np.arange(-r_half + 0.3, r_half - 0.3, 1.0):
                R(mid - sw / 2 + 0.3, lat0, mid + sw / 2 - 0.3, lat0 + 0.5, white)
    # manholes
    for _ in range(6):
        x, y = rng.uniform(-40, 40), rng.uniform(-ra, ra)
        cv2.circle(tex, (int((x + E) / _RES), int((E - y) / _RES)), 3, (55, 55, 55), -1, cv2.LINE_AA)
    site._cache["ground_tex"] = (tex, E)
    return tex, E


def _pixel_rays(site: Site) -> np.ndarray:
    """World ray directions [H,W,3] of every pixel (distortion removed)."""
    from ...geometry.projection import undistort_pixels

    W, H = site.width, site.height
    u, v = np.meshgrid(np.arange(W, dtype=np.float64) + 0.5, np.arange(H, dtype=np.float64) + 0.5)
    uv = np.stack([u.ravel(), v.ravel()], axis=1) - 0.5
    if not hasattr(site.intrinsics, "has_distortion"):  # a camera model: its own rays (NaN: no ray)
        rays_c, ok = site.intrinsics.unproject(uv)
        rays_w = np.where(ok[:, None], rays_c @ site.T_world_cam[:3, :3].T, [0.0, 0.0, 1.0])  # no ray: sky
        return rays_w.reshape(H, W, 3)
    K = site.intrinsics.K
    if site.intrinsics.has_distortion:
        uv = undistort_pixels(uv, K, site.intrinsics.distortion)
    x = (uv[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    rays_c = np.stack([x, y, np.ones_like(x)], axis=1)
    return (rays_c @ site.T_world_cam[:3, :3].T).reshape(H, W, 3)


def render_background(site: Site) -> np.ndarray:
    """Static [H,W,3] uint8 RGB background of the site (no objects)."""
    import cv2

    tex, E = ground_texture(site)
    W, H = site.width, site.height
    d = _pixel_rays(site).astype(np.float32)
    C = site.camera_position
    dz = d[..., 2]
    ground = dz < -1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(ground, -C[2] / dz, np.inf).astype(np.float32)
    gx = C[0] + t * d[..., 0]
    gy = C[1] + t * d[..., 1]
    dist = t * np.linalg.norm(d, axis=-1)
    mapx = np.where(ground, (gx + E) / _RES - 0.5, -10).astype(np.float32)
    mapy = np.where(ground, (E - gy) / _RES - 0.5, -10).astype(np.float32)
    far = np.array([78, 96, 60], np.uint8)
    sharp = cv2.remap(tex, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=tuple(int(v) for v in far)).astype(np.float32)
    blurred = cv2.remap(cv2.GaussianBlur(tex, (0, 0), 4), mapx, mapy, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=tuple(int(v) for v in far)).astype(np.float32)
    f = float(site.intrinsics.fx)
    wblur = np.clip((dist * dist / (f * max(C[2], 0.5)) - 0.08) / 0.4, 0, 1)[..., None]
    img = sharp * (1 - wblur) + blurred * wblur
    haze = (1 - np.exp(-np.nan_to_num(dist, posinf=1e6) / 350.0))[..., None]
    img = img * (1 - haze) + _HAZE * haze
    # sky above the horizon, with a tree line just above it
    elev = np.degrees(np.arcsin(np.clip(dz / np.linalg.norm(d, axis=-1), -1, 1)))
    sky = ~ground | (dist > 4000)
    top = np.array([110, 150, 205], np.float32)
    g = np.clip(elev / 25.0, 0, 1)[..., None]
    sky_img = _HAZE * (1 - g) + top * g
    rng = np.random.default_rng([site.seed, 99])
    az = np.arctan2(d[..., 1], d[..., 0])
    # skyline 300 m away: tree crowns (smooth random heights) and a few rectangular buildings
    n_az = 2048
    grid = np.linspace(-math.pi, math.pi, n_az + 1)
    crowns = np.convolve(rng.uniform(6, 16, n_az + 40), np.ones(9) / 9, mode="same")[20:n_az + 21]
    crowns += rng.uniform(0, 2.5, n_az + 1)
    bld = np.zeros(n_az + 1)
    bcol = np.zeros((n_az + 1, 3), np.float32)
    for _ in range(int(rng.integers(3, 9))):
        a0 = int(rng.integers(0, n_az))
        wdt = int(rng.integers(15, 70))
        bld[a0:a0 + wdt] = rng.uniform(14, 40)
        bcol[a0:a0 + wdt] = rng.uniform(120, 190) * np.array([1.0, 0.98, 0.95]) * rng.uniform(0.9, 1.1, 3)
    idx = np.clip(((az + math.pi) / (2 * math.pi) * n_az).astype(np.int32), 0, n_az)
    h_tree = np.degrees(np.arctan(crowns[idx] / 300.0))
    h_bld = np.degrees(np.arctan(bld[idx] / 300.0))
    trees = (elev >= -0.2) & (elev < h_tree)
    building = (elev >= -0.2) & (elev < h_bld) & (h_bld > h_tree * 0.0)
    tree_col = np.array([62, 82, 58], np.float32) + rng.normal(0, 7, (H, W, 1)).astype(np.float32)
    sky_img = np.where(trees[..., None], tree_col * 0.7 + _HAZE * 0.3, sky_img)
    win = ((np.floor(elev * 12) % 2) == 0)[..., None]
    bimg = bcol[idx] * np.where(win, 0.92, 1.0)
    sky_img = np.where(building[..., None], bimg * 0.65 + _HAZE * 0.35, sky_img)
    img = np.where(sky[..., None], sky_img, img)
    return np.clip(img, 0, 255).astype(np.uint8)


# ----------------------------------------------------------------------------- objects
# Faces as corner indices (c00, c10, c11, c01) of box7_corners; u horizontal, v up.
_FACES = {"front": (3, 0, 4, 7), "back": (1, 2, 6, 5), "left": (0, 1, 5, 4), "right": (2, 3, 7, 6),
          "top": (6, 7, 4, 5)}
_NORMALS = {"front": (1, 0, 0), "back": (-1, 0, 0), "left": (0, 1, 0), "right": (0, -1, 0), "top": (0, 0, 1)}
_GLASS, _TYRE, _LIGHT, _TAIL = (38, 48, 60), (22, 22, 24), (235, 232, 205), (170, 25, 25)


def _decals(cls: str, face: str, colour) -> list[tuple[tuple, tuple]]:
    """[(u0, u1, v0, v1), rgb] texture patches of one face (drawn after the base colour)."""
    side = face in ("left", "right")
    flip = face == "right"  # u runs back->front on the right side, front->back on the left

    def U(a, b):
        return (1 - b, 1 - a) if not flip else (a, b)

    out = []
    if cls in ("car", "van"):
        if side:
            out.append(((*U(0.18, 0.82), 0.58, 0.9) if cls == "car" else (*U(0.02, 0.3), 0.55, 0.88), _GLASS))
            out += [((*U(0.12, 0.27), 0.0, 0.3), _TYRE), ((*U(0.73, 0.88), 0.0, 0.3), _TYRE)]
        elif face == "front":
            out += [((0.08, 0.92, 0.55, 0.9), _GLASS), ((0.05, 0.2, 0.3, 0.42), _LIGHT), ((0.8, 0.95, 0.3, 0.42), _LIGHT),
                    ((0.3, 0.7, 0.18, 0.38), (40, 40, 42))]
        elif face == "back":
            out += [((0.12, 0.88, 0.6, 0.88), _GLASS), ((0.04, 0.18, 0.36, 0.48), _TAIL), ((0.82, 0.96, 0.36, 0.48), _TAIL)]
        elif face == "top" and cls == "car":
            out.append(((0.15, 0.8, 0.1, 0.9), tuple(int(v * 0.8) for v in colour)))
    elif cls == "truck":
        if side:
            out += [((*U(0.0, 0.2), 0.0, 1.0), tuple(int(v * 0.85) for v in colour)), ((*U(0.02, 0.17), 0.6, 0.85), _GLASS),
                    ((*U(0.22, 1.0), 0.2, 1.0), (228, 228, 222)),
                    ((*U(0.06, 0.14), 0.0, 0.18), _TYRE), ((*U(0.7, 0.78), 0.0, 0.18), _TYRE),
                    ((*U(0.82, 0.9), 0.0, 0.18), _TYRE)]
        elif face == "front":
            out += [((0.06, 0.94, 0.6, 0.85), _GLASS), ((0.05, 0.18, 0.2, 0.3), _LIGHT), ((0.82, 0.95, 0.2, 0.3), _LIGHT)]
        elif face == "top":
            out.append(((0.0, 0.78, 0.0, 1.0), (235, 235, 230)))
        elif face == "back":
            out.append(((0.02, 0.98, 0.2, 1.0), (215, 215, 210)))
    elif cls == "bus":
        if side:
            for k in range(7):
                a = 0.04 + k * 0.132
                out.append(((*U(a, a + 0.115), 0.5, 0.86), _GLASS))
            out += [((*U(0.1, 0.2), 0.0, 0.2), _TYRE), ((*U(0.74, 0.84), 0.0, 0.2), _TYRE)]
        elif face == "front":
            out += [((0.05, 0.95, 0.4, 0.9), _GLASS), ((0.05, 0.18, 0.12, 0.22), _LIGHT), ((0.82, 0.95, 0.12, 0.22), _LIGHT)]
        elif face == "back":
            out += [((0.15, 0.85, 0.65, 0.88), _GLASS), ((0.04, 0.14, 0.2, 0.32), _TAIL), ((0.86, 0.96, 0.2, 0.32), _TAIL)]
    elif cls in ("pedestrian", "cyclist"):
        if face != "top":
            low = (40, 42, 60) if cls == "pedestrian" else (30, 30, 32)
            out += [((0.0, 1.0, 0.0, 0.47 if cls == "pedestrian" else 0.38), low),
                    ((0.2, 0.8, 0.86, 1.0), (205, 165, 135) if cls == "pedestrian" else (235, 235, 235)),
                    ((0.0, 0.2, 0.86, 1.0), (1, 1, 1)), ((0.8, 1.0, 0.86, 1.0), (1, 1, 1))]
        else:
            out.append(((0.25, 0.75, 0.25, 0.75), (45, 35, 28) if cls == "pedestrian" else (235, 235, 235)))
    return out


def render_frame(site: Site, objs: SceneObjects, view: CameraView) -> np.ndarray:
    """Background + the frame's objects (shadows first, then objects far to near)."""
    import cv2

    img = site.background.copy()
    if not len(view.order):
        return img
    H, W = img.shape[:2]
    sun = site.sun_dir
    cam = site.camera_position
    corners = box7_corners(objs.box7)
    # ---- shadows: object corners projected onto the ground along the sun direction
    sh = np.zeros((H, W), np.uint8)
    pts = corners[view.order].reshape(-1, 3)
    g = pts - sun[None] * (pts[:, 2:3] / max(sun[2], 0.2))
    g[:, 2] = 0.01
    uv, dep = _project(site, g)
    if _wide(site):  # a wide-angle lens images points beside and behind its optical plane (Z <= 0)
        dep = np.where(np.isfinite(uv).all(axis=1), np.linalg.norm(_to_camera(site, g), axis=1), -1.0)
    uv, dep = uv.reshape(-1, 8, 2), dep.reshape(-1, 8)
    for k in range(len(view.order)):
        if np.all(dep[k] > 0.3):
            hull = cv2.convexHull(np.round(uv[k] * 16).astype(np.int32))
            cv2.fillConvexPoly(sh, hull, 1, cv2.LINE_8, _SHIFT)
    ys, xs = np.nonzero(sh)
    if len(ys):
        sub = img[ys, xs].astype(np.uint16)
        img[ys, xs] = (sub * 140 >> 8).astype(np.uint8)
    # ---- faces and decals of every object, projected in one call
    polys, cols, owners = [], [], []
    for i in view.order:
        c8 = corners[i]
        cls = str(objs.classes[i])
        base = np.asarray(objs.colours[i], np.float32)
        yaw = objs.box7[i, 6]
        cy, sy = math.cos(yaw), math.sin(yaw)
        for face, (a, b, cc, d) in _FACES.items():
            nl = _NORMALS[face]
            n = np.array([cy * nl[0] - sy * nl[1], sy * nl[0] + cy * nl[1], nl[2]])
            q = c8[[a, b, cc, d]]
            if np.dot(n, cam - q.mean(axis=0)) <= 0:
                continue
            shade = 0.5 + 0.5 * max(0.0, float(np.dot(n, sun)))
            polys.append(q)
            cols.append(base * shade)
            owners.append((i, 1))
            for (u0, u1, v0, v1), rgb in _decals(cls, face, base):
                if rgb == (1, 1, 1):  # "transparent": background shows through (beside the head)
                    continue
                uu = np.array([u0, u1, u1, u0])[:, None]
                vv = np.array([v0, v0, v1, v1])[:, None]
                pq = (1 - uu) * (1 - vv) * q[0] + uu * (1 - vv) * q[1] + uu * vv * q[2] + (1 - uu) * vv * q[3]
                polys.append(pq)
                cols.append(np.asarray(rgb, np.float32) * shade)
                owners.append((i, 0))
    if _wide(site):
        return _fill_wide(img, site, np.asarray(polys), cols, owners)
    P = np.asarray(polys).reshape(-1, 3)
    uvp, _ = _project(site, P)
    uvp = np.round(uvp.reshape(-1, 4, 2) * 16).astype(np.int32)
    for k in range(len(polys)):
        col = tuple(int(v) for v in np.clip(cols[k], 0, 255))
        cv2.fillConvexPoly(img, uvp[k], col, cv2.LINE_AA, _SHIFT)
        if owners[k][1]:
            edge = tuple(int(v * 0.6) for v in col)
            cv2.polylines(img, [uvp[k]], True, edge, 1, cv2.LINE_AA, _SHIFT)
    return img


#: points per side of a face drawn through a wide-angle lens (its straight sides curve)
WIDE_FACE_SAMPLES = 8


def _wide(site: Site) -> bool:
    return isinstance(site.intrinsics, CameraModel) and not site.intrinsics.is_pinhole


def _to_camera(site: Site, pts_world: np.ndarray) -> np.ndarray:
    T = site.T_cam_world
    return pts_world.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]


def _fill_wide(img: np.ndarray, site: Site, polys: np.ndarray, cols: list, owners: list) -> np.ndarray:
    """Faces [K,4,3] (world) through a wide-angle lens: each side sampled ``WIDE_FACE_SAMPLES``
    times, so that the drawn face curves as the box outlines (the 2D boxes) do, and faces beside
    or behind the optical plane are drawn too; a face with a point outside the lens's valid
    region is skipped (never a wrapped polygon)."""
    import cv2

    if not len(polys):
        return img
    w = (np.arange(WIDE_FACE_SAMPLES) / WIDE_FACE_SAMPLES)[None, None, :, None]
    a, b = polys[:, :, None, :], np.roll(polys, -1, axis=1)[:, :, None, :]
    dense = (a + (b - a) * w).reshape(len(polys), -1, 3)  # [K, 4 * samples, 3] around the face
    pc = _to_camera(site, dense)
    uv, ok = site.intrinsics.project(pc)
    ok &= np.linalg.norm(pc, axis=1) > 0.3
    uv, ok = uv.reshape(len(polys), -1, 2), ok.reshape(len(polys), -1).all(axis=1)
    for k in np.flatnonzero(ok):
        pts = np.round(uv[k] * 16).astype(np.int32)
        col = tuple(int(v) for v in np.clip(cols[k], 0, 255))
        cv2.fillPoly(img, [pts], col, cv2.LINE_AA, _SHIFT)
        if owners[k][1]:
            cv2.polylines(img, [pts], True, tuple(int(v * 0.6) for v in col), 1, cv2.LINE_AA, _SHIFT)
    return img
