"""Label-free 3D object boxes from LiDAR point clouds (pure numpy/scipy, OpenCV's minimum-area
rectangle).

The classical pipeline of the ROS perception stacks:

1. ground: a RANSAC plane below the sensor (normal within ``max_ground_tilt_deg`` of the
   LiDAR's z), refined by least squares and corrected per ``ground_cell_m`` cell (slopes, kerbs);
   points between ``ground_tol_m`` and ``max_height_m`` over the ground are object points;
2. static LiDAR (roadside): a background model over the recording (:class:`Background`: the
   points whose voxel, or an x-y neighbour, is occupied in at least ``background_fraction`` of
   the frames are dropped, and so is a cluster whose points mostly lie in voxels occupied in
   half that share) removes buildings, poles, vegetation and parked cars; a moving LiDAR skips it;
3. clustering: connected components of the occupied ``cell_m`` x-y grid (8-neighbour) of the
   points up to ``max_height_m`` + 2 m (a cluster taller than ``max_height_m`` is a tree, pole or
   building, and dropped whole); a cluster longer than 6 m is cut where its points leave a gap of
   ``split_gap_m`` along its long axis (parked cars in a row);
4. boxes: minimum-area rectangle of each cluster's footprint (yaw about the LiDAR z), bottom on
   the ground, top at the highest point; size filters keep traffic objects (pedestrian to bus).

Boxes are box7 ``[M, 7]`` (cx, cy, cz, length, width, height, yaw; LiDAR frame, metres,
radians); see :mod:`xcalib.geometry.boxes`.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = ["LidarDetectConfig", "GroundPlane", "Background", "fit_ground", "build_background", "lidar_boxes",
           "is_static_recording"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LidarDetectConfig:
    """Label-free LiDAR object extraction. Distances in metres, angles in degrees.

    ``mode``: static (roadside: background model over the recording), moving (ground removal
    and clustering only) or auto (static when the clouds of the recording overlap).
    ``complete_vehicles``: a LiDAR sees one or two faces of a vehicle; a vehicle-sized cluster
    (top >= ``vehicle_min_top_m``, footprint >= 1.4 m) seen along one side only gets
    ``vehicle_width_m``, seen at one end only ``vehicle_length_m``, the hidden part placed away
    from the sensor; ``"auto"``: for a high LiDAR (below), whose side views of vehicles are lines.

    Range-adaptive (for high, sparse LiDARs such as roadside ones): from above, a LiDAR's rings
    cross a roof or bonnet ``r**2 * beam_step / (sensor height - roof_height_m)`` metres apart
    along the line of sight, so points at range ``r`` are linked over that radial distance
    (at least ``cell_m``, at most ``max_link_m``; the beam step is measured from the cloud's
    elevation histogram, see :func:`beam_step`; a sensor less than 1 m above ``roof_height_m``
    links over ``cell_m`` only); an object needs ``min_points`` points up to
    ``min_points_range_m`` and fewer beyond, as its points thin with 1/r**2, never fewer than
    ``min_points_far``; objects from ``min_object_height_high_m`` tall (glass and dark roofs
    return little from above); ground cells where no ground is seen (the blind ring, shadows)
    take their neighbours' heights; a vehicle side seen as a line is completed rather than dropped as thin;
    a cluster over ``tall_min_m`` shorter than ``tall_min_length_m`` is dropped (from above, a
    bus or truck shows its long footprint: this is a tree crown, a sign or a gantry).
    """

    mode: Literal["auto", "static", "moving"] = "auto"
    max_range_m: float = 90.0
    max_ground_tilt_deg: float = 30.0
    ground_tol_m: float = 0.25
    ground_cell_m: float = 4.0
    max_height_m: float = 4.5
    cell_m: float = 0.4
    min_points: int = 10
    background_voxel_m: float = 0.5
    background_fraction: float = 0.7
    background_frames: int = 60
    min_object_height_m: float = 0.9
    min_object_height_high_m: float = 0.6
    max_length_m: float = 14.0
    max_width_m: float = 3.2
    max_gap_to_ground_m: float = 0.8
    min_width_m: float = 0.3
    split_gap_m: float = 0.3
    max_link_m: float = 2.0
    roof_height_m: float = 1.5
    min_points_range_m: float = 25.0
    min_points_far: int = 4
    complete_vehicles: bool | Literal["auto"] = "auto"
    vehicle_min_top_m: float = 0.8
    tall_min_m: float = 2.6
    tall_min_length_m: float = 4.5
    vehicle_width_m: float = 1.8
    vehicle_length_m: float = 4.4
    seed: int = 0

    def __post_init__(self):
        if self.mode not in ("auto", "static", "moving"):
            raise ValueError(f"mode must be auto, static or moving, got {self.mode!r}")
        if not (0 < self.cell_m <= 2 and 0 < self.background_voxel_m <= 2 and 0 < self.ground_tol_m < 1):
            raise ValueError("cell_m, background_voxel_m in (0, 2] m and ground_tol_m in (0, 1) m wanted")
        if not 0 < self.background_fraction <= 1:
            raise ValueError(f"background_fraction must be in (0, 1], got {self.background_fraction}")


@dataclass(frozen=True)
class GroundPlane:
    """``normal . p + d`` = height over the plane (normal [3] unit, the sensor's side positive),
    plus per-cell offsets: ``offsets`` [nx, ny] over a grid from ``origin`` [2] with ``cell_m``."""

    normal: np.ndarray
    d: float
    origin: np.ndarray | None = None
    cell_m: float = 4.0
    offsets: np.ndarray | None = None

    def height(self, xyz: np.ndarray) -> np.ndarray:
        """Height of points [N, 3] over the ground (metres)."""
        h = xyz @ self.normal + self.d
        if self.offsets is not None:
            ij = np.floor((xyz[:, :2] - self.origin) / self.cell_m).astype(np.int64)
            ok = np.all((ij >= 0) & (ij < self.offsets.shape), axis=1)
            h[ok] -= self.offsets[ij[ok, 0], ij[ok, 1]]
        return h

    def z_at(self, xy: np.ndarray) -> np.ndarray:
        """LiDAR z of the ground under points [N, 2]."""
        n = self.normal
        z = -(xy @ n[:2] + self.d) / n[2]
        if self.offsets is not None:
            ij = np.floor((xy - self.origin) / self.cell_m).astype(np.int64)
            ok = np.all((ij >= 0) & (ij < self.offsets.shape), axis=1)
            z[ok] += self.offsets[ij[ok, 0], ij[ok, 1]] / n[2]
        return z


def _in_range(xyz: np.ndarray, max_range: float) -> np.ndarray:
    return np.all(np.isfinite(xyz), axis=1) & (np.hypot(xyz[:, 0], xyz[:, 1]) <= max_range)


def fit_ground(xyz: np.ndarray, config: LidarDetectConfig = LidarDetectConfig(), *,
               rng: np.random.Generator | None = None) -> GroundPlane:
    """The ground: RANSAC (vectorised over 256 hypotheses on <= 6000 points; normal within
    ``max_ground_tilt_deg`` of z, the sensor no more than 1 m below it), least-squares refit on
    the inliers, then per-cell offsets for slopes and hills (the 5th percentile of the heights
    within 3 m of the plane in each ``ground_cell_m`` cell, median-filtered over 3 x 3 cells so a
    vehicle filling a cell does not lift its ground; +-3 m at most)."""
    rng = rng or np.random.default_rng(config.seed)
    p = np.asarray(xyz, dtype=np.float64)[:, :3]
    p = p[_in_range(p, config.max_range_m)]
    if len(p) < 50:
        raise ValueError(f"{len(p)} points in range: too few to find the ground")
    sub = p[rng.choice(len(p), min(len(p), 6000), replace=False)]
    tri = sub[rng.integers(0, len(sub), (256, 3))]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-9
    n, tri = n[ok] / norm[ok, None], tri[ok]
    n *= np.sign(n[:, 2:3] + 1e-12)
    d = -np.einsum("ij,ij->i", n, tri[:, 0])
    flat = (n[:, 2] >= np.cos(np.radians(config.max_ground_tilt_deg))) & (d > -1.0)  # not far above the sensor
    if not flat.any():
        raise ValueError("no ground plane below the sensor within the allowed tilt")
    n, d = n[flat], d[flat]
    inl = np.abs(sub @ n.T + d) < config.ground_tol_m
    best = int(np.argmax(inl.sum(0)))
    pts = sub[inl[:, best]]
    c = pts.mean(0)
    nrm = np.linalg.svd(pts - c, full_matrices=False)[2][2]
    nrm *= np.sign(nrm[2]) if nrm[2] != 0 else 1.0
    if nrm[2] < np.cos(np.radians(config.max_ground_tilt_deg)):
        nrm = n[best]
    dd = float(-nrm @ c)
    plane = GroundPlane(nrm, dd)
    h = plane.height(p)
    near = np.abs(h) < 3.0
    lo = p[:, :2].min(0)
    ij = np.floor((p[near, :2] - lo) / config.ground_cell_m).astype(np.int64)
    shape = tuple(np.floor((p[:, :2].max(0) - lo) / config.ground_cell_m).astype(int) + 1)
    flat_ij = ij[:, 0] * shape[1] + ij[:, 1]
    off = np.full(shape[0] * shape[1], np.nan)
    if len(flat_ij):
        order = np.lexsort((h[near], flat_ij))
        keys, start, counts = np.unique(flat_ij[order], return_index=True, return_counts=True)
        q = start + (0.05 * (counts - 1)).astype(np.int64)
        ok = counts >= 5
        off[keys[ok]] = h[near][order][q[ok]]
    off = _nan_median3(off.reshape(shape))
    if dd - config.roof_height_m >= 1.0:  # a high LiDAR's blind ring and shadows: neighbours, not the plane
        off = _fill_nan(off)
    return GroundPlane(nrm, dd, lo, config.ground_cell_m, np.clip(np.nan_to_num(off, nan=0.0), -3.0, 3.0))


def _fill_nan(a: np.ndarray, rounds: int = 3) -> np.ndarray:
    """Cells with no ground seen (the blind ring under a high sensor, shadows behind vehicles)
    take the median of their measured neighbours, grown outwards ring by ring, instead of the
    plane: a plane fitted to a whole junction is off by a metre on a local slope."""
    a = a.copy()
    for _ in range(rounds):
        miss = np.isnan(a)
        if not miss.any() or miss.all():
            break
        grown = _nan_median3(a)
        a[miss] = grown[miss]
    return a


def _nan_median3(a: np.ndarray) -> np.ndarray:
    """3 x 3 median of a 2D grid ignoring NaN (all-NaN neighbourhoods stay NaN)."""
    pad = np.pad(a, 1, constant_values=np.nan)
    stack = np.stack([pad[i:i + a.shape[0], j:j + a.shape[1]] for i in range(3) for j in range(3)])
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmedian(stack, axis=0)


def _voxel_keys(xyz: np.ndarray, size: float) -> np.ndarray:
    v = np.floor(xyz / size).astype(np.int64) + (1 << 20)
    return (v[:, 0] << 42) | (v[:, 1] << 21) | v[:, 2]


_XY_STEPS = np.array([dx * (1 << 42) + dy * (1 << 21) for dx in (-1, 0, 1) for dy in (-1, 0, 1)], dtype=np.int64)


@dataclass(frozen=True)
class Background:
    """A static LiDAR's scene without its traffic: every voxel (sorted int64 ``keys``,
    ``voxel_m`` edge) seen above the ground, with the share of the ``frames`` clouds it was
    occupied in (``fraction``). ``threshold``: the share from which a voxel is background."""

    keys: np.ndarray
    fraction: np.ndarray
    voxel_m: float
    frames: int
    threshold: float

    def _lookup(self, k: np.ndarray) -> np.ndarray:
        if not len(self.keys):
            return np.zeros(len(k))
        i = np.clip(np.searchsorted(self.keys, k), 0, len(self.keys) - 1)
        return np.where(self.keys[i] == k, self.fraction[i], 0.0)

    def fraction_of(self, xyz: np.ndarray) -> np.ndarray:
        """Per point: the share of the recording its voxel was occupied in (0-1)."""
        return self._lookup(_voxel_keys(np.asarray(xyz)[:, :3], self.voxel_m))

    def mask(self, xyz: np.ndarray) -> np.ndarray:
        """True for background points: their voxel or one of its 8 x-y neighbours is occupied in
        at least ``threshold`` of the recording."""
        k = _voxel_keys(np.asarray(xyz)[:, :3], self.voxel_m)
        out = np.zeros(len(k), dtype=bool)
        for step in _XY_STEPS:
            out |= self._lookup(k + step) >= self.threshold
        return out


def build_background(clouds, config: LidarDetectConfig = LidarDetectConfig(), *,
                     ground: GroundPlane | None = None) -> Background:
    """Background of a static LiDAR from ``clouds`` (an iterable of [P, >=3] arrays): the
    occupancy share of every voxel above ``ground`` (default: each cloud's own)."""
    keys_all, n = [], 0
    for c in clouds:
        xyz = np.asarray(c, dtype=np.float64)[:, :3]
        xyz = xyz[_in_range(xyz, config.max_range_m)]
        if len(xyz) >= 50:
            xyz = xyz[(ground or fit_ground(xyz, config)).height(xyz) > config.ground_tol_m]
        keys_all.append(np.unique(_voxel_keys(xyz, config.background_voxel_m)))
        n += 1
    if n == 0:
        return Background(np.zeros(0, np.int64), np.zeros(0), config.background_voxel_m, 0, config.background_fraction)
    k, cnt = np.unique(np.concatenate(keys_all), return_counts=True)
    return Background(k, cnt / n, config.background_voxel_m, n, config.background_fraction)


def is_static_recording(clouds, config: LidarDetectConfig = LidarDetectConfig()) -> bool:
    """True when the clouds come from a LiDAR that does not move: the occupied 1 m voxels of
    the first and the last cloud overlap by at least half (Jaccard). Needs >= 2 clouds."""
    cs = list(clouds)
    if len(cs) < 2:
        return False
    sets = []
    for c in (cs[0], cs[-1]):
        xyz = np.asarray(c, dtype=np.float64)[:, :3]
        sets.append(np.unique(_voxel_keys(xyz[_in_range(xyz, config.max_range_m)], 1.0)))
    inter = len(np.intersect1d(sets[0], sets[1], assume_unique=True))
    return inter / max(1, len(np.union1d(sets[0], sets[1]))) >= 0.5


def beam_step(xyz: np.ndarray) -> float:
    """A spinning LiDAR's vertical beam spacing (radians) from one cloud: the median gap between
    adjacent peaks of the points' elevation histogram (0.05 deg bins, points beyond 3 m);
    0.0 when the cloud shows no ring structure (fewer than 8 peaks)."""
    p = np.asarray(xyz, dtype=np.float64)[:, :3]
    r = np.hypot(p[:, 0], p[:, 1])
    ok = np.isfinite(r) & (r > 3.0) & np.isfinite(p[:, 2])
    if ok.sum() < 1000:
        return 0.0
    el = np.degrees(np.arctan2(p[ok, 2], r[ok]))
    hist, edges = np.histogram(el, bins=np.arange(-60.0, 30.0, 0.05))
    floor = max(20, 0.2 * np.percentile(hist[hist > 0], 90))
    pk = np.nonzero((hist[1:-1] >= hist[:-2]) & (hist[1:-1] > hist[2:]) & (hist[1:-1] > floor))[0] + 1
    if len(pk) < 8:
        return 0.0
    return float(np.radians(np.median(np.diff(edges[pk]))))


def _radial_link(r: np.ndarray, step: float, height: float, config: LidarDetectConfig) -> np.ndarray:
    """Radial link distance (m) at ranges ``r``: the gap between rings on a roof seen from above."""
    h_eff = height - config.roof_height_m
    if step <= 0 or h_eff < 1.0:
        return np.full(len(r), config.cell_m)
    return np.clip(r ** 2 * step / h_eff, config.cell_m, max(config.cell_m, config.max_link_m))


def _polar_clusters(xy: np.ndarray, link, cell: float, min_points) -> tuple[np.ndarray, np.ndarray]:
    """As :func:`_clusters`, with points linked when within ``1.5 * cell`` across the line of
    sight and ``1.5 * link(r)`` along it (``link`` the radial link distance at range r): pairs
    from a k-d tree on the points moved radially to s(r) (the integral of cell / link, so a
    radial gap of ``link`` becomes ``cell``), kept by that criterion, then connected components."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    r = np.maximum(np.hypot(xy[:, 0], xy[:, 1]), 1e-6)
    grid = np.linspace(0.0, float(r.max()) + 1.0, 2048)
    dens = cell / link(grid)
    s_grid = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(grid))])
    s = np.interp(r, grid, s_grid)
    p = xy / r[:, None] * s[:, None]  # across the line of sight shrunk by s/r <= 1: a superset of the pairs
    pairs = cKDTree(p).query_pairs(1.5 * cell * np.sqrt(2.0), output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    cross = np.abs(xy[i, 0] * xy[j, 1] - xy[i, 1] * xy[j, 0]) / np.maximum(r[i], r[j])  # ~ r * dphi
    keep = (np.abs(s[i] - s[j]) <= 1.5 * cell) & (cross <= 1.5 * cell)
    n = len(xy)
    g = coo_matrix((np.ones(int(keep.sum())), (i[keep], j[keep])), shape=(n, n))
    _, pl = connected_components(g, directed=False)
    cnt = np.bincount(pl)
    ok = cnt[pl] >= (min_points if np.isscalar(min_points) else min_points(pl, cnt))
    idx = np.nonzero(ok)[0]
    order = idx[np.argsort(pl[idx], kind="stable")]
    _, starts = np.unique(pl[order], return_index=True)
    return order, np.append(starts, len(order))


def _min_points(r: np.ndarray, config: LidarDetectConfig) -> np.ndarray:
    """Points an object needs at range ``r``: ``min_points`` up to ``min_points_range_m``, then
    falling as 1/r**2 (as its points do), never below ``min_points_far``."""
    scale = np.minimum(1.0, (config.min_points_range_m / np.maximum(r, 1e-6)) ** 2)
    return np.maximum(config.min_points_far, np.ceil(config.min_points * scale))


def _clusters(xy: np.ndarray, cell: float, min_points) -> tuple[np.ndarray, np.ndarray]:
    """(order of points sorted by cluster, start offsets [C+1]) of 8-connected grid components
    with at least ``min_points`` points (a number, or a function of the cluster's points)."""
    from scipy import ndimage

    lo = xy.min(0)
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    shape = tuple(ij.max(0) + 1)
    occ = np.zeros(shape, dtype=bool)
    occ[ij[:, 0], ij[:, 1]] = True
    lab, _ = ndimage.label(occ, structure=np.ones((3, 3), dtype=bool))
    pl = lab[ij[:, 0], ij[:, 1]]
    cnt = np.bincount(pl)
    keep = cnt[pl] >= (min_points if np.isscalar(min_points) else min_points(pl, cnt))
    idx = np.nonzero(keep)[0]
    order = idx[np.argsort(pl[idx], kind="stable")]
    _, starts = np.unique(pl[order], return_index=True)
    return order, np.append(starts, len(order))


def _min_area_rect(xy: np.ndarray) -> tuple[float, float, float, float, float]:
    """(cx, cy, length, width, yaw) of the smallest rectangle around points [N, 2]; length >= width,
    yaw of the length axis in [-pi/2, pi/2)."""
    import cv2

    (cx, cy), (w, h), ang = cv2.minAreaRect(xy.astype(np.float32))
    yaw = np.radians(ang)
    if h > w:
        w, h, yaw = h, w, yaw + np.pi / 2
    yaw = (yaw + np.pi / 2) % np.pi - np.pi / 2
    return float(cx), float(cy), float(w), float(h), float(yaw)


def _split_at_gaps(xy: np.ndarray, idx: np.ndarray, gap: float, sight: np.ndarray, ring_gap: float,
                   min_points: int) -> list[np.ndarray]:
    """A long cluster (a row of parked cars merged by the grid) cut where its points leave a gap
    of at least ``gap`` metres along its long axis, plus ``ring_gap`` (the extra radial link)
    times the axis's share along the line of sight ``sight`` [2] (unit); pieces under
    ``min_points`` are dropped."""
    p = xy[idx]
    c = p - p.mean(0)
    axis = np.linalg.svd(c, full_matrices=False)[2][0]
    gap = gap + max(0.0, ring_gap) * abs(float(axis @ sight))
    t = c @ axis
    order = np.argsort(t)
    cuts = np.nonzero(np.diff(t[order]) >= gap)[0] + 1
    return [idx[o] for o in np.split(order, cuts) if len(o) >= min_points]


def _complete_vehicle(cx, cy, length, width, yaw, top, config: LidarDetectConfig):
    """The footprint of a vehicle seen from one side or one end, completed away from the sensor."""
    if top < config.vehicle_min_top_m or length < 1.4:
        return cx, cy, length, width, yaw
    u = np.array([np.cos(yaw), np.sin(yaw)])  # length axis
    v = np.array([-u[1], u[0]])               # width axis
    c = np.array([cx, cy])
    away = np.sign(v @ c) or 1.0
    if length >= 2.5 and width < 0.6 * config.vehicle_width_m:  # one long side seen
        c = c + away * v * (config.vehicle_width_m - width) / 2
        width = config.vehicle_width_m
    elif length < 2.5 and width < 0.8:  # one end seen: the face is the width, the length is hidden
        c = c + away * v * (config.vehicle_length_m - width) / 2
        length, width, yaw = config.vehicle_length_m, length, yaw + np.pi / 2
        yaw = (yaw + np.pi / 2) % np.pi - np.pi / 2
    return float(c[0]), float(c[1]), float(length), float(width), float(yaw)


def lidar_boxes(points, config: LidarDetectConfig = LidarDetectConfig(), *, ground: GroundPlane | None = None,
                background: Background | None = None) -> np.ndarray:
    """Traffic-object boxes of one cloud ([P, >=3], LiDAR frame, metres) as box7 [M, 7] float32.

    ``ground``: a plane fitted before (a static LiDAR's, shared by its frames); default: fitted
    to this cloud. ``background``: a static LiDAR's background model (its points are dropped)."""
    xyz = np.asarray(points, dtype=np.float64)[:, :3]
    xyz = xyz[_in_range(xyz, config.max_range_m)]
    if len(xyz) < config.min_points:
        return np.zeros((0, 7), np.float32)
    if ground is None:
        try:
            ground = fit_ground(xyz, config)
        except ValueError as exc:  # no ground in view (indoor, pointed at the sky): no objects to stand on it
            log.warning("no 3D boxes: %s", exc)
            return np.zeros((0, 7), np.float32)
    h = ground.height(xyz)
    obj = (h > config.ground_tol_m) & (h < config.max_height_m + 2.0)  # taller clusters are seen whole, then dropped
    if background is not None:
        obj &= ~background.mask(xyz)
    xyz, h = xyz[obj], h[obj]
    bg_share = None if background is None else background.fraction_of(xyz) >= background.threshold / 2
    if len(xyz) < config.min_points_far:
        return np.zeros((0, 7), np.float32)
    rng = np.hypot(xyz[:, 0], xyz[:, 1])
    height = float(ground.height(np.zeros((1, 3)))[0])  # the sensor over the ground below it
    high = height - config.roof_height_m >= 1.0
    complete = high if config.complete_vehicles == "auto" else bool(config.complete_vehicles)
    link = functools.partial(_radial_link, step=beam_step(points) if high else 0.0,
                             height=height, config=config)
    need = functools.partial(_min_points, config=config) if high else (lambda r: np.full(len(r), config.min_points))
    min_top = config.min_object_height_high_m if high else config.min_object_height_m

    def enough(pl, cnt):
        return need(np.bincount(pl, weights=rng, minlength=len(cnt))[pl] / cnt[pl])

    if high:
        order, starts = _polar_clusters(xyz[:, :2], link, config.cell_m, enough)
    else:
        order, starts = _clusters(xyz[:, :2], config.cell_m, enough)
    pieces = []
    for a, b in zip(starts[:-1], starts[1:]):
        idx = order[a:b]
        ext = np.ptp(xyz[idx, :2], axis=0)
        if ext.max() > 6.0 and config.split_gap_m > 0:
            c = xyz[idx, :2].mean(0)
            r0 = float(np.hypot(*c))
            pieces += _split_at_gaps(xyz[:, :2], idx, config.split_gap_m, c / max(r0, 1e-6),
                                     float(link(np.array([r0]))[0]) - config.cell_m, int(need(np.array([r0]))[0]))
        else:
            pieces.append(idx)
    boxes = []
    for idx in pieces:
        hc = h[idx]
        if bg_share is not None and bg_share[idx].mean() >= 0.5:  # mostly where something usually is
            continue
        top = float(hc.max())
        if not min_top <= top <= config.max_height_m or float(hc.min()) > config.max_gap_to_ground_m:
            continue
        cx, cy, length, width, yaw = _min_area_rect(xyz[idx, :2])
        if complete and length >= 2.5:  # a vehicle's side seen as a line: completed, not dropped as thin
            cx, cy, length, width, yaw = _complete_vehicle(cx, cy, length, width, yaw, top, config)
        if length > config.max_length_m or width > config.max_width_m or width < config.min_width_m:
            continue  # too long or wide for traffic; too thin: fences, walls, kerbs, posts
        if length > 5.0 and width < 0.5:  # fences, walls
            continue
        if length < 1.2 and top > 2.3:  # poles, trunks, posts, signs
            continue
        if high and top > config.tall_min_m and length < config.tall_min_length_m:
            continue  # seen from above a tall vehicle (bus, truck) shows its long footprint: tree crowns, signs
        if complete:
            cx, cy, length, width, yaw = _complete_vehicle(cx, cy, length, width, yaw, top, config)
        zg = float(ground.z_at(np.array([[cx, cy]]))[0])
        z_top = float(xyz[idx, 2].max())
        height = max(z_top - zg, min_top)
        boxes.append((cx, cy, zg + height / 2, length, width, height, yaw))
    return np.asarray(boxes, dtype=np.float32).reshape(-1, 7)
