"""SUSTechPOINTS scenes (``shared/data/sustech_example``) as ``Sequence[Frame]``.

Layout (see that folder's README)::

    lidar/<id>.pcd            binary PCD, 48-byte records: x, y, z float32 @0/4/8, intensity
                              float32 @16, timestamp float64 @24 (s, sensor clock), ring uint16 @32
    camera/<cam>/<id>.jpg     pinhole images (no distortion model)
    label/<id>.json           [{psr: {position, scale, rotation}, obj_type, obj_id}] LiDAR frame
    calib/camera/<cam>.json   {"extrinsic": 16 numbers (LiDAR -> camera), "intrinsic": 9 numbers}

The PCD header misdescribes its padding, so the points are read from the record layout above
(exactly POINTS records). Each frame: ``bboxes_3d`` [M,7] box7 (centre, scale x/y/z = l/w/h, yaw
= rotation.z), ``meta["R_lidar_box"]`` = Rx(x) Ry(y) Rz(z) (the tool's exact rotation),
``track_ids_3d`` (``obj_id`` as ints), ``bboxes_2d`` [0,4] (none in the data:
:func:`xcalib.data.boxes2d.synthetic_2d_boxes`), ``extrinsics`` = the file's (hand-tuned)
``T_cam_lidar``, ``lidar_time_s`` = the sweep's last point time (sensor clock; no camera time).
Only frames with an image of the chosen camera are listed.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics
from ..geometry.rotations import euler_to_matrix
from ..io.files import load_json
from ..io.pointcloud import MAX_COORD_M as MAX_BOX_M
from ..io.timing import checked_time
from ..types import Frame
from ._checks import as_float, as_matrix, require
from ._media import load_rgb

__all__ = ["is_sustech_root", "SustechFrames", "read_sustech_pcd", "read_sustech_labels"]

_RECORD = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("_0", "V4"), ("intensity", "<f4"), ("_1", "V4"),
                    ("t", "<f8"), ("ring", "<u2"), ("_2", "V14")])


def is_sustech_root(path) -> bool:
    p = Path(path)
    return p.is_dir() and (p / "calib" / "camera").is_dir() and (p / "label").is_dir() and (p / "lidar").is_dir()


def read_sustech_pcd(path) -> tuple[np.ndarray, float]:
    """(points [P,4] x y z intensity float32, last point time in s) of a SUSTechPOINTS PCD."""
    path = Path(path)
    raw = path.read_bytes()
    end = raw.find(b"\nDATA binary\n")
    if end < 0:
        raise FormatError(path, "expected a binary PCD ('DATA binary')", "DATA")
    m = re.search(rb"\nPOINTS (\d+)", raw[:end])
    if m is None:
        raise FormatError(path, "missing POINTS", "POINTS")
    n, body = int(m.group(1)), raw[end + len(b"\nDATA binary\n"):]
    if len(body) < n * _RECORD.itemsize:
        raise FormatError(path, f"{n} points of 48 bytes need {n * 48} bytes, found {len(body)}", "POINTS")
    rec = np.frombuffer(body, dtype=_RECORD, count=n)
    pts = np.column_stack([rec["x"], rec["y"], rec["z"], rec["intensity"]]).astype(np.float32)
    ok = np.all(np.isfinite(pts[:, :3]), axis=1)
    t = rec["t"][np.isfinite(rec["t"])]
    return pts[ok], checked_time(path, "t", float(t.max())) if len(t) else float("nan")


def read_sustech_labels(path) -> dict:
    """``label/<id>.json`` -> {"box7" [M,7], "R_lidar_box" [M,3,3], "obj_ids", "types"}."""
    path = Path(path)
    raw = load_json(path, what="SUSTech label file")
    if not isinstance(raw, list):
        raise FormatError(path, f"expected a JSON list of objects, got {type(raw).__name__}")
    box7, rots, ids, types = [], [], [], []
    for i, o in enumerate(raw):
        psr = require(o, "psr", path, f"[{i}].", kind=dict)
        v = {k: [as_float(require(require(psr, k, path, f"[{i}].psr.", kind=dict), a, path, f"[{i}].psr.{k}."),
                          path, f"[{i}].psr.{k}.{a}") for a in "xyz"] for k in ("position", "scale", "rotation")}
        if min(v["scale"]) <= 0:
            raise FormatError(path, f"box sizes must be > 0 m, got {v['scale']}", f"[{i}].psr.scale")
        for k in ("position", "scale"):
            if max(abs(x) for x in v[k]) > MAX_BOX_M:
                raise FormatError(path, f"beyond {MAX_BOX_M:g} m: {v[k]} (corrupt data or wrong units)",
                                  f"[{i}].psr.{k}")
        box7.append([*v["position"], *v["scale"], v["rotation"][2]])
        rots.append(euler_to_matrix(v["rotation"], "XYZ"))  # THREE.js "XYZ": Rx @ Ry @ Rz
        ids.append(str(o.get("obj_id", "")))
        types.append(str(o.get("obj_type", "")))
    return {"box7": np.asarray(box7, dtype=np.float64).reshape(-1, 7),
            "R_lidar_box": np.asarray(rots, dtype=np.float64).reshape(-1, 3, 3), "obj_ids": ids, "types": types}


def read_sustech_calibration(path):
    """One camera's ``calib/camera/<cam>.json`` of a SUSTechPOINTS scene (``extrinsic``: 16 numbers,
    LiDAR -> camera; ``intrinsic``: 9, K) as a ``CalibrationResult`` named after the camera; the
    image size from the scene's first ``camera/<cam>/*.jpg`` when it is there."""
    from ._result import calibration_record

    path = Path(path)
    cal = load_json(path, what="SUSTech camera calibration")
    if not isinstance(cal, dict):
        raise FormatError(path, "expected a JSON object with 'extrinsic' and 'intrinsic'")
    K = as_matrix(require(cal, "intrinsic", path), (3, 3), path, "intrinsic")
    T = as_matrix(require(cal, "extrinsic", path), (4, 4), path, "extrinsic")
    imgs = sorted((path.parent.parent.parent / "camera" / path.stem).glob("*.jpg"))
    w, h = (load_rgb(imgs[0]).shape[1::-1]) if imgs else (None, None)
    try:
        intr = CameraIntrinsics.from_matrix(K, width=w, height=h)
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), "intrinsic") from None
    return calibration_record(intr, T, method="sustech", camera_name=path.stem, meta={"format": "sustech"})

class SustechFrames(Sequence):
    """A SUSTechPOINTS scene folder, one camera (default ``front``), as a lazy ``Sequence[Frame]``."""

    def __init__(self, root, *, camera: str | None = None, read_images: bool = True):
        self.root = Path(root)
        if not is_sustech_root(self.root):
            raise FormatError(self.root, "not a SUSTechPOINTS scene (calib/camera/, label/, lidar/)")
        self.camera = camera or "front"
        cal_path = self.root / "calib" / "camera" / f"{self.camera}.json"
        if not cal_path.is_file():
            raise FormatError(cal_path, "camera calibration not found")
        cal = load_json(cal_path, what="SUSTech camera calibration")
        K = as_matrix(require(cal, "intrinsic", cal_path), (3, 3), cal_path, "intrinsic")
        self.T_cam_lidar = as_matrix(require(cal, "extrinsic", cal_path), (4, 4), cal_path, "extrinsic")
        imgs = sorted((self.root / "camera" / self.camera).glob("*.jpg"))
        self.frame_keys = [p.stem for p in imgs if (self.root / "label" / f"{p.stem}.json").is_file()
                           and (self.root / "lidar" / f"{p.stem}.pcd").is_file()]
        w, h = (load_rgb(imgs[0]).shape[1::-1]) if imgs else (None, None)
        self.intrinsics = CameraIntrinsics.from_matrix(K, width=w, height=h)
        self.read_images = bool(read_images)
        all_ids = set()
        for p in sorted((self.root / "label").glob("*.json")):
            all_ids.update(read_sustech_labels(p)["obj_ids"])
        self._ids = {u: i for i, u in enumerate(sorted(all_ids))}

    def __len__(self) -> int:
        return len(self.frame_keys)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        key = self.frame_keys[index]
        lab = read_sustech_labels(self.root / "label" / f"{key}.json")
        pts, t_lidar = read_sustech_pcd(self.root / "lidar" / f"{key}.pcd")
        img_path = self.root / "camera" / self.camera / f"{key}.jpg"
        image = load_rgb(img_path) if self.read_images else np.zeros((0, 0, 3), dtype=np.uint8)
        return Frame(image=image, point_cloud=pts, bboxes_2d=np.zeros((0, 4), dtype=np.float32),
                     bboxes_3d=lab["box7"].astype(np.float32), camera_name=self.camera, frame_key=key,
                     intrinsics=self.intrinsics, extrinsics=self.T_cam_lidar.copy(),
                     point_fields=("x", "y", "z", "intensity"),
                     meta={"R_lidar_box": lab["R_lidar_box"], "classes_3d": lab["types"], "obj_ids": lab["obj_ids"],
                           "image_size": (self.intrinsics.width, self.intrinsics.height)},
                     lidar_time_s=t_lidar if np.isfinite(t_lidar) else None,
                     track_ids_3d=np.array([self._ids[u] for u in lab["obj_ids"]], dtype=np.int64))


def _register() -> None:
    from ..io.sources import register_source

    register_source("sustech", is_sustech_root, lambda p, camera=None, **kw: SustechFrames(p, camera=camera, **kw),
                    description="SUSTechPOINTS scene (lidar/, label/, camera/<cam>/, calib/camera/)", priority=20)


_register()
