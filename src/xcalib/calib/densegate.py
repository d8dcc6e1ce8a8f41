"""The unambiguous boxes of dense frames (a 360-degree LiDAR at a busy junction: 80-300 boxes a side).

On all boxes of a crowded frame (``bringup``: more than twice ``CalibConfig.max_candidates`` box
pairs) the matching aliases: a pose a few degrees / metres off still finds a box near most
projections, and a refinement can stop in that local minimum (junction, 200 boxes a side: 3.8 deg /
3.0 m off with 1,518 matches, against 2,498 at the true pose). The finalists' full refinement is
therefore also started from a fit on the boxes whose matches are unambiguous
(``bringup.unoccluded_frames``, ``api._full_refine``), chosen here:

* :func:`front_rows` (2D): at a busy junction most objects are partly hidden behind nearer ones
  (their 2D box is the visible part, smaller than the projected 3D box). Whether two overlapping 2D
  boxes occlude each other cannot be read from their overlap (it is the same for both); which one is
  in front can: objects stand on the ground below the camera, so the nearer one's box reaches lower
  in the image (a larger bottom edge). A box that no overlapping box reaches below is not hidden by
  any detected object.
* :func:`lidar_unoccluded` (3D): with the camera near the LiDAR (objects tens of metres away) what
  the LiDAR sees unoccluded the camera sees unoccluded too. A 3D box whose angular extent seen from
  the LiDAR origin is covered by more than a quarter by a nearer box's is likely hidden in the image
  as well; the others are kept. Where the camera is far from the LiDAR the view is merely less
  useful: the refinement on every box from the finalist itself is always run too, and the
  better-scoring one kept.

Synthetic junction (``bench_calibration_memory.junction_frames``, 200 2D boxes a frame, 6 frames, at
the true pose): 52 % of the 2D boxes match their projected 3D box at IoU >= 0.5; of the search's gate
(``hypotheses.informative_view``: the largest boxes covered by no other for more than a quarter, 24 a
frame) 30 %; of the front boxes 79 % (86 % of those at least 20 px). Of the 3D boxes in the camera's
view 46 % match; of those the LiDAR sees unoccluded (a quarter) 85 %.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .inputs import CalibFrame

__all__ = ["front_rows", "front_view", "lidar_unoccluded", "lidar_view", "FRONT_COVER", "LIDAR_COVER", "FRONT_MIN",
           "BLOCK"]

#: a 2D box counts as hidden when a box reaching lower in the image covers more than this share of it
#: (2 % : a shared pixel row of two boxes that merely touch does not hide either)
FRONT_COVER = 0.02
#: a 3D box counts as hidden from the LiDAR when a nearer box's angular extent covers more than this
#: share of its own (the quarter the 2D gate has always used for a box that is its whole outline)
LIDAR_COVER = 0.25
#: the fewest 2D boxes a crowded frame's view keeps (front ones first, then the largest others): enough
#: for a pose (3) on every frame with a margin for the few front boxes that are false detections
FRONT_MIN = 8
#: rows per block of the pairwise overlaps (memory linear in the boxes)
BLOCK = 256


def _cover(a: np.ndarray, b: np.ndarray, before: np.ndarray) -> np.ndarray:
    """Per row of ``a`` [n,4] (x0, y0, x1, y1), the largest share of its area covered by a row of
    ``b`` [m,4] for which ``before`` [n,m] is True (0 where none)."""
    w = np.clip(np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]), 0, None)
    h = np.clip(np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]), 0, None)
    ov = np.where(before, w * h, 0.0)
    area = np.maximum((a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1]), 1e-12)
    return ov.max(axis=1) / area if ov.shape[1] else np.zeros(len(a))


def front_rows(boxes2d: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """[K] bool: the 2D boxes inside the image (not truncated) that no box reaching lower in the
    image (a larger bottom edge: nearer, for objects on the ground below the camera) covers for more
    than ``FRONT_COVER`` of their area: not hidden behind another detected object."""
    b = np.asarray(boxes2d, dtype=np.float64).reshape(-1, 4)
    W, H = size
    inside = (b[:, 0] > 2) & (b[:, 1] > 2) & (b[:, 2] < W - 2) & (b[:, 3] < H - 2)
    cover = np.zeros(len(b))
    for s in range(0, len(b), BLOCK):
        blk = b[s:s + BLOCK]
        cover[s:s + len(blk)] = _cover(blk, b, b[None, :, 3] > blk[:, None, 3])
    return inside & (cover <= FRONT_COVER)


def lidar_unoccluded(corners: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """[M] bool: the 3D boxes (outline points ``corners`` [M,S,3], centres [M,3], LiDAR frame) whose
    angular extent seen from the LiDAR origin (azimuth about their centre's, elevation) no nearer
    box's extent covers for more than ``LIDAR_COVER`` of it."""
    c = np.asarray(corners, dtype=np.float64)
    x = np.asarray(centres, dtype=np.float64)[:, :3]
    if len(c) == 0:
        return np.zeros(0, dtype=bool)
    az0 = np.arctan2(x[:, 1], x[:, 0])
    az = az0[:, None] + (np.arctan2(c[..., 1], c[..., 0]) - az0[:, None] + np.pi) % (2 * np.pi) - np.pi
    el = np.arctan2(c[..., 2], np.hypot(c[..., 0], c[..., 1]))
    ext = np.column_stack([az.min(1), el.min(1), az.max(1), el.max(1)])
    rng = np.linalg.norm(x, axis=1)
    cover = np.zeros(len(c))
    for shift in (0.0, 2 * np.pi, -2 * np.pi):  # (extents near +-pi seen from both sides)
        other = ext + np.array([shift, 0.0, shift, 0.0])
        for s in range(0, len(c), BLOCK):
            blk = ext[s:s + BLOCK]
            cover[s:s + len(blk)] = np.fmax(cover[s:s + len(blk)],
                                            _cover(blk, other, rng[None, :] < rng[s:s + len(blk), None]))
    return cover <= LIDAR_COVER


def lidar_view(fr: CalibFrame) -> CalibFrame:
    """A view of ``fr`` with only the 3D boxes :func:`lidar_unoccluded` keeps (the frame itself when
    it keeps every one, or fewer than 3)."""
    keep = np.flatnonzero(lidar_unoccluded(fr.corners, fr.boxes3d[:, :3]))
    if len(keep) == fr.n3 or len(keep) < 3:
        return fr
    opt = {name: None if getattr(fr, name) is None else getattr(fr, name)[keep]
           for name in ("box_corners", "from_points", "yaw_ambiguous", "outline_sigma_m")}
    return replace(fr, boxes3d=fr.boxes3d[keep], corners=fr.corners[keep], idx3d=fr.idx3d[keep], **opt)



def front_view(fr: CalibFrame, max_2d: int) -> tuple[CalibFrame, np.ndarray]:
    """A view of ``fr`` with its front 2D boxes (:func:`front_rows`), at most ``max_2d``, largest
    first (near objects, whose size tells their depth best), topped up to ``FRONT_MIN`` with the
    others, largest first; and the rows kept (ascending). A frame within ``max_2d`` boxes is returned
    as it is. Only the front boxes (not a fixed count): a hidden object's box, smaller than its
    projected 3D box, pulls a fit towards a wrong depth."""
    if fr.n2 <= max_2d:
        return fr, np.arange(fr.n2)
    b = fr.boxes2d
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    front = front_rows(b, fr.size)
    order = np.lexsort((-area, ~front))
    n = min(max(int(front.sum()), FRONT_MIN), max_2d)
    rows = np.sort(order[:n])
    return replace(fr, boxes2d=fr.boxes2d[rows], idx2d=fr.idx2d[rows]), rows
