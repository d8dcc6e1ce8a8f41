"""Frames of a site (``Frame`` records with exact ground truth) and site folders of HDF5 caches."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...io.files import atomic_write
from ...options import Options, document, resolve, split_overrides
from ...types import Frame
from .detections import camera_view, detect, mirror_boxes
from .presets import NOISE_FIELDS, SiteConfig
from .scene import simulate_traffic
from .site import Site, sample_site

__all__ = ["iter_frames", "generate_frames", "write_site", "SiteWriteOptions", "blank_image", "SPLITS"]

SPLITS = ("train", "val", "test")
_SPLIT_SEED = {"train": 1, "val": 2, "test": 3}


def blank_image(site: Site) -> np.ndarray:
    """A shared read-only black [H,W,3] image costing no memory (labels-only mode)."""
    return np.broadcast_to(np.zeros(3, dtype=np.uint8), (site.height, site.width, 3))


def iter_frames(site: Site, n_frames: int, seed: int = 0, *, render_images: bool = True, lidar: bool = True,
                start: int = 0, noise_seed: int | None = None, **noise) -> Iterator[Frame]:
    """Yield ``n_frames`` consecutive frames (10 Hz by default) of one traffic sequence.

    Labels depend only on (site, seed, frame index): ``render_images`` / ``lidar`` / ``n_frames``
    never change them. ``noise`` overrides the site's noise fields for this call
    (``box_noise_px``, ``miss_rate_2d``, ``miss_rate_3d``, ``false_positive_rate_2d``,
    ``false_positive_rate_3d``, ``center_noise_m``, ``size_noise_frac``, ``yaw_noise_deg``,
    ``lidar_range_noise_m``, ``lidar_dropout``).

    Each frame: image [H,W,3] RGB (``render_images=False``: a shared blank image), point_cloud
    [P,3] float32 levelled LiDAR frame (``lidar=False``: [0,3]), bboxes_2d [K,4] px, bboxes_3d
    protocol [M,6] (site's ``box_convention``), match_matrix [K,M], intrinsics (the *given* ones,
    :attr:`Site.intrinsics_given`), extrinsics = GT ``T_cam_lidar``; lidar_time_s = k * frame_dt,
    camera_time_s = lidar_time_s + ``camera_time_offset_s``; track_ids_3d [M] (-1 = false
    positive), velocities_3d [M,3] (LiDAR frame, m/s); meta: ``box7`` [M,7] (detected, yaw; absent
    when ``box3d_yaw="dropped"``), ``box7_gt``, ``ids_2d`` / ``ids_3d`` (track ids, -1 = false
    positive), ``classes_2d`` / ``classes_3d``, ``boxes_2d_clean``, ``visibility_2d``,
    ``truncation_2d``, ``n_points_3d`` (with LiDAR), ``timestamp`` (s, = lidar_time_s),
    ``intrinsics_true`` (only when the given intrinsics differ).

    The 2D boxes see the scene at the camera time, the 3D boxes and points at the LiDAR time;
    ``image_mirrored`` flips the image and the 2D boxes (u -> W - u).

    ``noise_seed``: None (default) draws the detections' randomness (2D and 3D box noise, misses,
    false positives) from (site, seed, frame index) alone; an integer draws it afresh for the same
    traffic (the scene, the true boxes and the point clouds stay as they are): repeated noise
    draws of one scene, e.g. to tell a pose's bias from its spread.
    """
    unknown = sorted(set(noise) - set(NOISE_FIELDS))
    if unknown:
        raise TypeError(f"iter_frames: unknown noise parameter(s) {unknown}; expected some of {NOISE_FIELDS}")
    if n_frames < 0:
        raise ValueError(f"n_frames must be >= 0, got {n_frames}")
    if noise_seed is not None and int(noise_seed) < 0:
        raise ValueError(f"noise_seed: expected None or an integer >= 0, got {noise_seed}")
    c = site.config
    tracks = simulate_traffic(site, start + n_frames, np.random.default_rng([site.seed, int(seed), 11]))
    T = site.T_cam_lidar
    intr = site.intrinsics_given
    for k in range(start, start + n_frames):
        t_lidar = k * c.frame_dt
        t_cam = t_lidar + float(c.camera_time_offset_s)
        objs3 = tracks.at(k)
        objs = objs3 if t_cam == t_lidar else tracks.at_time(t_cam)
        view = camera_view(site, objs)
        det_seed = [site.seed, int(seed), k, 22] + ([] if noise_seed is None else [int(noise_seed)])
        det = detect(site, objs, np.random.default_rng(det_seed), view=view, noise=noise, objs_3d=objs3)
        b2, clean2 = det.boxes_2d, det.clean_2d
        if c.image_mirrored:
            b2, clean2 = mirror_boxes(b2, site.width), mirror_boxes(clean2, site.width)
        meta = {"box7": det.box7_3d, "box7_gt": det.box7_gt_3d, "ids_2d": det.ids_2d, "ids_3d": det.ids_3d,
                "classes_2d": det.classes_2d, "classes_3d": det.classes_3d, "boxes_2d_clean": clean2,
                "visibility_2d": det.visibility_2d, "truncation_2d": det.truncation_2d,
                "timestamp": t_lidar, "sequence_seed": int(seed), "site_seed": site.seed}
        if c.box3d_yaw == "dropped":
            del meta["box7"]
        if intr is not site.intrinsics:
            meta["intrinsics_true"] = site.intrinsics
        image = _image(site, objs, view, render_images)
        if lidar:
            from .lidar import scan

            scan_out = scan(site, objs3, np.random.default_rng([site.seed, int(seed), k, 33]), noise=noise)
            points = scan_out.points
            obj_of_id = {int(t): j for j, t in enumerate(objs3.ids)}
            counts = np.bincount(scan_out.labels[scan_out.labels >= 0], minlength=len(objs3))
            meta["n_points_3d"] = np.array([counts[obj_of_id[int(t)]] if t >= 0 else 0 for t in det.ids_3d],
                                           dtype=np.int64)
        else:
            points = np.zeros((0, 3), dtype=np.float32)
        yield Frame(image=image, point_cloud=points, bboxes_2d=b2.astype(np.float32),
                    bboxes_3d=det.boxes_3d.astype(np.float32), camera_name=site.camera_name,
                    frame_key=f"{k:06d}", match_matrix=det.match, intrinsics=intr,
                    extrinsics=T.copy(), meta=meta, lidar_time_s=float(t_lidar), camera_time_s=float(t_cam),
                    track_ids_3d=det.ids_3d.copy(), velocities_3d=det.velocity_3d)


def _image(site: Site, objs, view, render: bool) -> np.ndarray:
    """The rendered (or blank) image, mirrored left-right when the site's camera mirrors."""
    if not render:
        return blank_image(site)
    from .render import render_frame

    image = render_frame(site, objs, view)
    return np.ascontiguousarray(image[:, ::-1]) if site.config.image_mirrored else image


def generate_frames(site: Site, n_frames: int, seed: int = 0, *, render_images: bool = True,
                    lidar: bool = True, **noise) -> list[Frame]:
    """``list(iter_frames(...))`` — mind the memory for many rendered frames (use iter_frames)."""
    return list(iter_frames(site, n_frames, seed, render_images=render_images, lidar=lidar, **noise))


@dataclass(frozen=True)
class SiteWriteOptions(Options):
    """How :func:`write_site` writes (the defaults in one place): progress (``(split, done,
    total)`` after every frame), render_images (False: no camera images), lidar (False: no point
    clouds), image_format ("jpeg" | "png" | ...; of the HDF5 caches), overwrite (replace a
    non-empty ``out_dir``)."""

    progress: Callable[[str, int, int], None] | None = None
    render_images: bool = True
    lidar: bool = True
    image_format: str = "jpeg"
    overwrite: bool = False


@document(SiteWriteOptions, keep_kwargs=True)
def write_site(out_dir, n_train: int, n_val: int, n_test: int, seed: int = 0, preset: str = "roadside", *,
               options: SiteWriteOptions | None = None, **overrides: Any) -> Path:
    """Write ``train.h5``, ``val.h5``, ``test.h5`` (with /calibration) and ``site.json`` to ``out_dir``.

    Each split is its own traffic sequence (no temporal overlap). Keyword arguments: the fields
    of :class:`SiteWriteOptions` (``progress``, ``render_images``, ``lidar``, ``image_format``,
    ``overwrite``; or the record whole as ``options=``) and those of :class:`SiteConfig`, which
    go to :func:`sample_site`; any other name is a TypeError. ``progress(split, done, total)`` is
    called after every frame. The site is written into a temporary folder and swapped in whole
    (the caches and ``site.json`` always belong to the same run); an existing non-empty
    ``out_dir`` needs ``overwrite=True``.
    """
    given, site_overrides = split_overrides(overrides, [SiteWriteOptions, SiteConfig], "write_site")
    o = resolve(SiteWriteOptions, options, given, where="write_site")
    progress, render_images, lidar, image_format, overwrite = o.progress, o.render_images, o.lidar, o.image_format, \
        o.overwrite
    from ...io.files import atomic_dir, claim_output

    out = Path(out_dir)
    site = sample_site(seed, preset, **site_overrides)
    with claim_output(out, "output folder"), atomic_dir(out, overwrite=overwrite) as tmp:
        counts = {"train": int(n_train), "val": int(n_val), "test": int(n_test)}
        _write_site_files(tmp, site, counts, seed, progress, render_images, lidar, image_format)
    return out


def _write_site_files(out: Path, site: Site, counts: dict[str, int], seed: int, progress, render_images: bool,
                      lidar: bool, image_format: str) -> None:
    """The caches and ``site.json`` of ``site`` in ``out``; ``counts``: frames per split (train, val, test)."""
    from ...io.hdf5 import CacheWriter

    for split, n in counts.items():
        if n < 0:
            raise ValueError(f"write_site: n_{split} must be >= 0, got {n}")
        with CacheWriter(out / f"{split}.h5", camera_names=[site.camera_name], lidar_name=site.lidar_name,
                         label_sensor=site.camera_name, jpeg_quality=site.config.jpeg_quality,
                         image_format=image_format) as w:
            for i, frame in enumerate(iter_frames(site, n, seed=1000 * int(seed) + _SPLIT_SEED[split],
                                                  render_images=render_images, lidar=lidar)):
                w.add(frame)
                if progress is not None:
                    progress(split, i + 1, n)
    info = site.to_dict()
    info["splits"] = {s: {"file": f"{s}.h5", "frames": n, "sequence_seed": 1000 * int(seed) + _SPLIT_SEED[s]}
                      for s, n in counts.items()}
    atomic_write(out / "site.json", [json.dumps(info, indent=2).encode()])
