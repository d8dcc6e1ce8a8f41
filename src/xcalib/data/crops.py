"""Per-detection model inputs: image crops and LiDAR point crops (pure numpy + OpenCV).

Image crops (:func:`crop_images`)
    Each 2D box (pixels) is cut from the image and resized to ``crop_size`` x ``crop_size``.
    With ``keep_aspect`` (default) the box is first grown to a square about its centre, so
    objects are not stretched. Parts of the (square) box outside the image are filled with the
    normalisation mean, i.e. 0 after normalisation; boxes are never dropped just because they
    touch or cross an image border. Downscaling subsamples big boxes to about twice the output
    size, then area-averages (little aliasing, cheap); upscaling is bilinear. Values: uint8 ->
    /255 (float images are taken as already in [0, 1]), then
    ``(x - IMAGENET_MEAN) / IMAGENET_STD`` per channel when ``normalize``. Layout [N,3,S,S].
    Dropped: boxes with x2<=x1 or y2<=y1, non-finite boxes, boxes entirely outside the image.

LiDAR crops (:func:`crop_points`)
    Points inside each 3D box scaled by ``bbox_expansion`` (yaw-aware for box7 rows, via
    :func:`xcalib.geometry.points_in_boxes`), expressed in the box's own frame (origin at the
    box centre, x along the heading; protocol [M,6] boxes have yaw 0 so this is a translation),
    metres. Each crop is resampled to ``point_cloud_size`` points with a seeded
    ``np.random.Generator``: a random subset without replacement when the box holds enough
    points, otherwise every point once plus random repeats of its own points (never padding at
    the sensor origin). Dropped: degenerate boxes and boxes with fewer than ``min_points``.

Everything is vectorised over points and boxes (the integer crop windows of all 2D boxes at
once, :func:`xcalib.geometry.box_point_pairs` for the points); the only Python loop cuts and
resizes, one OpenCV call per 2D box. The outputs are bit-identical to 0.3.1's
(tests/test_crops_equivalence.py).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Mapping

import cv2
import numpy as np

from ..geometry.boxes import as_box7, box_point_pairs, take_rows

__all__ = [
    "IMAGENET_MEAN", "IMAGENET_STD", "CropFields", "CropConfig", "KeptCounts", "FrameInputs", "crop_images", "crop_points",
    "gather_box_points", "resample_points", "prepare_frame", "empty_inputs",
]

IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], dtype=np.float32)
IMAGENET_STD = np.array([0.229, 0.224, 0.225], dtype=np.float32)


@dataclass(frozen=True)
class CropFields:
    """The crop settings, unchecked (shared by :class:`CropConfig` and the models' typed configs,
    ``xcalib.models.registry.ModelConfig``). ``crop_size`` px, ``point_cloud_size`` points,
    ``bbox_expansion`` (scale on 3D box dims), ``min_points`` per kept 3D box, ``seed`` of the
    default point-resampling generator."""

    crop_size: int = 32
    point_cloud_size: int = 1024
    bbox_expansion: float = 1.25
    keep_aspect: bool = True
    normalize: bool = True
    min_points: int = 1
    seed: int = 0


@dataclass(frozen=True)
class CropConfig(CropFields):
    """How a frame becomes model inputs: the :class:`CropFields`, checked."""

    def __post_init__(self) -> None:
        if int(self.crop_size) < 4:
            raise ValueError(f"crop_size must be >= 4 px, got {self.crop_size}")
        if int(self.point_cloud_size) < 1:
            raise ValueError(f"point_cloud_size must be >= 1, got {self.point_cloud_size}")
        if not float(self.bbox_expansion) > 0:
            raise ValueError(f"bbox_expansion must be > 0, got {self.bbox_expansion}")
        if int(self.min_points) < 1:
            raise ValueError(f"min_points must be >= 1, got {self.min_points}")

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> "CropConfig":
        """Pick the crop keys out of a model config dict (missing keys keep their defaults)."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: cfg[k] for k in names if k in cfg})


class KeptCounts:
    """``num_2d`` / ``num_3d`` / ``empty`` of a record with ``kept_2d`` / ``kept_3d`` index arrays."""

    kept_2d: np.ndarray
    kept_3d: np.ndarray

    @property
    def num_2d(self) -> int:
        return int(len(self.kept_2d))

    @property
    def num_3d(self) -> int:
        return int(len(self.kept_3d))

    @property
    def empty(self) -> bool:
        return self.num_2d == 0 or self.num_3d == 0


@dataclass
class FrameInputs(KeptCounts):
    """One frame as model inputs (numpy; the ONNX Runtime path reuses it).

    crops_2d [N,3,S,S] float32 normalised; crops_3d [M,P,3] float32 box-frame metres;
    boxes_2d [N,4] float32 caller pixels (unclipped) of kept rows; boxes_3d [M,7] float32 box7
    (LiDAR frame) of kept columns; point_counts [M] int64 points inside each expanded box;
    image_size (W, H) px; kept_2d / kept_3d int64 maps to the caller's indices.
    """

    crops_2d: np.ndarray
    crops_3d: np.ndarray
    boxes_2d: np.ndarray
    boxes_3d: np.ndarray
    point_counts: np.ndarray
    image_size: tuple[int, int]
    kept_2d: np.ndarray
    kept_3d: np.ndarray



def _image_float_scale(image: np.ndarray) -> float:
    return 1.0 if image.dtype.kind == "f" else 1.0 / 255.0


def _crop_windows(b: np.ndarray, W: int, H: int, S: int, keep_aspect: bool):
    """Integer crop geometry of every 2D box, vectorised: (kept [N] int64, image windows
    [N,4] (x0, y0, x1, y1) px, output windows [N,4] (x0, y0, x1, y1) in the S x S crop,
    subsampling steps [N], whether each resize shrinks [N]). Few array calls: a frame has ~10
    boxes, so each call's fixed cost is what counts."""
    lo, hi = b[:, :2], b[:, 2:]
    ok = np.isfinite(b).all(1) & (hi > lo).all(1) & (hi > 0).all(1) & (lo < (W, H)).all(1)
    src = np.where(ok[:, None], b, 0.0)
    if keep_aspect and len(src):
        c = (src[:, :2] + src[:, 2:]) / 2.0
        ext = src[:, 2:] - src[:, :2]
        half = ext.max(1, keepdims=True) / 2.0
        src = np.concatenate([c - half, c + half], 1)
    win = np.minimum(np.maximum(src, 0), (W, H, W, H))  # as np.clip (src is finite)
    win = np.concatenate([np.floor(win[:, :2]), np.ceil(win[:, 2:])], 1).astype(np.int64)
    ok &= (win[:, 2:] > win[:, :2]).all(1)
    kept = np.flatnonzero(ok)
    src, win = src[kept], win[kept]
    o2 = src[:, :2]
    size = src[:, 2:] - o2  # (w, h) of the (square) source box
    rel = np.rint((win - np.concatenate([o2, o2], 1)) * S / np.concatenate([size, size], 1))  # half to even
    out = np.empty_like(win)
    out[:, :2] = np.minimum(np.maximum(rel[:, :2], 0), S - 1)
    out[:, 2:] = np.minimum(np.maximum(rel[:, 2:], out[:, :2] + 1), S)
    pwh, owh = win[:, 2:] - win[:, :2], out[:, 2:] - out[:, :2]  # (w, h) of patch and output
    step = ((pwh / owh).min(1) // 2).astype(np.int64)
    step[step < 1] = 1
    shrink = (-(-pwh // step[:, None]) > owh).any(1)  # subsampled patch larger than its window
    return kept, win, out, step, shrink


def crop_images(image: np.ndarray, bboxes_2d, crop_size: int = 32, *, keep_aspect: bool = True,
                normalize: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Crop + resize every 2D box. Returns (crops [N,3,S,S] float32, kept indices [N] int64).
    The crop geometry is computed for all boxes at once; the loop only cuts and resizes. A uint8
    image is resized in uint8 and normalised through a 256-entry table per channel (the same
    float32 operations as for a float image, so the same values)."""
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image: expected shape [H, W, 3], got {image.shape}")
    S = int(crop_size)
    b = np.asarray(bboxes_2d, dtype=np.float64).reshape(-1, 4) if np.size(bboxes_2d) else np.zeros((0, 4))
    H, W = image.shape[:2]
    kept, win, dst, step, shrink = _crop_windows(b, W, H, S, keep_aspect)
    scale = _image_float_scale(image)
    fill = IMAGENET_MEAN / scale if normalize else np.zeros(3, np.float32)
    if image.dtype == np.uint8:
        return _crop_uint8(image, CropWindows(win, dst, step, shrink), S, fill, scale, normalize), kept
    out = np.empty((len(kept), S, S, 3), dtype=np.float32)
    out[:] = fill
    _cut_and_resize(image, out, win, dst, step, shrink)
    return _normalized_chw(out, scale, normalize), kept


def _normalized_chw(x: np.ndarray, scale: float, normalize: bool) -> np.ndarray:
    """[..., 3] float32 pixel values -> ``x * scale`` (then ``(. - mean) / std`` per channel), in
    place, moved to channels-first [N,3,S,S]."""
    x *= scale
    if normalize:
        x -= IMAGENET_MEAN
        x /= IMAGENET_STD
    return np.ascontiguousarray(np.moveaxis(x, -1, 1)) if x.ndim == 4 else x


def _cut_and_resize(image: np.ndarray, out: np.ndarray, win, dst, step, shrink) -> None:
    """Resize each image window ``win[n]`` into ``out[n]``'s window ``dst[n]`` (same dtype or float)."""
    pixels = _pixel_view(image)
    S = out.shape[1]
    for n, (x0, y0, x1, y1), (u0, v0, u1, v1), st, sh in zip(range(len(win)), win.tolist(), dst.tolist(),
                                                            step.tolist(), shrink.tolist()):
        patch = pixels[y0:y1:st, x0:x1:st]  # big box: subsample to ~2x the output size, then area-average
        if st > 1:
            patch = np.ascontiguousarray(patch)
        patch = patch.view(image.dtype).reshape(patch.shape[0], patch.shape[1], 3)
        interp = cv2.INTER_AREA if sh else cv2.INTER_LINEAR
        if out.dtype == image.dtype and u1 - u0 == S and v1 - v0 == S:  # whole crop: resize in place
            cv2.resize(patch, (S, S), dst=out[n], interpolation=interp)
            continue
        patch = cv2.resize(patch, (u1 - u0, v1 - v0), interpolation=interp)
        out[n, v0:v1, u0:u1] = patch.reshape(v1 - v0, u1 - u0, 3)


@dataclass(frozen=True)
class CropWindows:
    """Where each kept 2D box's crop comes from and goes (``_crop_windows``): the image window
    ``win`` [n,4] and the crop window ``dst`` [n,4] (x0, y0, x1, y1 px), the subsampling ``step``
    [n] and whether the patch shrinks (``shrink`` [n], area interpolation)."""

    win: np.ndarray
    dst: np.ndarray
    step: np.ndarray
    shrink: np.ndarray


def _crop_uint8(image, windows: CropWindows, S: int, fill: np.ndarray, scale: float, normalize: bool) -> np.ndarray:
    """The crops of a uint8 image: resized in uint8 (as OpenCV does for uint8 input anyway),
    then every value mapped through its channel's table (exactly ``_normalized_chw`` of the
    value), the parts of a crop outside the image set to the normalised fill."""
    win, dst, step, shrink = windows.win, windows.dst, windows.step, windows.shrink
    N = len(win)
    buf = np.empty((N, S, S, 3), dtype=np.uint8)
    _cut_and_resize(image, buf, win, dst, step, shrink)
    lut = _normalized_chw(np.repeat(np.arange(256, dtype=np.float32)[:, None], 3, axis=1), scale, normalize)
    lut = np.ascontiguousarray(lut.T)  # [3, 256]
    out = np.empty((N, 3, S, S), dtype=np.float32)
    for c in range(3):  # a gather per channel, straight into the channels-first layout
        out[:, c] = lut[c].take(buf[..., c])
    part = np.flatnonzero(np.any(dst != np.array([0, 0, S, S]), axis=1))
    if len(part):
        fill_n = _normalized_chw(fill.astype(np.float32).reshape(1, 3), scale, normalize)[0]
        for n, (u0, v0, u1, v1) in zip(part.tolist(), dst[part].tolist()):
            inside = np.zeros((S, S), dtype=bool)
            inside[v0:v1, u0:u1] = True
            out[n][:, ~inside] = fill_n[:, None]
    return out


def _pixel_view(image: np.ndarray) -> np.ndarray:
    """[H,W] view of an [H,W,3] image with one opaque item per pixel (when its pixels are
    contiguous): a strided pick of pixels then copies whole pixels, not single channels."""
    if image.strides[2] != image.itemsize or image.strides[1] != 3 * image.itemsize:
        return image
    return image.view(np.dtype((np.void, 3 * image.itemsize)))[..., 0]


def gather_box_points(points: np.ndarray, boxes7: np.ndarray, expansion: float = 1.25
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Points inside each expanded box7, in that box's frame (metres).

    Returns (points [T,3] float32 grouped box by box, counts [M] int64) with T = counts.sum().
    """
    b = np.asarray(boxes7, dtype=np.float64).reshape(-1, 7)
    xyz = np.asarray(points)[:, :3]
    mi, pi = box_point_pairs(xyz, b, expansion=expansion)  # grouped box by box, points ascending
    counts = np.bincount(mi, minlength=len(b)).astype(np.int64)
    d = take_rows(xyz, pi).astype(np.float64) - b[mi, :3]
    c, s = np.cos(b[:, 6])[mi], np.sin(b[:, 6])[mi]  # per box, then per point (the same values)
    local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
    return local.astype(np.float32), counts


def resample_points(points: np.ndarray, counts: np.ndarray, n: int,
                    rng: np.random.Generator) -> np.ndarray:
    """Resample grouped points (see :func:`gather_box_points`) to ``n`` per group -> [M,n,3].

    Groups with >= n points: a random subset without replacement; smaller groups: all their
    points plus random repeats. Every count must be >= 1.
    """
    counts = np.asarray(counts, dtype=np.int64)
    M = len(counts)
    if M == 0:
        return np.zeros((0, n, 3), dtype=np.float32)
    if np.any(counts < 1):
        raise ValueError(f"resample_points: every group needs >= 1 point, got counts {counts.tolist()}")
    starts = np.cumsum(counts) - counts
    seg = np.repeat(np.arange(M), counts)
    order = _shuffle_within_groups(seg, rng.random(len(seg)))
    j = np.arange(n)[None, :]
    fill = np.minimum((rng.random((M, n)) * counts[:, None]).astype(np.int64), counts[:, None] - 1)
    src = np.where(j < counts[:, None], j, fill)
    return take_rows(np.asarray(points, dtype=np.float32), order[starts[:, None] + src])


def _shuffle_within_groups(seg: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``np.lexsort((r, seg))`` (r in [0, 1)), as one stable integer sort when the group ids fit:
    r * 2^53 is an exact integer below 2^53, so the key seg * 2^53 + that orders the same."""
    if len(seg) == 0 or seg[-1] >= 1 << 10:
        return np.lexsort((r, seg))
    return np.argsort((seg.astype(np.int64) << 53) + (r * 2.0 ** 53).astype(np.int64), kind="stable")


def crop_points(point_cloud: np.ndarray, bboxes_3d, point_cloud_size: int = 1024, *,
                expansion: float = 1.25, rng: np.random.Generator | None = None,
                min_points: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """LiDAR crops. Returns (crops [M,P,3] float32, box7 [M,7] float32, counts [M], kept [M])."""
    rng = np.random.default_rng(0) if rng is None else rng
    b = np.asarray(bboxes_3d, dtype=np.float64)
    if b.size == 0:
        return (np.zeros((0, point_cloud_size, 3), np.float32), np.zeros((0, 7), np.float32),
                np.zeros(0, np.int64), np.zeros(0, np.int64))
    box7 = as_box7(b)
    ok = np.all(np.isfinite(box7), axis=1) & np.all(box7[:, 3:6] > 0, axis=1)
    idx = np.nonzero(ok)[0]
    pc = np.asarray(point_cloud)
    if len(idx) and len(pc):
        pts, counts = gather_box_points(pc, box7[idx], expansion)
    else:
        pts, counts = np.zeros((0, 3), np.float32), np.zeros(len(idx), np.int64)
    keep = counts >= min_points
    if not keep.all():  # drop the groups of boxes that are too sparse
        pts = pts[np.repeat(keep, counts)]
        counts = counts[keep]
    kept = idx[keep].astype(np.int64)
    crops = resample_points(pts, counts, int(point_cloud_size), rng)
    return crops, box7[kept].astype(np.float32), counts, kept


def empty_inputs(cfg: CropConfig, image_size: tuple[int, int]) -> FrameInputs:
    S, P = int(cfg.crop_size), int(cfg.point_cloud_size)
    return FrameInputs(np.zeros((0, 3, S, S), np.float32), np.zeros((0, P, 3), np.float32),
                       np.zeros((0, 4), np.float32), np.zeros((0, 7), np.float32),
                       np.zeros(0, np.int64), image_size, np.zeros(0, np.int64), np.zeros(0, np.int64))


def prepare_frame(image: np.ndarray, point_cloud: np.ndarray, bboxes_2d, bboxes_3d,
                  cfg: CropConfig | None = None, rng: np.random.Generator | None = None, *,
                  images: Mapping[str, np.ndarray] | None = None,
                  camera_per_det: list[str] | None = None) -> FrameInputs:
    """Turn one frame into :class:`FrameInputs` (both sides kept even when the other is empty).

    ``rng`` defaults to ``np.random.default_rng(cfg.seed)`` so the same call gives the same
    crops. Multi-camera frames: pass ``images`` {camera: image} and ``camera_per_det`` (the
    source camera of each 2D box); a box whose camera is unknown is dropped.
    """
    cfg = cfg or CropConfig()
    rng = np.random.default_rng(cfg.seed) if rng is None else rng
    b2 = np.asarray(bboxes_2d, dtype=np.float64).reshape(-1, 4) if np.size(bboxes_2d) else np.zeros((0, 4))
    size = (int(image.shape[1]), int(image.shape[0]))
    if images is not None and camera_per_det is not None:
        if len(camera_per_det) != len(b2):
            raise ValueError(f"camera_per_det: expected {len(b2)} names (one per 2D box), got {len(camera_per_det)}")
        crops_l, kept_l = [], []
        for cam in dict.fromkeys(camera_per_det):
            if cam not in images:
                continue
            sel = np.nonzero(np.array([c == cam for c in camera_per_det]))[0]
            c, k = crop_images(images[cam], b2[sel], cfg.crop_size, keep_aspect=cfg.keep_aspect,
                               normalize=cfg.normalize)
            crops_l.append(c)
            kept_l.append(sel[k])
        kept_2d = np.concatenate(kept_l) if kept_l else np.zeros(0, np.int64)
        order = np.argsort(kept_2d, kind="stable")
        crops_2d = (np.concatenate(crops_l)[order] if crops_l
                    else np.zeros((0, 3, cfg.crop_size, cfg.crop_size), np.float32))
        kept_2d = kept_2d[order].astype(np.int64)
    else:
        crops_2d, kept_2d = crop_images(image, b2, cfg.crop_size, keep_aspect=cfg.keep_aspect,
                                        normalize=cfg.normalize)
    crops_3d, box7, counts, kept_3d = crop_points(point_cloud, bboxes_3d, cfg.point_cloud_size,
                                                  expansion=cfg.bbox_expansion, rng=rng,
                                                  min_points=cfg.min_points)
    return FrameInputs(crops_2d, crops_3d, b2[kept_2d].astype(np.float32), box7, counts, size,
                       kept_2d, kept_3d)
