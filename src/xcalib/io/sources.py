"""One registry of frame sources: each source registers ``(name, detect(path), open(path, **options))``.

A source is a module that calls :func:`register_source` when it is imported: frame folders
(:mod:`xcalib.io.frames`), HDF5 caches (:mod:`xcalib.io.hdf5`), bags (:mod:`xcalib.io.bags`),
and the dataset formats of :mod:`xcalib.formats` (KITTI, CalibAnything/OpenCalib, mmdetection3d
and nuScenes info pickles, Waymo). :func:`open_source` imports those modules on first use
(``xcalib.io`` itself never imports ``xcalib.formats``), asks each source's ``detect`` in
priority order and opens the first that accepts the path. Sources are discovered through the
``xcalib.sources`` entry-point group (:mod:`xcalib.plugins`): adding one is one module that calls
``register_source`` (or exposes a :class:`FrameSource`), declared in its package's
``pyproject.toml``; xcalib's own are declared the same way.

Every source takes ``camera=`` (a camera name; ``None``: the source's default camera) and
:func:`open_source` applies ``frames=`` (``"0:8"``, ``"0,3,5"``, ``"2:"``, ``"::2"``, or a list
of indices) to any source.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import FormatError
from ..plugins import BUILTIN
from ..plugins import entries as plugin_entries
from ..plugins import load as load_plugin
from ..types import Frame, FrameDetections

__all__ = ["FrameSource", "register_source", "unregister_source", "frame_sources", "find_source", "open_source",
           "parse_frame_range", "FrameSubset", "CameraView", "camera_view", "image_size_of", "merge_cameras", "SOURCE_MODULES"]

# Modules that register sources on import (imported by the registry on first use).
#: xcalib's own source modules (declared as ``xcalib.sources`` entry points; kept for reference).
SOURCE_MODULES = tuple(BUILTIN["xcalib.sources"].values())


@dataclass(frozen=True)
class FrameSource:
    """A frame source: ``detect(path) -> bool`` (cheap: names and headers only) and
    ``open(path, *, camera=None, **options) -> Sequence[Frame]``; lower ``priority`` is tried first."""

    name: str
    detect: Callable[[Path], bool]
    open: Callable[..., Sequence[Frame]]
    description: str = ""
    priority: int = 50


_REGISTRY: dict[str, FrameSource] = {}
_LOADED: list[str] = []  # entry points already loaded (the registry's own bookkeeping)


def register_source(name: str, detect: Callable[[Path], bool], open: Callable[..., Sequence[Frame]],  # noqa: A002
                    *, description: str = "", priority: int = 50) -> FrameSource:
    """Register (or replace) a frame source under ``name``."""
    src = FrameSource(name, detect, open, description, priority)
    _REGISTRY[name] = src
    return src


def unregister_source(name: str) -> None:
    """Remove a source (tests, plugins replacing a built-in)."""
    _REGISTRY.pop(name, None)


def _load_modules() -> None:
    """Load every ``xcalib.sources`` entry point once: a module registers itself on import; an
    entry that names a :class:`FrameSource` is registered here. A broken one is reported by name
    (:class:`xcalib.plugins.PluginWarning`) and the others still load."""
    for entry in plugin_entries("xcalib.sources"):
        key = f"{entry.name}={entry.value}"
        if key in _LOADED:
            continue
        _LOADED.append(key)
        obj = load_plugin(entry)
        if isinstance(obj, FrameSource):
            _REGISTRY[obj.name] = obj


def frame_sources() -> list[FrameSource]:
    """Every registered source, in the order ``open_source`` tries them."""
    _load_modules()
    return sorted(_REGISTRY.values(), key=lambda s: (s.priority, s.name))


def find_source(path) -> FrameSource:
    """The first source whose ``detect`` accepts ``path`` (FormatError listing them otherwise)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"frame source not found: {p}")
    for src in frame_sources():
        if src.detect(p):
            _check_single_dataset(p)
            return src
    raise FormatError(p, "not a recognised frame source; supported: " + ", ".join(s.name for s in frame_sources())
                      + _inside_hint(p))


_PEEK = 64  # entries of an unrecognised folder looked at for sources inside it


def _sources_inside(p: Path, *, dirs_only: bool = False) -> list[tuple[Path, str]]:
    """(entry, source name) for the first ``_PEEK`` entries of folder ``p`` that a source detects."""
    try:
        kids = sorted(p.iterdir())[:_PEEK]
    except OSError:
        return []
    found = []
    for k in kids:
        if dirs_only and not k.is_dir():
            continue
        for src in frame_sources():
            try:
                hit = src.detect(k)
            except (OSError, ValueError):
                hit = False
            if hit:
                found.append((k, src.name))
                break
    return found


def _check_single_dataset(p: Path) -> None:
    """Refuse a folder whose subfolders are frame sources of two or more kinds (a root holding several
    datasets, e.g. ``data/`` with ``kitti/`` and ``a9_sample/``): a source that accepts it because one
    subfolder qualifies would read one dataset and silently leave the others out."""
    if not p.is_dir():
        return
    found = _sources_inside(p, dirs_only=True)
    kinds = len({name for _, name in found})
    if kinds >= 2:
        raise FormatError(p, f"holds frame sources of {kinds} kinds: {_listed(found)}; give one of them")


def _listed(found: list[tuple[Path, str]], most: int = 6) -> str:
    """``"a (kitti), b (bag) and 3 more"``: the first ``most`` of ``found`` and how many more."""
    more = f" and {len(found) - most} more" if len(found) > most else ""
    return ", ".join(f"{k} ({name})" for k, name in found[:most]) + more


def _inside_hint(p: Path) -> str:
    """For an unrecognised folder: that it is empty, or which of its entries are frame sources
    (a dataset's root holding recordings), so the message says what to give instead."""
    if not p.is_dir():
        return ""
    try:
        empty = not any(True for _ in p.iterdir())
    except OSError:
        return ""
    if empty:
        return " (the folder is empty)"
    found = _sources_inside(p)
    return f"; frame sources inside it: {_listed(found)} (give one of them)" if found else ""


def parse_frame_range(spec, count: int, *, where="frames") -> list[int]:
    """``"0:8"`` / ``"0,3,5"`` / ``"2:"`` / ``"-4:"`` / ``"::2"`` / ``[0, 3]`` -> frame indices in
    ``range(count)`` (ValueError naming the bad part; out-of-range indices are errors, not clipped)."""
    if spec is None:
        return list(range(count))
    parts = [str(v) for v in spec] if isinstance(spec, (list, tuple)) else str(spec).split(",")
    out: list[int] = []
    for part in (p.strip() for p in parts):
        if not part:
            continue
        try:
            if ":" in part:
                bits = [int(b) if b.strip() else None for b in part.split(":")]
                if len(bits) > 3:
                    raise ValueError
                out.extend(range(count)[slice(*bits)])
                continue
            i = int(part)
        except ValueError:
            raise ValueError(f"{where}: {part!r} is not an index or a start:stop[:step] range") from None
        if not -count <= i < count:
            raise ValueError(f"{where}: index {i} is out of range (the source has {count} frames)")
        out.append(i % count)
    if not out:
        raise ValueError(f"{where}: {spec!r} selects no frame (the source has {count} frames)")
    return out


class FrameSubset(Sequence):
    """The frames ``indices`` of a lazy source, still lazy; forwards ``intrinsics`` / ``camera`` /
    ``camera_names`` / ``source_name`` of the source (and a bag's frame names and tf)."""

    def __init__(self, base: Sequence[Frame], indices: list[int]):
        self.base, self.indices = base, list(indices)
        for attr in ("intrinsics", "camera", "camera_names", "source_name", "path", "report",
                     "lidar_frame_id", "camera_frame_id", "tf_T_cam_lidar"):  # a bag's frame names and tf
            if hasattr(base, attr):
                setattr(self, attr, getattr(base, attr))

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return self.base[self.indices[index]]

    @property
    def frame_keys(self) -> list[str]:
        keys = getattr(self.base, "frame_keys", None)
        return [keys[i] for i in self.indices] if keys is not None else [str(i) for i in self.indices]


def image_size_of(frame: Frame) -> tuple[int, int] | None:
    """(width, height) of a frame's image: its array's, or, for a frame read without decoding its
    image (``decode_images=False`` of a frame folder or an HDF5 cache), the size its reader took from
    the image's header; None when the frame has no image."""
    from .images import image_header_size

    img = np.asarray(frame.image)
    if img.ndim >= 2 and min(img.shape[:2]) > 1:
        return int(img.shape[1]), int(img.shape[0])
    meta = frame.meta or {}
    if meta.get("image_size") is not None:
        w, h = meta["image_size"]
        return int(w), int(h)
    blob = (meta.get("image_bytes") or {}).get(frame.camera_name)
    if blob is None and meta.get("image_bytes"):
        blob = next(iter(meta["image_bytes"].values()))
    return None if blob is None else image_header_size(bytes(blob[:1 << 18]))


def camera_view(frame: Frame, name: str) -> Frame:
    """One camera of a multi-camera frame (``Frame.images`` / ``camera_per_det``) as a plain
    single-camera frame: that camera's image, 2D boxes, match-matrix rows, and its intrinsics and
    extrinsics when the frame carries them per camera."""
    image, points, b2, b3, mm = frame.camera_view(name)
    keep = (np.ones(frame.num_2d, dtype=bool) if frame.camera_per_det is None
            else np.array([c == name for c in frame.camera_per_det], dtype=bool))
    intr = (frame.meta.get("intrinsics_by_camera") or {}).get(name, frame.intrinsics if name == frame.camera_name
                                                             else None)
    extr = (frame.meta.get("extrinsics_by_camera") or {}).get(name, frame.extrinsics if name == frame.camera_name
                                                             else None)
    meta = {k: v for k, v in frame.meta.items() if k not in ("intrinsics_by_camera", "extrinsics_by_camera")}
    meta["kept_2d_indices"] = np.flatnonzero(keep)
    return Frame(image=image, point_cloud=points, bboxes_2d=b2, bboxes_3d=b3, camera_name=name,
                 frame_key=frame.frame_key, match_matrix=mm, intrinsics=intr, extrinsics=extr,
                 point_fields=frame.point_fields, meta=meta, lidar_time_s=frame.lidar_time_s,
                 camera_time_s=frame.camera_time_s, track_ids_3d=frame.track_ids_3d,
                 velocities_3d=frame.velocities_3d, detections=_kept_detections(frame.detections, keep))


def _kept_detections(made, keep: np.ndarray):
    """A frame's :class:`~xcalib.types.FrameDetections` for its 2D boxes ``keep`` (one camera's, see
    :func:`camera_view`): the per-box scores and classes of those boxes only (the whole frame's do
    not line up with one camera's boxes, and scores of another length are not used)."""
    if made is None:
        return None
    pick = np.flatnonzero(keep)
    cut = {k: tuple(v[i] for i in pick) for k in ("scores_2d", "classes_2d")
           if (v := getattr(made, k)) is not None and len(v) == len(keep)}
    return dataclasses.replace(made, **cut) if cut else made


class CameraView(Sequence):
    """A multi-camera source seen through one camera (:func:`camera_view` per frame)."""

    def __init__(self, base: Sequence[Frame], camera: str):
        self.base, self.camera = base, camera
        self.intrinsics = None
        for attr in ("source_name", "path"):
            if hasattr(base, attr):
                setattr(self, attr, getattr(base, attr))

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return camera_view(self.base[index], self.camera)

    @property
    def frame_keys(self) -> list[str]:
        return list(getattr(self.base, "frame_keys", [str(i) for i in range(len(self))]))


def open_source(path, *, source: str | None = None, camera: str | None = None, frames=None,
                **options) -> Sequence[Frame]:
    """Open ``path`` with the named ``source`` (default: detected) as a lazy ``Sequence[Frame]``;
    ``camera`` picks a camera, ``frames`` a subset (see :func:`parse_frame_range`); other options
    go to the source's ``open``."""
    p = Path(path)
    if source is None:
        src = find_source(p)
    else:
        _load_modules()
        if source not in _REGISTRY:
            raise ValueError(f"unknown frame source {source!r}; known: {', '.join(s.name for s in frame_sources())}")
        src = _REGISTRY[source]
        if not p.exists():
            raise FileNotFoundError(f"frame source not found: {p}")
    seq = src.open(p, camera=camera, **options) if camera is not None else src.open(p, **options)
    if not hasattr(seq, "source_name"):
        try:
            seq.source_name = src.name
        except AttributeError:
            pass
    if frames is not None:
        seq = FrameSubset(seq, parse_frame_range(frames, len(seq)))
    return seq


def merge_cameras(views: dict[str, Sequence[Frame]]) -> list[Frame]:
    """Per-camera views of the same recording (frame ``i`` of each = the same LiDAR sweep) -> one
    multi-camera frame per sweep: ``images`` per camera, every camera's 2D boxes
    (``camera_per_det``), the union of their 3D boxes (identical rows merged), the match matrix
    against that union, per-camera intrinsics / extrinsics / camera times in ``meta``."""
    names = list(views)
    counts = {n: len(v) for n, v in views.items()}
    if len(set(counts.values())) != 1:
        raise ValueError(f"merge_cameras: cameras have different frame counts {counts}")
    out = []
    for i in range(counts[names[0]]):
        frames = {n: views[n][i] for n in names}
        rows: dict[bytes, int] = {}
        boxes, b2, per_det, mm_parts, tracks, vels = [], [], [], [], [], []
        for n, f in frames.items():
            b3 = np.asarray(f.bboxes_3d, dtype=np.float32)
            cols = []
            for k, r in enumerate(b3):
                key = r.tobytes()
                if key not in rows:
                    rows[key] = len(boxes)
                    boxes.append(r)
                    tracks.append(None if f.track_ids_3d is None else int(f.track_ids_3d[k]))
                    vels.append(None if f.velocities_3d is None else np.asarray(f.velocities_3d[k], np.float64))
                cols.append(rows[key])
            b2.append(np.asarray(f.bboxes_2d, dtype=np.float32).reshape(-1, 4))
            per_det += [n] * f.num_2d
            mm_parts.append((f.match_matrix, cols, f.num_2d))
        width = frames[names[0]].bboxes_3d.shape[1] if boxes else 6
        union = np.asarray(boxes, dtype=np.float32).reshape(-1, width)
        mm = None
        if all(m is not None for m, _, _ in mm_parts):
            mm = np.zeros((len(per_det), len(union)), dtype=bool)
            r0 = 0
            for m, cols, k in mm_parts:
                if k:
                    mm[r0:r0 + k][:, cols] = np.asarray(m, dtype=bool)
                r0 += k
        first = frames[names[0]]
        dets = _merged_detections(frames, i)
        out.append(Frame(image=first.image, point_cloud=first.point_cloud, bboxes_2d=np.vstack(b2), bboxes_3d=union,
                         camera_name=names[0], frame_key=first.frame_key, match_matrix=mm,
                         intrinsics=first.intrinsics, extrinsics=first.extrinsics,
                         images={n: f.image for n, f in frames.items()}, camera_per_det=per_det,
                         point_fields=first.point_fields,
                         meta={"intrinsics_by_camera": {n: f.intrinsics for n, f in frames.items()},
                               "extrinsics_by_camera": {n: f.extrinsics for n, f in frames.items()},
                               "camera_time_s_by_camera": {n: f.camera_time_s for n, f in frames.items()},
                               "frame_key_by_camera": {n: f.frame_key for n, f in frames.items()}},
                         lidar_time_s=first.lidar_time_s,
                         track_ids_3d=None if any(t is None for t in tracks) else np.asarray(tracks, np.int64),
                         velocities_3d=None if any(v is None for v in vels) else np.asarray(vels).reshape(-1, 3),
                         detections=dets))
    return out


def _merged_detections(frames: dict[str, Frame], index: int) -> FrameDetections | None:
    """The cameras' ``Frame.detections`` of one sweep as one record for the merged frame: the 2D scores
    and classes in the merged frame's box order (camera by camera), None where any camera lacks them.
    Cameras whose boxes came from different detectors cannot share one record: a warning names them
    and the merged frame carries none (its boxes are then used as they are, unweighted)."""
    recs = {n: f.detections for n, f in frames.items()}
    if all(r is None for r in recs.values()):
        return None
    kinds = {(r.source, r.detector_2d, r.lidar_mode) if r is not None else None for r in recs.values()}
    if len(kinds) != 1:
        import warnings

        said = ", ".join(f"{n}: {r.source if r is not None else 'none'}" for n, r in recs.items())
        warnings.warn(f"merge_cameras: frame {index}: the cameras' boxes come from different detectors ({said}); "
                      "the merged frame keeps no detector record (scores not used)", stacklevel=3)
        return None

    def joined(field: str):
        parts = []
        for n, f in frames.items():
            v = getattr(recs[n], field)
            if v is None or len(v) != f.num_2d:
                return None
            parts.extend(v)
        return tuple(parts)

    r0 = next(iter(recs.values()))
    return dataclasses.replace(r0, scores_2d=joined("scores_2d"), classes_2d=joined("classes_2d"))
