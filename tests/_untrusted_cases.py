"""Readers under fuzz (issue 16): one valid sample per reader, byte-level and header-level
mutations, and the classification of what a reader did with a mutated file.

Shared by ``tests/test_fuzz_readers.py`` (small seeded campaign in the suite) and
``benchmarks/bench_untrusted.py`` (the larger campaign and the per-reader table).

Outcomes: ``ok`` (read, and the data passed the validity check), ``clear`` (FormatError naming the
file, or FileNotFoundError naming the missing path), ``unclear`` (any other exception),
``garbage`` (read, but the data is not finite / not valid).
"""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from xcalib.errors import FormatError

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
OUTCOMES = ("ok", "clear", "unclear", "garbage")


@dataclass(frozen=True)
class Reader:
    """``make(dir) -> the file to mutate`` (other files of the sample live beside it),
    ``read(path) -> data``, ``valid(data) -> bool``; ``text``: header-level edits apply."""

    name: str
    make: Callable[[Path], Path]
    read: Callable[[Path], Any]
    valid: Callable[[Any], bool]
    text: bool = False


# ------------------------------------------------------------------------------ samples
def _frame(k: int = 0):
    from xcalib.geometry import CameraIntrinsics
    from xcalib.types import Frame

    rng = np.random.default_rng(k)
    b2 = np.array([[10, 10, 40, 30], [50, 20, 70, 60]], np.float32)
    b3 = np.array([[1, 1, 0, 2, 2, 1], [4, -1, 0, 5, 0, 2]], np.float32)
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.2, 0.3]
    return Frame(image=rng.integers(0, 255, (24, 32, 3), dtype=np.uint8),
                 point_cloud=rng.normal(size=(20, 4)).astype(np.float32), bboxes_2d=b2, bboxes_3d=b3,
                 camera_name="cam", frame_key=f"{k:04d}", match_matrix=np.eye(2, dtype=bool), extrinsics=T,
                 intrinsics=CameraIntrinsics(50.0, 50.0, 16.0, 12.0, None, 32, 24),
                 point_fields=("x", "y", "z", "intensity"))


def _result():
    from xcalib.calib.result import CalibrationResult
    from xcalib.geometry import CameraIntrinsics, euler_to_matrix

    return CalibrationResult(success=True, intrinsics=CameraIntrinsics(1000, 1000, 640, 360, [-0.1, 0.01, 0, 0, 0.001],
                                                                       1280, 720),
                             rotation=euler_to_matrix([-1.5, 0.02, -1.6]), translation=[0.1, -0.3, -0.2],
                             camera_name="cam")


def _pcd(encoding: str) -> Callable[[Path], Path]:
    def make(d: Path) -> Path:
        from xcalib.io import write_pcd

        pts = np.random.default_rng(1).normal(size=(40, 4)).astype(np.float32) * 10
        return write_pcd(d / "cloud.pcd", pts, encoding=encoding)
    return make


def _bin(d: Path) -> Path:
    from xcalib.io import write_points

    return write_points(d / "cloud.bin", np.random.default_rng(2).normal(size=(40, 4)).astype(np.float32) * 10)


def _npy(d: Path) -> Path:
    from xcalib.io import write_points

    return write_points(d / "cloud.npy", np.random.default_rng(3).normal(size=(40, 4)).astype(np.float32) * 10)


def _image(ext: str) -> Callable[[Path], Path]:
    def make(d: Path) -> Path:
        from xcalib.io import write_image

        return write_image(d / f"img{ext}", np.random.default_rng(4).integers(0, 255, (24, 32, 3), dtype=np.uint8))
    return make


def _folder(d: Path) -> Path:
    from xcalib.io import write_frame_folder

    return write_frame_folder(d / "frames", [_frame(0)])


def _detections(d: Path) -> Path:
    return _folder(d).parent / "frame_0000" / "detections.json"


def _cache(d: Path) -> Path:
    from xcalib.io.hdf5 import write_cache

    return write_cache(d / "cache.h5", [_frame(0), _frame(1)], image_format="png")


def _calib(suffix: str) -> Callable[[Path], Path]:
    return lambda d: _result().save(d / f"calibration{suffix}")


_PAIR_ID = re.compile(rb"xcalib_pair\"?: \"?([0-9a-f]{16})")


def _export(fmt: str) -> Callable[[Path], Path]:
    def make(d: Path) -> Path:
        from xcalib.formats.export import FORMATS, export_calibration

        paths = export_calibration(_result(), fmt, d / FORMATS[fmt].filename)
        _fix_pair_id(d)
        return paths[0]
    return make


def _fix_pair_id(d: Path) -> None:
    """The writers of two-file formats (OpenCalib, ROS YAML) tie the files with a random
    ``xcalib_pair`` id; a fixed one in every file keeps a sample's bytes, and so the mutations'
    targets (the n-th number), the same from run to run."""
    files = [p for p in sorted(d.rglob("*")) if p.is_file()]
    ids = {m.group(1) for p in files for m in _PAIR_ID.finditer(p.read_bytes())}
    for old in ids:
        for p in files:
            p.write_bytes(p.read_bytes().replace(old, b"5eed" * 4))


def _kitti_labels(d: Path) -> Path:
    p = d / "000000.txt"
    p.write_text("Pedestrian 0.00 0 -0.20 712.40 143.00 810.73 307.92 1.89 0.48 1.20 1.84 1.47 8.41 0.01\n"
                 "Car 0.00 0 -1.58 587.01 173.33 614.12 200.12 1.65 1.67 3.64 -0.65 1.71 46.70 -1.59\n"
                 "DontCare -1 -1 -10 503.89 169.71 590.61 190.13 -1 -1 -1 -1000 -1000 -1000 -10\n")
    return p


def _weights(d: Path) -> Path:
    import torch

    from xcalib.engine.matcher import Matcher
    from xcalib.models import create_model

    torch.manual_seed(0)
    m = Matcher(create_model("fastmatch", {"embed_dim": 16}), device="cpu")
    return m.save_pretrained(d / "w")["weights"]


def _weights_yaml(d: Path) -> Path:
    return _weights(d).with_suffix(".yaml")


def _waymo(d: Path) -> Path:
    src = SHARED / "waymo" / "mmdet3d_tests" / "waymo_format" / "validation" / "val.tfrecord"
    if not src.is_file():
        raise FileNotFoundError(src)
    return Path(shutil.copy(src, d / "val.tfrecord"))


def _lucid_scene(d: Path) -> Path:
    from xcalib.formats.calibanything import write_lucid_calib
    from xcalib.io import write_image, write_pcd

    root = d / "scene"
    write_pcd(root / "000000.pcd", np.random.default_rng(5).normal(size=(30, 4)).astype(np.float32) * 5)
    write_image(root / "cam" / "000000.png", np.zeros((720, 1280, 3), np.uint8))
    return write_lucid_calib(_result(), root / "cam" / "lucid_calib.json")


# ------------------------------------------------------------------------------ readers
def _finite(*arrays) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, dtype=np.float64))) for a in arrays)


def _cloud_ok(pc) -> bool:
    from xcalib.io.pointcloud import MAX_COORD_M

    xyz = pc.points[:, :3]
    return pc.points.ndim == 2 and _finite(xyz) and (xyz.size == 0 or np.abs(xyz).max() <= MAX_COORD_M)


def _frame_ok(fr) -> bool:
    from xcalib.geometry.rotations import orthonormality_error

    if not (_finite(fr.bboxes_2d, fr.bboxes_3d, fr.point_cloud[:, :3]) and fr.image.dtype == np.uint8):
        return False
    b2 = np.asarray(fr.bboxes_2d)
    if len(b2) and np.any(b2[:, 2:] < b2[:, :2]):
        return False
    T = fr.extrinsics
    return T is None or (_finite(T) and orthonormality_error(np.asarray(T)[:3, :3]) < 1e-2)


def _calib_ok(r) -> bool:
    from xcalib.geometry.rotations import orthonormality_error

    return (_finite(r.rotation, r.translation) and orthonormality_error(r.rotation) < 1e-4
            and np.abs(r.translation).max() < 1e6)


def _read_cloud(p: Path):
    from xcalib.io import read_point_cloud

    return read_point_cloud(p)


def _read_image(p: Path):
    from xcalib.io import read_image

    return read_image(p)


def _read_folder(p: Path):
    from xcalib.io import FrameFolder

    return list(FrameFolder(p.parent))


def _read_cache(p: Path):
    """Labels, points and calibration (image blobs: ``_read_cache_images``; libhdf5 can loop forever
    on a corrupted variable-length blob, so the benchmark reads those in a killable worker)."""
    from xcalib.io.hdf5 import CacheReader

    with CacheReader(p, read_images=False) as r:
        return [r[i] for i in range(len(r))]


def _read_cache_images(p: Path):
    from xcalib.io.hdf5 import CacheReader

    with CacheReader(p) as r:
        return [r[i] for i in range(len(r))]


def _read_calib(p: Path):
    from xcalib.calib.result import CalibrationResult

    return CalibrationResult.load(p)


def _read_format(fmt: str) -> Callable[[Path], Any]:
    def read(p: Path):
        from xcalib.formats.export import read_calibration

        return read_calibration(p, fmt)
    return read


def _read_labels(p: Path):
    from xcalib.formats.kitti import load_kitti_labels

    return load_kitti_labels(p)


def _labels_ok(lab) -> bool:
    return _finite(lab.bboxes_2d, lab.dimensions, lab.location, lab.rotation_y)


def _read_weights(p: Path):
    from xcalib.engine.matcher import Matcher

    return Matcher.from_pretrained("fastmatch", weights=p.parent, device="cpu")


def _weights_ok(m) -> bool:
    import torch

    return all(bool(torch.isfinite(t).all()) for t in m.model.state_dict().values() if t.is_floating_point())


def _read_waymo(p: Path):
    from xcalib.formats.waymo import read_waymo_tfrecord

    return read_waymo_tfrecord(p)


def _waymo_ok(recs) -> bool:
    return all(_finite(c.T_vehicle_cam, c.intrinsic) for r in recs for c in r.cameras.values())


def _read_scene(p: Path):
    from xcalib.formats.calibanything_scene import calibanything_frames

    return list(calibanything_frames(p.parents[1]))


def _scene_ok(frames) -> bool:
    return all(_finite(f.point_cloud[:, :3]) and (f.extrinsics is None or _finite(f.extrinsics)) for f in frames)


READERS: dict[str, Reader] = {r.name: r for r in [
    Reader("pcd_ascii", _pcd("ascii"), _read_cloud, _cloud_ok, text=True),
    Reader("pcd_binary", _pcd("binary"), _read_cloud, _cloud_ok),
    Reader("pcd_compressed", _pcd("binary_compressed"), _read_cloud, _cloud_ok),
    Reader("bin", _bin, _read_cloud, _cloud_ok),
    Reader("npy", _npy, _read_cloud, _cloud_ok),
    Reader("png", _image(".png"), _read_image, lambda a: a.dtype == np.uint8 and a.ndim == 3),
    Reader("jpeg", _image(".jpg"), _read_image, lambda a: a.dtype == np.uint8 and a.ndim == 3),
    Reader("detections_json", _detections, _read_folder, lambda fs: all(map(_frame_ok, fs)), text=True),
    Reader("frame_manifest", _folder, _read_folder, lambda fs: all(map(_frame_ok, fs)), text=True),
    Reader("hdf5_cache", _cache, _read_cache, lambda fs: all(map(_frame_ok, fs))),
    Reader("hdf5_cache_images", _cache, _read_cache_images, lambda fs: all(map(_frame_ok, fs))),
    Reader("calibration_json", _calib(".json"), _read_calib, _calib_ok, text=True),
    Reader("calibration_npz", _calib(".npz"), _read_calib, _calib_ok),
    Reader("weights", _weights, _read_weights, _weights_ok),
    Reader("yaml_config", _weights_yaml, _read_weights, _weights_ok, text=True),
    Reader("kitti_calib", _export("kitti"), _read_format("kitti"), _calib_ok, text=True),
    Reader("kitti_labels", _kitti_labels, _read_labels, _labels_ok, text=True),
    Reader("lucid_calib", _export("lucid"), _read_format("lucid"), _calib_ok, text=True),
    Reader("calibanything_json", _export("calib_json"), _read_format("calib_json"), _calib_ok, text=True),
    Reader("calibanything_txt", _export("calib_txt"), _read_format("calib_txt"), _calib_ok, text=True),
    Reader("calibanything_scene", _lucid_scene, _read_scene, _scene_ok, text=True),
    Reader("opencalib", _export("opencalib"), _read_format("opencalib"), _calib_ok, text=True),
    Reader("nuscenes", _export("nuscenes"), _read_format("nuscenes"), _calib_ok, text=True),
    Reader("openlabel", _export("openlabel"), _read_format("openlabel"), _calib_ok, text=True),
    Reader("ros_yaml", _export("ros"), _read_format("ros"), _calib_ok, text=True),
    Reader("waymo_tfrecord", _waymo, _read_waymo, _waymo_ok),
]}


# ---------------------------------------------------------------------------- mutations
_NUM = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
_EDITS = (b"NaN", b"Infinity", b"-1", b"1e308", b"3.7", b"99999999999", b"0", b"null", b'"x"', b"[]", b"{}",
          b"[[[[[[[[1]]]]]]]]", b"../../../etc/passwd", b"/dev/zero", b"1000000000")
KINDS = ("flip", "truncate", "append", "zero_block", "number", "token", "nest", "dup_line")


def mutate(data: bytes, kind: str, a: int, b: int, text: bool) -> bytes:
    """One deterministic mutation of ``data`` picked by ``kind`` and the integers ``a``, ``b``."""
    n = max(len(data), 1)
    if kind in ("number", "token", "nest", "dup_line") and not text:
        kind = "flip"
    if kind == "flip":
        out = bytearray(data)
        for k in range(1 + b % 4):
            if out:
                out[(a + 7919 * k) % n] ^= 1 << ((b + k) % 8)
        return bytes(out)
    if kind == "truncate":
        return data[:a % n]
    if kind == "append":
        return data + bytes((a + i * b) % 256 for i in range(1 + b % 64))
    if kind == "zero_block":
        s = a % n
        return data[:s] + b"\x00" * (1 + b % 256) + data[s + 1 + b % 256:]
    if kind == "number":
        nums = list(_NUM.finditer(data))
        if not nums:
            return data + b"NaN"
        m = nums[a % len(nums)]
        return data[:m.start()] + _EDITS[b % len(_EDITS)] + data[m.end():]
    if kind == "token":
        s = a % n
        return data[:s] + _EDITS[b % len(_EDITS)] + data[s:]
    if kind == "nest":
        depth = 100 + 1000 * (b % 60)
        s = a % n
        return data[:s] + b"[" * depth + data[s:]
    lines = data.split(b"\n")  # dup_line
    i = a % len(lines)
    return b"\n".join(lines[:i + 1] + [lines[i]] * (1 + b % 3) + lines[i + 1:])


def classify(reader: Reader, path: Path) -> tuple[str, str]:
    """(outcome, detail) of reading ``path`` with ``reader``."""
    try:
        data = reader.read(path)
    except FormatError as exc:
        named = exc.path is not None or path.name in str(exc)
        return ("clear" if named else "unclear"), f"FormatError: {str(exc)[:160]}"
    except FileNotFoundError as exc:
        return ("clear" if "/" in str(exc) or "\\" in str(exc) else "unclear"), f"FileNotFoundError: {str(exc)[:160]}"
    except Exception as exc:  # noqa: BLE001 - that is what we count
        return "unclear", f"{type(exc).__name__}: {str(exc)[:160]}"
    try:
        return ("ok" if reader.valid(data) else "garbage"), ""
    except Exception as exc:  # noqa: BLE001
        return "garbage", f"validity check failed: {type(exc).__name__}: {exc}"


class Samples:
    """Valid samples made once per reader in ``root``; ``fresh(name)`` copies one into a new folder."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self._made: dict[str, tuple[Path, Path]] = {}
        self._n = 0

    def base(self, name: str) -> tuple[Path, Path]:
        if name not in self._made:
            d = self.root / f"sample_{name}"
            d.mkdir(parents=True, exist_ok=True)
            f = READERS[name].make(d)
            self._made[name] = (d, f)
        return self._made[name]

    def fresh(self, name: str, data: bytes) -> Path:
        d, f = self.base(name)
        self._n += 1
        dst = self.root / f"case_{self._n}"
        shutil.copytree(d, dst, symlinks=True)
        target = dst / f.relative_to(d)
        target.write_bytes(data)
        return target

    def original(self, name: str) -> bytes:
        return self.base(name)[1].read_bytes()

    def cleanup(self, path: Path) -> None:
        case = path
        while case.parent != self.root:
            case = case.parent
        shutil.rmtree(case, ignore_errors=True)


def run_case(samples: Samples, name: str, kind: str, a: int, b: int) -> tuple[str, str]:
    reader = READERS[name]
    data = mutate(samples.original(name), kind, a, b, reader.text)
    path = samples.fresh(name, data)
    try:
        return classify(reader, path)
    finally:
        samples.cleanup(path)


def summary_line(counts: dict[str, int]) -> str:
    return json.dumps(counts)
