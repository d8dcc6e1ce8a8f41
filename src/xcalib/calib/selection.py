"""Frame selection: the informative frames of a long recording, up to a budget (pure numpy, stateless).

A recording of minutes holds thousands of frames, most of them repeating what others show: a
parked car seen in 500 frames is one object at one place, and its 500 observations share one
error (``uncertainty`` clusters by object). The calibration's cost grows with frames, its
information with *distinct* objects, places in the image, depths and bearings. This module
chooses, in time linear in the frames (plus a sort), the frames that cover those:

1. **Objects.** Each 3D box gets an object id: the frames' ``track_ids_3d`` where every frame
   has them, else boxes of consecutive frames are associated by 3D position (greedy nearest
   neighbour under a gate that grows with the time since the track was last seen, with a
   constant-velocity prediction; a track survives ``MAX_GAP_S`` of misses, one seen once
   ``FIRST_GAP_S``; where few boxes (``CLUTTER_SHARE``) are in tracks shorter than
   ``MIN_TRACK_FRAMES`` frames, those are clutter and belong to no object), in the world frame
   when every frame carries its ego pose (``meta["T_world_lidar"]``), else in the LiDAR frame.
2. **What a frame shows**, as keys with a weight and a decay per repeat: each object (high
   weight, steep decay: one observation of every object first), each object at a place (3 m
   cells: a moving car along its path is many places, a parked one is one), the image cells and
   sizes of its 2D boxes, the range x bearing cells of its 3D boxes, and its part of the
   recording (a spread in time).
3. **Greedy coverage** (lazy, with a heap): the frame whose keys add the most, until the budget
   or nothing adds. Frames without 2D or without 3D boxes add nothing. The chosen frames keep
   their recording order. The first frame of every other camera (name or intrinsics) is kept too:
   a mix of cameras is then refused as it is without selection.

Below the budget nothing is chosen: every frame is used (the calibration is the same as without
selection); the objects are still counted for the result. ``FrameSelection`` says how many
frames were given and used and how many distinct objects the used frames hold.
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from ..geometry.boxes import as_box7, check_boxes2d, check_boxes3d

__all__ = ["FrameBoxes", "FrameSelection", "frame_boxes", "scan_frames", "associate_objects", "select_frames",
           "MAX_GAP_S", "PLACE_CELL_M"]

#: a track missed for longer than this (s; 10 frames without timestamps) is ended
MAX_GAP_S = 1.0
#: frame period assumed when frames carry no LiDAR timestamps (s)
DEFAULT_DT_S = 0.1
#: a track seen once (no velocity yet) is continued only this soon (s): clutter does not chain up
FIRST_GAP_S = 0.25
#: association gate (m): GATE_M + speed x time since the track was last seen
GATE_M = 1.0
#: speed (m/s) allowed for a track seen once (its velocity is not known yet) / for the error of a
#: constant-velocity prediction of a track seen twice or more
FIRST_SPEED_MPS, PREDICTION_MPS = 15.0, 5.0
#: fewest frames of a track by position that make an object, where the boxes in shorter tracks
#: are at most CLUTTER_SHARE of all boxes (else every track is an object)
MIN_TRACK_FRAMES, CLUTTER_SHARE = 3, 0.1
#: size of the place cells (m) of an object's position
PLACE_CELL_M = 3.0
_RANGE_EDGES = np.array([8.0, 15.0, 25.0, 40.0, 60.0])
_BEARING_BINS = 24
_IMAGE_GRID = (8, 6)
_TIME_BINS = 16
# key types: (weight, decay per repeat) -- gain of the (c+1)-th frame showing a key: weight x decay^c
_OBJECT, _PLACE, _IMAGE, _RANGE, _TIME = range(5)
_WEIGHT = np.array([4.0, 1.0, 0.5, 0.5, 0.5])
_DECAY = np.array([0.25, 0.5, 0.7, 0.7, 0.5])


@dataclass(frozen=True)
class FrameBoxes:
    """What selection reads of one frame: 3D box centres [M,3] (LiDAR frame), their track ids [M]
    (None: not given), 2D box centres [K,2] and heights [K] (px), image size (W, H) or None, LiDAR
    time (s) or None, ego pose ``T_world_lidar`` [4,4] or None, the frame's camera name and
    intrinsics (None: not given; frames of other cameras are kept, see :func:`select_frames`)."""

    centres_3d: np.ndarray
    track_ids: np.ndarray | None
    centres_2d: np.ndarray
    heights_2d: np.ndarray
    size: tuple[int, int] | None = None
    time_s: float | None = None
    T_world_lidar: np.ndarray | None = None
    camera: str = ""
    intrinsics: Any = None


@dataclass(frozen=True)
class FrameSelection:
    """The frames chosen from a recording.

    indices: [n_used] chosen frame indices, in recording order (all frames below the budget).
    n_given: frames given. n_objects: distinct objects (3D tracks) in all of them; n_objects_used:
    those seen in a chosen frame. identity: how objects were told apart: "tracks" (the frames'
    track ids), "positions" (associated by 3D position) or "none" (no 3D boxes). max_frames: the
    budget (None: none). elapsed_s: time the selection took (s)."""

    indices: np.ndarray
    n_given: int
    n_objects: int
    n_objects_used: int
    identity: str
    max_frames: int | None
    elapsed_s: float = 0.0

    @property
    def n_used(self) -> int:
        return int(len(self.indices))

    @property
    def all_used(self) -> bool:
        return self.n_used == self.n_given


def _size_of(image, meta: dict, default) -> tuple[int, int] | None:
    shape = getattr(image, "shape", None)
    if shape is not None and len(shape) >= 2 and shape[0] > 1 and shape[1] > 1:
        return int(shape[1]), int(shape[0])
    s = meta.get("image_size")
    if s is not None and len(s) == 2:
        return int(s[0]), int(s[1])
    return default


def frame_boxes(item: Any, i: int, size: tuple[int, int] | None = None) -> FrameBoxes:
    """The :class:`FrameBoxes` of ``frames[i]`` (a ``Frame`` or an (image, points, b2, b3) tuple).
    ``size``: image size to assume when the frame tells none. Raises ValueError for malformed
    boxes (named as ``prepare_frames`` names them) and TypeError for an unknown item."""
    if hasattr(item, "bboxes_2d") and hasattr(item, "bboxes_3d"):
        image, b2, b3 = getattr(item, "image", None), item.bboxes_2d, item.bboxes_3d
        ids, t = getattr(item, "track_ids_3d", None), getattr(item, "lidar_time_s", None)
        meta = dict(getattr(item, "meta", None) or {})
        camera, intr = str(getattr(item, "camera_name", "") or ""), getattr(item, "intrinsics", None)
    elif isinstance(item, (tuple, list)) and len(item) == 4:
        image, _, b2, b3 = item
        ids, t, meta, camera, intr = None, None, {}, "", None
    else:
        raise TypeError(f"frames[{i}]: expected an xcalib.types.Frame or an (image, point_cloud, bboxes_2d, "
                        f"bboxes_3d) tuple, got {type(item).__name__}")
    b2 = check_boxes2d(b2, f"frames[{i}].bboxes_2d")[:, :4]
    b3 = check_boxes3d(b3, f"frames[{i}].bboxes_3d")
    ok2 = np.all(np.isfinite(b2), axis=1) & (b2[:, 2] > b2[:, 0]) & (b2[:, 3] > b2[:, 1])
    b2 = b2[ok2]
    if not np.all(np.isfinite(b3)):
        raise ValueError(f"frames[{i}].bboxes_3d: NaN/Inf values")
    c3 = as_box7(b3)[:, :3] if len(b3) else np.zeros((0, 3))
    if ids is not None:
        ids = np.asarray(ids).reshape(-1)
        ids = ids.astype(np.int64) if len(ids) == len(c3) else None
    T = meta.get("T_world_lidar")
    T = None if T is None or np.shape(T) != (4, 4) else np.asarray(T, dtype=np.float64)
    return FrameBoxes(c3, ids, np.column_stack([(b2[:, 0] + b2[:, 2]) / 2, (b2[:, 1] + b2[:, 3]) / 2]),
                      b2[:, 3] - b2[:, 1], _size_of(image, meta, size),
                      None if t is None or not np.isfinite(t) else float(t), T, camera, intr)


def _times(boxes: Sequence[FrameBoxes]) -> np.ndarray:
    t = [b.time_s for b in boxes]
    if all(v is not None for v in t) and (len(t) < 2 or np.all(np.diff(np.asarray(t, dtype=np.float64)) > 0)):
        return np.asarray(t, dtype=np.float64)
    return np.arange(len(boxes), dtype=np.float64) * DEFAULT_DT_S


def _world_centres(boxes: Sequence[FrameBoxes]) -> list[np.ndarray]:
    if boxes and all(b.T_world_lidar is not None for b in boxes):
        return [b.centres_3d @ b.T_world_lidar[:3, :3].T + b.T_world_lidar[:3, 3] for b in boxes]
    return [b.centres_3d for b in boxes]


def associate_objects(boxes: Sequence[FrameBoxes]) -> tuple[list[np.ndarray], int, str]:
    """(per frame [M] object ids 0..N-1 or -1, N, identity): the frames' track ids when every
    frame has them (a box with track id -1 belongs to no object: -1, not counted), else an
    association of the 3D boxes by position over consecutive frames (see the module doc; where
    few boxes are in short tracks, those are clutter: -1)."""
    if not boxes or sum(len(b.centres_3d) for b in boxes) == 0:
        return [np.zeros(0, np.int64) for _ in boxes], 0, "none"
    if all(b.track_ids is not None for b in boxes):
        allids = np.concatenate([b.track_ids for b in boxes])
        known, inv = np.unique(allids[allids >= 0], return_inverse=True)
        dense = np.full(len(allids), -1, np.int64)
        dense[allids >= 0] = inv
        splits = np.cumsum([len(b.track_ids) for b in boxes])[:-1]
        return list(np.split(dense, splits)), int(len(known)), "tracks"
    times, centres = _times(boxes), _world_centres(boxes)
    pos, vel = np.zeros((0, 3)), np.zeros((0, 3))
    last_t, seen, tid = np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64)
    out, n = [], 0
    for k, c in enumerate(centres):
        alive = times[k] - last_t <= np.where(seen > 1, MAX_GAP_S, FIRST_GAP_S) + 1e-9
        pos, vel, last_t, seen, tid = pos[alive], vel[alive], last_t[alive], seen[alive], tid[alive]
        ids = np.full(len(c), -1, np.int64)
        if len(c) and len(pos):
            dt = times[k] - last_t
            pred = pos + vel * dt[:, None]
            d = np.linalg.norm(c[:, None, :2] - pred[None, :, :2], axis=2)  # [M, A]
            gate = GATE_M + np.where(seen > 1, PREDICTION_MPS, FIRST_SPEED_MPS) * dt
            mi, ai = np.nonzero(d <= gate[None, :])
            order = np.argsort(d[mi, ai], kind="stable")
            used_m, used_a = np.zeros(len(c), bool), np.zeros(len(pos), bool)
            for m, a in zip(mi[order], ai[order]):
                if not used_m[m] and not used_a[a]:
                    used_m[m] = used_a[a] = True
                    ids[m] = tid[a]
                    vel[a] = (c[m] - pos[a]) / max(times[k] - last_t[a], 1e-3)
                    pos[a], last_t[a], seen[a] = c[m], times[k], seen[a] + 1
        new = np.flatnonzero(ids < 0)
        ids[new] = n + np.arange(len(new))
        n += len(new)
        pos, vel = np.vstack([pos, c[new]]), np.vstack([vel, np.zeros((len(new), 3))])
        last_t = np.r_[last_t, np.full(len(new), times[k])]
        seen, tid = np.r_[seen, np.ones(len(new), np.int64)], np.r_[tid, ids[new]]
        out.append(ids)
    # boxes in tracks shorter than MIN_TRACK_FRAMES are clutter (false detections) where they are
    # few (at most CLUTTER_SHARE of the boxes: a detector's false-positive rate); where they are
    # many, the frames are too far apart in time for tracks (A9's 16 frames: 21 % of the boxes)
    # and each is an object of its own
    life = np.bincount(np.concatenate(out), minlength=n)
    if np.sum(life[life < MIN_TRACK_FRAMES]) <= CLUTTER_SHARE * np.sum(life):
        keep = life >= MIN_TRACK_FRAMES
        dense = np.where(keep, np.cumsum(keep) - 1, -1)
        out, n = [dense[o] for o in out], int(np.sum(keep))
    return out, n, "positions"


def _keys(boxes: Sequence[FrameBoxes], ids: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(frame index, key code) of every key every frame shows (repeats within a frame included)."""
    F = len(boxes)
    W = max((b.size[0] for b in boxes if b.size), default=None)
    H = max((b.size[1] for b in boxes if b.size), default=None)
    if W is None:  # no image size anywhere: the extent of the 2D boxes
        allc = np.concatenate([b.centres_2d for b in boxes]) if boxes else np.zeros((0, 2))
        W, H = (float(np.max(allc[:, 0])) + 1, float(np.max(allc[:, 1])) + 1) if len(allc) else (1.0, 1.0)
    centres = _world_centres(boxes)
    fr, codes = [], []
    shift = np.int64(1) << np.int64(56)
    for k, (b, oid, cw) in enumerate(zip(boxes, ids, centres)):
        if not len(b.centres_3d) or not len(b.centres_2d):
            continue  # a frame without both sensors' boxes shows nothing the calibration can use
        known = oid >= 0
        cell = np.floor(cw[known, :2] / PLACE_CELL_M).astype(np.int64) & 0xFFFF
        place = (oid[known] << np.int64(32)) | (cell[:, 0] << np.int64(16)) | cell[:, 1]
        gx = np.clip((b.centres_2d[:, 0] / W * _IMAGE_GRID[0]).astype(np.int64), 0, _IMAGE_GRID[0] - 1)
        gy = np.clip((b.centres_2d[:, 1] / H * _IMAGE_GRID[1]).astype(np.int64), 0, _IMAGE_GRID[1] - 1)
        hb = np.clip(np.floor(np.log2(np.maximum(b.heights_2d, 1.0) / 16.0)), 0, 4).astype(np.int64)
        image = (gx * _IMAGE_GRID[1] + gy) * 8 + hb
        r = np.linalg.norm(b.centres_3d[:, :2], axis=1)
        az = np.arctan2(b.centres_3d[:, 1], b.centres_3d[:, 0])
        ab = np.clip(((az + np.pi) / (2 * np.pi) * _BEARING_BINS).astype(np.int64), 0, _BEARING_BINS - 1)
        rb = np.searchsorted(_RANGE_EDGES, r).astype(np.int64) * _BEARING_BINS + ab
        tb = np.array([k * _TIME_BINS // F], np.int64)
        c = np.concatenate([np.int64(_OBJECT) * shift + oid[known], np.int64(_PLACE) * shift + place,
                            np.int64(_IMAGE) * shift + image, np.int64(_RANGE) * shift + rb,
                            np.int64(_TIME) * shift + tb])
        codes.append(c)
        fr.append(np.full(len(c), k, np.int64))
    if not codes:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(fr), np.concatenate(codes)


def _greedy(frame_of: np.ndarray, codes: np.ndarray, n_frames: int, budget: int) -> np.ndarray:
    """Lazy greedy coverage: up to ``budget`` frames, each adding the most to what is chosen."""
    if not len(codes):
        return np.zeros(0, np.int64)
    key_codes, key = np.unique(codes, return_inverse=True)
    kind = (key_codes >> np.int64(56)).astype(np.int64)
    w, logr = _WEIGHT[kind], np.log(_DECAY[kind])
    pair = np.unique(frame_of * np.int64(len(key_codes)) + key)  # each key once per frame, sorted by frame
    f_of, k_of = pair // len(key_codes), pair % len(key_codes)
    starts = np.searchsorted(f_of, np.arange(n_frames + 1))
    count = np.zeros(len(key_codes))
    gain0 = np.bincount(f_of, weights=w[k_of], minlength=n_frames)
    heap = [(-float(g), int(f)) for f, g in enumerate(gain0) if g > 0]
    heapq.heapify(heap)
    chosen: list[int] = []
    while heap and len(chosen) < budget:
        _, f = heapq.heappop(heap)
        ks = k_of[starts[f]:starts[f + 1]]
        g = float(np.sum(w[ks] * np.exp(logr[ks] * count[ks])))
        if heap and g < -heap[0][0] - 1e-12:  # stale: back in, with its true gain
            heapq.heappush(heap, (-g, f))
            continue
        chosen.append(f)
        count[ks] += 1
    return np.sort(np.asarray(chosen, dtype=np.int64))


def _other_cameras(boxes: Sequence[FrameBoxes]) -> np.ndarray:
    """The first frame of each camera (name, or intrinsics) other than the first frame's: kept
    beside the chosen ones, so that a mix of cameras is still refused as one (``prepare_frames``)."""
    seen_cam, seen_intr, out = set(), [], []
    for k, b in enumerate(boxes):
        new = bool(b.camera) and b.camera not in seen_cam
        if b.intrinsics is not None and not any(b.intrinsics is x or _same(b.intrinsics, x) for x in seen_intr):
            seen_intr.append(b.intrinsics)
            new = True
        if b.camera:
            seen_cam.add(b.camera)
        if new and k > 0 and (len(seen_cam) > 1 or len(seen_intr) > 1):
            out.append(k)
    return np.asarray(out, dtype=np.int64)


def _same(a, b) -> bool:
    try:
        return bool(a == b)
    except Exception:  # noqa: BLE001 - arrays and the like: compare the values
        return bool(np.array_equal(np.asarray(a), np.asarray(b)))


def select_frames(boxes: Sequence[FrameBoxes], max_frames: int | None) -> FrameSelection:
    """Choose up to ``max_frames`` informative frames of ``boxes`` (one :class:`FrameBoxes` per
    frame; see the module doc). ``max_frames`` None or at least the frames: every frame."""
    t0 = time.perf_counter()
    ids, n_obj, identity = associate_objects(boxes)
    F = len(boxes)
    if max_frames is None or F <= max_frames:
        return FrameSelection(np.arange(F, dtype=np.int64), F, n_obj, n_obj, identity, max_frames,
                              time.perf_counter() - t0)
    frame_of, codes = _keys(boxes, ids)
    chosen = _greedy(frame_of, codes, F, int(max_frames))
    if len(chosen) == 0:  # nothing shows both sensors' boxes: keep the frames spread over the recording
        chosen = np.unique(np.linspace(0, F - 1, int(max_frames)).round().astype(np.int64))
    chosen = np.union1d(chosen, _other_cameras(boxes))
    used = np.unique(np.concatenate([ids[i] for i in chosen])) if len(chosen) else np.zeros(0, np.int64)
    return FrameSelection(chosen, F, n_obj, int(np.sum(used >= 0)), identity, max_frames, time.perf_counter() - t0)


def scan_frames(frames: Sequence, size: tuple[int, int] | None = None,
                progress: Callable[[str, int, int], None] | None = None) -> list[FrameBoxes]:
    """:func:`frame_boxes` of every frame of ``frames`` (a list or an indexable sequence read one
    frame at a time), with ``progress("frames", done, total)``."""
    n = len(frames)
    step = max(1, n // 200)
    out = []
    for i in range(n):
        out.append(frame_boxes(frames[i], i, size))
        if progress and ((i + 1) % step == 0 or i + 1 == n):
            progress("frames", i + 1, n)
    return out
