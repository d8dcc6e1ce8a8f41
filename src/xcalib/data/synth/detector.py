"""Detector-like 2D boxes: what a real camera detector (YOLO-type) draws instead of exact labels.

:class:`DetectorStyle` (typed, frozen) says which of a real detector's habits are simulated;
:func:`detector_frame` turns one generated ``Frame`` (its noise-free visible boxes,
``meta["boxes_2d_clean"]``, and per-box track ids / classes / visibility / truncation) into the
boxes such a detector would output. Deterministic given (site seed, frame key, style).

Habits (each can be switched off):

* ``outline``: the box is the *visible outline* of a vehicle-shaped object, not the rectangle
  around its cuboid's 8 corners: narrower (rounded front/back, mirrors inside the cuboid) and
  lower (roof narrower than the cuboid top), by a class-dependent share of the box size
  (:data:`OUTLINE_SHRINK`; a car about 10 % narrower and 12 % shorter, as PandaSet's detector
  boxes against projected cuboids) with a per-object part (the same car keeps its shape over the
  frames) and per-box jitter. Persons' boxes grow a little (arms, bags). Edges on the image border
  stay there.
* ``max_truncation`` (a site option, see ``RealismCondition``) lets objects cut by the image
  border be detected: their boxes end at the border, only the inner edges carry information.
* ``merge_prob``: two overlapping objects of one kind (vehicles, or persons) are drawn as one
  box around both with this probability (a queue of cars, a group of pedestrians).
* ``class_misses``: misses depend on the class and grow for small and occluded objects
  (:data:`MISS_RATE`); ``part_boxes``: false boxes on a part of a large vehicle (a truck's cab
  detected as a car) and duplicates slightly off the object; the site's generic false boxes stay.
* ``score_noise``: every box gets a confidence score (lower for small, occluded, truncated
  objects); the coordinate noise grows as the score falls, ``sigma = base_px + rel_noise x size
  x (1 - score)``; boxes below ``score_threshold`` are dropped.

The output frame keeps ``meta["ids_2d"]`` (track id per output box, -1 for false boxes) and
``meta["classes_2d"]``, sets ``Frame.detections`` (a :class:`xcalib.types.FrameDetections` with
source ``"synth detector"``, the scores and the classes, as ``xcalib detect`` does) and adds
``meta["boxes_2d_corner"]`` (the noise-free corner box each output box came from; NaN rows for
false boxes, the union for merged ones).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ...types import Frame, FrameDetections

__all__ = ["DetectorStyle", "detector_frame", "OUTLINE_SHRINK", "MISS_RATE"]

#: class -> (width share, top share, bottom share) the visible outline lies inside the corner box
#: (negative: the box grows, e.g. a person's arms and bags)
OUTLINE_SHRINK: dict[str, tuple[float, float, float]] = {
    "car": (0.10, 0.12, 0.02),
    "van": (0.07, 0.08, 0.02),
    "truck": (0.04, 0.04, 0.02),
    "bus": (0.03, 0.03, 0.01),
    "pedestrian": (-0.06, -0.01, 0.0),
    "cyclist": (0.03, 0.02, 0.0),
}
#: class -> miss probability of a large, fully visible object
MISS_RATE: dict[str, float] = {"car": 0.04, "van": 0.06, "truck": 0.08, "bus": 0.06, "pedestrian": 0.15,
                               "cyclist": 0.18}
_VEHICLES = ("car", "van", "truck", "bus")


@dataclass(frozen=True)
class DetectorStyle:
    """Which detector habits to simulate (see the module docstring); the defaults: all of them."""

    outline: bool = True
    outline_object_sd: float = 0.025   # per-object spread of the shrink shares
    outline_box_sd: float = 0.015      # per-box jitter of the shrink shares
    merge_prob: float = 0.5
    merge_min_overlap: float = 0.4     # intersection over the smaller box's area that makes two boxes merge
    class_misses: bool = True
    part_boxes: bool = True
    part_box_rate: float = 0.15        # per truck / bus box
    duplicate_rate: float = 0.03       # per true box
    score_noise: bool = True
    base_px: float = 1.0               # coordinate noise (px, 1-sigma) of a box with score 1
    rel_noise: float = 0.06            # extra noise per unit of (1 - score), share of sqrt(w h)
    score_threshold: float = 0.3

    def __post_init__(self) -> None:
        for name in ("outline_object_sd", "outline_box_sd", "merge_prob", "merge_min_overlap", "part_box_rate",
                     "duplicate_rate", "base_px", "rel_noise", "score_threshold"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"DetectorStyle.{name} must be finite and >= 0, got {v!r}")
        if self.merge_prob > 1 or self.score_threshold >= 1:
            raise ValueError("DetectorStyle: merge_prob must be <= 1 and score_threshold < 1")


def _shares(cls: str, tid: int, site_seed: int, style: DetectorStyle, rng: np.random.Generator) -> np.ndarray:
    base = np.asarray(OUTLINE_SHRINK.get(cls, (0.0, 0.0, 0.0)), dtype=np.float64)
    obj = np.random.default_rng([int(site_seed), int(tid) & 0x7FFFFFFF, 4242]).normal(0.0, 1.0, 3)
    return base + style.outline_object_sd * obj + style.outline_box_sd * rng.normal(0.0, 1.0, 3)


def _outline(box: np.ndarray, sh: np.ndarray, split: float, W: int, H: int) -> np.ndarray:
    """``box`` shrunk by the shares ``sh`` (width, top, bottom); the width share split ``split`` :
    ``1 - split`` between the left and right edge; edges on the image border stay."""
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    out = np.array([x0 + split * sh[0] * w, y0 + sh[1] * h, x1 - (1 - split) * sh[0] * w, y1 - sh[2] * h])
    border = np.array([x0 <= 0.5, y0 <= 0.5, x1 >= W - 0.5, y1 >= H - 0.5])
    out[border] = box[border]
    if out[2] - out[0] < 2 or out[3] - out[1] < 2:
        return box.copy()
    return out


def _overlap_small(a: np.ndarray, b: np.ndarray) -> float:
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    small = min((a[2] - a[0]) * (a[3] - a[1]), (b[2] - b[0]) * (b[3] - b[1]))
    return float(iw * ih / max(small, 1e-9))


def _kind(cls: str) -> str:
    return "vehicle" if cls in _VEHICLES else ("person" if cls in ("pedestrian", "cyclist") else cls)


def detector_frame(frame: Frame, style: DetectorStyle, size: tuple[int, int], site_seed: int) -> Frame:
    """``frame`` with the 2D boxes a detector of ``style`` would draw (``size``: image (W, H))."""
    W, H = int(size[0]), int(size[1])
    meta = frame.meta
    clean = np.asarray(meta["boxes_2d_clean"], dtype=np.float64).reshape(-1, 4)
    ids = np.asarray(meta["ids_2d"], dtype=np.int64)
    classes = list(meta["classes_2d"])
    vis = np.asarray(meta.get("visibility_2d", np.ones(len(ids))), dtype=np.float64)
    trunc = np.asarray(meta.get("truncation_2d", np.zeros(len(ids))), dtype=np.float64)
    key = int(frame.frame_key) if str(frame.frame_key).isdigit() else abs(hash(frame.frame_key)) % (1 << 31)
    rng = np.random.default_rng([int(site_seed), key, 7373])
    true = ids >= 0
    # boxes: list of (corner box, track id, class, visibility, truncation)
    items = [(clean[i].copy(), int(ids[i]), classes[i], float(vis[i]), float(trunc[i])) for i in np.flatnonzero(true)]
    false_boxes = [(clean[i].copy(), -1, "false_positive", 0.0, 0.0) for i in np.flatnonzero(~true)]
    if style.class_misses:
        kept = []
        for it in items:
            h = it[0][3] - it[0][1]
            p = MISS_RATE.get(it[2], 0.1) + 0.3 * float(np.clip((24.0 - h) / 16.0, 0, 1)) \
                + 0.3 * float(np.clip((0.5 - it[3]) / 0.3, 0, 1))
            if rng.uniform() >= p:
                kept.append(it)
        items = kept
    if style.merge_prob > 0 and len(items) > 1:  # overlapping objects of one kind -> one box
        area = [(b[2] - b[0]) * (b[3] - b[1]) for b, *_ in items]
        order = sorted(range(len(items)), key=lambda i: -area[i])
        gone: set[int] = set()
        for a_i, a in enumerate(order):
            if a in gone:
                continue
            for b in order[a_i + 1:]:
                if b in gone or _kind(items[a][2]) != _kind(items[b][2]):
                    continue
                near = _overlap_small(items[a][0], items[b][0]) >= style.merge_min_overlap
                if near and rng.uniform() < style.merge_prob:
                    A, B = items[a][0], items[b][0]
                    u = np.array([min(A[0], B[0]), min(A[1], B[1]), max(A[2], B[2]), max(A[3], B[3])])
                    items[a] = (u, items[a][1], items[a][2], min(items[a][3], items[b][3]), items[a][4])
                    gone.add(b)
        items = [it for i, it in enumerate(items) if i not in gone]
    corner = [it[0] for it in items]
    boxes = []
    for it in items:
        b = it[0]
        if style.outline:
            b = _outline(b, _shares(it[2], it[1], site_seed, style, rng), float(rng.uniform(0.35, 0.65)), W, H)
        boxes.append(b)
    out_ids = [it[1] for it in items]
    out_cls = [it[2] for it in items]
    vis_l = [it[3] for it in items]
    tr_l = [it[4] for it in items]
    def add(box, cls: str, v: float) -> None:  # a false box (no object, no corner box)
        boxes.append(box)
        corner.append(np.full(4, np.nan))
        out_ids.append(-1)
        out_cls.append(cls)
        vis_l.append(v)
        tr_l.append(0.0)

    if style.part_boxes:  # a large vehicle's cab as its own box; duplicates slightly off
        for k in range(len(items)):
            b, cls = boxes[k], out_cls[k]
            w, h = b[2] - b[0], b[3] - b[1]
            if cls in ("truck", "bus") and rng.uniform() < style.part_box_rate:
                left = rng.uniform() < 0.5
                cut = float(rng.uniform(0.3, 0.45)) * w
                part = np.array([b[0], b[1] + 0.1 * h, b[0] + cut, b[3]]) if left else \
                    np.array([b[2] - cut, b[1] + 0.1 * h, b[2], b[3]])
                add(part, "car", 0.5)
            if rng.uniform() < style.duplicate_rate:
                add(b + rng.normal(0, 0.12, 4) * np.array([w, h, w, h]), cls, 0.4)
    for b, _, c, _v, _t in false_boxes:
        add(b, c if c != "false_positive" else str(rng.choice(_VEHICLES)), 0.3)
    n = len(boxes)
    B = np.asarray(boxes, dtype=np.float64).reshape(n, 4)
    ids_o = np.asarray(out_ids, dtype=np.int64)
    wh = np.maximum(B[:, 2:] - B[:, :2], 1.0)
    if style.score_noise:
        hpx = wh[:, 1]
        score = 0.95 - 0.4 * (1 - np.asarray(vis_l)) - 0.3 * np.clip((40.0 - hpx) / 40.0, 0, 1) \
            - 0.3 * np.asarray(tr_l) + rng.normal(0, 0.05, n)
        score = np.where(ids_o >= 0, score, rng.uniform(0.25, 0.7, n))
        score = np.clip(score, 0.05, 0.99)
        sd = style.base_px + style.rel_noise * np.sqrt(wh[:, 0] * wh[:, 1]) * (1 - score)
    else:
        score = np.where(ids_o >= 0, 0.9, 0.5)
        sd = np.full(n, style.base_px)
    on_border = np.column_stack([B[:, 0] <= 0.5, B[:, 1] <= 0.5, B[:, 2] >= W - 0.5, B[:, 3] >= H - 0.5])
    B = B + np.where(on_border, 0.0, rng.normal(0, 1, (n, 4)) * sd[:, None])
    B[:, [0, 2]] = np.clip(B[:, [0, 2]], 0, W)
    B[:, [1, 3]] = np.clip(B[:, [1, 3]], 0, H)
    B[:, 2] = np.maximum(B[:, 2], np.minimum(B[:, 0] + 2, W))
    B[:, 0] = np.minimum(B[:, 0], B[:, 2] - 2)
    B[:, 3] = np.maximum(B[:, 3], np.minimum(B[:, 1] + 2, H))
    B[:, 1] = np.minimum(B[:, 1], B[:, 3] - 2)
    keep = score >= style.score_threshold
    perm = rng.permutation(int(keep.sum()))
    sel = np.flatnonzero(keep)[perm]
    m = dict(meta)
    for k in ("boxes_2d_clean", "visibility_2d", "truncation_2d"):
        m.pop(k, None)
    m["ids_2d"] = ids_o[sel]
    m["classes_2d"] = [out_cls[i] for i in sel]
    m["boxes_2d_corner"] = np.asarray(corner, dtype=np.float64).reshape(n, 4)[sel]
    made = FrameDetections("synth detector", tuple(float(s) for s in score[sel]), tuple(out_cls[i] for i in sel))
    return dataclasses.replace(frame, bboxes_2d=B[sel].astype(np.float32), match_matrix=None, meta=m, detections=made)
