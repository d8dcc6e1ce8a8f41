"""Is a matcher at home on this frame? Out-of-domain scores, and the geometric fallback.

A model trained for one site scores another site's boxes badly, and says nothing about it. Two
symptoms, read from one frame's similarity (torch-free, shared by the PyTorch and ONNX Runtime
matchers):

* **no confident pair**: the median over 2D boxes of the best "is a match" probability is below
  ``MIN_BEST_PROBABILITY`` (in-domain fastmatch: 0.85-1.0 on synthetic sites; the shipped
  weights on the real A9 frames: 0.00-0.53);
* **collapse**: with ``COLLAPSE_MIN_ROWS``+ 2D boxes, ``COLLAPSE_SHARE`` or more of them pick the
  same 3D box (in-domain: at most 0.4; A9 with the ``generic`` weights: up to 0.85).

``match(..., geometry="auto")`` (the default), for a matcher with the shipped weights (``site``
"synthetic" / "generic", trained on synthetic sites) and no site calibration, matches by
geometric consensus (:mod:`xcalib.calib.consensus`, reached by a lazy delegation: calib sits
above engine) when the intrinsics are known (``match(..., intrinsics=)``, a frame's) or the
scores look out of domain (then the intrinsics are searched), and warns once, naming ``xcalib
bootstrap``: on every dataset of ``benchmarks/bench_matching_sites.py`` the consensus beats
these weights (e.g. synthetic site B: generic weights Top-1 0.95 but matches precision 0.60;
consensus 1.00 / 1.00). ``geometry="on"`` always matches by consensus, ``"off"`` never.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ..types import MatchResult

__all__ = ["GEOMETRY_MODES", "SHIPPED_SITES", "out_of_domain", "check_geometry_mode", "geometry_match_result",
           "site_geometry_result", "BOOTSTRAP_HINT"]

log = logging.getLogger("xcalib.matcher")

GEOMETRY_MODES = ("auto", "on", "off")
SHIPPED_SITES = ("synthetic", "generic")  # packaged weights: trained on synthetic sites, not on the user's
MIN_BEST_PROBABILITY = 0.5
COLLAPSE_MIN_ROWS = 4
COLLAPSE_SHARE = 0.5
BOOTSTRAP_HINT = ("Adapt a matcher to this site without labels: `xcalib bootstrap RECORDING --intrinsics K.json "
                  "--site NAME` (or Matcher.oneshot), then Matcher.from_pretrained(model, site=NAME)")


def check_geometry_mode(geometry: str) -> str:
    if geometry not in GEOMETRY_MODES:
        raise ValueError(f"geometry must be one of {GEOMETRY_MODES}, got {geometry!r}")
    return geometry


def out_of_domain(similarity: np.ndarray, score_range=(0.0, 1.0), fill_value: float | None = None) -> str:
    """Why the scores of one frame look out of domain ("" when they do not, or cannot tell)."""
    s = np.asarray(similarity, dtype=np.float64)
    if s.ndim != 2 or s.shape[0] < 2 or s.shape[1] < 2:
        return ""
    lo, hi = float(score_range[0]), float(score_range[1])
    p = (s - lo) / (hi - lo)
    if fill_value is not None:
        p = np.where(s == fill_value, -np.inf, p)
    best = np.median(p.max(axis=1))
    if best < MIN_BEST_PROBABILITY:
        return f"no confident pair (median best match probability {best:.2f} < {MIN_BEST_PROBABILITY})"
    if s.shape[0] >= COLLAPSE_MIN_ROWS:
        share = np.bincount(p.argmax(axis=1), minlength=s.shape[1]).max() / s.shape[0]
        if share >= COLLAPSE_SHARE:
            return f"scores collapsed onto one 3D box ({share:.0%} of the 2D boxes pick it)"
    return ""


def geometry_match_result(m, image, point_cloud, bboxes_2d, bboxes_3d, *, intrinsics, match_threshold: float,
                          t0: float | None = None) -> tuple[MatchResult | None, str]:
    """(``MatchResult`` with ``source="geometry"``, "") from geometric consensus, or (None, why)."""
    from ..calib.consensus import consensus_matches  # lazy: calib sits above engine

    t0 = time.perf_counter() if t0 is None else t0
    cm = consensus_matches((image, point_cloud, bboxes_2d, bboxes_3d), intrinsics)
    if not cm.found:
        return None, cm.message
    if cm.message:  # matches left out as ambiguous (another pose pairs those boxes otherwise)
        log.info("geometric consensus: %s", cm.message)
    k2, k3 = cm.kept_2d, cm.kept_3d
    sim = cm.iou[np.ix_(k2, k3)].astype(np.float32)
    top = sim.argmax(axis=1).astype(np.int64) if sim.size else np.full(len(k2), -1, np.int64)
    if sim.size:
        top[sim.max(axis=1) <= 0] = -1
    gate = max(float(match_threshold), cm.config.gate)
    matches = [(int(i), int(j), float(cm.iou[i, j])) for i, j in cm.pairs if cm.iou[i, j] >= gate]
    return MatchResult(similarity=sim, top_indices=top, matches=matches, kept_2d_indices=k2, kept_3d_indices=k3,
                       latency_ms=(time.perf_counter() - t0) * 1000.0, model=m.model_name, device=str(m.device),
                       assignment="hungarian", geometry_iou=sim, fusion_weight=1.0, source="geometry"), ""


def site_geometry_result(m, image, point_cloud, bboxes_2d, bboxes_3d, *, box7=None, t0: float | None = None) -> MatchResult:
    """``MatchResult`` (``source="geometry"``) of a site whose default is geometry: every 3D box
    projected through the site calibration ``m.calibration`` and assigned one to one (Hungarian,
    IoU >= ``POSE_IOU_GATE``) over **all** boxes (the projection needs no LiDAR points inside a
    box, unlike the model's crops), the same matches as ``derive_matches``."""
    from .fusion import POSE_IOU_GATE, geometric_iou
    from .assign import assign

    t0 = time.perf_counter() if t0 is None else t0
    k2 = np.arange(len(np.asarray(bboxes_2d).reshape(-1, 4)), dtype=np.int64)
    b3 = np.asarray(bboxes_3d)
    k3 = np.arange(len(b3) if b3.size else 0, dtype=np.int64)
    geo = geometric_iou(image, point_cloud, bboxes_2d, bboxes_3d, m.calibration, k2, k3, box7=box7) \
        if len(k2) and len(k3) else np.zeros((len(k2), len(k3)))
    top, pairs = assign(geo, top_k=1, threshold=POSE_IOU_GATE, method="hungarian")
    return MatchResult(similarity=geo.astype(np.float32), top_indices=top, matches=pairs, kept_2d_indices=k2,
                       kept_3d_indices=k3, latency_ms=(time.perf_counter() - t0) * 1000.0, model=m.model_name,
                       device=str(m.device), assignment="hungarian", geometry_iou=geo, fusion_weight=1.0,
                       source="geometry")
