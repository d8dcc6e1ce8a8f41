"""Multi-beam spinning LiDAR ray-cast against the ground plane and the objects' boxes.

Rays: ``lidar_beams`` rings evenly spread over ``lidar_vfov_deg`` x ``lidar_azimuth_steps``
azimuths, in the physical (tilted) sensor frame, expressed in the levelled LiDAR frame. Each box
is tested only against the rays of the azimuth bins it covers (vectorised ray x box slab tests),
so cost grows with the objects' angular size, not rays x boxes. Points are in the levelled LiDAR
frame (metres), with Gaussian range noise and random dropouts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...geometry.boxes import box7_corners
from .detections import world_to_lidar_box7
from .scene import SceneObjects
from .site import Site

__all__ = ["Scan", "scan", "ray_directions"]

_NBINS = 720  # azimuth bins (0.5 deg) for ray candidate lookup


@dataclass
class Scan:
    """points [P,3] float32 (levelled LiDAR frame, m), labels [P] int64 (index into the frame's
    objects, -1 = ground), ring [P] int16 (beam index, 0 = lowest)."""

    points: np.ndarray
    labels: np.ndarray
    ring: np.ndarray


def ray_directions(site: Site):
    """(dirs [R,3] unit, levelled frame; ring [R] int16; bin order [R]; bin starts [NBINS+1]) — cached."""
    if "lidar_rays" not in site._cache:
        c = site.config
        elev = np.radians(np.linspace(c.lidar_vfov_deg[0], c.lidar_vfov_deg[1], int(c.lidar_beams)))
        az = np.linspace(-math.pi, math.pi, int(c.lidar_azimuth_steps), endpoint=False)
        e, a = np.meshgrid(elev, az, indexing="ij")
        d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)
        d = d @ site.R_lidar_sensor.T
        ring = np.repeat(np.arange(len(elev), dtype=np.int16), len(az))
        azl = np.arctan2(d[:, 1], d[:, 0])
        bins = np.minimum(((azl + math.pi) / (2 * math.pi) * _NBINS).astype(np.int64), _NBINS - 1)
        order = np.argsort(bins, kind="stable")
        starts = np.concatenate([[0], np.cumsum(np.bincount(bins, minlength=_NBINS))])
        site._cache["lidar_rays"] = (d, ring, order, starts)
    return site._cache["lidar_rays"]


def _candidates(b7: np.ndarray, order: np.ndarray, starts: np.ndarray):
    """(ray index, box index) pairs whose azimuth bins overlap each box's azimuth interval."""
    rays, boxes = [], []
    if not len(b7):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    corners = box7_corners(b7)[:, :, :2]
    ac = np.arctan2(b7[:, 1], b7[:, 0])
    rel = (np.arctan2(corners[..., 1], corners[..., 0]) - ac[:, None] + math.pi) % (2 * math.pi) - math.pi
    lo, hi = ac + rel.min(axis=1), ac + rel.max(axis=1)
    inside = np.hypot(b7[:, 0], b7[:, 1]) < 0.5 * np.hypot(b7[:, 3], b7[:, 4])
    bw = 2 * math.pi / _NBINS
    for i in np.flatnonzero(~inside):
        b0 = int(math.floor((lo[i] + math.pi) / bw)) - 1
        b1 = int(math.floor((hi[i] + math.pi) / bw)) + 1
        spans = [(b0, b1)] if 0 <= b0 and b1 < _NBINS else \
            [(b0 % _NBINS, _NBINS - 1), (0, b1 % _NBINS)] if b0 < 0 or b1 >= _NBINS else [(b0, b1)]
        for s0, s1 in spans:
            r = order[starts[s0]:starts[s1 + 1]]
            rays.append(r)
            boxes.append(np.full(len(r), i, dtype=np.int64))
    if not rays:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(rays), np.concatenate(boxes)


def scan(site: Site, objs: SceneObjects, rng: np.random.Generator, *, noise: dict | None = None) -> Scan:
    """One sweep of the site's LiDAR over ``objs`` (world boxes)."""
    c = site.config
    nz = {"lidar_range_noise_m": c.lidar_range_noise_m, "lidar_dropout": c.lidar_dropout}
    nz.update({k: v for k, v in (noise or {}).items() if k in nz})
    d, ring, order, starts = ray_directions(site)
    h = float(site.lidar_position[2])
    with np.errstate(divide="ignore"):
        t = np.where(d[:, 2] < -1e-9, -h / np.minimum(d[:, 2], -1e-9), np.inf)
    labels = np.full(len(d), -1, dtype=np.int64)
    b7 = world_to_lidar_box7(site, objs.box7) if len(objs) else np.zeros((0, 7))
    ri, bi = _candidates(b7, order, starts)
    if len(ri):
        cy, sy = np.cos(b7[bi, 6]), np.sin(b7[bi, 6])
        dx, dy, dz = d[ri, 0], d[ri, 1], d[ri, 2]
        cx, cyy, cz = b7[bi, 0], b7[bi, 1], b7[bi, 2]
        dl = np.stack([cy * dx + sy * dy, -sy * dx + cy * dy, dz], axis=1)
        ol = np.stack([-(cy * cx + sy * cyy), -(-sy * cx + cy * cyy), -cz], axis=1)
        half = b7[bi, 3:6] / 2.0
        dl = np.where(np.abs(dl) < 1e-12, 1e-12, dl)
        t1, t2 = (-half - ol) / dl, (half - ol) / dl
        tnear = np.minimum(t1, t2).max(axis=1)
        tfar = np.maximum(t1, t2).min(axis=1)
        hit = (tnear <= tfar) & (tnear > 0)
        ri, bi, tn = ri[hit], bi[hit], tnear[hit]
        np.minimum.at(t, ri, tn)
        win = tn <= t[ri]
        labels[ri[win]] = bi[win]
    keep = np.isfinite(t) & (t >= c.lidar_min_range) & (t <= c.lidar_max_range)
    if c.lidar_blind_radius_m > 0:
        with np.errstate(invalid="ignore"):
            keep &= np.hypot(d[:, 0], d[:, 1]) * t >= c.lidar_blind_radius_m
    if nz["lidar_dropout"] > 0:
        keep &= rng.uniform(size=len(t)) >= nz["lidar_dropout"]
    idx = np.flatnonzero(keep)
    r = t[idx]
    if nz["lidar_range_noise_m"] > 0:
        r = r + rng.normal(0.0, nz["lidar_range_noise_m"], len(idx))
    pts = (d[idx] * r[:, None]).astype(np.float32)
    return Scan(points=pts, labels=labels[idx], ring=ring[idx])
