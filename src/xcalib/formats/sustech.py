"""SUSTechPOINTS scenes (``calib/camera/<cam>.json``, ``camera/<cam>/<frame>.jpg``,
``lidar/<frame>.pcd``, ``label/<frame>.json``) as frames of one camera.

Conventions (see the scene README): ``extrinsic`` = 4x4 row-major LiDAR -> OpenCV camera,
``intrinsic`` = 3x3 K (no distortion); labels ``psr`` = centre, full size (x = length along the
heading), Euler ``R = Rx(x) Ry(y) Rz(z)`` in the LiDAR frame (metres). The PCD header misplaces
one padding field, so the cloud is read by name from the header offsets (x, y, z, intensity
only, exactly ``POINTS`` records).

The scene has no 2D detections: ``bboxes_2d`` are the labelled 3D boxes (full rotation) projected
with the file's calibration and clipped to the image (a box needs all corners 0.5 m or more in
front of the camera and a third or more of its projected area inside the image). They are
ground-truth-derived and unoccluded, not a detector's output: ``meta["boxes_2d_source"] =
"projected_labels"``. ``bboxes_3d`` are every label of the frame as box7 (the x/y tilt, at most a
few degrees, dropped), ``match_matrix`` links each 2D box to its label.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..geometry.boxes import boxes2d_from_points
from ..geometry.camera import CameraIntrinsics
from ..geometry.projection import project_points
from ..geometry.rotations import euler_to_matrix
from ..types import Frame
from ._media import load_rgb

__all__ = ["is_sustech_scene", "SustechFrames", "read_sustech_pcd"]

_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4",
              ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4"}


def is_sustech_scene(path) -> bool:
    p = Path(path)
    return p.is_dir() and (p / "calib" / "camera").is_dir() and (p / "label").is_dir() and (p / "lidar").is_dir()


def read_sustech_pcd(path) -> np.ndarray:
    """x, y, z, intensity [N, 4] float32 of a SUSTech binary PCD (offsets from SIZE x COUNT)."""
    path = Path(path)
    raw = path.read_bytes()
    end = raw.find(b"DATA binary\n")
    if end < 0:
        raise FormatError(path, "expected a binary PCD (DATA binary)", "DATA")
    head = {ln.split()[0]: ln.split()[1:] for ln in raw[:end].decode("ascii", "replace").splitlines()
            if ln.strip() and not ln.startswith("#")}
    try:
        names, sizes = head["FIELDS"], [int(v) for v in head["SIZE"]]
        types, counts, n = head["TYPE"], [int(v) for v in head["COUNT"]], int(head["POINTS"][0])
    except (KeyError, ValueError, IndexError):
        raise FormatError(path, "PCD header needs FIELDS, SIZE, TYPE, COUNT and POINTS") from None
    offsets = np.concatenate([[0], np.cumsum(np.array(sizes) * np.array(counts))])
    step = int(offsets[-1])
    data = raw[end + len(b"DATA binary\n"):]
    if len(data) < n * step:
        raise FormatError(path, f"{len(data)} data bytes for {n} points of {step} bytes", "POINTS")
    rec = np.frombuffer(data[: n * step], dtype=np.uint8).reshape(n, step)
    cols = []
    for want in ("x", "y", "z", "intensity"):
        if want not in names:
            raise FormatError(path, f"no field {want!r}; fields: {names}", "FIELDS")
        k = names.index(want)
        dt = _PCD_TYPES.get((types[k], sizes[k]))
        if dt is None:
            raise FormatError(path, f"field {want!r}: unsupported TYPE {types[k]} SIZE {sizes[k]}", "TYPE")
        o = int(offsets[k])
        cols.append(np.ascontiguousarray(rec[:, o:o + sizes[k]]).view(dt).reshape(-1).astype(np.float32))
    pts = np.stack(cols, axis=1)
    return np.ascontiguousarray(pts[np.isfinite(pts[:, :3]).all(axis=1)])


def _labels(path: Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(box7 [M,7], full rotations [M,3,3], obj ids)."""
    try:
        items = json.loads(path.read_text())
        rows, rots, ids = [], [], []
        for it in items:
            psr = it["psr"]
            p, s, r = psr["position"], psr["scale"], psr["rotation"]
            rows.append([p["x"], p["y"], p["z"], s["x"], s["y"], s["z"], r["z"]])
            rots.append(euler_to_matrix([r["x"], r["y"], r["z"]], "xyz"))  # R = Rx Ry Rz (THREE.js "XYZ")
            ids.append(str(it.get("obj_id", "")))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise FormatError(path, f"not a SUSTech label list ({exc})") from None
    return np.asarray(rows, dtype=np.float64).reshape(-1, 7), np.asarray(rots).reshape(-1, 3, 3), ids


_SIGNS = np.array([[sx, sy, sz] for sz in (-1, 1) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]) / 2.0


def _projected_boxes(box7, rots, K, T, size) -> tuple[np.ndarray, np.ndarray]:
    """2D boxes of the labels visible in the image and the indices of their labels."""
    if len(box7) == 0:
        return np.zeros((0, 4), np.float32), np.zeros(0, int)
    corners = np.einsum("mij,mkj->mki", rots, _SIGNS[None] * box7[:, None, 3:6]) + box7[:, None, :3]
    uv, depth = project_points(corners.reshape(-1, 3), K, T[:3, :3], T[:3, 3], min_depth=-1e9)
    uv, depth = uv.reshape(-1, 8, 2), depth.reshape(-1, 8)
    w, h = size
    keep, out = [], []
    for m in range(len(box7)):
        if np.any(depth[m] < 0.5):
            continue
        b = boxes2d_from_points(uv[m][None])[0]
        c = np.array([np.clip(b[0], 0, w), np.clip(b[1], 0, h), np.clip(b[2], 0, w), np.clip(b[3], 0, h)])
        area = (b[2] - b[0]) * (b[3] - b[1])
        if area <= 0 or (c[2] - c[0]) * (c[3] - c[1]) < area / 3 or c[2] - c[0] < 4 or c[3] - c[1] < 4:
            continue
        keep.append(m)
        out.append(c)
    return np.asarray(out, dtype=np.float32).reshape(-1, 4), np.asarray(keep, dtype=int)


class SustechFrames(Sequence):
    """Frames of one camera (default ``front``) of a SUSTechPOINTS scene (module docstring)."""

    def __init__(self, root, camera: str | None = None):
        self.root = Path(root)
        self.camera_names = sorted(p.stem for p in (self.root / "calib" / "camera").glob("*.json"))
        self.camera = camera or ("front" if "front" in self.camera_names else self.camera_names[0])
        if self.camera not in self.camera_names:
            raise FormatError(self.root / "calib" / "camera", f"no camera {self.camera!r}; cameras: "
                                                              f"{self.camera_names}", "camera")
        calib_path = self.root / "calib" / "camera" / f"{self.camera}.json"
        try:
            c = json.loads(calib_path.read_text())
            self.T_cam_lidar = np.asarray(c["extrinsic"], dtype=np.float64).reshape(4, 4)
            self.K = np.asarray(c["intrinsic"], dtype=np.float64).reshape(3, 3)
        except (OSError, ValueError, KeyError) as exc:
            raise FormatError(calib_path, f"expected 'extrinsic' (16) and 'intrinsic' (9) numbers ({exc})") from None
        self.intrinsics = None  # sized per image (CameraIntrinsics with the image size)
        self.keys = sorted(p.stem for p in (self.root / "label").glob("*.json")
                           if (self.root / "camera" / self.camera / f"{p.stem}.jpg").is_file()
                           and (self.root / "lidar" / f"{p.stem}.pcd").is_file())

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def frame_keys(self) -> list[str]:
        return list(self.keys)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        key = self.keys[index]
        image = load_rgb(self.root / "camera" / self.camera / f"{key}.jpg")
        h, w = image.shape[:2]
        intr = CameraIntrinsics.from_matrix(self.K, None, width=w, height=h)
        box7, rots, ids = _labels(self.root / "label" / f"{key}.json")
        b2, idx = _projected_boxes(box7, rots, self.K, self.T_cam_lidar, (w, h))
        mm = np.zeros((len(b2), len(box7)), dtype=bool)
        mm[np.arange(len(idx)), idx] = True
        return Frame(image=image, point_cloud=read_sustech_pcd(self.root / "lidar" / f"{key}.pcd"),
                     bboxes_2d=b2, bboxes_3d=box7.astype(np.float32), camera_name=self.camera, frame_key=key,
                     match_matrix=mm, intrinsics=intr, extrinsics=self.T_cam_lidar.copy(),
                     point_fields=("x", "y", "z", "intensity"),
                     meta={"source": "sustech", "boxes_2d_source": "projected_labels", "ids_3d": ids,
                           "ids_2d": [ids[i] for i in idx]})


def _register() -> None:
    from ..io.sources import register_source

    register_source("sustech", is_sustech_scene, SustechFrames,
                    description="SUSTechPOINTS scene (calib/camera, camera/<cam>, lidar, label; 2D boxes = "
                                "projected labels)", priority=28)


_register()
