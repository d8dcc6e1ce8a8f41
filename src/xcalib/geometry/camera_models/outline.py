"""Image outlines of 3D boxes under any camera model (vectorised over poses and boxes).

Under a pinhole camera a box's image is the convex hull of its 8 projected corners, so the
rectangle around them is its 2D box. Under a wide-angle model straight edges curve: the
rectangle around the 8 corners misses the bulge of the edges (tens of pixels near the rim of a
fisheye image). Every model here maps the directions of its valid region one-to-one with a
radial profile that keeps increasing, so the extremes of u and v over a box's surface lie on
its edges. ``densify_box_edges`` samples the 12 edges of a box (8 points in another
arrangement: the 28 segments between them, which stay inside their convex hull and so never
move the outline wrongly); the samples find the segment and interval that hold each extreme of u
and v, which is then refined along that segment (golden section, then Newton on its slope): the
rectangle is the tight box of the projected box, exact to < 0.001 px (over 300 boxes 3-9 m from
a wide camera of each model: samples alone 0.06-0.18 px off at the 95th percentile and up to
20-60 px for an edge passing near the camera). The synthetic sites' 2D boxes
(``xcalib.data.synth.detections``) are made with the same exact extremes.
"""

from __future__ import annotations

import numpy as np

from .base import CameraModel

__all__ = ["densify_box_edges", "project_outline_rects", "outline_extremes", "outline_rects_and_extremes",
           "pixels_per_metre", "EDGE_SAMPLES", "STEP_DEG"]

#: points per segment between corners (besides the corners themselves)
EDGE_SAMPLES = 7
#: the same when many poses are scored at once (hypothesis search: IoU, a pixel does not matter)
COARSE_SAMPLES = 2
_COARSE_ABOVE = 4096  # poses x boxes
_I, _J = np.triu_indices(8, k=1)
# the 12 edges of xcalib.geometry.boxes.box7_corners' order (bottom face 0-3, top face 4-7)
_EI = np.array([0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3])
_EJ = np.array([1, 2, 3, 0, 5, 6, 7, 4, 4, 5, 6, 7])


def _box7_order(c: np.ndarray) -> bool:
    """Every outline [M,8,3] a parallelepiped in box7_corners' corner order (then its 12 edges are
    known); otherwise (a hull of 8 LiDAR points) all 28 segments between points are used."""
    scale = np.abs(c).max() + 1.0
    tol = 1e-6 * scale
    for a, b in (((1, 2, 5, 6), (0, 3, 4, 7)), ((2, 3, 6, 7), (1, 0, 5, 4)), ((4, 5, 6, 7), (0, 1, 2, 3))):
        v = c[:, list(a)] - c[:, list(b)]
        if np.abs(v - v[:, :1]).max() > tol:
            return False
    return True


def densify_box_edges(corners: np.ndarray, samples: int = EDGE_SAMPLES) -> np.ndarray:
    """[M,8,3] box corners -> [M, 8 + 12 * samples, 3]: the corners, then ``samples`` evenly
    spaced interior points of each edge (corners in box7_corners' order; 8 points in any other
    arrangement: of each of the 28 segments between them, which stay inside their convex hull).
    Outlines with other than 8 points (a hull of LiDAR points) are returned as they are."""
    c = np.asarray(corners, dtype=np.float64)
    if c.ndim != 3 or c.shape[1] != 8 or samples <= 0 or len(c) == 0:
        return c
    return _densify(c, samples, *((_EI, _EJ) if _box7_order(c) else (_I, _J)))


def _densify(c: np.ndarray, samples: int, ii: np.ndarray, jj: np.ndarray) -> np.ndarray:
    """:func:`densify_box_edges` with the segments (ii -> jj) already chosen."""
    if samples <= 0 or len(c) == 0:
        return c
    w = (np.arange(1, samples + 1) / (samples + 1))[None, None, :, None]
    a, b = c[:, ii, None, :], c[:, jj, None, :]
    return np.concatenate([c, (a + (b - a) * w).reshape(len(c), -1, 3)], axis=1)


class _DenseMemo:
    """The last outlines densified (one slot): a fit under a wide-angle model projects the same
    outlines at every step, residuals and Jacobian (only the pose moves), and densifying them and
    testing their corner order was ~5 % of a 20-frame calibration's CPU. :meth:`get` gives the
    segments (ii, jj) and ``_densify``'s points of ``c`` [M,8,3] with ``n`` points per edge, made
    again unless ``c`` has the dtype, shape and bytes of the last call's and the same ``n`` (the
    same computation on the same numbers: the same points to the bit). The points are read-only
    (shared by the calls). One slot per process, replaced whole in one assignment (threads at
    worst make them again)."""

    def __init__(self) -> None:
        self.slot = None

    def get(self, c: np.ndarray, n: int):
        key = (c.dtype.str, c.shape, int(n), c.tobytes())
        slot = self.slot
        if slot is not None and slot[0] == key:
            return slot[1], slot[2]
        edges = (_EI, _EJ) if _box7_order(c) else (_I, _J)
        if n <= 0 or not len(c):  # nothing to add: c itself (not kept, its flags not touched)
            return edges, c
        pts = _densify(c, n, *edges)
        pts.flags.writeable = False
        self.slot = (key, edges, pts)
        return edges, pts


_LAST_DENSE = _DenseMemo()


def project_outline_rects(corners: np.ndarray, R: np.ndarray, t: np.ndarray, camera: CameraModel,
                          size: tuple[int, int], *, clip: bool = True, min_distance: float = 0.3,
                          samples: int | None = None):
    """The 2D box of each 3D outline under ``camera`` for H poses.

    Args:
        corners: [M,S,3] LiDAR-frame outline points (the 8 corners of a box are densified for a
            non-pinhole model, see :func:`densify_box_edges`).
        R: [H,3,3] or [3,3]; t: [H,3] or [3] (LiDAR -> camera).
        size: (width, height) px used for clipping.
        min_distance: metres; a pinhole camera needs every point this far in front of it (Z), a
            wide-angle one this far from it and inside the model's valid region.
        samples: points per edge; None: by the angle the box spans (one per ``STEP_DEG``, at most
            ``EDGE_SAMPLES``; ``COARSE_SAMPLES`` at most when many poses are scored at once).
            The samples only find the segment and interval that hold each extreme: it is then
            refined along the segment (golden section, then Newton), so the rectangle is the tight
            box of the projected box (to < 0.001 px), not the samples' (a fraction of a pixel inside,
            tens of pixels for an edge passing near the camera). Not refined when many poses are
            scored at once (more than 4096 poses x boxes: the hypothesis search's IoU).
    Returns:
        rects [H,M,4] (NaN where invalid), valid [H,M]: every point projectable and a non-empty
        clipped rectangle (as :func:`xcalib.calib.boxproj.project_rects`).
    """
    return _outline_rects(corners, R, t, camera, (size, clip, min_distance, samples), False)[:2]


def outline_rects_and_extremes(corners: np.ndarray, R: np.ndarray, t: np.ndarray, camera: CameraModel,
                               size: tuple[int, int], *, min_distance: float = 0.3):
    """:func:`project_outline_rects` (clipped, samples by angle) and the outline points [H,M,4,3]
    (frame of ``corners``; [M,4,3] for one pose) at which each unclipped edge is taken (u min, v min,
    u max, v max), found in the same projection and refinement as the rectangle: at a valid
    rectangle what :func:`outline_extremes` finds, without projecting the outlines again (a fit's
    residuals and Jacobian at one pose). The points of box corners are None above 4096 poses x
    outlines (not refined there: call :func:`outline_extremes`). Returns (rects, valid, points)."""
    return _outline_rects(corners, R, t, camera, (size, True, min_distance, None), True)


def _outline_rects(corners, R, t, camera: CameraModel, how: tuple, points: bool):
    """:func:`project_outline_rects` with ``how`` = (size, clip, min_distance, samples) and, with
    ``points``, the points of :func:`outline_rects_and_extremes` (else None): (rects, valid, points)."""
    size, clip, min_distance, samples = how
    single, R, t, c = pose_batch(R, t, corners)
    H, M = len(R), len(c)
    where = None
    if M == 0:
        return no_rects(H, single) + (None,)
    geo = _Outline(camera, min_distance, H * M <= _COARSE_ABOVE)
    if camera.is_pinhole or c.shape[1] != 8:
        rect, front, where = geo.extremes(c, R, t, None, points=points)
    elif samples is not None:
        rect, front, _ = geo.extremes(c, R, t, int(samples))
    else:
        k = _samples_needed(c, R, t, COARSE_SAMPLES if H * M > _COARSE_ABOVE else EDGE_SAMPLES)
        if geo.refine:  # exact whatever the samples: one group (fewer, larger array operations)
            k = np.full_like(k, k.max())
        rect, front = np.empty((H, M, 4)), np.empty((H, M), dtype=bool)
        keep = points and geo.refine  # one group: its extremes' points are the outlines'
        for n in np.unique(k):
            sel = np.flatnonzero(k == n)
            rect[:, sel], front[:, sel], where = geo.extremes(c[sel], R, t, int(n), points=keep)
    valid = finish_rects(rect, front, size, clip)
    if single:
        return rect[0], valid[0], None if where is None else where[0]
    return rect, valid, where


def outline_extremes(corners: np.ndarray, R: np.ndarray, t: np.ndarray, camera: CameraModel) -> np.ndarray:
    """[M,4,3] for one pose (R [3,3], t [3]): the outline points (LiDAR frame, as given) at which
    each outline's image takes its u minimum, v minimum, u maximum and v maximum -- the points
    that define the edges of :func:`project_outline_rects`' rectangle (the same densified edges,
    each extreme refined along its edge), so the rectangle's derivative is theirs (an analytic
    Jacobian: at an extreme inside an edge the derivative along the edge is 0). Points that cannot
    be projected count as pixel 0 (such an outline is invalid and has no derivative anyway)."""
    c = np.asarray(corners, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64).reshape(1, 3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(1, 3)
    M = len(c)
    out = np.zeros((M, 4, 3))
    if M == 0:
        return out
    geo = _Outline(camera, 0.0, M <= _COARSE_ABOVE, nan_as_zero=True)
    if camera.is_pinhole or c.shape[1] != 8:
        return geo.extremes(c, R, t, None, points=True)[2][0]
    k = _samples_needed(c, R, t, COARSE_SAMPLES if M > _COARSE_ABOVE else EDGE_SAMPLES)
    if geo.refine:  # as project_outline_rects for one pose
        k = np.full_like(k, k.max())
    for n in np.unique(k):
        sel = np.flatnonzero(k == n)
        out[sel] = geo.extremes(c[sel], R, t, int(n), points=True)[2][0]
    return out


#: at most this angle (degrees, seen from the camera) between outline points along an edge
STEP_DEG = 3.0


def _samples_needed(c: np.ndarray, R: np.ndarray, t: np.ndarray, cap: int) -> np.ndarray:
    """[M] points per edge: the angle each box spans from the camera (its widest over the poses)
    divided by ``STEP_DEG``, at most ``cap``."""
    ctr = c.mean(1)
    radius = np.linalg.norm(c - ctr[:, None], axis=2).max(1)  # [M]
    X = np.matmul(R, ctr.T) + t[:, :, None]  # [H,3,M]
    dist = np.linalg.norm(X, axis=1).min(0)  # [M] nearest over the poses
    ang = np.degrees(2 * np.arcsin(np.clip(radius / np.maximum(dist, 1e-9), 0.0, 1.0)))
    return np.minimum(np.ceil(ang / STEP_DEG).astype(np.int64) - 1, cap).clip(0, None)


#: golden-section steps refining an extreme between the samples: the bracket shrinks to 0.618^n of
#: itself, the pixel error (quadratic in the distance to the true extreme) to ~0.002 of the samples'
REFINE_STEPS = 4
#: Newton steps after the golden section (to machine precision: a smooth rectangle)
NEWTON_STEPS = 2
_GOLD = (np.sqrt(5.0) - 1.0) / 2.0
_SIGN = np.array([1.0, 1.0, -1.0, -1.0])  # u min, v min, u max, v max as maxima of -u, -v, u, v
_AXIS = np.array([0, 1, 0, 1])


class _Outline:
    """The extremes of the image of outlines [M,S,3] for H poses: the samples' extremes and, for the
    8 corners of a box (densified edges), each refined along the segment that holds it."""

    def __init__(self, camera: CameraModel, min_distance: float, refine: bool, nan_as_zero: bool = False):
        self.camera, self.min_distance, self.refine, self.nan_as_zero = camera, min_distance, refine, nan_as_zero

    def _project(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uv, ok = self.camera.project(P)
        if self.camera.is_pinhole:
            ok = ok & (P[:, 2] > self.min_distance)
        else:
            ok = ok & (np.einsum("ij,ij->i", P, P) > self.min_distance ** 2)
        return uv, ok

    def extremes(self, c: np.ndarray, R: np.ndarray, t: np.ndarray, n: int | None, points: bool = False):
        """``n``: points per edge of the 8 corners ``c`` [M,8,3] (None: ``c`` [M,S,3] as it is, no
        refinement). Returns rect [H,M,4] (u min, v min, u max, v max, unclipped; NaN where a
        point cannot be projected, at least where ``front`` is False), front [H,M] (every point
        projectable) and, with ``points``, the outline points (frame of ``c``) [H,M,4,3] at which
        each extreme is taken (else None)."""
        (ii, jj), pts = ((_EI, _EJ), c) if n is None else _LAST_DENSE.get(c, n)
        H, M, S = len(R), len(c), pts.shape[1]
        X = np.matmul(R, pts.reshape(-1, 3).T) + t[:, :, None]  # [H,3,M*S]
        uv, ok = self._project(X.transpose(0, 2, 1).reshape(-1, 3))
        front = np.all(ok.reshape(H, M, S), axis=2)
        if self.nan_as_zero:
            uv = np.nan_to_num(uv, nan=0.0)
        u, v = uv[:, 0].reshape(H, M, S), uv[:, 1].reshape(H, M, S)
        refine = n is not None and self.refine
        if not refine and not points:  # NaN propagates through min / max (such an outline is invalid)
            return np.stack([u.min(2), v.min(2), u.max(2), v.max(2)], axis=-1), front, None
        w = np.empty((H, M, 4, S))  # the values to maximise: -u, -v, u, v
        np.negative(u, out=w[:, :, 0])
        np.negative(v, out=w[:, :, 1])
        w[:, :, 2], w[:, :, 3] = u, v
        if np.isnan(uv).any():  # an invalid outline: its extremes NaN as min / max gives them
            w[np.isnan(w).any(axis=3)] = np.nan
        best = w.max(axis=3)
        where = None
        if points:
            if self.nan_as_zero:  # uv went through nan_to_num: w holds no NaN or inf, nan_to_num(w) is w
                idx = np.argmax(w, axis=3)
            else:
                with np.errstate(invalid="ignore"):
                    idx = np.argmax(np.nan_to_num(w, nan=-np.inf), axis=3)
            where = pts[np.arange(M)[None, :, None], idx]  # [H,M,4,3]
        if refine:
            self._refine(c, (ii, jj, n), (R, t), w, best, where, front & np.isfinite(best).all(axis=2))
            return -_SIGN * best, front, where
        # not refined: the rect as without ``points`` (min / max), the points beside it
        return np.stack([u.min(2), v.min(2), u.max(2), v.max(2)], axis=-1), front, where

    def _refine(self, c, edges, pose, w, best, where, ok) -> None:
        """Golden section along the segments that may hold each extreme, in place on ``best``
        [H,M,4] (values to maximise) and ``where`` [H,M,4,3] (None: not kept). ``w`` [H,M,4,S]:
        the densified points' values; ``edges``: (ii, jj, n) the segments and their samples. A
        segment is refined where its samples' peak, or the vertex of a parabola through three
        neighbouring samples (within one sample of the middle one), reaches the sampled extreme:
        around that sample (from an end sample: only where the image still rises leaving it)."""
        ii, jj, n = edges
        R, t = pose
        ne, L = len(ii), n + 2
        G = np.empty((ne, L), dtype=np.int64)  # each segment's samples in order: corner, n inside, corner
        G[:, 0], G[:, -1] = ii, jj
        G[:, 1:-1] = 8 + np.arange(ne)[:, None] * n + np.arange(n)[None, :]
        seq = w[ok][:, :, G]  # [V,4,ne,L] the valid outlines only
        p = seq.argmax(axis=3)
        # the samples around the peak: gathers from the flat rows of seq (as take_along_axis along
        # axis 3 gathers them, without its broadcast index arrays over the other three axes)
        flat = seq.reshape(-1)
        row = np.arange(0, flat.size, L).reshape(p.shape)  # where each row of L samples starts
        y1 = flat.take(row + p)
        est = y1
        if L >= 3:  # the parabola through three samples around the peak
            pm = np.clip(p, 1, L - 2)[..., None]
            at = row + pm[..., 0]
            y0 = flat.take(at - 1)
            yc = flat.take(at)
            y2 = flat.take(at + 1)
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                curv = 2.0 * yc - y0 - y2
                xv = (y2 - y0) / (2.0 * curv)  # vertex, in samples from pm
                peak = yc + (y2 - y0) ** 2 / (8.0 * curv)
                near = (curv > 0) & (np.abs(pm[..., 0] + xv - p) <= 1.0) & np.isfinite(peak)
            est = np.where(near, np.maximum(peak, y1), y1)
        bv = best[ok]
        tol = 1e-9 * (1.0 + np.abs(bv))
        cand = est >= (bv - tol)[..., None]
        vi, k, e = np.nonzero(cand)
        if not len(vi):
            return
        hv, mv = np.nonzero(ok)
        h, m = hv[vi], mv[vi]
        y1c = y1[vi, k, e]
        pe = p[vi, k, e]
        a, b = np.maximum(pe - 1, 0) / (n + 1.0), np.minimum(pe + 1, L - 1) / (n + 1.0)
        A, B = c[m, ii[e]], c[m, jj[e]]  # [N,3] the segment (frame of c)
        Rh, th = R[h], t[h]
        ax, sg = _AXIS[k], _SIGN[k]

        def f(s):
            P = A + (B - A) * s[:, None]
            X = np.einsum("nij,nj->ni", Rh, P) + th
            uv, okp = self._project(X)
            val = -sg * uv[np.arange(len(s)), ax]
            return np.where(okp & np.isfinite(val), val, -np.inf)

        end = (pe == 0) | (pe == L - 1)  # peak at a corner: refine only where the image rises leaving it
        if end.any():
            s0 = np.where(pe == 0, 0.0, 1.0)
            eps = np.where(pe == 0, 1e-6, -1e-6) / (n + 1.0)
            keep = ~end | (f(s0 + eps) > y1c)
            h, m, k, a, b, A, B, Rh, th, ax, sg = (x[keep] for x in (h, m, k, a, b, A, B, Rh, th, ax, sg))
            if not len(h):
                return
        a0, b0 = a, b
        x1, x2 = b - _GOLD * (b - a), a + _GOLD * (b - a)
        f1, f2 = f(x1), f(x2)
        bs, bf = np.where(f1 >= f2, x1, x2), np.maximum(f1, f2)
        for _ in range(REFINE_STEPS):
            left = f1 >= f2  # the maximum lies in [a, x2]
            a, b = np.where(left, a, x1), np.where(left, x2, b)
            keep_x, keep_f = np.where(left, x1, x2), np.where(left, f1, f2)
            nx = np.where(left, b - _GOLD * (b - a), a + _GOLD * (b - a))
            nf = f(nx)
            x1, f1 = np.where(left, nx, keep_x), np.where(left, nf, keep_f)
            x2, f2 = np.where(left, keep_x, nx), np.where(left, keep_f, nf)
            better = nf > bf
            bs, bf = np.where(better, nx, bs), np.where(better, nf, bf)
        bs, bf = self._newton(bs, bf, (A, B, Rh, th, ax, sg), (a0, b0))
        gain = bf > best[h, m, k]
        h, m, k, bs, bf, A, B = (x[gain] for x in (h, m, k, bs, bf, A, B))
        # several segments for one extreme: the largest wins
        key = (h * best.shape[1] + m) * 4 + k
        order = np.lexsort((-bf, key))
        first = np.ones(len(order), dtype=bool)
        first[1:] = key[order][1:] != key[order][:-1]
        sel = order[first]
        h, m, k, bs, bf, A, B = (x[sel] for x in (h, m, k, bs, bf, A, B))
        best[h, m, k] = bf
        if where is not None:
            where[h, m, k] = A + (B - A) * bs[:, None]


    def _newton(self, s, fs, seg, bracket):
        """:data:`NEWTON_STEPS` Newton steps on d value / ds = 0 from the golden section's best
        ``s`` (value ``fs``), each kept only inside the bracket and where it does not lower the
        value: the extreme to machine precision, so the rectangle is a smooth function of the pose
        (its derivative the outline point's, as the analytic Jacobian takes it)."""
        A, B, Rh, th, ax, sg = seg
        lo, hi = bracket
        D = np.einsum("nij,nj->ni", Rh, B - A)  # d X_cam / ds
        rows = np.arange(len(s))

        def slope(x):
            X = np.einsum("nij,nj->ni", Rh, A + (B - A) * x[:, None]) + th
            _, J, okp = self.camera.project_jacobian(X)
            return np.where(okp, -sg * np.einsum("nj,nj->n", J[rows, ax], D), np.nan)

        def value(x):
            X = np.einsum("nij,nj->ni", Rh, A + (B - A) * x[:, None]) + th
            uv, okp = self._project(X)
            return np.where(okp, -sg * uv[rows, ax], -np.inf)

        step = 1e-7 * (hi - lo)
        for _ in range(NEWTON_STEPS):
            g = slope(s)
            g2 = slope(s + step)
            with np.errstate(invalid="ignore", divide="ignore"):
                nxt = s - g * step / (g2 - g)
            inside = np.isfinite(nxt) & (nxt >= lo) & (nxt <= hi) & ((g2 - g) < 0)
            nxt = np.where(inside, nxt, s)
            fn = value(nxt)
            up = inside & (fn >= fs - 1e-9 * (1.0 + np.abs(fs)))
            s, fs = np.where(up, nxt, s), np.where(up, fn, fs)
        return s, fs


def pose_batch(R, t, corners) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray]:
    """``(single, R [H,3,3], t [H,3], corners)`` as float64: one pose ([3,3], [3]) or H poses."""
    single = np.ndim(R) == 2
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    return single, R, t, np.asarray(corners, dtype=np.float64)


def no_rects(H: int, single: bool):
    """The rects [H,0,4] and valid [H,0] of no boxes (the first pose's alone when ``single``)."""
    out = np.zeros((H, 0, 4)), np.zeros((H, 0), dtype=bool)
    return (out[0][0], out[1][0]) if single else out


def finish_rects(rect: np.ndarray, front: np.ndarray, size: tuple[int, int], clip: bool) -> np.ndarray:
    """Clip rects [...,4] (px) to the image ``size`` (W, H) when ``clip``, in place; return valid
    [...]: ``front`` and wider and taller than 1 px; invalid rects become NaN (in place)."""
    if clip:  # in place on the strided views of the x and y edges (the same clip, no gather / scatter copies)
        W, Hh = size
        xs, ys = rect[..., 0::2], rect[..., 1::2]
        np.clip(xs, 0.0, W, out=xs)
        np.clip(ys, 0.0, Hh, out=ys)
    with np.errstate(invalid="ignore"):
        valid = front & (rect[..., 2] - rect[..., 0] > 1.0) & (rect[..., 3] - rect[..., 1] > 1.0)
    rect[~valid] = np.nan
    return valid


def pixels_per_metre(camera: CameraModel, points: np.ndarray) -> np.ndarray:
    """[N] image scale (px per metre, square root of the area scale) of a small patch facing the
    camera at camera-frame ``points`` [N,3]: ``f / Z`` on the axis of a pinhole camera; for a
    fisheye, the local scale its Jacobian gives (NaN outside the valid region)."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    _, J, valid = camera.project_jacobian(P)
    d = np.linalg.norm(P, axis=1, keepdims=True)
    r = P / np.where(d > 0, d, 1.0)
    # an orthonormal basis of the plane perpendicular to the ray
    helper = np.where(np.abs(r[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(r, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(r, e1)
    a = np.einsum("nij,nj->ni", J, e1)
    b = np.einsum("nij,nj->ni", J, e2)
    det = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    out = np.sqrt(det)
    out[~valid] = np.nan
    return out
