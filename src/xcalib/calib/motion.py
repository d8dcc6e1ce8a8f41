"""Object motion for the time-offset term: per 3D box, its velocity relative to the rig (LiDAR frame, m/s).

Sources, in order: the frames' ``velocities_3d`` (world velocity in the frame's LiDAR axes);
else tracks over the frames' LiDAR times (``track_ids_3d``; without ids, 3D boxes of
consecutive frames associated by mutual nearest neighbour within a speed gate). When the frames
carry the ego pose (``meta["T_world_lidar"]``, PandaSet) the rig's own motion is subtracted:
``v_rel = v_obj - v_ego - w_ego x p`` (LiDAR frame), and tracks are differenced in the world
frame. Timestamps are checked first: missing where needed, non-monotonic, or camera and LiDAR
stamps hours apart (different clocks) -> a ``problem`` message instead of velocities.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .inputs import CalibFrame

__all__ = ["BoxMotion", "box_motion", "check_timestamps", "MOVING_MPS", "MAX_SPEED_MPS", "MAX_CLOCK_GAP_S"]

MOVING_MPS = 0.5       # an object faster than this (relative to the rig) is moving
MAX_SPEED_MPS = 40.0   # speed gate of nearest-neighbour association
MAX_CLOCK_GAP_S = 1.0  # camera and LiDAR stamps of one frame further apart: different clocks


@dataclass
class BoxMotion:
    """velocity: per CalibFrame [M,3] (LiDAR frame, m/s, relative to the rig) or None; source:
    "given" | "tracks" | "nearest" | "" ; problem: why there are none ("" if there are);
    ego_motion: the rig's motion was subtracted; stamp_offset_s: median camera - LiDAR stamp."""

    velocity: list[np.ndarray | None]
    source: str = ""
    problem: str = ""
    ego_motion: bool = False
    stamp_offset_s: float | None = None

    def n_moving(self) -> int:
        return int(sum(np.sum(np.linalg.norm(v, axis=1) > MOVING_MPS) for v in self.velocity if v is not None))


def _times(frames_in, name: str) -> np.ndarray | None:
    t = [getattr(f, name, None) for f in frames_in]
    return None if any(v is None for v in t) else np.asarray(t, dtype=np.float64)


def check_timestamps(frames_in, need_lidar_times: bool) -> tuple[str, float | None]:
    """(problem or "", median camera - LiDAR stamp). Problems: LiDAR times missing (when
    ``need_lidar_times``), not strictly increasing, or camera and LiDAR stamps more than
    ``MAX_CLOCK_GAP_S`` apart (different clocks)."""
    tl, tc = _times(frames_in, "lidar_time_s"), _times(frames_in, "camera_time_s")
    gap = None if tl is None or tc is None else float(np.median(tc - tl))
    if tl is None:
        if need_lidar_times:
            missing = sum(getattr(f, "lidar_time_s", None) is None for f in frames_in)
            return (f"timestamps missing: {missing} of {len(frames_in)} frames have no lidar_time_s (needed to "
                    "derive object velocities from tracks)"), gap
        return "", gap
    if not np.all(np.isfinite(tl)) or (len(tl) > 1 and np.any(np.diff(tl) <= 0)):
        k = int(np.argmax(np.diff(tl) <= 0)) + 1 if len(tl) > 1 else 0
        return f"timestamps non-monotonic: lidar_time_s of frame {k} ({tl[k]:.6f} s) is not after the one before", gap
    if tc is not None:
        d = np.abs(tc - tl)
        if not np.all(np.isfinite(d)) or np.max(d) > MAX_CLOCK_GAP_S:
            return (f"timestamps in different clocks: camera and LiDAR stamps differ by up to {np.nanmax(d):.1f} s "
                    f"(> {MAX_CLOCK_GAP_S:g} s); fix the clocks or give a fixed time_offset"), gap
    return "", gap


def _ego(frames_in) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None:
    """Per frame (R_world_lidar, v_ego world m/s, w_ego LiDAR-frame rad/s) from meta T_world_lidar
    and lidar_time_s (central differences); None when not all frames carry both."""
    T = [(getattr(f, "meta", None) or {}).get("T_world_lidar") for f in frames_in]
    tl = _times(frames_in, "lidar_time_s")
    if len(frames_in) < 2 or tl is None or any(x is None for x in T):
        return None
    T = np.asarray(T, dtype=np.float64)
    out = []
    for k in range(len(T)):
        a, b = max(k - 1, 0), min(k + 1, len(T) - 1)
        dt = tl[b] - tl[a]
        v = (T[b, :3, 3] - T[a, :3, 3]) / dt
        w_world = Rotation.from_matrix(T[b, :3, :3] @ T[a, :3, :3].T).as_rotvec() / dt
        out.append((T[k, :3, :3], v, T[k, :3, :3].T @ w_world))
    return out


def _track_velocity_world(centres_w: list[np.ndarray], ids: list[np.ndarray], tl: np.ndarray) -> list[np.ndarray]:
    """World velocity per box from its track's centres in the neighbouring frames (central differences)."""
    where: dict[int, list[tuple[int, int]]] = {}
    for k, idk in enumerate(ids):
        for j, i in enumerate(idk):
            if i >= 0:
                where.setdefault(int(i), []).append((k, j))
    out = [np.zeros((len(c), 3)) for c in centres_w]
    for seen in where.values():
        for n, (k, j) in enumerate(seen):
            a, b = seen[max(n - 1, 0)], seen[min(n + 1, len(seen) - 1)]
            if a != b and tl[b[0]] > tl[a[0]]:
                out[k][j] = (centres_w[b[0]][b[1]] - centres_w[a[0]][a[1]]) / (tl[b[0]] - tl[a[0]])
    return out


def _nearest_ids(centres_w: list[np.ndarray], tl: np.ndarray) -> list[np.ndarray]:
    """Track ids by mutual nearest neighbour between consecutive frames, gated by MAX_SPEED_MPS x dt
    and by ambiguity (the second nearest must be 1.5x farther)."""
    ids = [np.full(len(c), -1, dtype=np.int64) for c in centres_w]
    nxt = 0
    for k in range(len(centres_w)):
        if k > 0 and len(centres_w[k]) and len(centres_w[k - 1]):
            a, b = centres_w[k - 1], centres_w[k]
            d = np.linalg.norm(a[:, None, :2] - b[None, :, :2], axis=2)
            gate = MAX_SPEED_MPS * (tl[k] - tl[k - 1]) + 0.5
            ja, ib = d.argmin(1), d.argmin(0)
            for i in range(len(a)):
                j = ja[i]
                srt = np.sort(d[i])
                unique = len(srt) < 2 or srt[1] > 1.5 * srt[0]
                if ib[j] == i and d[i, j] <= gate and unique:
                    if ids[k - 1][i] < 0:
                        ids[k - 1][i], nxt = nxt, nxt + 1
                    ids[k][j] = ids[k - 1][i]
        for j in np.flatnonzero(ids[k] < 0):
            ids[k][j], nxt = nxt, nxt + 1
    return ids


def box_motion(frames_in, cframes: list[CalibFrame]) -> BoxMotion:
    """Velocities (relative to the rig, LiDAR frame) of the CalibFrames' 3D boxes; see the module docstring."""
    given = [getattr(f, "velocities_3d", None) for f in frames_in]
    have_v = all(v is not None and len(np.asarray(v)) > (c.idx3d.max() if len(c.idx3d) else -1)
                 for v, c in zip(given, cframes))
    problem, gap = check_timestamps(frames_in, need_lidar_times=not have_v)
    if problem:
        return BoxMotion([None] * len(cframes), problem=problem, stamp_offset_s=gap)
    ego = _ego(frames_in)
    tl = _times(frames_in, "lidar_time_s")
    if have_v:
        v_w = [np.asarray(v, dtype=np.float64).reshape(-1, 3)[c.idx3d] for v, c in zip(given, cframes)]  # LiDAR axes
        source = "given"
    else:
        if len(cframes) < 2:
            return BoxMotion([None] * len(cframes), problem="one frame: no tracks to derive object velocities from",
                             stamp_offset_s=gap)
        # centres in the world frame (the LiDAR frame itself for a static rig)
        Tw = [np.eye(4)] * len(cframes) if ego is None else \
            [np.asarray(f.meta["T_world_lidar"], dtype=np.float64) for f in frames_in]
        Rw = [T[:3, :3] for T in Tw]
        centres_w = [c.boxes3d[:, :3] @ T[:3, :3].T + T[:3, 3] for c, T in zip(cframes, Tw)]
        tid = [getattr(f, "track_ids_3d", None) for f in frames_in]
        if all(t is not None and len(np.asarray(t)) > (c.idx3d.max() if len(c.idx3d) else -1)
               for t, c in zip(tid, cframes)):
            ids, source = [np.asarray(t, dtype=np.int64)[c.idx3d] for t, c in zip(tid, cframes)], "tracks"
        else:
            ids, source = _nearest_ids(centres_w, tl), "nearest"
        v_world = _track_velocity_world(centres_w, ids, tl)
        v_w = [v @ R for v, R in zip(v_world, Rw)]  # world -> LiDAR axes (R^T v, row form)
    if ego is not None:
        v_w = [v - R.T @ ve - np.cross(w, c.boxes3d[:, :3]) for v, c, (R, ve, w) in zip(v_w, cframes, ego)]
    return BoxMotion(v_w, source=source, ego_motion=ego is not None, stamp_offset_s=gap)


def shift_frames(cframes: list[CalibFrame], velocity: list[np.ndarray | None], dt_s: float) -> list[CalibFrame]:
    """Copies of ``cframes`` with every 3D box (centre, outline, corners) moved by velocity x ``dt_s``
    (where the objects were at the camera time)."""
    from dataclasses import replace

    out = []
    for c, v in zip(cframes, velocity):
        if v is None or dt_s == 0.0 or not len(v):
            out.append(c)
            continue
        d = v * dt_s
        b = c.boxes3d.copy()
        b[:, :3] += d
        out.append(replace(c, boxes3d=b, corners=c.corners + d[:, None, :],
                           box_corners=None if c.box_corners is None else c.box_corners + d[:, None, :]))
    return out
