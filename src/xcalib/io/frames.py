"""Frame folders (protocol v1.0 demo layout) and the ``read_frames`` entry point.

Layout (``format: xcalib-demo-frames-v1``)::

    <root>/manifest.json      {"format", "site", "split", "camera",
                               "frames": [{"frame_key", "detections": "frame_0000/detections.json"}]}
    <root>/intrinsics.json    optional {"name", "fx", "fy", "cx", "cy", "distortion"} (pixels)
    <root>/frame_0000/detections.json
        {"frame_key", "camera_name", "image": "image.png", "point_cloud": "point_cloud.pcd",
         "bboxes_2d": [[x1, y1, x2, y2], ...] (pixels), "bboxes_3d": [[6 or 7 numbers], ...]
         (LiDAR frame, metres), optional "match_matrix" [K][M] (0/1), optional "extrinsics"
         4x4 T_cam_lidar, optional "lidar_time_s" / "camera_time_s" (seconds, one clock),
         optional "track_ids_3d" [M] ints (-1 = none), optional "velocities_3d" [M][3] (m/s,
         LiDAR frame)}

A bare folder of sub-folders that each hold a ``detections.json`` (no manifest) is read the
same way. Frames load lazily: :class:`FrameFolder` is a ``Sequence[Frame]`` that reads one
frame's files when it is indexed.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ..errors import FormatError, MissingFileError
from ..geometry.camera import CameraIntrinsics
from ..types import Frame
from .files import atomic_dir, atomic_write, inside, load_json, open_regular
from .images import MAX_IMAGE_FILE_BYTES, MAX_IMAGE_PIXELS, image_header_size, read_image, write_image
from ._validate import check_boxes_2d, check_boxes_3d, check_rigid
from .pointcloud import read_point_cloud, write_pcd
from .sources import open_source, register_source
from .timing import TIMING_FIELDS, checked_timing, timing_of

__all__ = ["FRAME_FOLDER_FORMAT", "FrameFolder", "read_frames", "write_frame_folder",
           "read_detections", "read_intrinsics_json", "is_frame_folder", "register_reader",
           "open_frame_folder"]

FRAME_FOLDER_FORMAT = "xcalib-demo-frames-v1"
_REQUIRED_KEYS = ("image", "point_cloud", "bboxes_2d", "bboxes_3d")


def _load_json(path: Path) -> dict:
    if not path.exists():
        raise FileNotFoundError(f"JSON file not found: {path}")
    obj = load_json(path)
    if not isinstance(obj, dict):
        raise FormatError(path, f"expected a JSON object at the top level, got {type(obj).__name__}")
    return obj


def _numeric_row(row, widths: tuple[int, ...]) -> bool:
    """True for a list of ``widths`` numbers (not bools, not strings)."""
    return (isinstance(row, list) and len(row) in widths
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row))


def _box_array(path: Path, key: str, value, widths: tuple[int, ...]) -> np.ndarray:
    """A JSON list of rows -> float32 [N, w]; w in ``widths``."""
    want = " or ".join(str(w) for w in widths)
    if not isinstance(value, list):
        raise FormatError(path, f"expected a list of [{want}]-number rows, got {type(value).__name__}", field=key)
    if len(value) == 0:
        return np.zeros((0, widths[0]), dtype=np.float32)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        bad = next(((i, r) for i, r in enumerate(value) if not _numeric_row(r, widths)), None)
        what = (f"row {bad[0]} is {str(bad[1])[:80]}" if bad is not None
                else f"rows of different lengths {sorted({len(r) for r in value})}")
        raise FormatError(path, f"rows must be lists of {want} numbers; {what}", field=key) from None
    if arr.ndim != 2 or arr.shape[1] not in widths:
        raise FormatError(path, f"expected shape [N, {want}], got {list(arr.shape)}", field=key)
    big = np.isfinite(arr) & (np.abs(arr) > np.finfo(np.float32).max)
    if big.any():  # cast to float32 they would become inf (and warn): name the value instead
        r, c = np.argwhere(big)[0]
        raise FormatError(path, f"row {r} holds {arr[r, c]:g}, beyond a 32-bit float's range", field=key)
    return arr.astype(np.float32)


def _name_field(path: Path, obj: dict, key: str, default: str = "") -> str:
    """A name (frame key, camera name) of a JSON object: a string or an integer (written as its
    digits); missing / null / "": ``default``; anything else (a number with a fraction, NaN, a
    bool, a list, an object) is a FormatError naming the field."""
    v = obj.get(key)
    if v is None or v == "":
        return default
    if isinstance(v, str):
        return v
    if isinstance(v, int) and not isinstance(v, bool):
        return str(v)
    raise FormatError(path, f"expected a name (a string), got {str(v)[:60]!r} ({type(v).__name__})", field=key)


def read_intrinsics_json(path) -> CameraIntrinsics:
    """``{"fx", "fy", "cx", "cy", "distortion"?, "width"?, "height"?}`` (pixels) -> intrinsics
    (:meth:`CameraIntrinsics.from_json`); with a wide-angle ``"model"`` (``docs/camera-models.md``)
    -> that camera model (``xcalib.geometry.camera_models``)."""
    d = load_json(path, what="intrinsics file")
    if isinstance(d, dict) and d.get("model") is not None:
        from ..geometry.camera_models import canonical_name, model_from_dict

        try:
            if canonical_name(d["model"]) not in ("pinhole", "pinhole_radtan"):
                return model_from_dict({k: v for k, v in d.items() if k != "name"}, source="intrinsics")
        except (TypeError, ValueError) as exc:
            head = str(exc).split(":", 1)[0]
            field = head.rpartition(".")[2] if "." in head and " " not in head else "model"
            raise FormatError(path, str(exc), field) from None
    return CameraIntrinsics.from_json_object(d, path)


def read_detections(path, *, default_key: str = "", default_camera: str = "",
                    intrinsics: CameraIntrinsics | None = None,
                    columns=None, drop_nonfinite: bool = False, allow_outside: bool = False,
                    decode_images: bool = True) -> Frame:
    """Read one frame from its ``detections.json`` (image and point cloud relative to it; a path
    that leaves the folder, absolute or through ``..``, is a FormatError unless ``allow_outside``).
    Boxes must be finite and not inverted, extrinsics rigid, the match matrix 0/1.
    ``decode_images=False``: a PNG / JPEG image is not decoded; its size is read from its header
    (``meta["image_size"]``, :func:`xcalib.io.sources.image_size_of`) and ``image`` is an empty
    [0,0,3] placeholder (other formats, or a header that does not parse, are decoded as usual)."""
    path = Path(path)
    det = _load_json(path)
    for key in _REQUIRED_KEYS:
        if key not in det:
            raise FormatError(path, f"missing key (required: {', '.join(_REQUIRED_KEYS)})", field=key)
    for key in ("image", "point_cloud"):
        if not isinstance(det[key], str) or not det[key]:
            raise FormatError(path, f"expected a relative file path string, got {det[key]!r}", field=key)
    b2 = check_boxes_2d(path, "bboxes_2d", _box_array(path, "bboxes_2d", det["bboxes_2d"], (4,)))
    b3 = check_boxes_3d(path, "bboxes_3d", _box_array(path, "bboxes_3d", det["bboxes_3d"], (6, 7)))
    mm = None
    if det.get("match_matrix") is not None:
        raw = det["match_matrix"]
        try:
            mm = np.asarray(raw, dtype=np.float64).reshape(len(raw), -1) if len(raw) else np.zeros((0, len(b3)))
        except (TypeError, ValueError, OverflowError):
            raise FormatError(path, "expected a [K][M] list of 0/1 values", field="match_matrix") from None
        if mm.shape != (len(b2), len(b3)):
            raise FormatError(path, f"expected shape [K, M] = [{len(b2)}, {len(b3)}], got {list(mm.shape)}",
                              field="match_matrix")
        if not np.isin(mm, (0.0, 1.0)).all():
            raise FormatError(path, "expected only 0/1 values", field="match_matrix")
        mm = mm != 0
    ext = None
    if det.get("extrinsics") is not None:
        try:
            ext = np.asarray(det["extrinsics"], dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise FormatError(path, "expected a 4x4 numeric matrix (T_cam_lidar)", field="extrinsics") from None
        if ext.shape == (3, 4):
            ext = np.vstack([ext, [0.0, 0.0, 0.0, 1.0]])
        if ext.shape != (4, 4) or not np.all(np.isfinite(ext)):
            raise FormatError(path, f"expected a finite 4x4 matrix (T_cam_lidar), got shape {list(ext.shape)}",
                              field="extrinsics")
        check_rigid(path, "extrinsics", ext)
    timing = checked_timing(path, len(b3), **{k: det.get(k) for k in TIMING_FIELDS})
    root = path.parent
    image_path = inside(root, det["image"], source=path, field="image", allow_outside=allow_outside)
    cloud_path = inside(root, det["point_cloud"], source=path, field="point_cloud", allow_outside=allow_outside)
    for field, file in (("image", image_path), ("point_cloud", cloud_path)):
        if not file.is_file():
            what = "is not a file" if file.exists() else "does not exist"
            raise MissingFileError(path, f"names the {field.replace('_', ' ')} {det[field]!r}, which {what} ({file})",
                                   field)
    size = None if decode_images else _header_size(image_path)
    image = read_image(image_path) if size is None else np.zeros((0, 0, 3), dtype=np.uint8)
    pc = read_point_cloud(cloud_path, columns=columns, drop_nonfinite=drop_nonfinite)
    meta = {"detections_path": str(path), "image_path": str(image_path), "point_cloud_path": str(cloud_path)}
    if size is not None:
        meta["image_size"] = size
    if pc.num_dropped:
        meta["points_dropped_nonfinite"] = pc.num_dropped
    return Frame(image=image, point_cloud=pc.points, bboxes_2d=b2, bboxes_3d=b3,
                 camera_name=_name_field(path, det, "camera_name", default_camera),
                 frame_key=_name_field(path, det, "frame_key", default_key),
                 match_matrix=mm, intrinsics=intrinsics, extrinsics=ext,
                 point_fields=pc.fields, meta=meta, **timing)


def _header_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from a PNG / JPEG file's header (its first 256 KiB), None when it does not parse."""
    with open_regular(path, max_bytes=MAX_IMAGE_FILE_BYTES, what="image file") as fh:  # read_image's checks
        size = image_header_size(fh.read(1 << 18))
    ok = size is not None and size[0] > 0 and size[1] > 0 and size[0] * size[1] <= MAX_IMAGE_PIXELS
    return size if ok else None  # else decoded: read_image names what is wrong


class FrameFolder(Sequence):
    """A frame folder as a lazy ``Sequence[Frame]``: ``len``, indexing (one frame read per
    access; slices give lists), iteration. ``camera`` / ``intrinsics`` / ``site`` / ``split``
    come from the manifest and ``intrinsics.json`` when present."""

    def __init__(self, path, *, columns=None, drop_nonfinite: bool = False, allow_outside: bool = False,
                 decode_images: bool = True):
        p = Path(path)
        self._decode = bool(decode_images)
        self._allow_outside = bool(allow_outside)
        if not p.exists():
            raise FileNotFoundError(f"frame folder not found: {p}")
        if p.is_file():
            if p.name == "detections.json":
                self.root, self.manifest_path = p.parent, None
                self._entries = [(p.parent.name, p)]
            else:
                self.root, self.manifest_path = p.parent, p
        else:
            self.root = p
            self.manifest_path = p / "manifest.json" if (p / "manifest.json").exists() else None
        self._columns, self._drop = columns, drop_nonfinite
        self.camera: str = ""
        self.site: str | None = None
        self.split: str | None = None
        if self.manifest_path is not None:
            self._entries = self._read_manifest(self.manifest_path)
        elif not (p.is_file() and p.name == "detections.json"):
            if (self.root / "detections.json").exists():
                self._entries = [(self.root.name, self.root / "detections.json")]
            else:
                subs = sorted(d for d in self.root.iterdir() if (d / "detections.json").is_file())
                if not subs:
                    raise FormatError(self.root, "not a frame folder: no manifest.json and no sub-folder "
                                                 "with a detections.json")
                self._entries = [(d.name, d / "detections.json") for d in subs]
        intr = self.root / "intrinsics.json"
        self.intrinsics: CameraIntrinsics | None = read_intrinsics_json(intr) if intr.exists() else None
        if not self.camera and self.intrinsics is not None:
            self.camera = _name_field(intr, _load_json(intr), "name")
        self._size_checked = False

    def _read_manifest(self, path: Path) -> list[tuple[str, Path]]:
        man = _load_json(path)
        if "format" not in man:
            raise FormatError(path, f"missing key (expected \"{FRAME_FOLDER_FORMAT}\")", field="format")
        if man["format"] != FRAME_FOLDER_FORMAT:
            raise FormatError(path, f"unsupported format {man['format']!r}; expected {FRAME_FOLDER_FORMAT!r}",
                              field="format")
        if "frames" not in man:
            raise FormatError(path, "missing key", field="frames")
        if not isinstance(man["frames"], list):
            raise FormatError(path, f"expected a list, got {type(man['frames']).__name__}", field="frames")
        self.camera = _name_field(path, man, "camera")
        self.site, self.split = man.get("site"), man.get("split")
        entries = []
        for i, fr in enumerate(man["frames"]):
            if not isinstance(fr, dict) or not isinstance(fr.get("detections"), str):
                raise FormatError(path, "each entry needs a \"detections\" path string", field=f"frames[{i}].detections")
            det = inside(path.parent, fr["detections"], source=path, field=f"frames[{i}].detections",
                         allow_outside=self._allow_outside)
            if not det.is_file():
                raise MissingFileError(path, f"detections file {det} does not exist", field=f"frames[{i}].detections")
            entries.append((_name_field(path, fr, "frame_key", det.parent.name), det))
        return entries

    @property
    def frame_keys(self) -> list[str]:
        return [k for k, _ in self._entries]

    def detections_path(self, index: int) -> Path:
        return self._entries[index][1]

    def __len__(self) -> int:
        return len(self._entries)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        key, det = self._entries[index]
        frame = read_detections(det, default_key=key, default_camera=self.camera, intrinsics=self.intrinsics,
                                columns=self._columns, drop_nonfinite=self._drop, allow_outside=self._allow_outside,
                                decode_images=self._decode)
        # a 1-pixel image is a placeholder whose size comes from the intrinsics (the calibration's
        # convention, ``calib.inputs``), not an image size to check the principal point against
        if not self._size_checked and self.intrinsics is not None and min(frame.image.shape[:2], default=0) > 1:
            h, w = frame.image.shape[:2]
            try:  # a principal point far outside the images: the file's problem, named as such
                self.intrinsics.check_image_size(w, h)
            except ValueError as exc:
                raise FormatError(self.root / "intrinsics.json", f"{exc} (the image of {det})", field="cx, cy") from None
            self._size_checked = True
        return frame

    def __repr__(self) -> str:
        return f"FrameFolder({str(self.root)!r}, frames={len(self)}, camera={self.camera!r})"


def is_frame_folder(path) -> bool:
    """True for a manifest, a folder with a manifest, a frame directory or a folder of frame directories."""
    p = Path(path)
    if p.is_file():
        return p.name in ("manifest.json", "detections.json")
    if not p.is_dir():
        return False
    if (p / "manifest.json").is_file() or (p / "detections.json").is_file():
        return True
    return any((d / "detections.json").is_file() for d in p.iterdir() if d.is_dir())


def open_frame_folder(path, *, camera: str | None = None, **kwargs) -> FrameFolder:
    """A frame folder as a source (one camera: ``camera``, when given, must be the folder's)."""
    folder = FrameFolder(path, **kwargs)
    if camera is not None and folder.camera and camera != folder.camera:
        raise FormatError(folder.manifest_path or folder.root, f"no camera {camera!r}: this frame folder "
                          f"holds camera {folder.camera!r} only", field="camera")
    return folder


register_source("frame-folder", is_frame_folder, open_frame_folder,
                description="xcalib frame folder (manifest.json + frame_*/detections.json)", priority=10)


def register_reader(name: str, detect: Callable[[Path], bool], open_: Callable[..., Sequence[Frame]],
                    *, first: bool = True) -> None:
    """Add a source to :func:`read_frames` (compatibility name of
    :func:`xcalib.io.sources.register_source`; ``first``: tried before the built-ins)."""
    register_source(name, detect, open_, priority=0 if first else 100)


def read_frames(path, *, camera: str | None = None, frames=None, **kwargs) -> Sequence[Frame]:
    """Open any registered frame source as a lazy ``Sequence[Frame]`` (:func:`xcalib.io.sources.open_source`:
    ``camera`` picks a camera, ``frames`` a subset such as ``"0:8"`` or ``"0,3,5"``)."""
    return open_source(path, camera=camera, frames=frames, **kwargs)


def _rows(a) -> list:
    return [] if a is None else np.asarray(a, dtype=np.float64).tolist()


def write_frame_folder(out_dir, frames: Iterable[Frame], *, camera: str | None = None,
                       intrinsics: CameraIntrinsics | None = None, pcd_encoding: str = "binary",
                       image_ext: str = ".png", site: str | None = None, split: str | None = None) -> Path:
    """Write frames in the demo layout. A new (or empty) folder is built beside ``out_dir`` and
    swapped in whole (``atomic_dir``): a killed writer leaves no folder, never a partial one. Into
    an existing non-empty folder the files are written in place, ``manifest.json`` last.

    Returns the manifest path. Point-cloud field names (``Frame.point_fields``) are kept.
    """
    out = Path(out_dir)
    def write(folder: Path) -> Path:
        return _write_frames_into(folder, frames, camera=camera, intrinsics=intrinsics, pcd_encoding=pcd_encoding,
                                  image_ext=image_ext, site=site, split=split)

    if out.is_dir() and any(out.iterdir()):
        return write(out)
    with atomic_dir(out) as tmp:
        write(tmp)
    return out / "manifest.json"


def _write_frames_into(out: Path, frames: Iterable[Frame], *, camera, intrinsics, pcd_encoding, image_ext,
                       site, split) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    first_camera = None
    for i, fr in enumerate(frames):
        sub = out / f"frame_{i:04d}"
        sub.mkdir(exist_ok=True)
        key = fr.frame_key or f"{i:04d}"
        first_camera = first_camera or fr.camera_name
        image_name = "image" + image_ext
        write_image(sub / image_name, fr.image)
        pc = np.asarray(fr.point_cloud, dtype=np.float32)
        fields = tuple(fr.point_fields) if len(fr.point_fields) == pc.shape[1] else None
        write_pcd(sub / "point_cloud.pcd", pc, fields, encoding=pcd_encoding)
        det = {"frame_key": key, "camera_name": fr.camera_name or camera or "", "image": image_name,
               "point_cloud": "point_cloud.pcd", "bboxes_2d": _rows(fr.bboxes_2d),
               "bboxes_3d": _rows(fr.bboxes_3d)}
        if fr.match_matrix is not None:
            det["match_matrix"] = np.asarray(fr.match_matrix).astype(int).tolist()
        if fr.extrinsics is not None:
            det["extrinsics"] = _rows(fr.extrinsics)
        for k, v in timing_of(fr).items():
            det[k] = np.asarray(v).tolist()
        atomic_write(sub / "detections.json", [json.dumps(det, indent=1).encode()])
        entries.append({"frame_key": key, "detections": f"{sub.name}/detections.json"})
        if intrinsics is None and fr.intrinsics is not None:
            intrinsics = fr.intrinsics
    cam = camera or first_camera or ""
    if intrinsics is not None:
        intr = {"name": cam, **intrinsics.to_dict()}
        atomic_write(out / "intrinsics.json", [json.dumps(intr, indent=1).encode()])
    manifest = {"format": FRAME_FOLDER_FORMAT, "site": site, "split": split, "camera": cam, "frames": entries}
    return atomic_write(out / "manifest.json", [json.dumps(manifest, indent=1).encode()])
