"""Traffic on the site: lanes, road users with class sizes, tracks over frames (world frame, metres).

One road (the green phase) carries moving vehicles, cyclists and pedestrians on its sidewalks; the
other road's vehicles queue at their stop lines and pedestrians wait at its corners. Objects in a
lane share the lane's speed, so nobody collides and consecutive frames form tracks with stable ids.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from typing import TYPE_CHECKING

import numpy as np

from .presets import CLASS_SIZES, _draw

if TYPE_CHECKING:  # annotations only: the site module renders with this one (no import cycle)
    from .site import Site

__all__ = ["Tracks", "SceneObjects", "simulate_traffic", "CLASSES", "sample_sizes"]

CLASSES = ("car", "van", "truck", "bus", "pedestrian", "cyclist")

_VEHICLE_COLOURS = np.array([
    [235, 235, 235], [25, 25, 28], [160, 163, 168], [95, 98, 104], [150, 20, 25], [30, 55, 130],
    [25, 70, 45], [210, 180, 40], [120, 80, 50], [200, 200, 210], [60, 60, 70], [180, 90, 30]], dtype=np.uint8)
_BUS_COLOURS = np.array([[230, 190, 30], [240, 240, 240], [170, 30, 30]], dtype=np.uint8)
_CLOTHES = np.array([
    [200, 40, 40], [40, 80, 160], [30, 30, 30], [230, 230, 220], [60, 130, 70], [220, 160, 40],
    [120, 60, 140], [90, 90, 90]], dtype=np.uint8)


@dataclass
class SceneObjects:
    """The objects present at one instant: ids [N] int64 (stable per track), classes [N] str,
    box7 [N,7] world (cx, cy, cz, l, w, h, yaw), colours [N,3] uint8 RGB, velocity [N,3] world
    m/s (None: unknown)."""

    ids: np.ndarray
    classes: np.ndarray
    box7: np.ndarray
    colours: np.ndarray
    velocity: np.ndarray | None = None

    def __len__(self) -> int:
        return int(len(self.ids))


@dataclass
class Tracks:
    """All tracks of a sequence: position at frame k is ``origin + (s0 + speed * k * dt) * heading``."""

    classes: np.ndarray      # [T] str
    size: np.ndarray         # [T,3] l, w, h
    colours: np.ndarray      # [T,3]
    origin: np.ndarray       # [T,2]
    heading: np.ndarray      # [T,2] unit
    s0: np.ndarray           # [T]
    speed: np.ndarray        # [T] m/s
    yaw_offset: np.ndarray   # [T] radians (standing pedestrians face anywhere)
    half_length: float
    dt: float

    def at(self, k: int) -> SceneObjects:
        """The objects of frame ``k`` (time ``k * dt``)."""
        return self.at_time(k * self.dt)

    def at_time(self, t_s: float) -> SceneObjects:
        """The objects present at time ``t_s`` (seconds from the sequence start)."""
        s = self.s0 + self.speed * t_s
        present = np.abs(s) <= self.half_length
        idx = np.flatnonzero(present)
        xy = self.origin[idx] + s[idx, None] * self.heading[idx]
        yaw = np.arctan2(self.heading[idx, 1], self.heading[idx, 0]) + self.yaw_offset[idx]
        sz = self.size[idx]
        box7 = np.column_stack([xy, sz[:, 2] / 2.0, sz, yaw])
        vel = np.column_stack([self.speed[idx, None] * self.heading[idx], np.zeros(len(idx))])
        return SceneObjects(ids=idx.astype(np.int64), classes=self.classes[idx], box7=box7,
                            colours=self.colours[idx], velocity=vel)


def sample_sizes(rng: np.random.Generator, classes) -> np.ndarray:
    """[N,3] (l, w, h) metres drawn from each class's size distribution (clipped to +-2.5 sigma)."""
    classes = list(classes)
    mean = np.array([CLASS_SIZES[c][0] for c in classes]).reshape(-1, 3)
    std = np.array([CLASS_SIZES[c][1] for c in classes]).reshape(-1, 3)
    z = np.clip(rng.standard_normal((len(classes), 3)), -2.5, 2.5)
    return mean + z * std


def _right(h: np.ndarray) -> np.ndarray:
    return np.array([h[1], -h[0]])


def simulate_traffic(site: Site, n_frames: int, rng: np.random.Generator) -> Tracks:
    """Draw one sequence's tracks (phase, densities, road users) for ``n_frames`` frames."""
    c = site.config
    L, dt = float(c.scene_half_length), float(c.frame_dt)
    horizon = max(n_frames, 1) * dt
    moving = "a" if site.preset == "vehicle" else str(rng.choice(["a", "b"]))
    stopped = "b" if moving == "a" else "a"
    axis = {"a": np.array([1.0, 0.0]), "b": np.array([0.0, 1.0])}
    n_lanes = {"a": site.lanes_a, "b": site.lanes_b}
    target = _draw(rng, c.n_objects, integer=True)
    wcls = {k: float(v) for k, v in c.class_weights.items() if v > 0}
    vcls, vp = list(wcls), np.array(list(wcls.values()))
    vp = vp / vp.sum()

    rows: list[tuple] = []  # (cls, origin, heading, s0, speed, yaw_offset, size, colour)

    def new_row(r, cls, origin, heading, s0, speed, yaw_off=0.0, size=None):
        size = sample_sizes(r, [cls])[0] if size is None else size
        if cls in ("pedestrian", "cyclist"):
            col = _CLOTHES[r.integers(0, len(_CLOTHES))]
        elif cls == "bus":
            col = _BUS_COLOURS[r.integers(0, len(_BUS_COLOURS))]
        else:
            col = _VEHICLE_COLOURS[r.integers(0, len(_VEHICLE_COLOURS))]
        rows.append((cls, origin, heading, s0, speed, yaw_off, size, col))
        return size

    def fill_lane(r, origin, heading, kind, expected, speed):
        # place objects from the far end backwards so the lane holds ~expected objects in [-L, L];
        # a lane's own generator keeps earlier frames identical whatever n_frames is
        spacing = 100.0 / max(expected, 0.25)  # ``expected`` counts objects per 100 m of lane
        s = L + r.uniform(0, spacing)
        end = -L - speed * horizon
        while s > end:
            cls = str(r.choice(vcls, p=vp)) if kind == "vehicle" else kind
            size = sample_sizes(r, [cls])[0]
            new_row(r, cls, origin, heading, s - size[0] / 2, speed, size=size)
            mean_gap = max(spacing - size[0] - c.min_gap_m, 0.5)
            s -= size[0] + c.min_gap_m + r.exponential(mean_gap)

    M = moving
    e = axis[M]
    nM = n_lanes[M]
    hM = site.half_width(M)
    lanes = []
    for sign in (1.0, -1.0):
        h = sign * e
        for i in range(nM):
            lanes.append((_right(h) * (i + 0.5) * c.lane_width, h, "vehicle"))
        lanes.append((_right(h) * (nM * c.lane_width + c.bike_lane_width / 2), h, "cyclist"))
        for side in (1.0, -1.0):
            off = nM * c.lane_width + c.bike_lane_width + c.sidewalk_width / 2 + 0.6 * sign
            lanes.append((_right(e) * side * off, h, "pedestrian"))
    n_veh = sum(1 for ln in lanes if ln[2] == "vehicle")
    m = float(c.moving_share)
    share = {"vehicle": 0.6 * m * target / n_veh, "cyclist": 0.05 * m * target, "pedestrian": 0.03 * m * target}
    lane_seeds = rng.integers(0, 2**62, size=len(lanes))
    for (origin, h, kind), ls in zip(lanes, lane_seeds):
        if share[kind] <= 0:
            continue
        r = np.random.default_rng(int(ls))
        rng_speed = {"vehicle": c.vehicle_speed, "cyclist": c.cyclist_speed, "pedestrian": c.pedestrian_speed}[kind]
        fill_lane(r, origin, h, kind, share[kind], _draw(r, rng_speed))
    # queues on the stopped road, in front of their stop lines
    S, eS, nS = stopped, axis[stopped], n_lanes[stopped]
    s_stop = -(hM + 1.0)
    q_lanes = [(sign * eS, i) for sign in (1.0, -1.0) for i in range(nS)]
    if site.preset == "vehicle":  # the ego car waits in road B lane 0 heading +y
        q_lanes = [q for q in q_lanes if not (q[0][1] > 0 and q[1] == 0)]
    for h, i in q_lanes:
        n_q = int(rng.poisson(float(c.queue_share) * target / max(len(q_lanes), 1)))
        s = s_stop - rng.uniform(0.2, 2.0)
        for _ in range(min(n_q, int(c.queue_max))):
            cls = str(rng.choice(vcls, p=vp))
            size = sample_sizes(rng, [cls])[0]
            ln = new_row(rng, cls, _right(h) * (i + 0.5) * c.lane_width, h, s - size[0] / 2, 0.0, size=size)[0]
            s -= ln + rng.uniform(1.5, 3.5)
    # pedestrians waiting at the stopped road's corners
    for _ in range(int(rng.poisson(0.07 * target))):
        side, end = rng.choice([-1.0, 1.0], size=2)
        lat = nS * c.lane_width + c.bike_lane_width + rng.uniform(0.4, c.sidewalk_width - 0.4)
        along = end * (hM + rng.uniform(0.6, 3.0))
        origin = _right(eS) * side * lat + eS * along
        new_row(rng, "pedestrian", origin, eS, 0.0, 0.0, rng.uniform(-math.pi, math.pi))
    if not rows:
        z2 = np.zeros((0, 2))
        return Tracks(np.zeros(0, dtype=object), np.zeros((0, 3)), np.zeros((0, 3), np.uint8), z2, z2,
                      np.zeros(0), np.zeros(0), np.zeros(0), L, dt)
    classes = np.array([r[0] for r in rows], dtype=object)
    size = np.array([r[6] for r in rows], dtype=np.float64)
    colours = np.array([r[7] for r in rows], dtype=np.uint8)
    origin = np.array([r[1] for r in rows], dtype=np.float64)
    heading = np.array([r[2] for r in rows], dtype=np.float64)
    return Tracks(classes=classes, size=size, colours=colours, origin=origin, heading=heading,
                  s0=np.array([r[3] for r in rows]), speed=np.array([r[4] for r in rows]),
                  yaw_offset=np.array([r[5] for r in rows]), half_length=L, dt=dt)
