"""PandaSet sequences in the neutral layout of ``shared/data/pandaset_002`` as ``Sequence[Frame]``.

Layout (see that folder's README)::

    calibration.json          {"dataset": "PandaSet ...", "cameras": {<cam>: {fx, fy, cx, cy, width,
                               height, distortion, frames: {NN: {T_cam_lidar, camera_timestamp,
                               lidar_timestamp}}}}, "lidar": {"frames": {NN: {timestamp, T_world_lidar}}}}
    lidar/NN.pcd              x y z intensity, LiDAR-pose frame of frame NN (metres)
    camera/<cam>/NN.jpg       undistorted pinhole images
    cuboids/NN.json           [{track_id, label, center, size [l, w, h], yaw, rotation_matrix,
                                stationary, ...}] in the LiDAR-pose frame of frame NN

Each frame: ``bboxes_3d`` [M,7] box7 (centre, l, w, h, yaw about LiDAR z) in the LiDAR frame,
``bboxes_2d`` [0,4] (PandaSet has no 2D boxes; :func:`xcalib.data.boxes2d.synthetic_2d_boxes`
makes them), ``intrinsics`` of the camera, ``extrinsics`` = the frame's ground-truth
``T_cam_lidar`` (LiDAR-pose frame -> camera at the camera's own time, ego motion included),
``lidar_time_s`` / ``camera_time_s`` (Unix seconds; the front camera fires ~49.85 ms before the
LiDAR), ``track_ids_3d`` (an int per PandaSet track uuid, stable over the sequence),
``velocities_3d`` (the object's world velocity, central differences of its world-frame centre
over neighbouring frames, in the frame's LiDAR axes, m/s; 0 for boxes marked stationary and for
tracks seen in one frame only). ``meta``: ``R_lidar_box`` [M,3,3] (exact box rotation, keeps the
1.6-2.2 deg tilt that ``yaw`` drops), ``labels_3d``, ``track_uuids``, ``stationary`` [M] bool,
``T_world_lidar`` [4,4] (ego pose), ``source_frame`` ("NN").
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics
from ..io.files import load_json
from ..io.timing import checked_time
from ..types import Frame
from ._checks import as_float, as_matrix, checked_rotation, plausible_camera, require
from ._media import load_cloud, load_rgb

__all__ = ["is_pandaset_root", "PandaSetFrames", "pandaset_frames", "read_pandaset_cuboids"]


def is_pandaset_root(path) -> bool:
    """A folder with ``calibration.json`` naming PandaSet and ``cuboids/`` + ``lidar/`` folders."""
    p = Path(path)
    cal = p / "calibration.json"
    if not (p.is_dir() and cal.is_file() and (p / "cuboids").is_dir() and (p / "lidar").is_dir()):
        return False
    with open(cal, "rb") as fh:
        return b"PandaSet" in fh.read(4096)


def _load_json(path: Path):
    try:
        return load_json(path, what="PandaSet JSON file")
    except FileNotFoundError:
        raise FormatError(path, "file not found") from None


def read_pandaset_cuboids(path) -> dict:
    """One ``cuboids/NN.json`` -> {"box7" [M,7], "R_lidar_box" [M,3,3], "track_uuids", "labels",
    "stationary" [M] bool}, validated (FormatError naming the file and ``[i].field``)."""
    path = Path(path)
    raw = _load_json(path)
    if not isinstance(raw, list):
        raise FormatError(path, f"expected a JSON list of cuboids, got {type(raw).__name__}")
    box7, rots, uuids, labels, stat = [], [], [], [], []
    for i, c in enumerate(raw):
        pre = f"[{i}]."
        centre = as_matrix(require(c, "center", path, pre), (3,), path, pre + "center")
        size = as_matrix(require(c, "size", path, pre), (3,), path, pre + "size")
        if not np.all(size > 0):
            raise FormatError(path, f"box sizes must be > 0 m, got {size.tolist()}", pre + "size")
        yaw = as_float(require(c, "yaw", path, pre), path, pre + "yaw")
        R = as_matrix(c["rotation_matrix"], (3, 3), path, pre + "rotation_matrix") if "rotation_matrix" in c else None
        uuid = require(c, "track_id", path, pre)
        if not isinstance(uuid, str) or not uuid:
            raise FormatError(path, f"expected a track id string, got {uuid!r}", pre + "track_id")
        cy, sy = np.cos(yaw), np.sin(yaw)
        box7.append([*centre, *size, yaw])
        rots.append(R if R is not None else np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]]))
        uuids.append(uuid)
        labels.append(str(c.get("label", "")))
        stat.append(bool(c.get("stationary", False)))
    return {"box7": np.asarray(box7, dtype=np.float64).reshape(-1, 7),
            "R_lidar_box": np.asarray(rots, dtype=np.float64).reshape(-1, 3, 3), "track_uuids": uuids,
            "labels": labels, "stationary": np.asarray(stat, dtype=bool)}


def _size(cal_path: Path, cam: dict, key: str, pre: str) -> int | None:
    """An image width / height: a positive integer, or absent / null / 0 (unknown)."""
    v = cam.get(key)
    if v is None or (v == 0 and not isinstance(v, bool)):  # (false == 0 in Python: not a size either)
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v != int(v) or not 0 < v <= 1e5:
        raise FormatError(cal_path, f"expected an image size in pixels (an integer 1..100000), got {str(v)[:40]!r}",
                          pre + key)
    return int(v)


def _intrinsics(cal_path: Path, cam: dict, name: str) -> CameraIntrinsics:
    pre = f"cameras.{name}."
    vals = [as_float(require(cam, k, cal_path, pre), cal_path, pre + k) for k in ("fx", "fy", "cx", "cy")]
    if cam.get("model") not in (None, "pinhole"):  # the converter writes pinhole; anything else would be dropped
        raise FormatError(cal_path, f"unsupported camera model {str(cam.get('model'))[:40]!r}; PandaSet's images are "
                                    "pinhole (expected \"pinhole\" or none)", pre + "model")
    if cam.get("distortion") not in (None, []) and not (isinstance(cam["distortion"], list) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and v == 0 for v in cam["distortion"])):
        raise FormatError(cal_path, f"PandaSet's images are undistorted; a distortion {str(cam['distortion'])[:60]} "
                                    "would be ignored", pre + "distortion")
    try:
        intr = CameraIntrinsics(*vals, None, _size(cal_path, cam, "width", pre), _size(cal_path, cam, "height", pre))
    except ValueError as exc:
        if isinstance(exc, FormatError):
            raise
        raise FormatError(cal_path, str(exc), pre + "fx") from None
    return plausible_camera(intr, cal_path, pre + "fx")


class PandaSetFrames(Sequence):
    """A PandaSet sequence folder as a lazy ``Sequence[Frame]`` (see the module docstring).

    Args:
        root: the sequence folder. camera: camera name (default ``front_camera``); only the
            frames that camera has are listed. read_images / read_points: False skips the JPEG /
            the PCD (an empty image / [0,4] cloud).
    """

    def __init__(self, root, *, camera: str | None = None, read_images: bool = True, read_points: bool = True):
        self.root = Path(root)
        if not is_pandaset_root(self.root):
            raise FormatError(self.root, "not a PandaSet sequence folder (calibration.json naming PandaSet, "
                                         "cuboids/, lidar/)")
        self.cal_path = self.root / "calibration.json"
        cal = _load_json(self.cal_path)
        cams = require(cal, "cameras", self.cal_path, kind=dict)
        self.camera = camera or "front_camera"
        if self.camera not in cams:
            raise FormatError(self.cal_path, f"no camera {self.camera!r}; cameras: {sorted(cams)}", "cameras")
        cam = cams[self.camera]
        self.camera_names = sorted(cams)
        self.intrinsics = _intrinsics(self.cal_path, cam, self.camera)
        self._cam_frames = require(cam, "frames", self.cal_path, f"cameras.{self.camera}.", kind=dict)
        self._lidar_frames = require(require(cal, "lidar", self.cal_path, kind=dict), "frames", self.cal_path,
                                     "lidar.", kind=dict)
        self.frame_keys = sorted(k for k in self._cam_frames if k in self._lidar_frames
                                 and (self.root / "cuboids" / f"{k}.json").is_file())
        self.read_images, self.read_points = bool(read_images), bool(read_points)
        self._tracks: dict | None = None

    def __len__(self) -> int:
        return len(self.frame_keys)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return self.read_frame(self.frame_keys[index])

    def __repr__(self) -> str:
        return f"PandaSetFrames({str(self.root)!r}, camera={self.camera!r}, frames={len(self)})"

    # ------------------------------------------------------------------ tracks
    def _pose(self, key: str) -> np.ndarray:
        lf = self._lidar_frames[key]
        return as_matrix(require(lf, "T_world_lidar", self.cal_path, f"lidar.frames.{key}."), (4, 4),
                         self.cal_path, f"lidar.frames.{key}.T_world_lidar")

    def _lidar_time(self, key: str) -> float:
        field = f"lidar.frames.{key}.timestamp"
        return checked_time(self.cal_path, field, as_float(require(self._lidar_frames[key], "timestamp", self.cal_path,
                                                                   f"lidar.frames.{key}."), self.cal_path, field))

    def tracks(self) -> dict:
        """{"ids": {uuid: int}, "world": {uuid: [(t_s, centre_world [3])...]}} over every cuboid file
        of the sequence (read once)."""
        if self._tracks is None:
            keys = sorted(k for k in self._lidar_frames if (self.root / "cuboids" / f"{k}.json").is_file())
            world: dict[str, list] = {}
            for k in keys:
                cub = read_pandaset_cuboids(self.root / "cuboids" / f"{k}.json")
                T, t = self._pose(k), self._lidar_time(k)
                cw = cub["box7"][:, :3] @ T[:3, :3].T + T[:3, 3]
                for u, c in zip(cub["track_uuids"], cw):
                    world.setdefault(u, []).append((t, c))
            self._tracks = {"ids": {u: i for i, u in enumerate(sorted(world))}, "world": world}
        return self._tracks

    def _velocity_world(self, uuid: str, t: float) -> np.ndarray:
        obs = self.tracks()["world"][uuid]
        ts = np.array([o[0] for o in obs])
        i = int(np.argmin(np.abs(ts - t)))
        lo, hi = max(i - 1, 0), min(i + 1, len(obs) - 1)
        if hi == lo or ts[hi] <= ts[lo]:
            return np.zeros(3)
        return (obs[hi][1] - obs[lo][1]) / (ts[hi] - ts[lo])

    # ------------------------------------------------------------------ frames
    def read_frame(self, key: str) -> Frame:
        """Frame ``key`` ("00" ...) of the chosen camera."""
        cf = self._cam_frames[key]
        where = f"cameras.{self.camera}.frames.{key}."
        T = as_matrix(require(cf, "T_cam_lidar", self.cal_path, where), (4, 4), self.cal_path, where + "T_cam_lidar")
        checked_rotation(T[:3, :3], self.cal_path, where + "T_cam_lidar")  # the recorded pose: a rigid transform
        if np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9 or np.abs(T[:3, 3]).max() > 1e4:
            raise FormatError(self.cal_path, f"not a rigid transform within 1e4 m (last row {T[3].tolist()}, "
                                             f"translation {T[:3, 3].tolist()})", where + "T_cam_lidar")
        t_cam = checked_time(self.cal_path, where + "camera_timestamp",
                             as_float(require(cf, "camera_timestamp", self.cal_path, where), self.cal_path,
                                      where + "camera_timestamp"))
        t_lidar = self._lidar_time(key)
        cub = read_pandaset_cuboids(self.root / "cuboids" / f"{key}.json")
        T_wl = self._pose(key)
        tr = self.tracks()
        ids = np.array([tr["ids"][u] for u in cub["track_uuids"]], dtype=np.int64)
        vel = np.array([np.zeros(3) if s else self._velocity_world(u, t_lidar)
                        for u, s in zip(cub["track_uuids"], cub["stationary"])]).reshape(-1, 3)
        vel_lidar = vel @ T_wl[:3, :3]  # world -> LiDAR axes: R_lidar_world = R_world_lidar^T
        img_path = self.root / "camera" / self.camera / f"{key}.jpg"
        image = load_rgb(img_path) if self.read_images else np.zeros((0, 0, 3), dtype=np.uint8)
        if self.read_points:
            points, fields = load_cloud(self.root / "lidar" / f"{key}.pcd")
        else:
            points, fields = np.zeros((0, 4), dtype=np.float32), ("x", "y", "z", "intensity")
        meta = {"R_lidar_box": cub["R_lidar_box"], "labels_3d": cub["labels"], "track_uuids": cub["track_uuids"],
                "stationary": cub["stationary"], "T_world_lidar": T_wl, "source_frame": key,
                "image_size": (self.intrinsics.width, self.intrinsics.height), "image_path": str(img_path)}
        return Frame(image=image, point_cloud=np.ascontiguousarray(points, dtype=np.float32),
                     bboxes_2d=np.zeros((0, 4), dtype=np.float32), bboxes_3d=cub["box7"].astype(np.float32),
                     camera_name=self.camera, frame_key=key, intrinsics=self.intrinsics, extrinsics=T,
                     point_fields=tuple(fields), meta=meta, lidar_time_s=t_lidar, camera_time_s=t_cam,
                     track_ids_3d=ids, velocities_3d=vel_lidar)


def pandaset_frames(root, *, camera: str | None = None, **kwargs) -> PandaSetFrames:
    """Open a PandaSet sequence folder (frame-source entry point; see :class:`PandaSetFrames`)."""
    return PandaSetFrames(root, camera=camera, **kwargs)


def _register() -> None:
    from ..io.sources import register_source

    register_source("pandaset", is_pandaset_root, pandaset_frames,
                    description="PandaSet sequence (calibration.json, lidar/NN.pcd, cuboids/NN.json, camera/<cam>/)",
                    priority=30)


_register()
