"""HDF5 frame caches (``../shared/specs/hdf5-cache-format.md``): lazy reader and atomic writer.

Layout (spec) ::

    /images/<cam>/data                          vlen uint8 [n]   JPEG blobs, index = frame index
    /point_clouds/<lidar>/<key>/xyz             float32 [P,3]    LiDAR frame, metres
    /labels/<sensor>/<key>/num_camera_detections, num_lidar_detections   scalar K, M
    /labels/<sensor>/<key>/camera_bbox_2d       float32 [>=K,4]  pixels (x1,y1,x2,y2)
    /labels/<sensor>/<key>/lidar_bbox_3d        float32 [>=M,6]  protocol boxes, LiDAR frame
    /labels/<sensor>/<key>/match_matrix         uint8 [K,M]      (optional here: None when absent)
    /labels/<sensor>/<key>/camera_names         bytes [K]        (optional) source camera per box
    /calibration/<cam>/intrinsics               float64 [3,3]    (optional)
    /calibration/<cam>/extrinsics[/<key>]       float64 [4,4]    LiDAR->camera, one or per frame

xcalib's additive extras (ignored by spec readers): ``/calibration/<cam>/intrinsics@camera_model``
(a wide-angle camera model as xcalib's intrinsics JSON text; K is then its fx, fy, cx, cy only, not
the camera), ``/calibration/<cam>/distortion`` [n]
(OpenCV order), image size as ``width``/``height`` attributes of ``intrinsics``;
``lidar_bbox_7`` float64 [>=M,7] (box7 with yaw, exposed as ``Frame.meta["box7"]``),
``lidar_bbox_7_gt`` [M,7] / ``camera_bbox_2d_clean`` [K,4] (noise-free boxes: ``meta["box7_gt"]``,
``["boxes_2d_clean"]``), ``camera_visibility`` / ``camera_truncation`` float64 [K]
(``meta["visibility_2d"]``, ``["truncation_2d"]``), ``camera_object_ids`` / ``lidar_object_ids``
int64 and ``camera_classes`` / ``lidar_classes`` bytes per detection (``meta["ids_2d"]``,
``["ids_3d"]``, ``["classes_2d"]``, ``["classes_3d"]``);
extra point columns as ``/point_clouds/<lidar>/<key>/<field>`` [P] listed in the group's
``fields`` attribute; per-frame timing and tracks in the label group (``Frame`` fields of the
same meaning): ``lidar_time_s`` / ``camera_time_s`` float64 scalars (seconds, one clock),
``lidar_track_ids`` int64 [>=M] (``Frame.track_ids_3d``, -1 = none), ``lidar_velocities``
float64 [>=M,3] (``Frame.velocities_3d``, m/s, LiDAR frame).

Unlike the reference loader: any label sensor / LiDAR can be chosen (a warning when several exist
and none was chosen), numeric keys can be ordered numerically, K==0 / M==0 frames are returned,
``Frame.camera_view`` filters the match matrix, and the file closes itself when the reader is
garbage collected or closed.
"""

from __future__ import annotations

import json
import logging
import os
import uuid
import weakref
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics, check_camera_numbers
from ..types import DatasetFrame, Frame
from .files import tmp_prefix, open_regular, sweep_stale
from .pointcloud import MAX_COORD_M
from ._validate import check_boxes_2d, check_boxes_3d, check_count, check_rigid
from .timing import checked_timing, timing_of

__all__ = ["CacheReader", "CacheWriter", "write_cache", "load_dataset", "open_dataset", "Dataset", "cache_summary",
           "CorruptImageError", "is_hdf5_cache", "HDF5_SUFFIXES"]

log = logging.getLogger(__name__)

HDF5_SUFFIXES = (".h5", ".hdf5")
#: A dataset may declare at most this many bytes beyond 32x the file size (compression of float
#: data stays far below 32:1); larger declarations are refused before anything is allocated.
_DECLARED_SLACK = 64 << 20
_DECLARED_RATIO = 32
_KEY_ORDERS = ("lexicographic", "numeric")
# Frame.meta key -> (dataset name, kind) of the additive per-detection extras.
_META_DATASETS = {
    "box7": ("lidar_bbox_7", "f3d7"),
    "box7_gt": ("lidar_bbox_7_gt", "f3d7"),
    "boxes_2d_clean": ("camera_bbox_2d_clean", "f2d4"),
    "visibility_2d": ("camera_visibility", "v2d"),
    "truncation_2d": ("camera_truncation", "v2d"),
    "ids_2d": ("camera_object_ids", "i2d"),
    "ids_3d": ("lidar_object_ids", "i3d"),
    "classes_2d": ("camera_classes", "s2d"),
    "classes_3d": ("lidar_classes", "s3d"),
}

# Frame timing/track field -> dataset of the label group (additive, optional).
_TIMING_DATASETS = {"lidar_time_s": "lidar_time_s", "camera_time_s": "camera_time_s",
                    "track_ids_3d": "lidar_track_ids", "velocities_3d": "lidar_velocities"}


class CorruptImageError(FormatError):
    """A frame's image blob could not be decoded (iteration skips such frames with one warning)."""


def is_hdf5_cache(path) -> bool:
    """True for an existing file with an .h5/.hdf5 suffix (used by ``read_frames``)."""
    p = Path(path)
    return p.is_file() and p.suffix.lower() in HDF5_SUFFIXES


def _h5py():
    try:
        import h5py
    except ImportError as exc:  # pragma: no cover - h5py is a core dependency
        raise ImportError("HDF5 caches need h5py: pip install h5py") from exc
    return h5py


def _as_str(v) -> str:
    return v.decode("utf-8") if isinstance(v, (bytes, np.bytes_)) else str(v)


def _numeric(key: str) -> bool:
    return key.isascii() and key.isdigit()


def _match_camera(name: str, candidates: Iterable[str]) -> str | None:
    """Canonicalise a camera name against ``candidates``: exact, then suffix match either way."""
    cands = list(candidates)
    if name in cands:
        return name
    hits = [c for c in cands if c.endswith(name) or name.endswith(c)]
    return hits[0] if len(hits) == 1 else (min(hits, key=len) if hits else None)


# --------------------------------------------------------------------------------- reader
class CacheReader(Sequence):
    """Lazy ``Sequence[Frame]`` over an HDF5 cache (one frame read per access).

    Args:
        path: the .h5 file.
        label_sensor: subgroup of ``/labels`` to read (default: first key alphabetically, as the
            spec says; a warning names the others when there are several).
        lidar_name: subgroup of ``/point_clouds`` (default: first alphabetically, warned likewise).
        key_order: ``"lexicographic"`` (spec) or ``"numeric"`` (all keys numeric; sorted by value).
            With the spec order a warning is logged once when non-padded numeric keys make it
            differ from numeric order.
        read_images: False skips images entirely (``Frame.image`` is an empty [0,0,3] array).
        decode_images: False keeps the encoded blobs in ``Frame.meta["image_bytes"]`` ({cam: bytes})
            instead of decoding them.
        read_extras: False skips xcalib's additive per-detection datasets (``lidar_bbox_7``, ids,
            classes, ...; see the module docstring). ``read_images=False, read_extras=False`` is the
            fastest path (labels + points only).

    ``len`` counts every labelled frame. ``reader[i]`` / ``reader[key]`` raise
    :class:`CorruptImageError` for a frame whose image does not decode; iteration skips such
    frames and logs ONE warning naming all of them at the end (``skipped_keys`` lists them), so
    iteration may yield fewer than ``len`` frames, never more.
    Use as a context manager or call ``close()``; the file is also closed on garbage collection.
    """

    def __init__(self, path, *, label_sensor: str | None = None, lidar_name: str | None = None,
                 key_order: str = "lexicographic", read_images: bool = True, decode_images: bool = True,
                 read_extras: bool = True):
        h5py = _h5py()
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"HDF5 cache not found: {self.path}")
        if key_order not in _KEY_ORDERS:
            raise ValueError(f"key_order must be one of {_KEY_ORDERS}, got {key_order!r}")
        open_regular(self.path, max_bytes=1 << 46, what="HDF5 cache").close()  # FIFOs / devices refused
        self._max_bytes = self.path.stat().st_size * _DECLARED_RATIO + _DECLARED_SLACK
        try:
            self._f = h5py.File(self.path, "r")
        except (OSError, ValueError) as exc:
            raise FormatError(self.path, f"not a readable HDF5 file ({exc})") from None
        self._finalizer = weakref.finalize(self, self._f.close)
        try:
            self._open_layout(label_sensor, lidar_name, key_order, read_images, decode_images, read_extras)
        except FormatError:
            raise
        except (OSError, KeyError, ValueError, TypeError, RuntimeError) as exc:  # h5py: checksums, truncation
            self.close()
            raise FormatError(self.path, f"corrupt HDF5 layout ({type(exc).__name__}: {str(exc)[:200]})") from None

    def _open_layout(self, label_sensor, lidar_name, key_order, read_images, decode_images, read_extras) -> None:
        h5py = _h5py()
        self.read_images = bool(read_images)
        self.decode_images = bool(decode_images)
        self.read_extras = bool(read_extras)
        self.skipped_keys: list[str] = []
        f = self._f
        for grp in ("labels", "point_clouds", "images"):
            if grp not in f or not isinstance(f[grp], h5py.Group):
                self.close()
                raise FormatError(self.path, f"missing root group /{grp} (expected /images, "
                                             f"/point_clouds and /labels)", field=f"/{grp}")
        self.label_sensors = sorted(f["labels"].keys())
        self.lidar_names = sorted(f["point_clouds"].keys())
        self.camera_names = list(f["images"].keys())
        if not self.label_sensors:
            self.close()
            raise FormatError(self.path, "/labels has no sensor subgroup", field="/labels")
        if not self.lidar_names:
            self.close()
            raise FormatError(self.path, "/point_clouds has no LiDAR subgroup", field="/point_clouds")
        if not self.camera_names:
            self.close()
            raise FormatError(self.path, "/images has no camera subgroup", field="/images")
        self.label_sensor = self._choose(label_sensor, self.label_sensors, "label sensor", "/labels")
        self.lidar_name = self._choose(lidar_name, self.lidar_names, "LiDAR", "/point_clouds")
        keys = sorted(f["labels"][self.label_sensor].keys())
        numeric = bool(keys) and all(_numeric(k) for k in keys)
        if key_order == "numeric":
            if not numeric:
                bad = next(k for k in keys if not _numeric(k))
                self.close()
                raise FormatError(self.path, f"key_order='numeric' needs numeric frame keys; found {bad!r}",
                                  field=f"/labels/{self.label_sensor}")
            keys = sorted(keys, key=lambda k: (int(k), k))
        elif numeric and keys != sorted(keys, key=lambda k: (int(k), k)):
            log.warning("%s: frame keys are numeric but not zero-padded, so the spec's lexicographic "
                        "order (%s, %s, ...) differs from numeric order; pass key_order='numeric' "
                        "to iterate in numeric order", self.path, keys[0], keys[1] if len(keys) > 1 else "")
        self.key_order = key_order
        self._keys = keys
        # Spec: numeric keys index the blob array, others their position in the sorted key list.
        lex = sorted(keys)
        pos = {k: i for i, k in enumerate(lex)}
        self._image_index = {k: (int(k) if _numeric(k) else pos[k]) for k in keys}
        self._key_pos = {k: i for i, k in enumerate(keys)}
        self._calib_cache: dict | None = None
        self._static: dict[str, dict] = {}

    def _choose(self, wanted, names, what, group) -> str:
        if wanted is not None:
            if wanted not in names:
                self.close()
                raise FormatError(self.path, f"no {what} {wanted!r}; available: {names}", field=group)
            return wanted
        if len(names) > 1:
            log.warning("%s: %d %ss under %s (%s); reading %r (pass %s= to choose)", self.path, len(names),
                        what, group, ", ".join(names), names[0],
                        "label_sensor" if group == "/labels" else "lidar_name")
        return names[0]

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        """Close the file (idempotent)."""
        self._finalizer()

    @property
    def closed(self) -> bool:
        return not self._finalizer.alive

    def __enter__(self) -> "CacheReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"CacheReader({str(self.path)!r}, frames={len(self._keys)}, sensor={self.label_sensor!r}, "
                f"lidar={self.lidar_name!r}, cameras={self.camera_names})")

    # ---------------------------------------------------------------- sequence API
    @property
    def frame_keys(self) -> list[str]:
        """Frame keys in iteration order."""
        return list(self._keys)

    def __len__(self) -> int:
        return len(self._keys)

    def __getitem__(self, index) -> Frame:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        if isinstance(index, str):
            if index not in self._key_pos:
                raise KeyError(f"{self.path}: no frame {index!r} under /labels/{self.label_sensor}")
            return self.read_frame(index)
        i = int(index)
        n = len(self._keys)
        if not -n <= i < n:
            raise IndexError(f"{self.path}: frame index {index} out of range for {n} frames")
        return self.read_frame(self._keys[i])

    def __iter__(self) -> Iterator[Frame]:
        bad: list[str] = []
        for key in self._keys:
            try:
                frame = self.read_frame(key)
            except CorruptImageError:
                bad.append(key)
                continue
            yield frame
        self.skipped_keys = bad
        if bad:
            log.warning("%s: skipped %d frame(s) whose image did not decode: %s", self.path, len(bad),
                        ", ".join(bad[:20]) + (" ..." if len(bad) > 20 else ""))

    def camera_views(self, name: str) -> Iterator[tuple]:
        """Per frame ``(image, point_cloud, bboxes_2d, bboxes_3d, match_matrix)`` of camera ``name``
        (exact or suffix match); the match matrix keeps only that camera's rows."""
        cam = _match_camera(name, self.camera_names)
        if cam is None:
            raise KeyError(f"{self.path}: no camera {name!r}; cameras: {self.camera_names}")
        for frame in self:
            if frame.camera_per_det is not None and cam not in frame.camera_per_det and frame.camera_name != cam:
                continue
            yield frame.camera_view(cam)

    def for_camera(self, name: str) -> Iterator[tuple]:
        """Per frame the reference's 4 values ``(image, point_cloud, bboxes_2d, bboxes_3d)`` of
        camera ``name`` (:meth:`camera_views` adds the match matrix)."""
        for view in self.camera_views(name):
            yield view[:4]

    # ----------------------------------------------------------------- one frame
    def _group(self, path: str, key: str, what: str) -> "_Group":
        try:
            return _Group(self._f.id, path)
        except KeyError:
            raise FormatError(self.path, f"frame {key!r}: missing {what} group", field=path) from None

    def read_frame(self, key: str) -> Frame:
        """Read frame ``key`` (labels, points, images per the reader's options, calibration).
        Counts must be integral, boxes finite and not inverted, extrinsics rigid; any HDF5-level
        failure (checksum, truncation, a declared size beyond what the file can hold) is a
        FormatError naming the frame."""
        if self.closed:
            raise ValueError(f"{self.path}: the cache is closed")
        try:
            return self._read_frame(key)
        except FormatError as exc:
            if exc.path is None:  # raised below the reader (dataset size check): name the file
                raise type(exc)(self.path, exc.problem, exc.field) from None
            raise
        except (OSError, ValueError, TypeError, KeyError, IndexError, OverflowError, MemoryError, RuntimeError,
                UnicodeDecodeError) as exc:
            raise FormatError(self.path, f"frame {key!r}: unreadable ({type(exc).__name__}: {str(exc)[:200]})",
                              field=f"/labels/{self.label_sensor}/{key}") from None

    def _read_frame(self, key: str) -> Frame:
        where = f"/labels/{self.label_sensor}/{key}"
        g = self._group(where, key, "labels")
        g.max_bytes = self._max_bytes
        K = check_count(self.path, f"{where}/num_camera_detections", g.require("num_camera_detections", self, key))
        M = check_count(self.path, f"{where}/num_lidar_detections", g.require("num_lidar_detections", self, key))
        b2_all = g.require("camera_bbox_2d", self, key)
        b3_all = g.require("lidar_bbox_3d", self, key)
        b2 = check_boxes_2d(self.path, f"{where}/camera_bbox_2d", self._rows(b2_all, "camera_bbox_2d", K, 4, key, where))
        b3 = check_boxes_3d(self.path, f"{where}/lidar_bbox_3d", self._rows(b3_all, "lidar_bbox_3d", M, 6, key, where))
        mm = None
        if "match_matrix" in g:
            raw = g.read("match_matrix")
            if raw.ndim != 2 and raw.size == 0 and K * M == 0:
                raw = raw.reshape(K, M)
            stored = (b2_all.shape[:1] + b3_all.shape[:1])
            ok = raw.ndim == 2 and (raw.shape == (K, M) or raw.shape == stored)
            if not ok:
                raise FormatError(self.path, f"frame {key!r}: match_matrix has shape {tuple(raw.shape)}, "
                                             f"expected (K, M) = ({K}, {M})", field=f"{where}/match_matrix")
            if raw.size and not np.isin(raw[:K, :M], (0, 1)).all():
                raise FormatError(self.path, f"frame {key!r}: match_matrix holds values other than 0/1",
                                  field=f"{where}/match_matrix")
            mm = raw[:K, :M].astype(bool)
        cams_per_det = None
        if "camera_names" in g:
            names = [_as_str(n) for n in g.read("camera_names").reshape(-1)]
            if len(names) < K:
                raise FormatError(self.path, f"frame {key!r}: camera_names has {len(names)} entries, "
                                             f"expected K = {K}", field=f"{where}/camera_names")
            cams_per_det = []
            for n in names[:K]:
                c = _match_camera(n, self.camera_names)
                if c is None:
                    raise FormatError(self.path, f"frame {key!r}: detection camera {n!r} is not under "
                                                 f"/images (cameras: {self.camera_names})",
                                      field=f"{where}/camera_names")
                cams_per_det.append(c)
        meta: dict = {}
        for mkey, (dname, kind) in (_META_DATASETS.items() if self.read_extras else ()):
            if dname in g:
                n = K if "2d" in kind else M
                if kind == "f3d7":  # the yawed boxes the calibration uses: checked as the [M,6] ones
                    meta[mkey] = check_boxes_3d(self.path, f"{where}/{dname}",
                                                self._rows(g.read(dname), dname, M, 7, key, where, np.float64))
                elif kind == "f2d4":
                    meta[mkey] = self._rows(g.read(dname), dname, K, 4, key, where, np.float64)
                else:
                    arr = g.read(dname).reshape(-1)
                    if len(arr) < n:
                        raise FormatError(self.path, f"frame {key!r}: {dname} has {len(arr)} rows, expected "
                                                     f">= {n}", field=f"{where}/{dname}")
                    if kind.startswith("s"):
                        meta[mkey] = [_as_str(s) for s in arr[:n]]
                    else:
                        meta[mkey] = arr[:n].astype(np.float64 if kind.startswith("v") else np.int64)
        timing = self._timing(g, key, where, M)
        points, fields = self._points(key)
        # Images: every camera referenced by the frame (or the first camera).
        primary = cams_per_det[0] if cams_per_det else self.camera_names[0]
        referenced = list(dict.fromkeys(cams_per_det)) if cams_per_det else [primary]
        image = np.zeros((0, 0, 3), dtype=np.uint8)
        images = None
        if self.read_images:
            blobs = {c: self._blob(c, key) for c in referenced}
            if self.decode_images:
                images = {c: self._decode(b, c, key) for c, b in blobs.items()}
                image = images[primary]
            else:
                meta["image_bytes"] = blobs
        intr, extr, intr_all, extr_all = self._calibration(key, referenced, primary, image)
        if intr_all:
            meta["intrinsics_by_camera"] = intr_all
        if extr_all:
            meta["extrinsics_by_camera"] = extr_all
        return Frame(image=image, point_cloud=points, bboxes_2d=b2, bboxes_3d=b3, camera_name=primary,
                     frame_key=key, match_matrix=mm, intrinsics=intr, extrinsics=extr, images=images,
                     camera_per_det=cams_per_det if cams_per_det is not None else [primary] * K,
                     point_fields=fields, meta=meta, **timing)

    def _timing(self, g: "_Group", key: str, where: str, M: int) -> dict:
        """The optional timing / track datasets of a label group, validated."""
        vals, names = {}, {}
        for field, dname in _TIMING_DATASETS.items():
            if dname in g:
                v = g.read(dname)
                if field in ("track_ids_3d", "velocities_3d") and v.ndim >= 1 and len(v) >= M:
                    v = v[:M]
                vals[field], names[field] = v, f"{where}/{dname}"
        return checked_timing(self.path, M, fields=names, **vals) if vals else {}

    def _rows(self, arr: np.ndarray, name: str, n: int, width: int, key: str, where: str,
              dtype=np.float32) -> np.ndarray:
        if n < 0:
            raise FormatError(self.path, f"frame {key!r}: negative detection count {n}", field=f"{where}/{name}")
        shape = arr.shape
        if n == 0 and (len(shape) == 0 or shape[0] == 0 or (len(shape) == 2 and shape[1] == width)):
            return np.zeros((0, width), dtype=dtype)
        if len(shape) != 2 or shape[1] != width:
            raise FormatError(self.path, f"frame {key!r}: {name} has shape {shape}, expected [>= {n}, {width}]",
                              field=f"{where}/{name}")
        if shape[0] < n:
            raise FormatError(self.path, f"frame {key!r}: {name} stores {shape[0]} rows but the count says "
                                         f"{n}", field=f"{where}/{name}")
        return np.ascontiguousarray(arr[:n], dtype=dtype)

    def _points(self, key: str) -> tuple[np.ndarray, tuple[str, ...]]:
        where = f"/point_clouds/{self.lidar_name}/{key}"
        pg = self._group(where, key, "point cloud")
        pg.max_bytes = self._max_bytes
        xyz = pg.require("xyz", self, key)
        if xyz.ndim != 2 or xyz.shape[1] < 3:
            raise FormatError(self.path, f"frame {key!r}: xyz has shape {xyz.shape}, expected [P, 3]",
                              field=f"{where}/xyz")
        xyz = _checked_xyz(self.path, f"{where}/xyz", key, xyz)
        extra = pg.field_names()
        if not extra:
            return (xyz[:, :3] if xyz.shape[1] != 3 else xyz), ("x", "y", "z")
        cols = [xyz[:, :3]]
        for name in extra:
            cols.append(np.asarray(pg.require(name, self, key), dtype=np.float32).reshape(len(xyz), -1))
        return np.hstack(cols), ("x", "y", "z", *extra)

    def _blob(self, cam: str, key: str) -> bytes:
        where = f"/images/{cam}/data"
        ds = self._f.get(where)
        if ds is None:
            raise FormatError(self.path, f"frame {key!r}: missing image dataset", field=where)
        idx = self._image_index[key]
        if not 0 <= idx < len(ds):
            raise CorruptImageError(self.path, f"frame {key!r}: image index {idx} outside the {len(ds)} "
                                               "stored blobs", field=where)
        return np.asarray(ds[idx], dtype=np.uint8).tobytes()

    def _decode(self, blob: bytes, cam: str, key: str) -> np.ndarray:
        from .images import decode_image

        where = f"/images/{cam}/data[{self._image_index[key]}]"
        if not blob:  # what the writer stores for a frame without image pixels (CacheWriter._encode)
            return np.zeros((0, 0, 3), dtype=np.uint8)
        try:
            return decode_image(blob, source=f"{self.path}:{where}")
        except FormatError as exc:
            raise CorruptImageError(self.path, f"frame {key!r}: {exc.problem}", field=where) from None

    # ---------------------------------------------------------------- calibration
    def _calib_groups(self) -> dict[str, str]:
        """image camera name -> /calibration subgroup name (canonicalised, exact or suffix)."""
        if self._calib_cache is None:
            out: dict[str, str] = {}
            cal = self._f.get("calibration")
            if cal is not None:
                for cname in cal.keys():
                    cam = _match_camera(cname, self.camera_names)
                    if cam is not None and cam not in out:
                        out[cam] = cname
            self._calib_cache = out
        return self._calib_cache

    def _calibration(self, key, cams, primary, image):
        groups = self._calib_groups()
        intr_all: dict[str, CameraIntrinsics] = {}
        extr_all: dict[str, np.ndarray] = {}
        for cam in cams:
            cname = groups.get(cam)
            if cname is None:
                continue
            static = self._static_calib(cam, cname, image if cam == primary else None)
            if static["intrinsics"] is not None:
                intr_all[cam] = static["intrinsics"]
            T = static["extrinsics"]
            if T is None and static["per_frame"]:
                eg = f"/calibration/{cname}/extrinsics"
                g = _Group(self._f.id, eg)
                T = g.read(key) if key in g else None
                if T is not None and T.shape != (4, 4):
                    raise FormatError(self.path, f"frame {key!r}: extrinsics have shape {T.shape}, "
                                                 "expected [4, 4]", field=f"{eg}/{key}")
                if T is not None:
                    check_rigid(self.path, f"{eg}/{key}", T)
            if T is not None:
                extr_all[cam] = np.array(T, dtype=np.float64)
        return intr_all.get(primary), extr_all.get(primary), intr_all, extr_all

    def _static_calib(self, cam: str, cname: str, image) -> dict:
        """Intrinsics and a single extrinsics matrix of one camera, read once."""
        cache = self._static.get(cam)
        if cache is not None and not (cache["intrinsics"] is not None and cache["intrinsics"].width is None
                                      and image is not None and image.size):
            return cache
        cg = self._f[f"calibration/{cname}"]
        where = f"/calibration/{cname}"
        intr = None
        if "intrinsics" in cg:
            ds = cg["intrinsics"]
            Km = np.asarray(ds[()], dtype=np.float64)
            if Km.shape != (3, 3):
                raise FormatError(self.path, f"intrinsics have shape {Km.shape}, expected [3, 3]",
                                  field=f"{where}/intrinsics")
            dist = np.asarray(cg["distortion"][()], dtype=np.float64) if "distortion" in cg else None
            w, h = ds.attrs.get("width"), ds.attrs.get("height")
            if w is None and image is not None and image.size:
                h, w = image.shape[:2]
            if "camera_model" in ds.attrs:  # a wide-angle camera model (the writer's extra)
                intr = _camera_model_attr(self.path, f"{where}/intrinsics@camera_model", ds.attrs["camera_model"], Km)
            else:
                intr = None
            try:
                intr = intr or CameraIntrinsics.from_matrix(Km, dist, width=None if w is None else check_count(
                    self.path, f"{where}/intrinsics@width", w), height=None if h is None else check_count(
                    self.path, f"{where}/intrinsics@height", h))
            except (TypeError, ValueError) as exc:
                if isinstance(exc, FormatError):
                    raise
                raise FormatError(self.path, str(exc), field=f"{where}/intrinsics") from None
            _plausible(intr, self.path, f"{where}/intrinsics")
        T, per_frame = None, False
        if "extrinsics" in cg:
            e = cg["extrinsics"]
            if hasattr(e, "keys"):
                per_frame = True
            else:
                T = np.asarray(e[()], dtype=np.float64)
                if T.shape != (4, 4):
                    raise FormatError(self.path, f"extrinsics have shape {T.shape}, expected [4, 4]",
                                      field=f"{where}/extrinsics")
                check_rigid(self.path, f"{where}/extrinsics", T)
        cache = {"intrinsics": intr, "extrinsics": T, "per_frame": per_frame}
        self._static[cam] = cache
        return cache


class _Group:
    """Low-level view of one HDF5 group: member names and whole-dataset reads (fast per-frame access)."""

    __slots__ = ("gid", "names", "path", "max_bytes")

    def __init__(self, fid, path: str):
        import h5py

        try:
            self.gid = h5py.h5g.open(fid, path.encode())
        except (KeyError, ValueError):
            raise KeyError(path) from None
        self.path = path
        self.max_bytes = None
        self.names = {n.decode() for n in self.gid}

    def __contains__(self, name: str) -> bool:
        return name in self.names

    def read(self, name: str) -> np.ndarray:
        import h5py

        d = h5py.h5d.open(self.gid, name.encode())
        nbytes = int(np.prod(d.shape, dtype=object)) * d.dtype.itemsize
        if self.max_bytes is not None and nbytes > self.max_bytes:
            raise FormatError(None, f"dataset {self.path}/{name} declares shape {d.shape} ({nbytes} bytes), more than "
                                    f"the file can hold ({self.max_bytes} bytes allowed)", field=f"{self.path}/{name}")
        arr = np.empty(d.shape, dtype=d.dtype)
        if arr.size:
            d.read(h5py.h5s.ALL, h5py.h5s.ALL, arr)
        return arr

    def require(self, name: str, reader: "CacheReader", key: str) -> np.ndarray:
        if name not in self.names:
            raise FormatError(reader.path, f"frame {key!r}: missing dataset {name!r}", field=f"{self.path}/{name}")
        return self.read(name)

    def field_names(self) -> list[str]:
        import h5py

        if not h5py.h5a.exists(self.gid, b"fields"):
            return []
        a = h5py.h5a.open(self.gid, b"fields")
        arr = np.empty(a.shape, dtype=a.dtype)
        a.read(arr)
        return [_as_str(v) for v in arr.reshape(-1)]


class Dataset:
    """What the reference's ``load_dataset`` returns: a sequence of :class:`xcalib.types.DatasetFrame`
    (``intrinsics`` / ``extrinsics`` as ``{camera: matrix}`` dicts, ``for_camera`` -> 4 values)
    over a :class:`CacheReader` (``reader``). Iteration skips frames whose image does not decode,
    as the reader does. A context manager; ``close()`` closes the file."""

    def __init__(self, reader: CacheReader):
        self.reader = reader

    def __len__(self) -> int:
        return len(self.reader)

    def __getitem__(self, index):
        got = self.reader[index]
        return [DatasetFrame(f) for f in got] if isinstance(got, list) else DatasetFrame(got)

    def __iter__(self) -> Iterator[DatasetFrame]:
        return (DatasetFrame(f) for f in self.reader)

    @property
    def camera_names(self) -> list[str]:
        return list(self.reader.camera_names)

    @property
    def path(self) -> Path:
        return self.reader.path

    def close(self) -> None:
        self.reader.close()

    def __enter__(self) -> "Dataset":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Dataset({self.reader!r})"


def load_dataset(site, split: str = "test", *, repo_id: str | None = None, revision: str | None = None,
                 token: str | None = None, local=None, **reader_kwargs) -> Dataset:
    """The reference's ``load_dataset``: :func:`open_dataset` wrapped as a :class:`Dataset` of
    reference-shaped frames. Never downloads: ``repo_id`` / ``revision`` / ``token`` are
    rejected with a ``ValueError`` naming the local alternatives."""
    if repo_id is not None or revision is not None or token is not None:
        raise ValueError("load_dataset: xcalib never downloads datasets (repo_id/revision/token given); "
                         "pass a local .h5 file or folder (local=..., or ./datasets/<site>/hdf5_cache/), or make "
                         "a site with `xcalib synth --out DIR`")
    return Dataset(open_dataset(site, split, local=local, **reader_kwargs))


def open_dataset(site, split: str = "test", *, local=None, **reader_kwargs) -> CacheReader:
    """Open a cache split as a :class:`CacheReader` of xcalib :class:`Frame`s; never downloads.

    Resolution (the reference's, minus the Hub): ``local`` (must exist) -> ``site`` as an
    .h5 file (``site`` is a site folder name or a path, as in the reference) -> a folder holding ``<split>.h5`` (as ``xcalib synth`` writes) or ``*_<split>.h5`` ->
    the checkout-local ``datasets/<site>/hdf5_cache/*_<split>.h5`` under the working directory.
    """
    if split not in ("train", "val", "test") and not Path(str(site)).is_file():
        log.warning("load_dataset: unusual split name %r (expected train, val or test)", split)
    if local is not None:
        lp = Path(local)
        if not lp.exists():
            raise FileNotFoundError(f"load_dataset: local={str(lp)!r} does not exist")
        return open_dataset(lp, split, **reader_kwargs)
    p = Path(site)
    if p.is_file():
        return CacheReader(p, **reader_kwargs)
    folders = [p] if p.is_dir() else []
    folders.append(Path.cwd() / "datasets" / str(site) / "hdf5_cache")
    for folder in folders:
        if not folder.is_dir():
            continue
        cands = [folder / f"{split}{s}" for s in HDF5_SUFFIXES]
        cands += sorted(q for s in HDF5_SUFFIXES for q in folder.glob(f"*_{split}{s}"))
        for c in cands:
            if c.is_file():
                return CacheReader(c, **reader_kwargs)
    if p.is_dir():
        raise FileNotFoundError(
            f"load_dataset: no {split!r} split in {p} (looked for {split}.h5, {split}.hdf5, *_{split}.h5). "
            f"Make a synthetic site with `xcalib synth --out {p}`.")
    raise FileNotFoundError(
        f"load_dataset: {str(site)!r} is neither an HDF5 cache, a site folder nor "
        f"./datasets/{site}/hdf5_cache. xcalib never downloads datasets; pass a local .h5 file or "
        "make a synthetic site with `xcalib synth --out DIR`.")


def cache_summary(path) -> dict:
    """Counts, cameras, LiDARs, label sensors and calibration present in a cache (no image decode)."""
    with CacheReader(path, read_images=False) as r:
        f = r._f
        n_det2 = n_det3 = n_match = 0
        for key in r.frame_keys:
            g = f[f"labels/{r.label_sensor}/{key}"]
            n_det2 += int(g["num_camera_detections"][()])
            n_det3 += int(g["num_lidar_detections"][()])
            if "match_matrix" in g:
                n_match += int(np.count_nonzero(g["match_matrix"][()]))
        cal = {}
        for cam, cname in r._calib_groups().items():
            cg = f[f"calibration/{cname}"]
            e = cg.get("extrinsics")
            cal[cam] = {"group": cname, "intrinsics": "intrinsics" in cg,
                        "extrinsics": None if e is None else ("per-frame" if hasattr(e, "keys") else "single")}
        return {"path": str(r.path), "frames": len(r), "label_sensors": r.label_sensors,
                "label_sensor": r.label_sensor, "lidars": r.lidar_names, "cameras": r.camera_names,
                "image_blobs": {c: len(f[f"images/{c}/data"]) for c in r.camera_names
                                if f"images/{c}/data" in f},
                "detections_2d": n_det2, "detections_3d": n_det3, "matches": n_match,
                "calibration": cal, "first_key": r.frame_keys[0] if len(r) else None,
                "last_key": r.frame_keys[-1] if len(r) else None}


# --------------------------------------------------------------------------------- writer
class CacheWriter:
    """Write frames to an HDF5 cache in the spec's layout, atomically.

    Everything goes to a temporary file next to ``path``; ``close()`` renames it to ``path``
    (an exception inside the ``with`` block deletes it instead), so a half-written cache never
    appears under the final name.

    Args:
        camera_names: cameras under /images (default: discovered from the frames, in first-seen
            order). Frames lacking a camera get an empty blob for it.
        lidar_name: the /point_clouds subgroup. label_sensor: the /labels subgroup (default: the
            first camera name).
        image_format: ``"jpeg"`` (spec; lossy, ``jpeg_quality``) or ``"png"`` (lossless; any
            OpenCV reader, ours included, decodes it).
        key_width: frame keys are the frame index zero-padded to this width (keeps lexicographic
            == numeric order). A frame whose ``frame_key`` is all digits keeps that key and its
            blob goes to index ``int(key)``; other keys are replaced (original in the label
            group's ``source_key`` attribute).
    """

    def __init__(self, path, *, camera_names: list[str] | None = None, lidar_name: str = "lidar",
                 label_sensor: str | None = None, image_format: str = "jpeg", jpeg_quality: int = 92,
                 key_width: int = 6, compression: str | None = None):
        h5py = _h5py()
        if image_format not in ("jpeg", "png"):
            raise ValueError(f"image_format must be 'jpeg' or 'png', got {image_format!r}")
        self.path = Path(path)
        if self.path.suffix.lower() not in HDF5_SUFFIXES:
            raise ValueError(f"CacheWriter: {self.path} should end in .h5 or .hdf5")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        sweep_stale(self.path.parent, self.path.name)  # temps of writers that were killed
        self._tmp = self.path.with_name(f"{tmp_prefix(self.path.name)}{uuid.uuid4().hex[:8]}.tmp")
        self._f = h5py.File(self._tmp, "w", libver=("v110", "latest"))
        self._finalizer = weakref.finalize(self, _abandon, self._f, self._tmp)
        self.camera_names = list(camera_names) if camera_names else []
        self.lidar_name = lidar_name
        self.label_sensor = label_sensor
        self.image_format = image_format
        self.jpeg_quality = int(jpeg_quality)
        self.key_width = int(key_width)
        self.compression = compression
        self._n = 0
        self._keys: set[str] = set()
        self._blobs: dict[str, object] = {}
        self._intr: dict[str, tuple] = {}
        self._extr: dict[str, dict[str, np.ndarray]] = {}
        self._vlen = h5py.vlen_dtype(np.dtype("uint8"))
        self._f.attrs["format"] = "xcalib-hdf5-cache"
        self._f.attrs["format_version"] = 1

    def __enter__(self) -> "CacheWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    @property
    def num_frames(self) -> int:
        return self._n

    def abort(self) -> None:
        """Discard everything written (the final path is left untouched)."""
        self._finalizer()

    def _blob_ds(self, cam: str):
        if cam not in self._blobs:
            if cam not in self.camera_names:
                self.camera_names.append(cam)
            self._blobs[cam] = self._f.create_dataset(f"images/{cam}/data", shape=(0,), maxshape=(None,),
                                                      dtype=self._vlen, chunks=(16,))
        return self._blobs[cam]

    def _encode(self, img, cam, key) -> np.ndarray:
        from .images import encode_image

        a = np.ascontiguousarray(img)
        if a.size == 0:
            return np.zeros(0, dtype=np.uint8)
        try:
            data = encode_image(a, ".jpg" if self.image_format == "jpeg" else ".png", quality=self.jpeg_quality)
        except ValueError as exc:
            raise ValueError(f"CacheWriter: frame {key!r} camera {cam!r}: {exc}") from None
        return np.frombuffer(data, dtype=np.uint8)

    def add(self, frame: Frame) -> str:
        """Append one frame; returns the frame key it was stored under."""
        if not self._finalizer.alive:
            raise ValueError(f"CacheWriter({self.path}) is closed")
        fk = str(frame.frame_key or "")
        key = fk if _numeric(fk) else f"{self._n:0{self.key_width}d}"
        if key in self._keys:
            raise ValueError(f"CacheWriter: duplicate frame key {key!r} (frame #{self._n})")
        idx = int(key)
        b2 = np.asarray(frame.bboxes_2d, dtype=np.float32).reshape(-1, 4)
        b3 = np.asarray(frame.bboxes_3d, dtype=np.float32)
        b3 = b3.reshape(-1, b3.shape[-1] if b3.ndim == 2 else 6)
        meta = dict(frame.meta)
        if b3.shape[1] == 7:  # box7 input: spec wants [M,6]; keep the yaw in lidar_bbox_7
            from ..geometry.boxes import box7_corners

            meta.setdefault("box7", b3.astype(np.float64))
            corners = box7_corners(b3)
            b3 = np.hstack([corners.min(axis=1), corners.max(axis=1)]).astype(np.float32)
        if b3.shape[1] != 6:
            raise ValueError(f"CacheWriter: frame {key!r}: bboxes_3d must be [M,6] or [M,7], got {b3.shape}")
        K, M = len(b2), len(b3)
        cam_primary = frame.camera_name or (self.camera_names[0] if self.camera_names else "camera")
        if self.label_sensor is None:
            self.label_sensor = cam_primary
        lg = self._f.create_group(f"labels/{self.label_sensor}/{key}")
        if fk and fk != key:
            lg.attrs["source_key"] = fk
        _small(lg, "num_camera_detections", np.int64(K))
        _small(lg, "num_lidar_detections", np.int64(M))
        _small(lg, "camera_bbox_2d", b2)
        _small(lg, "lidar_bbox_3d", b3)
        if frame.match_matrix is not None:
            mm = np.asarray(frame.match_matrix)
            if mm.shape != (K, M):
                raise ValueError(f"CacheWriter: frame {key!r}: match_matrix has shape {mm.shape}, expected "
                                 f"(K, M) = ({K}, {M})")
            _small(lg, "match_matrix", mm.astype(np.uint8))
        if frame.camera_per_det is not None and (frame.images is not None or
                                                 any(c != cam_primary for c in frame.camera_per_det)):
            if len(frame.camera_per_det) != K:
                raise ValueError(f"CacheWriter: frame {key!r}: camera_per_det has {len(frame.camera_per_det)} "
                                 f"entries, expected K = {K}")
            _small(lg, "camera_names", np.array([c.encode() for c in frame.camera_per_det], dtype="S"))
        for mkey, (dname, kind) in _META_DATASETS.items():
            v = meta.get(mkey)
            if v is None:
                continue
            n = K if "2d" in kind else M
            if kind == "f3d7":
                arr = np.asarray(v, dtype=np.float64).reshape(-1, 7)
            elif kind == "f2d4":
                arr = np.asarray(v, dtype=np.float64).reshape(-1, 4)
            elif kind.startswith("v"):
                arr = np.asarray(v, dtype=np.float64).reshape(-1)
            elif kind.startswith("s"):
                arr = np.array([str(s).encode() for s in v], dtype="S") if len(v) else np.zeros(0, dtype="S1")
            else:
                arr = np.asarray(v, dtype=np.int64).reshape(-1)
            if len(arr) != n:
                raise ValueError(f"CacheWriter: frame {key!r}: meta[{mkey!r}] has {len(arr)} rows, expected {n}")
            _small(lg, dname, arr)
        for field, v in timing_of(frame).items():
            arr = np.asarray(v, dtype=np.int64 if field == "track_ids_3d" else np.float64)
            if field in ("track_ids_3d", "velocities_3d") and len(arr) != M:
                raise ValueError(f"CacheWriter: frame {key!r}: {field} has {len(arr)} rows, expected M = {M}")
            _small(lg, _TIMING_DATASETS[field], arr)
        # points
        pts = np.asarray(frame.point_cloud)
        if pts.ndim != 2 or (pts.size and pts.shape[1] < 3):
            raise ValueError(f"CacheWriter: frame {key!r}: point_cloud must be [P, >=3], got {pts.shape}")
        pts = pts.reshape(-1, max(3, pts.shape[1] if pts.ndim == 2 else 3))
        pg = self._f.create_group(f"point_clouds/{self.lidar_name}/{key}")
        kw = {"compression": self.compression} if self.compression and len(pts) else {}
        pg.create_dataset("xyz", data=np.ascontiguousarray(pts[:, :3], dtype=np.float32), **kw)
        fields = list(frame.point_fields[3:pts.shape[1]]) if pts.shape[1] > 3 else []
        fields += [f"f{i}" for i in range(3 + len(fields), pts.shape[1])]
        if fields:
            pg.attrs["fields"] = np.array([s.encode() for s in fields], dtype="S")
            for j, name in enumerate(fields):
                pg.create_dataset(name, data=np.ascontiguousarray(pts[:, 3 + j], dtype=np.float32), **kw)
        # images
        imgs = dict(frame.images) if frame.images else {}
        if cam_primary not in imgs and frame.image is not None and np.asarray(frame.image).size:
            imgs[cam_primary] = frame.image
        # the frame's own camera gets a blob (empty without pixels: a cache needs a camera to be read)
        cams = list(self.camera_names) + [c for c in imgs if c not in self.camera_names]
        for cam in cams + ([cam_primary] if cam_primary not in cams else []):
            ds = self._blob_ds(cam)
            if len(ds) <= idx:
                ds.resize((idx + 1,))
            if cam in imgs:
                ds[idx] = self._encode(imgs[cam], cam, key)
        # calibration (buffered; written on close)
        intr = dict(meta.get("intrinsics_by_camera") or {})
        extr = dict(meta.get("extrinsics_by_camera") or {})
        if frame.intrinsics is not None:
            intr.setdefault(cam_primary, frame.intrinsics)
        if frame.extrinsics is not None:
            extr.setdefault(cam_primary, frame.extrinsics)
        for cam, ci in intr.items():
            if cam not in self._intr:
                self._intr[cam] = ci
        for cam, T in extr.items():
            T = np.asarray(T, dtype=np.float64)
            if T.shape != (4, 4):
                raise ValueError(f"CacheWriter: frame {key!r}: extrinsics for {cam!r} must be [4,4], got {T.shape}")
            self._extr.setdefault(cam, {})[key] = T
        self._keys.add(key)
        self._n += 1
        return key

    def close(self) -> Path:
        """Finish the file and move it to its final name; returns the path."""
        if not self._finalizer.alive:
            return self.path
        f = self._f
        try:
            for cam in self.camera_names:  # every camera gets a blob array
                ds = self._blob_ds(cam)
                n_idx = max((int(k) for k in self._keys), default=-1) + 1
                if len(ds) < n_idx:
                    ds.resize((n_idx,))
            # the root groups the reader requires, also for no frames or frames without image pixels
            f.require_group(f"labels/{self.label_sensor or 'camera'}")
            f.require_group(f"point_clouds/{self.lidar_name}")
            f.require_group("images")
            for cam, ci in self._intr.items():
                cg = f.require_group(f"calibration/{cam}")
                ds = cg.create_dataset("intrinsics", data=ci.K)
                if ci.width is not None:
                    ds.attrs["width"], ds.attrs["height"] = ci.width, ci.height
                if not isinstance(ci, CameraIntrinsics):  # a camera model: kept whole (its K alone is not it)
                    ds.attrs["camera_model"] = json.dumps(ci.to_dict())
                elif ci.distortion is not None:
                    cg.create_dataset("distortion", data=np.asarray(ci.distortion, dtype=np.float64))
            for cam, per_key in self._extr.items():
                cg = f.require_group(f"calibration/{cam}")
                mats = list(per_key.values())
                if len(per_key) == self._n and all(np.array_equal(mats[0], m) for m in mats[1:]):
                    cg.create_dataset("extrinsics", data=mats[0])
                else:
                    eg = cg.create_group("extrinsics")
                    for k, T in per_key.items():
                        eg.create_dataset(k, data=T)
            f.close()
        except BaseException:
            self.abort()
            raise
        os.replace(self._tmp, self.path)
        self._finalizer.detach()
        return self.path


def _plausible(intr, path, field: str) -> None:
    """A pinhole camera's numbers can be a real camera's (``geometry.camera.check_camera_numbers``),
    else a FormatError naming the dataset."""
    if intr is None or not hasattr(intr, "check_plausible") or not hasattr(intr, "fx"):
        return
    try:
        check_camera_numbers(intr)
    except ValueError as exc:
        raise FormatError(path, str(exc), field=field) from None


def _checked_xyz(path, field: str, key: str, xyz: np.ndarray) -> np.ndarray:
    """A frame's stored points as float32, or a FormatError naming the dataset: NaN / Inf
    coordinates (the protocol's point clouds are finite; a frame folder's PCD reader refuses them
    too) and coordinates beyond ``MAX_COORD_M`` (the bound of every other cloud reader: a wrong
    layout or unit, or corrupt data)."""
    if xyz.dtype.kind not in "fiu":
        raise FormatError(path, f"frame {key!r}: xyz holds {xyz.dtype} values, expected numbers", field=field)
    c = xyz[:, :3]
    if not np.isfinite(c.sum(dtype=np.float64)):  # finite for float32 values iff every value is
        bad = ~np.isfinite(c).all(axis=1)
        if bad.any():
            raise FormatError(path, f"frame {key!r}: {int(bad.sum())} of {len(c)} point(s) have NaN/Inf in x, y, z "
                                    f"(first at row {int(np.argmax(bad))}); a cache's points must be finite",
                              field=field)
    if c.size and np.abs(c).max() > MAX_COORD_M:
        i = int(np.argmax(np.abs(c).max(axis=1)))
        raise FormatError(path, f"frame {key!r}: point {i} has a coordinate of {float(np.abs(c[i]).max()):.3g} m, "
                                f"beyond {MAX_COORD_M:g} m: corrupt data or not metres", field=field)
    return xyz.astype(np.float32, copy=False)


def _camera_model_attr(path, field: str, text, K: np.ndarray):
    """The camera model of a ``camera_model`` attribute (xcalib's intrinsics JSON object); its fx,
    fy, cx, cy must be the dataset's K. FormatError naming ``field`` otherwise."""
    from ..geometry.camera_models import model_from_dict

    try:
        d = json.loads(text if isinstance(text, str) else bytes(text).decode("utf-8"))
        cam = model_from_dict(d, source="camera_model")
    except (ValueError, TypeError, UnicodeDecodeError) as exc:
        raise FormatError(path, f"not a camera model: {exc}", field=field) from None
    if not np.allclose(cam.K, K, rtol=1e-12, atol=1e-9):
        raise FormatError(path, f"the model's fx, fy, cx, cy {cam.K[[0, 1, 0, 1], [0, 1, 2, 2]].tolist()} differ from "
                                f"the intrinsics matrix's {K[[0, 1, 0, 1], [0, 1, 2, 2]].tolist()}", field=field)
    return cam


def _small(group, name: str, data: np.ndarray) -> None:
    """Create a dataset; small ones use the compact layout (stored in the object header: one read)."""
    import h5py

    data = np.asarray(data)
    if data.nbytes < 32_000 and data.size:
        dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
        dcpl.set_layout(h5py.h5d.COMPACT)
        group.create_dataset(name, data=data, dcpl=dcpl)
    else:
        group.create_dataset(name, data=data)


def _abandon(f, tmp: Path) -> None:
    try:
        f.close()
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass


def write_cache(path, frames: Iterable[Frame], *, camera_names: list[str] | None = None,
                lidar_name: str = "lidar", label_sensor: str | None = None, progress=None,
                **writer_kwargs) -> Path:
    """Write ``frames`` to ``path`` (see :class:`CacheWriter`); returns the path.

    ``progress``: optional callable invoked with the number of frames written after each frame.
    """
    with CacheWriter(path, camera_names=camera_names, lidar_name=lidar_name, label_sensor=label_sensor,
                     **writer_kwargs) as w:
        for frame in frames:
            w.add(frame)
            if progress is not None:
                progress(w.num_frames)
    return w.path


def open_hdf5_source(path, *, camera: str | None = None, **kwargs) -> Sequence[Frame]:
    """An HDF5 cache as a frame source; ``camera`` (exact or suffix name) views one camera of a
    multi-camera cache (its image, 2D boxes, intrinsics and extrinsics)."""
    from .sources import CameraView

    reader = CacheReader(path, **kwargs)
    if camera is None:
        return reader
    cam = _match_camera(camera, reader.camera_names)
    if cam is None:
        reader.close()
        raise FormatError(path, f"no camera {camera!r}; cameras: {reader.camera_names}", field="/images")
    view = CameraView(reader, cam)
    view.camera_names = list(reader.camera_names)
    return view


def _register() -> None:
    from .sources import register_source

    register_source("hdf5-cache", is_hdf5_cache, open_hdf5_source,
                    description="xcalib HDF5 cache (.h5/.hdf5; multi-camera: camera=)", priority=20)


_register()
