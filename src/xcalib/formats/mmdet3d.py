"""mmdetection3d (v1.x) info pickles (``data_list`` / ``metainfo``) for nuScenes, Waymo (KITTI
format) and similar datasets, read with a restricted unpickler (numpy data only).

Per sample and camera the info holds ``cam2img`` ([3,3] or [3,4]/[4,4]: camera -> pixels) and
``lidar2cam`` [4,4] (LiDAR -> camera, OpenCV optical axes). xcalib's ``T_cam_lidar`` is
``Translate(K^-1 cam2img[:3,3]) @ lidar2cam`` (the offset is zero except for KITTI's P2), so
``K @ T_cam_lidar[:3] == cam2img[:3] @ lidar2cam``.

``instances[*].bbox_3d`` are LiDAR-frame ``[x, y, z, dx, dy, dz, yaw]``; the z origin differs:
nuScenes/Lyft infos store the box's geometric centre, Waymo infos its bottom centre (checked on
the samples by projecting the boxes onto the 2D labels). :func:`read_mmdet3d_infos` returns
xcalib box7 (geometric centre) in both cases. KITTI infos (camera-frame boxes) are read by
:mod:`xcalib.formats.kitti`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics
from ..geometry.projection import project_points
from ..geometry.transforms import make_transform
from ..types import Frame
from ..io.timing import checked_timing
from ._checks import as_float, as_matrix, checked_rotation
from ._media import IMAGE_EXTS, image_size, load_cloud, load_rgb
from ._pickle import load_pickle_restricted

__all__ = ["InfoCamera", "InfoSample", "read_mmdet3d_infos", "Mmdet3dFrames", "mmdet3d_frames",
           "BOX_Z_ORIGIN", "TIMESTAMP_UNIT_S"]

# mmdetection3d's class lists when the info's metainfo has none.
_DEFAULT_CLASSES = {"waymo": ["Car", "Pedestrian", "Cyclist"]}

#: Fraction of the box height between the stored z and the bottom face, per dataset.
BOX_Z_ORIGIN = {"nuscenes": 0.5, "lyft": 0.5, "waymo": 0.0}

#: Seconds per unit of an info's ``timestamp``, per dataset: mmdetection3d's Waymo converter stores
#: the frame's ``timestamp_micros`` (microseconds); its nuScenes converter divides nuScenes'
#: microseconds to seconds. Datasets not listed are taken as seconds (and bounded as every clock is).
TIMESTAMP_UNIT_S = {"waymo": 1e-6}


@dataclass
class InfoCamera:
    """One camera of a sample: intrinsics (pixels), ``T_cam_lidar`` [4,4] (LiDAR -> camera),
    2D boxes [K,4] (x1 y1 x2 y2) with ``box_index`` [K] into the sample's box7 (-1 = none)."""

    name: str
    intrinsics: CameraIntrinsics
    T_cam_lidar: np.ndarray
    image_path: Path | None
    boxes_2d: np.ndarray
    box_index: np.ndarray
    classes_2d: list[str] = field(default_factory=list)


@dataclass
class InfoSample:
    """One sample: LiDAR file, box7 [M,7] (LiDAR frame, geometric centre), labels [M], cameras."""

    key: str
    dataset: str
    lidar_path: Path | None
    num_pts_feats: int
    boxes7: np.ndarray
    labels: np.ndarray
    cameras: dict[str, InfoCamera]
    meta: dict[str, Any] = field(default_factory=dict)


def _find(name: str | None, roots: list[Path], subdirs: tuple[str, ...], exts: tuple[str, ...]) -> Path | None:
    if not name:
        return None
    base = Path(name)
    for r in roots:
        for cand in (r / base, r / base.name):
            if cand.is_file():
                return cand
    for r in roots:  # KITTI-format exports: training/image_0/<stem>.png for img_path <stem>.jpg
        for sub in subdirs:
            for e in exts:
                for cand in (r / sub / (base.stem + e), r / "training" / sub / (base.stem + e)):
                    if cand.is_file():
                        return cand
    return None


def _check_box7(b: np.ndarray, path: Path, where: str) -> None:
    if not np.all(np.isfinite(b)):
        raise FormatError(path, "NaN/Inf in bbox_3d", where)
    if len(b) and (np.any(b[:, 3:6] <= 0) or np.abs(b[:, :6]).max() > 1e4):
        raise FormatError(path, "bbox_3d sizes must be > 0 and values within 1e4 m", where)


def _check_boxes2d(b: np.ndarray, path: Path, where: str) -> None:
    if not np.all(np.isfinite(b)) or (b.size and np.abs(b).max() > 1e6):
        raise FormatError(path, "NaN/Inf or values beyond 1e6 px in bbox", where)
    if len(b) and np.any(b[:, 2:] < b[:, :2]):
        raise FormatError(path, "inverted 2D bbox (need x1 <= x2, y1 <= y2)", where)


def _cam_calib(cam: dict, path: Path, where: str) -> tuple[CameraIntrinsics, np.ndarray]:
    M = as_matrix(cam.get("cam2img", []), (3, 4), path, where + ".cam2img", alt_shapes=[(4, 4)]) \
        if np.size(cam.get("cam2img", [])) != 9 else np.hstack([as_matrix(cam["cam2img"], (3, 3), path,
                                                                         where + ".cam2img"), np.zeros((3, 1))])
    L = as_matrix(cam.get("lidar2cam", []), (4, 4), path, where + ".lidar2cam")
    R = checked_rotation(L[:3, :3], path, where + ".lidar2cam")
    K = M[:, :3]
    off = np.linalg.solve(K, M[:, 3])
    T = make_transform(np.eye(3), off) @ make_transform(R, L[:3, 3])
    try:
        intr = CameraIntrinsics.from_matrix(K, width=cam.get("width"), height=cam.get("height"))
        intr.check_plausible()
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), where + ".cam2img") from None
    if not np.all(np.isfinite(T)) or np.abs(T[:3, 3]).max() > 1e4:
        raise FormatError(path, "lidar2cam translation / cam2img offset not finite or beyond 1e4 m", where)
    return intr, T


def read_mmdet3d_infos(path, data_root=None) -> list[InfoSample]:
    """Samples of an mmdetection3d v1.x info pickle (nuScenes / Waymo / Lyft style).

    Files are looked up under ``data_root`` and next to the pickle. Each camera's 2D boxes come
    from ``cam_instances`` and are tied to the LiDAR boxes by their 3D centre (they are the same
    boxes expressed in the camera frame; tolerance 1 cm). Every value read is checked (finite
    boxes with positive sizes, rigid extrinsics, plausible intrinsics); a malformed info is a
    FormatError naming the file and the sample."""
    path = Path(path)
    d = load_pickle_restricted(path)
    if not isinstance(d, dict) or "data_list" not in d or not isinstance(d["data_list"], (list, tuple)):
        raise FormatError(path, "expected an mmdetection3d v1.x info dict with a 'data_list' list", "data_list")
    state = {"where": "metainfo"}
    try:
        return _read_infos(d, path, data_root, state)
    except FormatError:
        raise
    except (TypeError, KeyError, AttributeError, IndexError, ValueError, OverflowError, ZeroDivisionError,
            np.linalg.LinAlgError) as exc:
        raise FormatError(path, f"malformed info ({type(exc).__name__}: {str(exc)[:120]})", state["where"]) from None


def _checked(info, key: str, kind, path, where: str, default):
    """``info[key]`` of type ``kind`` (``default`` when absent or None)."""
    v = info.get(key)
    if v is None:
        return default
    if not isinstance(v, kind):
        raise FormatError(path, f"expected {getattr(kind, '__name__', kind)}, got {type(v).__name__}",
                          f"{where}.{key}")
    return v


def _read_infos(d: dict, path: Path, data_root, state: dict) -> list[InfoSample]:
    meta = d.get("metainfo", {}) or {}
    if not isinstance(meta, dict):
        raise FormatError(path, f"expected a mapping, got {type(meta).__name__}", "metainfo")
    dataset = str(meta.get("dataset", meta.get("DATASET", ""))).lower()
    if dataset == "kitti":
        raise FormatError(path, "KITTI infos hold camera-frame boxes: read them with xcalib.formats.kitti "
                                "(load_kitti_calibration / kitti_frames)", "metainfo.dataset")
    z0 = BOX_Z_ORIGIN.get(dataset, 0.0)
    cats = meta.get("categories", meta.get("classes")) or _DEFAULT_CLASSES.get(dataset, {})
    names = ({int(v): str(k) for k, v in cats.items()} if isinstance(cats, dict)
             else {i: str(c) for i, c in enumerate(cats)})
    roots = [Path(data_root)] if data_root is not None else []
    roots.append(path.parent)
    out = []
    for si, info in enumerate(d["data_list"]):
        where = f"data_list[{si}]"
        state["where"] = where
        if not isinstance(info, dict):
            raise FormatError(path, f"expected a mapping, got {type(info).__name__}", where)
        insts = _checked(info, "instances", (list, tuple), path, where, [])
        try:
            b = np.array([[float(v) for v in i["bbox_3d"]] for i in insts], dtype=np.float64)
            if b.size == 0:
                b = b.reshape(0, 7)
            if b.ndim != 2 or b.shape[1] != 7:
                raise ValueError
        except (KeyError, TypeError, ValueError, IndexError):
            raise FormatError(path, "instances need bbox_3d with 7 numbers", where + ".instances") from None
        _check_box7(b, path, where + ".instances")
        b[:, 2] += (0.5 - z0) * b[:, 5]
        labels = np.array([int(i.get("bbox_label_3d", i.get("bbox_label", -1))) for i in insts], dtype=np.int64)
        lp = info.get("lidar_points", {}) or {}
        nfeat = int(lp.get("num_pts_feats", 4))
        if not 3 <= nfeat <= 64:
            raise FormatError(path, f"num_pts_feats {nfeat} outside 3..64", where + ".lidar_points.num_pts_feats")
        lidar = _find(lp.get("lidar_path"), roots, ("velodyne",), (".bin",))
        cams: dict[str, InfoCamera] = {}
        for name, cam in _checked(info, "images", dict, path, where, {}).items():
            if not isinstance(cam, dict) or "lidar2cam" not in cam:
                continue
            state["where"] = f"{where}.images.{name}"
            intr, T = _cam_calib(cam, path, f"{where}.images.{name}")
            ci = _checked(info, "cam_instances", dict, path, where, {}).get(name, []) or []
            state["where"] = f"{where}.cam_instances.{name}"
            b2 = np.array([[float(v) for v in c["bbox"]] for c in ci], dtype=np.float64).reshape(-1, 4)
            _check_boxes2d(b2, path, f"{where}.cam_instances.{name}")
            idx = np.full(len(ci), -1, dtype=np.int64)
            cls2d = [names.get(int(c.get("bbox_label", -1)), str(c.get("bbox_label", ""))) for c in ci]
            if len(ci) and len(b):
                c3 = np.array([[float(v) for v in c["bbox_3d"][:3]] for c in ci])
                L = np.asarray(cam["lidar2cam"], dtype=np.float64)
                stored = b.copy()
                stored[:, 2] -= (0.5 - z0) * b[:, 5]
                pc = stored[:, :3] @ L[:3, :3].T + L[:3, 3]
                dist = np.linalg.norm(c3[:, None] - pc[None], axis=2)
                j = dist.argmin(axis=1)
                idx = np.where(dist[np.arange(len(ci)), j] < 0.01, j, -1)
            img = _find(cam.get("img_path"), roots, ("image_0", "image_2"), IMAGE_EXTS)
            cams[name] = InfoCamera(name, intr, T, img, b2, idx, cls2d)
        key = str(info.get("token", info.get("sample_idx", si)))
        out.append(InfoSample(key, dataset, lidar, nfeat, b, labels, cams,
                              {"source": str(path), "ego2global": info.get("ego2global"),
                               "lidar2ego": (lp.get("lidar2ego")),
                               "classes": [names.get(int(v), str(int(v))) for v in labels],
                               **_timing(info, insts, path, where, TIMESTAMP_UNIT_S.get(dataset, 1.0))}))
    return out


def _timing(info: dict, insts: list, path: Path, where: str, unit_s: float = 1.0) -> dict:
    """Sample meta: ``lidar_time_s`` (the info's ``timestamp`` x ``unit_s``), ``camera_times`` {camera: s}
    and ``velocities`` [M,3] (instances' ``velocity`` vx, vy in the LiDAR frame, vz = 0; rows the
    file leaves NaN are 0 and False in ``velocity_known``) where the info has them."""
    out: dict = {}
    if info.get("timestamp") is not None:
        out["lidar_time_s"] = as_float(info["timestamp"], path, where + ".timestamp") * unit_s
    cams = {n: c.get("timestamp") for n, c in (info.get("images", {}) or {}).items() if isinstance(c, dict)}
    out["camera_times"] = {n: as_float(t, path, f"{where}.images.{n}.timestamp") * unit_s
                           for n, t in cams.items() if t is not None}
    if insts and all("velocity" in i for i in insts):
        try:
            v = np.array([[float(x) for x in i["velocity"]][:2] for i in insts], dtype=np.float64).reshape(-1, 2)
        except (TypeError, ValueError):
            raise FormatError(path, "instances' velocity must be 2 numbers (vx, vy)", where + ".instances") from None
        known = np.all(np.isfinite(v), axis=1)
        out["velocities"] = np.column_stack([np.where(known[:, None], v, 0.0), np.zeros(len(v))])
        out["velocity_known"] = known
    return out


class Mmdet3dFrames(Sequence):
    """Lazy ``Sequence[Frame]``: one frame per (sample, camera) with the camera's 2D boxes, the
    LiDAR box7 that have a 2D box in it or whose centre projects into the image, the match matrix
    from the info's own association, ``intrinsics`` and ``extrinsics`` = ``T_cam_lidar``."""

    def __init__(self, path, camera: str | None = None, *, data_root=None, load_image: bool = True,
                 load_points: bool = True):
        self.path = Path(path)
        self.samples = read_mmdet3d_infos(self.path, data_root)
        self.items = [(s, c) for s in self.samples for c in s.cameras if camera is None or c == camera]
        if camera is not None and not self.items:
            raise KeyError(f"{self.path}: no camera {camera!r}; cameras: "
                           f"{sorted({c for s in self.samples for c in s.cameras})}")
        self.load_image, self.load_points = load_image, load_points

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        s, name = self.items[index]
        return self._load(s, s.cameras[name])

    def _load(self, s: InfoSample, cam: InfoCamera) -> Frame:
        image = np.zeros((0, 0, 3), dtype=np.uint8)
        size = (cam.intrinsics.width, cam.intrinsics.height)
        if cam.image_path is not None:
            if self.load_image:
                image = load_rgb(cam.image_path)
                size = (image.shape[1], image.shape[0])
            elif size[0] is None:
                size = image_size(cam.image_path)
        elif self.load_image:
            raise FormatError(self.path, f"sample {s.key} camera {cam.name}: image file not found")
        points, fields = np.zeros((0, 3), dtype=np.float32), ("x", "y", "z")
        if self.load_points:
            if s.lidar_path is None:
                raise FormatError(self.path, f"sample {s.key}: LiDAR file not found")
            points, fields = load_cloud(s.lidar_path, columns=s.num_pts_feats)
        T = cam.T_cam_lidar
        uv, depth = project_points(s.boxes7[:, :3], cam.intrinsics.K, T[:3, :3], T[:3, 3])
        visible = depth > 0.5
        if size[0] is not None:
            visible &= (uv[:, 0] >= 0) & (uv[:, 0] < size[0]) & (uv[:, 1] >= 0) & (uv[:, 1] < size[1])
        visible[cam.box_index[cam.box_index >= 0]] = True
        keep = np.flatnonzero(visible)
        col = {j: k for k, j in enumerate(keep)}
        mm = np.zeros((len(cam.boxes_2d), len(keep)), dtype=bool)
        for i, j in enumerate(cam.box_index):
            if j >= 0:
                mm[i, col[j]] = True
        intr = cam.intrinsics if size[0] is None else cam.intrinsics.with_image_size(*size)
        return Frame(image=image, point_cloud=np.ascontiguousarray(points, dtype=np.float32),
                     bboxes_2d=cam.boxes_2d.astype(np.float32), bboxes_3d=s.boxes7[keep].astype(np.float32),
                     camera_name=cam.name, frame_key=f"{s.key}/{cam.name}", match_matrix=mm, intrinsics=intr,
                     extrinsics=T.copy(), point_fields=tuple(fields),
                     meta={"source": f"mmdet3d:{s.dataset}", "labels_3d": s.labels[keep].tolist(),
                           "classes_2d": list(cam.classes_2d), "box7": s.boxes7[keep].copy(),
                           "classes_3d": [s.meta["classes"][j] for j in keep],
                           "box_indices": keep, "image_path": cam.image_path, "lidar_path": s.lidar_path,
                           **({"velocity_known": s.meta["velocity_known"][keep]} if "velocity_known" in s.meta else {})},
                     **checked_timing(self.path, len(keep), lidar_time_s=s.meta.get("lidar_time_s"),
                                      camera_time_s=s.meta.get("camera_times", {}).get(cam.name),
                                      velocities_3d=s.meta["velocities"][keep] if "velocities" in s.meta else None))


def mmdet3d_frames(path, camera: str | None = None, **kwargs) -> Sequence[Frame]:
    """An mmdetection3d info pickle as a lazy ``Sequence[Frame]`` (see :class:`Mmdet3dFrames`);
    a KITTI info pickle (``<id>.pkl`` next to ``<id>.bin``) is read by :func:`~.kitti.kitti_frames`."""
    path = Path(path)
    d = load_pickle_restricted(path)
    meta = d.get("metainfo", {}) if isinstance(d, dict) else {}
    if str((meta or {}).get("dataset", (meta or {}).get("DATASET", ""))).lower() == "kitti":
        from .kitti import kitti_frames

        kwargs.pop("data_root", None)
        return kitti_frames(path.parent, ids=[path.stem], **kwargs)
    return Mmdet3dFrames(path, camera, **kwargs)


def _is_info_pickle(path) -> bool:
    p = Path(path)
    return p.is_file() and p.suffix.lower() == ".pkl"


def _register() -> None:
    from ..io.sources import register_source

    register_source("mmdet3d-info", _is_info_pickle, mmdet3d_frames,
                    description="mmdetection3d info pickle (nuScenes, KITTI, ...; camera= e.g. CAM_FRONT)",
                    priority=60)


_register()
