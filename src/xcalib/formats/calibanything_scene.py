"""CalibAnything / OpenCalib scene folders as ``Sequence[Frame]`` (one frame per point cloud and
camera; no detections: empty box arrays).

Layouts (``calibanything-scene-format.md`` and the OpenCalib samples):

* **lucid multi-camera** — ``scene/<id>.pcd`` + ``scene/<cam>/lucid_calib.json`` + images in
  each camera folder (any name; paired with the clouds by file stem, else in sorted order);
* **lucid time-series** — the same with one camera and ``<cam>/<id>.png`` per ``<id>.pcd``;
* **CalibAnything v2** — ``calib.json`` + ``<img_folder>/<id><img_format>`` +
  ``<pc_folder>/<id><pc_format>`` for each ``file_name``;
* **CalibAnything v1** — ``calib.txt`` + ``calib.pcd`` + ``calib.{png,jpg}``;
* **OpenCalib** — ``<lidar>-to-<cam>-extrinsic.json`` (+ ``<cam>-intrinsic.json``) + one
  ``.pcd`` and the image with the same stem.

A folder holding several scenes (``DATA/scene1``, ``DATA/scene2``) is read scene by scene.
``Frame.extrinsics`` is the file's ground-truth ``T_cam_lidar`` (LiDAR -> camera); for a v2
``calib.json`` without ``T_lidar_to_cam_gt`` it is None and ``meta["initial_extrinsics"]`` holds
``T_lidar_to_cam``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..calib.result import CalibrationResult
from ..errors import FormatError
from ..io.files import inside
from ..types import Frame
from ._media import IMAGE_EXTS, image_size, load_cloud, load_rgb
from .calibanything import read_calib_json, read_calib_txt, read_lucid_calib, read_opencalib

__all__ = ["SceneItem", "find_scene_items", "is_calibanything_scene", "CalibAnythingFrames",
           "calibanything_frames", "scene_layout"]

log = logging.getLogger("xcalib.formats.calibanything")
_CLOUD_EXTS = (".pcd", ".bin", ".npy")


@dataclass(frozen=True)
class SceneItem:
    """One (point cloud, camera image) pair of a scene and its calibration."""

    frame_key: str
    camera: str
    cloud: Path
    image: Path
    calibration: CalibrationResult
    ground_truth: np.ndarray | None
    layout: str
    meta: dict[str, Any] = field(default_factory=dict)


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS
                  and not p.stem.lower().startswith("mask"))


def _clouds(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in _CLOUD_EXTS)


def scene_layout(path) -> str | None:
    """``"lucid" | "calib_json" | "calib_txt" | "opencalib" | "multi"`` (a folder of scenes) or None."""
    p = Path(path)
    if not p.is_dir():
        return None
    if (p / "calib.json").is_file():
        return "calib_json"
    if (p / "calib.txt").is_file() and _clouds(p):
        return "calib_txt"
    if any(p.glob("*-extrinsic.json")):
        return "opencalib"
    subdirs = [d for d in p.iterdir() if d.is_dir()]
    if any((d / "lucid_calib.json").is_file() for d in subdirs) and _clouds(p):
        return "lucid"
    if any(scene_layout(d) is not None for d in subdirs):
        return "multi"
    return None


def is_calibanything_scene(path) -> bool:
    """True for any folder :func:`calibanything_frames` can read."""
    return scene_layout(path) is not None


def _pair(clouds: list[Path], images: list[Path], where: Path) -> list[tuple[Path, Path]]:
    by_stem = {im.stem: im for im in images}
    pairs = [(c, by_stem[c.stem]) for c in clouds if c.stem in by_stem]
    if pairs:
        if len(pairs) < len(clouds):
            log.warning("%s: %d of %d point clouds have no image with the same name; skipped",
                        where, len(clouds) - len(pairs), len(clouds))
        return pairs
    if len(clouds) == len(images):
        return list(zip(clouds, images))
    if len(clouds) == 1 and images:
        return [(clouds[0], im) for im in images]
    raise FormatError(where, f"cannot pair {len(clouds)} point cloud(s) with {len(images)} image(s): "
                             "name them alike (000000.pcd <-> 000000.png) or give one of each")


def find_scene_items(root, camera: str | None = None, *, repair: bool = False) -> list[SceneItem]:
    """All (cloud, image, calibration) items of a scene folder or a folder of scenes."""
    root = Path(root)
    if not root.exists():
        raise FileNotFoundError(f"CalibAnything scene folder not found: {root}")
    layout = scene_layout(root)
    items: list[SceneItem] = []
    if layout is None:
        raise FormatError(root, "not a CalibAnything/OpenCalib scene: expected <cam>/lucid_calib.json with "
                                "*.pcd, calib.json, calib.txt + calib.pcd, or *-extrinsic.json + a .pcd")
    if layout == "multi":
        for d in sorted(x for x in root.iterdir() if x.is_dir() and scene_layout(x) is not None):
            items += [SceneItem(f"{d.name}/{it.frame_key}", it.camera, it.cloud, it.image, it.calibration,
                                it.ground_truth, it.layout, it.meta)
                      for it in find_scene_items(d, camera, repair=repair)]
        return items
    if layout == "lucid":
        clouds = _clouds(root)
        if not clouds:
            raise FormatError(root, "no point clouds (*.pcd) next to the camera folders")
        for cam_dir in sorted(d for d in root.iterdir() if (d / "lucid_calib.json").is_file()):
            if camera is not None and cam_dir.name != camera:
                continue
            calib = read_lucid_calib(cam_dir / "lucid_calib.json", repair=repair)
            calib.camera_name = cam_dir.name
            for c, im in _pair(clouds, _images(cam_dir), cam_dir):
                items.append(SceneItem(c.stem, cam_dir.name, c, im, calib, calib.extrinsics, "lucid",
                                       {"calib_path": str(cam_dir / "lucid_calib.json")}))
        if camera is not None and not items:
            raise KeyError(f"{root}: no camera folder {camera!r} with lucid_calib.json")
        return items
    if layout == "calib_json":
        calib = read_calib_json(root / "calib.json", repair=repair)
        m = calib.meta
        gt = None if m.get("T_cam_lidar_gt") is None else np.asarray(m["T_cam_lidar_gt"])
        cj = root / "calib.json"
        names = m.get("file_name") or []
        fields = {k: m.get(k, d) for k, d in (("img_folder", "images"), ("pc_folder", "pc"),
                                              ("img_format", ".png"), ("pc_format", ".pcd"))}
        if not isinstance(names, list) or not all(isinstance(n, (str, int)) for n in names):
            raise FormatError(cj, "expected a list of file-name stems", "file_name")
        for k, v in fields.items():
            if not isinstance(v, str):
                raise FormatError(cj, f"expected a string, got {v!r:.40}", k)
        img_dir = inside(root, fields["img_folder"], source=cj, field="img_folder")
        pc_dir = inside(root, fields["pc_folder"], source=cj, field="pc_folder")
        if not names and pc_dir.is_dir():
            names = [c.stem for c in _clouds(pc_dir)]
        for n in names:
            c = inside(root, f"{fields['pc_folder']}/{n}{fields['pc_format']}", source=cj, field="file_name")
            im = inside(root, f"{fields['img_folder']}/{n}{fields['img_format']}", source=cj, field="file_name")
            for p, what in ((c, "point cloud"), (im, "image")):
                if not p.is_file():
                    raise FormatError(root / "calib.json", f"{what} {p} listed by file_name is missing", "file_name")
            items.append(SceneItem(n, "camera", c, im, calib, gt, "calib_json",
                                   {"calib_path": str(root / "calib.json")}))
        return items
    if layout == "calib_txt":
        calib = read_calib_txt(root / "calib.txt", repair=repair)
        for c, im in _pair(_clouds(root), _images(root), root):
            items.append(SceneItem(c.stem, "camera", c, im, calib, calib.extrinsics, "calib_txt",
                                   {"calib_path": str(root / "calib.txt")}))
        return items
    # opencalib
    for ext in sorted(root.glob("*-extrinsic.json")):
        calib = read_opencalib(ext, repair=repair)
        cam = calib.camera_name or "camera"
        if camera is not None and cam != camera:
            continue
        for c, im in _pair(_clouds(root), _images(root), root):
            items.append(SceneItem(c.stem, cam, c, im, calib, calib.extrinsics, "opencalib",
                                   {"calib_path": str(ext)}))
    return items


class CalibAnythingFrames(Sequence):
    """Lazy ``Sequence[Frame]`` over a scene folder (see the module docstring). Each frame has
    the image (RGB), the cloud (all PCD fields), empty ``bboxes_2d`` [0,4] / ``bboxes_3d``
    [0,6], intrinsics sized to the image and ``extrinsics`` = ground-truth ``T_cam_lidar`` or None."""

    def __init__(self, root, camera: str | None = None, *, load_image: bool = True,
                 load_points: bool = True, repair: bool = False):
        self.root = Path(root)
        self.items = find_scene_items(self.root, camera, repair=repair)
        self.load_image, self.load_points = load_image, load_points

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return self.load(self.items[index])

    def load(self, it: SceneItem) -> Frame:
        if self.load_image:
            image = load_rgb(it.image)
            size = (image.shape[1], image.shape[0])
        else:
            image = np.zeros((0, 0, 3), dtype=np.uint8)
            size = image_size(it.image)
        points, fields = (load_cloud(it.cloud) if self.load_points
                          else (np.zeros((0, 3), dtype=np.float32), ("x", "y", "z")))
        intr = it.calibration.intrinsics
        meta = {"source": f"calibanything:{it.layout}", "calibration": it.calibration,
                "initial_extrinsics": it.calibration.extrinsics, "image_path": it.image,
                "cloud_path": it.cloud, **it.meta}
        if intr is not None:
            if intr.width is not None and (intr.width, intr.height) != size:
                log.warning("%s: intrinsics are for %dx%d but the image is %dx%d; using the image size",
                            it.meta.get("calib_path"), intr.width, intr.height, *size)
                meta["intrinsics_size_in_file"] = (intr.width, intr.height)
            try:
                intr = intr.with_image_size(*size)
            except ValueError as exc:
                raise FormatError(it.meta.get("calib_path"), f"intrinsics do not fit the image {it.image} "
                                                             f"({size[0]}x{size[1]}): {exc}") from None
        return Frame(image=image, point_cloud=np.ascontiguousarray(points, dtype=np.float32),
                     bboxes_2d=np.zeros((0, 4), dtype=np.float32), bboxes_3d=np.zeros((0, 6), dtype=np.float32),
                     camera_name=it.camera, frame_key=f"{it.frame_key}/{it.camera}", intrinsics=intr,
                     extrinsics=None if it.ground_truth is None else np.asarray(it.ground_truth, dtype=np.float64),
                     point_fields=tuple(fields), meta=meta)


def calibanything_frames(root, camera: str | None = None, **kwargs) -> CalibAnythingFrames:
    """A CalibAnything/OpenCalib scene (or folder of scenes) as a lazy ``Sequence[Frame]``;
    ``camera`` keeps one camera folder of a multi-camera scene."""
    return CalibAnythingFrames(root, camera, **kwargs)


def _register() -> None:
    from ..io.sources import register_source

    register_source("calibanything", is_calibanything_scene, calibanything_frames,
                    description="CalibAnything / OpenCalib scene folder (camera= picks a camera folder)",
                    priority=40)


_register()
