"""Frames streamed from a recording in bounded memory: each frame is read once and slimmed to what
calibration needs, before the next is read.

A slimmed frame keeps its boxes, times, tracks, intrinsics and meta; of its point cloud only the
points near its 3D boxes (where the yaw fit and the point-hull outlines of
:mod:`xcalib.calib.boxmodel` look: a cylinder around each box, wider than any of them, see
:func:`keep_mask`), its image only as its size (``meta["image_size"]``; the image becomes an
empty placeholder). The scan step of the whole cloud (``lidar_angular_step``), which the
point-hull outlines use, is computed while the whole cloud is there and carried in
``meta[SCAN_STEP_KEY]``; so the calibration of slimmed frames is the calibration of the whole
ones (same poses and verdicts). The report re-reads the few frames it draws
(:meth:`StreamedFrames.for_report`).

Memory: :class:`StreamConfig.max_memory_mb` bounds the frames held (the slimmed frames of every
camera plus the frame being read); the need is estimated up front from the frame count and the
first, middle and last frame of each camera (their points and images, and what slimming keeps
of them), and an input
over the limit is refused then (:class:`~xcalib.errors.MemoryLimitError` naming the input, the
estimate and the limit), or as soon as the frames read exceed it.

Layer: site (above calib). Frames: LiDAR frame, metres.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..calib.boxmodel import lidar_angular_step
from ..calib.inputs import SCAN_STEP_KEY
from ..errors import MemoryLimitError
from ..geometry.boxes import as_box7
from ..types import Frame

__all__ = ["StreamConfig", "StreamedFrames", "ReportFrames", "MemoryEstimate", "stream_views", "slim_frame",
           "keep_mask", "frame_nbytes", "estimate_memory", "parse_memory"]

log = logging.getLogger(__name__)

MB = 1 << 20
#: bytes a slimmed frame holds beyond its arrays (the Frame, its meta, the lists that hold it)
FRAME_OVERHEAD = 4096
#: memory to read and slim one frame, as a multiple of its cloud's x, y, z bytes (float32): the
#: decoded cloud, the slimming masks, and the scan-step search (float64 angles and a k-d tree)
READ_FACTOR_POINTS = 12.0
#: ... and of its image's bytes (the decoded image and the decoder's buffer)
READ_FACTOR_IMAGE = 2.0
#: frames with a cloud and 3D boxes whose whole cloud is searched for the LiDAR's scan step before
#: it is taken as not found for the recording (the search takes seconds on a cloud of millions)
STEP_TRIES = 3
#: grid cell (m) of the point selection (the points of the cells a box's cylinder touches are tested)
CELL_M = 1.0


@dataclass(frozen=True)
class StreamConfig:
    """How a recording is streamed.

    max_memory_mb: the most memory the frames may take (MB, 2^20 bytes): every camera's slimmed
        frames plus the frame being read; 0: no limit. The process adds the interpreter and the
        libraries (about 150-250 MB) and the calibration's own arrays.
    margin_m: points kept up to this far (m, horizontally) beyond the largest region the yaw fit
        and the point hulls read around a 3D box (for boxes a fixed time offset moves: ``0.25 m +
        40 m/s x |offset|`` is what ``xcalib calibrate`` asks).
    """

    max_memory_mb: float = 1536.0
    margin_m: float = 0.25

    def __post_init__(self):
        if not (np.isfinite(self.max_memory_mb) and self.max_memory_mb >= 0):
            raise ValueError(f"max_memory_mb: expected a size >= 0 MB (0: no limit), got {self.max_memory_mb!r}")
        if not (np.isfinite(self.margin_m) and self.margin_m >= 0):
            raise ValueError(f"margin_m: expected metres >= 0, got {self.margin_m!r}")

    @property
    def limit_bytes(self) -> int | None:
        return None if self.max_memory_mb == 0 else int(self.max_memory_mb * MB)


def parse_memory(text: str) -> float:
    """``"2G"`` / ``"1500M"`` / ``"1.5GB"`` / ``"800"`` (MB) / ``"0"`` (no limit) -> MB."""
    s = str(text).strip().upper().removesuffix("B").removesuffix("I")
    scale = {"K": 1 / 1024, "M": 1.0, "G": 1024.0, "T": 1024.0 ** 2}
    try:
        value = float(s[:-1]) * scale[s[-1]] if s and s[-1] in scale else float(s)
    except ValueError:
        raise ValueError(f"{text!r} is not a memory size (e.g. 2G, 1500M, 0 for no limit)") from None
    if not (np.isfinite(value) and value >= 0):
        raise ValueError(f"{text!r} is not a memory size >= 0")
    return value


def frame_nbytes(frame: Frame) -> int:
    """Bytes a frame's arrays hold (cloud, images, boxes, matrices), plus a fixed overhead."""
    n = FRAME_OVERHEAD
    for v in (frame.image, frame.point_cloud, frame.bboxes_2d, frame.bboxes_3d, frame.match_matrix,
              frame.track_ids_3d, frame.velocities_3d):
        if isinstance(v, np.ndarray):
            n += v.nbytes
    for v in (frame.images or {}).values():
        if isinstance(v, np.ndarray):
            n += v.nbytes
    for v in (frame.meta or {}).values():
        if isinstance(v, np.ndarray):
            n += v.nbytes
    return int(n)


def _regions(frame: Frame, margin_m: float) -> np.ndarray:
    """[B,5] (cx, cy, radius, z_lo, z_hi) per 3D box: the cylinder (LiDAR frame, m) around it that
    holds every point the calibration reads for it, whatever its yaw: the yaw fit reads within
    half its diagonal + 0.3 m of its centre and 0.3 m above its bottom to max(0.7 x height, 0.6 m);
    the point hull reads the box grown 1.1x in x-y from 0.2 m above its bottom to 0.1 m above its
    top (:mod:`xcalib.calib.boxmodel`). Boxes as given and as ``meta["box7"]`` (both are used)."""
    rows = []
    cands = [frame.bboxes_3d]
    m7 = (frame.meta or {}).get("box7")
    if m7 is not None:
        cands.append(m7)
    for b in cands:
        b = np.asarray(b, dtype=np.float64)
        if b.ndim != 2 or b.shape[0] == 0 or b.shape[1] not in (6, 7):
            continue
        b7 = as_box7(b)
        b7 = b7[np.all(np.isfinite(b7), axis=1)]
        if not len(b7):
            continue
        size = np.abs(b7[:, 3:6])
        r = 0.55 * np.hypot(size[:, 0], size[:, 1]) + 0.3 + margin_m
        bottom = b7[:, 2] - size[:, 2] / 2
        zm = 0.05 + 0.1 * margin_m  # vertical slack (m): boxes a time offset moves move a little in z too
        z_lo = bottom + 0.2 - zm
        z_hi = np.maximum(b7[:, 2] + size[:, 2] / 2 + 0.1, bottom + np.maximum(0.7 * size[:, 2], 0.6)) + zm
        rows.append(np.column_stack([b7[:, 0], b7[:, 1], r, z_lo, z_hi]))
    return np.concatenate(rows) if rows else np.zeros((0, 5))


def keep_mask(points: np.ndarray, regions: np.ndarray) -> np.ndarray:
    """[P] bool: the points (LiDAR frame [P,>=3]) inside any of the cylinders ``regions`` [B,5]
    (cx, cy, radius, z_lo, z_hi; m). A grid (``CELL_M``) finds the points near a cylinder in a few
    passes over the cloud; only those are tested against the cylinders touching their cell."""
    P = len(points)
    keep = np.zeros(P, dtype=bool)
    if P == 0 or not len(regions):
        return keep
    x, y, z = (np.asarray(points[:, k]) for k in range(3))
    cx, cy, r, zl, zh = regions.T
    small = (2 * r / CELL_M + 2) ** 2 <= 40_000  # few cells: gridded; a huge cylinder is tested directly
    for k in np.flatnonzero(~small):
        keep |= ((x - cx[k]) ** 2 + (y - cy[k]) ** 2 <= r[k] ** 2) & (z >= zl[k]) & (z <= zh[k])
    if not small.any():
        return keep
    reg = regions[small]
    cx, cy, r, zl, zh = reg.T
    lo_x, lo_y = np.floor((cx - r) / CELL_M).astype(np.int64), np.floor((cy - r) / CELL_M).astype(np.int64)
    hi_x, hi_y = np.floor((cx + r) / CELL_M).astype(np.int64), np.floor((cy + r) / CELL_M).astype(np.int64)
    keys, owner = [], []
    for k in range(len(reg)):  # (cell, cylinder) pairs: the cells of each cylinder's bounding square
        gx, gy = np.meshgrid(np.arange(lo_x[k], hi_x[k] + 1), np.arange(lo_y[k], hi_y[k] + 1), indexing="ij")
        keys.append((gx.ravel() << 32) + (gy.ravel() & 0xFFFFFFFF))
        owner.append(np.full(gx.size, k))
    keys_a, owner_a = np.concatenate(keys), np.concatenate(owner)
    order = np.argsort(keys_a, kind="stable")
    keys_a, owner_a = keys_a[order], owner_a[order]
    # cheap prefilter: inside the cells' bounding box and the cylinders' z range
    cand = (x >= lo_x.min() * CELL_M) & (x < (hi_x.max() + 1) * CELL_M) & (y >= lo_y.min() * CELL_M) \
        & (y < (hi_y.max() + 1) * CELL_M) & (z >= zl.min()) & (z <= zh.max())
    idx = np.flatnonzero(cand)
    if not len(idx):
        return keep
    pk = (np.floor(x[idx] / CELL_M).astype(np.int64) << 32) + (np.floor(y[idx] / CELL_M).astype(np.int64) & 0xFFFFFFFF)
    start, stop = np.searchsorted(keys_a, pk, "left"), np.searchsorted(keys_a, pk, "right")
    n = stop - start
    idx, start, n = idx[n > 0], start[n > 0], n[n > 0]
    if not len(idx):
        return keep
    # every (point, cylinder of its cell) pair, tested exactly
    pt = np.repeat(idx, n)
    first = np.repeat(np.cumsum(n) - n, n)
    cyl = owner_a[np.repeat(start, n) + (np.arange(len(pt)) - first)]
    inside = ((x[pt] - cx[cyl]) ** 2 + (y[pt] - cy[cyl]) ** 2 <= r[cyl] ** 2) & (z[pt] >= zl[cyl]) & (z[pt] <= zh[cyl])
    keep[pt[inside]] = True
    return keep


_EMPTY_IMAGE = np.zeros((0, 0, 3), dtype=np.uint8)


def slim_frame(frame: Frame, margin_m: float = 0.25, scan_step=...) -> Frame:
    """``frame`` with only what calibration reads: the points near its 3D boxes (:func:`keep_mask`;
    x, y, z only; one point kept where none is near, so a frame with a cloud keeps one), its image
    replaced by an empty placeholder and its size in ``meta["image_size"]``, the images of other
    cameras dropped. ``scan_step``: the whole cloud's scan step to carry in
    ``meta[SCAN_STEP_KEY]`` (a (az, el) pair or None; ``...``: not carried)."""
    meta = dict(frame.meta or {})
    if scan_step is not ...:
        meta[SCAN_STEP_KEY] = None if scan_step is None else (float(scan_step[0]), float(scan_step[1]))
    pts = frame.point_cloud
    if isinstance(pts, np.ndarray) and pts.ndim == 2 and pts.shape[1] >= 3:
        try:
            regions = _regions(frame, margin_m)
        except ValueError:  # malformed boxes: calibration names them; nothing is dropped here
            regions = None
        if regions is not None:
            keep = keep_mask(pts, regions)
            if not keep.any() and len(pts):
                keep[0] = True  # a frame with a cloud keeps one (calibration tells "a cloud" from "none")
            pts = np.ascontiguousarray(pts[keep, :3])
    image = frame.image
    if isinstance(image, np.ndarray) and image.ndim >= 2 and image.shape[0] > 1 and image.shape[1] > 1:
        meta["image_size"] = (int(image.shape[1]), int(image.shape[0]))
        image = _EMPTY_IMAGE
    return dataclasses.replace(frame, point_cloud=pts, image=image, images=None,
                               point_fields=tuple(frame.point_fields[:3]) if pts is not frame.point_cloud
                               else frame.point_fields, meta=meta)


def _read_bytes(frame: Frame) -> int:
    """Memory to read and slim one frame like ``frame``."""
    pts = frame.point_cloud
    n_pts = len(pts) if isinstance(pts, np.ndarray) and pts.ndim == 2 else 0
    img = sum(v.nbytes for v in [frame.image, *(frame.images or {}).values()] if isinstance(v, np.ndarray))
    return int(READ_FACTOR_POINTS * 12 * n_pts + READ_FACTOR_IMAGE * img + frame_nbytes(frame))


@dataclass(frozen=True)
class MemoryEstimate:
    """The up-front estimate of one camera's frames: ``frames`` to read, ``points`` and
    ``image_bytes`` of its largest sampled frame, ``slim_bytes`` slimming keeps of a frame (their
    mean), ``read_bytes`` to read one."""

    camera: str
    frames: int
    points: int
    image_bytes: int
    slim_bytes: int
    read_bytes: int

    @property
    def held_bytes(self) -> int:
        return self.frames * self.slim_bytes


def estimate_memory(estimates: Sequence[MemoryEstimate]) -> int:
    """Bytes of the frames of every camera held together plus one frame being read."""
    return int(sum(e.held_bytes for e in estimates) + max((e.read_bytes for e in estimates), default=0))


def _describe(estimates: Sequence[MemoryEstimate]) -> str:
    parts = [f"camera {e.camera}: {e.frames} frame(s) x {e.slim_bytes / 1024:.0f} kB kept of each (its first, "
             f"middle and last frame: up to {e.points} points and {e.image_bytes / MB:.1f} MB of image)"
             for e in estimates]
    read = max((e.read_bytes for e in estimates), default=0)
    return "; ".join(parts) + f"; + {read / MB:.0f} MB to read one frame"


class StreamedFrames(Sequence):
    """One camera's frames read once and slimmed (:func:`slim_frame`), in the source's order; the
    source's attributes (``intrinsics``, ``camera``, a bag's frame names and tf) are forwarded.
    :meth:`for_report` gives the frames a report draws, re-read whole."""

    _FORWARD = ("intrinsics", "camera", "camera_names", "source_name", "path", "report", "lidar_frame_id",
                "camera_frame_id", "tf_T_cam_lidar")

    def __init__(self, source: Sequence[Frame], frames: list[Frame], held_bytes: int, name: str = ""):
        self.source, self.frames, self.held_bytes, self.name = source, frames, int(held_bytes), name
        for attr in self._FORWARD:
            if hasattr(source, attr):
                setattr(self, attr, getattr(source, attr))

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index):
        return self.frames[index]

    def for_report(self, max_overlays: int, review: Sequence[int] = ()) -> "ReportFrames":
        """The frames as a report reads them: whole (re-read from the source) where it draws them
        (``xcalib.calib.report.write_report``'s overlays: up to ``max_overlays`` spread over the
        sequence, which are also the review file's by default; its frames ``review`` where given),
        slimmed elsewhere."""
        n = len(self.frames)
        k = max(int(max_overlays), 1)
        spread = np.unique(np.linspace(0, n - 1, min(k, n)).round().astype(int)) if n else []
        extra = [int(i) for i in review if 0 <= int(i) < n]
        return ReportFrames(self.source, self.frames, set(int(i) for i in spread) | set(extra))


class ReportFrames(Sequence):
    """Slimmed frames, except ``whole`` indices, which are read again from ``source`` (their boxes,
    times and meta stay the slimmed frame's: those the calibration used); the last one read is
    cached."""

    def __init__(self, source: Sequence[Frame], frames: list[Frame], whole: set[int]):
        self.source, self.frames, self.whole = source, frames, whole
        self._cache: tuple[int, Frame] | None = None

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = range(len(self.frames))[index]
        slim = self.frames[i]
        if i not in self.whole:
            return slim
        if self._cache is not None and self._cache[0] == i:
            return self._cache[1]
        full = self.source[i]
        if str(full.frame_key) != str(slim.frame_key):
            raise ValueError(f"frame {i}: the source changed while it was read (frame key {full.frame_key!r}, "
                             f"first read as {slim.frame_key!r})")
        # drawn as today from the whole frame: its own image size and scan step
        meta = {k: v for k, v in (slim.meta or {}).items() if k not in ("image_size", SCAN_STEP_KEY)}
        for k in ("image_size", SCAN_STEP_KEY):
            if k in (full.meta or {}):
                meta[k] = full.meta[k]
        out = dataclasses.replace(slim, image=full.image, point_cloud=full.point_cloud, images=full.images,
                                  point_fields=full.point_fields, meta=meta)
        self._cache = (i, out)
        return out


def _first_estimate(name: str, seq: Sequence[Frame], config: StreamConfig) -> MemoryEstimate:
    """The estimate of one camera's frames from its first, middle and last frame (read, measured,
    let go): the mean of what slimming keeps of them, the most it takes to read one."""
    n = len(seq)
    if n == 0:
        return MemoryEstimate(name, 0, 0, 0, 0, 0)
    pts, img, slim, read = [], [], [], []
    for i in sorted({0, n // 2, n - 1}):
        f = seq[i]
        p = f.point_cloud
        pts.append(len(p) if isinstance(p, np.ndarray) and p.ndim == 2 else 0)
        img.append(sum(v.nbytes for v in [f.image, *(f.images or {}).values()] if isinstance(v, np.ndarray)))
        slim.append(frame_nbytes(slim_frame(f, config.margin_m)))
        read.append(_read_bytes(f))
        del f
    return MemoryEstimate(name, n, max(pts), int(max(img)), int(np.mean(slim)), max(read))


def stream_views(views: dict[str, Sequence[Frame]], config: StreamConfig | None = None, *, source: str = "",
                 progress: Callable[[str, int, int], None] | None = None) -> dict[str, StreamedFrames]:
    """Read each camera's frames once, slimmed (:func:`slim_frame`), within ``config.max_memory_mb``.

    Up front, the memory the slimmed frames of every camera will hold is estimated from the frame
    counts and each camera's first, middle and last frame; over the limit ->
    :class:`MemoryLimitError` before the rest is read (naming ``source``, the estimate and the limit). While reading, the frames held
    are counted; over the limit -> the same error, at that frame. ``progress(stage, done, total)``
    per frame read. The whole cloud's scan step (``lidar_angular_step``) is computed frame by
    frame until a frame with 3D boxes gives one (or ``STEP_TRIES`` such frames gave none); later
    frames carry that step (one LiDAR: the calibration uses the first frames' step)."""
    config = config or StreamConfig()
    limit = config.limit_bytes
    where = source or "input"
    est = [_first_estimate(name, seq, config) for name, seq in views.items()]
    need = estimate_memory(est)
    if limit is not None and need > limit:
        raise MemoryLimitError(where, f"its frames would need about {need / MB:.0f} MB of memory even slimmed to "
                                      f"the points near their 3D boxes ({_describe(est)}); the limit is "
                                      f"{limit / MB:.0f} MB (--max-memory); calibrate fewer frames (--frames, "
                                      "--limit) or raise the limit", need, limit)
    out: dict[str, StreamedFrames] = {}
    held_before = 0
    read_peak = max((e.read_bytes for e in est), default=0)
    for name, seq in views.items():
        frames: list[Frame] = []
        held = 0
        step, step_final, tries = ..., False, 0
        n = len(seq)
        stage = f"{name}: reading frames" if len(views) > 1 or name else "reading frames"
        for i in range(n):
            f = seq[i]
            if not step_final:
                step = _whole_step(f)
                if _has_box(f) and step is not ...:
                    tries += 1
                    step_final = step is not None or tries >= STEP_TRIES
            slim = slim_frame(f, config.margin_m, step)
            del f
            frames.append(slim)
            held += frame_nbytes(slim)
            if limit is not None and held_before + held + read_peak > limit:
                total = held_before + held + read_peak
                raise MemoryLimitError(where, f"camera {name}: after {i + 1} of {n} frames the slimmed frames hold "
                                              f"{(held_before + held) / MB:.0f} MB (+ {read_peak / MB:.0f} MB to read "
                                              f"one; estimated up front: {need / MB:.0f} MB); the limit is "
                                              f"{limit / MB:.0f} MB (--max-memory); their 3D boxes hold more points "
                                              "than the frames sampled for the estimate: calibrate fewer frames "
                                              "(--frames, --limit) or raise the limit", total, limit)
            if progress:
                progress(stage, i + 1, n)
        out[name] = StreamedFrames(seq, frames, held, name)
        held_before += held
    return out


def _whole_step(frame: Frame):
    """The scan step of the frame's whole cloud (None: not found); ``...`` without a cloud."""
    pts = frame.point_cloud
    if not (isinstance(pts, np.ndarray) and pts.ndim == 2 and pts.shape[1] >= 3 and len(pts)):
        return ...
    return lidar_angular_step(pts)


def _has_box(frame: Frame) -> bool:
    b = np.asarray(frame.bboxes_3d)
    return b.ndim == 2 and len(b) > 0
