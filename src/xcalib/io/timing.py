"""Validation of a frame's optional timing and track fields as read from a file.

``Frame.lidar_time_s`` / ``camera_time_s`` (seconds, one clock), ``track_ids_3d`` ([M] int64,
-1 = no track) and ``velocities_3d`` ([M,3] m/s, LiDAR frame). Every reader that fills them
passes them through :func:`checked_timing`, which raises :class:`~xcalib.errors.FormatError`
naming the file and the field.
"""

from __future__ import annotations

import numpy as np

from ..errors import FormatError

__all__ = ["MAX_SPEED_MPS", "MAX_TIME_S", "TIMING_FIELDS", "checked_time", "checked_timing", "timing_of"]

#: The Frame fields (and the keys a frame folder's detections.json may carry).
TIMING_FIELDS = ("lidar_time_s", "camera_time_s", "track_ids_3d", "velocities_3d")
#: Largest |time| in seconds. A clock in seconds stays below it: Unix time is 1.7e9 s today, the
#: largest unsigned 64-bit nanosecond stamp (ROS 2 / MCAP) is 1.8e10 s; a Unix time written in
#: milliseconds exceeds it for every date after March 1973 (microseconds, nanoseconds even more):
#: beyond it the value is a stamp in the wrong unit or corrupt.
MAX_TIME_S = 1.0e11
#: Largest |velocity| component (m/s) of a tracked object: 1000 m/s (3600 km/h) is three times the
#: speed of sound, far above anything a LiDAR tracks near the ground; beyond it the value is in
#: the wrong unit (mm/s) or corrupt. (The velocity moves a box by v x the LiDAR-camera time gap.)
MAX_SPEED_MPS = 1.0e3


def _time(path, field: str, value) -> float | None:
    if value is None:
        return None
    a = np.asarray(value)
    if a.size != 1 or a.dtype.kind not in "iuf":
        raise FormatError(path, f"expected one number (seconds), got {value!r}", field)
    v = float(a.reshape(()))
    if not np.isfinite(v):
        raise FormatError(path, f"expected a finite time in seconds, got {v}", field)
    if abs(v) > MAX_TIME_S:
        raise FormatError(path, f"time {v:.6g} s is beyond {MAX_TIME_S:g} s in magnitude: not a clock in seconds "
                                "(a stamp in milliseconds, microseconds or nanoseconds?) or corrupt", field)
    return v


def checked_time(path, field: str, value) -> float | None:
    """One time in seconds (None stays None): a finite number within ``MAX_TIME_S``, or a
    FormatError naming ``path`` and ``field`` (the bound of :func:`checked_timing`, for readers
    whose times come one at a time)."""
    return _time(path, field, value)


def checked_timing(path, n_3d: int, *, lidar_time_s=None, camera_time_s=None, track_ids_3d=None,
                   velocities_3d=None, fields: dict[str, str] | None = None) -> dict:
    """Validated ``{Frame field: value}`` for the given (non-None) values of a frame with
    ``n_3d`` 3D boxes; ``fields`` maps a Frame field to the name the file uses (for messages)."""
    name = {f: f for f in TIMING_FIELDS} | dict(fields or {})
    out: dict = {"lidar_time_s": _time(path, name["lidar_time_s"], lidar_time_s),
                 "camera_time_s": _time(path, name["camera_time_s"], camera_time_s)}
    if track_ids_3d is not None:
        try:
            ids = np.asarray(track_ids_3d)
        except (TypeError, ValueError):
            ids = np.asarray([None])
        if ids.dtype.kind not in "iu" and not (ids.dtype.kind == "f" and np.all(np.isfinite(ids))
                                               and np.all(ids == np.round(ids))):
            raise FormatError(path, "expected integer track ids", name["track_ids_3d"])
        if ids.shape != (n_3d,):
            raise FormatError(path, f"expected [M] = [{n_3d}] track ids (one per 3D box), got shape "
                                    f"{list(ids.shape)}", name["track_ids_3d"])
        out["track_ids_3d"] = ids.astype(np.int64)
    if velocities_3d is not None:
        try:
            v = np.asarray(velocities_3d, dtype=np.float64)
        except (TypeError, ValueError):
            raise FormatError(path, "expected [M,3] numbers (m/s, LiDAR frame)", name["velocities_3d"]) from None
        if n_3d == 0 and v.size == 0:
            v = v.reshape(0, 3)
        if v.shape != (n_3d, 3):
            raise FormatError(path, f"expected [M, 3] = [{n_3d}, 3] velocities (m/s, LiDAR frame), got shape "
                                    f"{list(v.shape)}", name["velocities_3d"])
        if not np.all(np.isfinite(v)):
            raise FormatError(path, "velocities must be finite (m/s)", name["velocities_3d"])
        if v.size and np.abs(v).max() > MAX_SPEED_MPS:
            r = int(np.argmax(np.abs(v).max(axis=1)))
            raise FormatError(path, f"row {r} holds a velocity of {float(np.abs(v[r]).max()):.3g} m/s, beyond "
                                    f"{MAX_SPEED_MPS:g} m/s: not m/s (mm/s?) or corrupt", name["velocities_3d"])
        out["velocities_3d"] = v
    return {k: v for k, v in out.items() if v is not None}


def timing_of(frame) -> dict:
    """The frame's timing/track fields that are set, as ``{field: value}``."""
    return {k: getattr(frame, k) for k in TIMING_FIELDS if getattr(frame, k, None) is not None}
