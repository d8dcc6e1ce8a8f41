"""Geometric consensus matching: a frame's 2D and 3D boxes matched through the one rigid pose
that explains most of them, found from that frame alone (no site weights, no labels).

This is the calibration bring-up (:mod:`xcalib.calib.hypotheses`: box triples -> P3P ->
Kabsch, scored by how well every projected 3D box explains the 2D boxes), run on one frame,
followed by a short refinement of the best few distinct poses, all at once
(:func:`xcalib.calib.poses_refine.refine_poses`: ``refine_pose``'s schedule and objective, one
batched Levenberg-Marquardt with analytic Jacobians) and one-to-one matching by projection (Hungarian on IoU >= ``gate``). A match is kept only when
no other refined pose that pairs either of its boxes differently explains the frame within
``min_margin`` summed IoU of the best (:func:`pair_margins`): a frame whose few boxes fit two
poses equally well (SUSTech's right camera: 2 objects and a false box) gets no matches rather
than wrong ones (``ConsensusMatches.ambiguous`` lists them). It transfers between
sites because it learns nothing: what it needs is 3+ objects seen by both sensors, not on one
line.

Intrinsics: given (a ``CameraIntrinsics`` / 3x3 K), or, when unknown, searched: a pinhole
camera with the principal point at the image centre and the horizontal field of view in
``ConsensusConfig.fov_deg``; the field of view whose best pose hypothesis explains the boxes
best is kept (the matches need a pose that projects boxes onto their partners, not the exact
lens). ``ConsensusConfig.fisheye_fov_deg`` adds equidistant (Kannala-Brandt, k = 0) lenses of
those fields of view to the search, for a fisheye camera whose intrinsics are unknown (a pinhole
cannot image past 90 degrees off axis). On the 16 real A9 frames (judged against the matches of the all-frame calibration):
recall 0.98 / precision 0.97 with the intrinsics, 0.96 / 0.94 with the searched ones
(``benchmarks/bench_matching_sites.py``).

The pose found here is *not* a calibration: one frame rarely determines it to the accuracy
``calibrate`` demands (it refuses such poses); it only has to put each 3D box on its 2D box.
``Matcher.match`` reaches this module through a lazy delegation (``source="geometry"``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..geometry.camera import CameraIntrinsics
from ..geometry.camera_models import KannalaBrandt
from ..geometry.rotations import rotation_angle
from .hypotheses import TripleSearch, frame_hypotheses
from .inputs import CalibFrame, as_intrinsics, prepare_frames
from .poses_refine import refine_poses
from .refine import RefineOptions, RefineResult

__all__ = ["ConsensusConfig", "ConsensusMatches", "consensus_matches", "pair_margins", "searched_intrinsics"]

SEARCH_KEEP = 2  # searched intrinsics: fields of view whose poses are refined (the best is kept)


@dataclass(frozen=True)
class ConsensusConfig:
    """``gate``: IoU gate of a match; ``max_baseline_m``: first search with the camera within this
    distance of the LiDAR-frame origin (then without); ``n_refine``: distinct poses refined;
    ``fov_deg``: horizontal fields of view tried when the intrinsics are unknown (pinhole lenses);
    ``fisheye_fov_deg``: the same for equidistant fisheye lenses (none by default); ``min_altitude_m``:
    thinnest box triangle (m) the pose search accepts; ``score_budget``: IoU entries (2D x 3D boxes
    x poses) the search scores, so small frames keep more hypotheses than ``keep`` (a true pose
    that puts only 3 box centres into their boxes is not lost behind poses that hit more);
    ``min_margin``: summed IoU by which the best
    pose must beat every refined pose that pairs a box differently for that match to be kept
    (:func:`pair_margins`); ``seed``."""

    gate: float = 0.3
    max_baseline_m: float | None = 8.0
    n_refine: int = 6
    keep: int = 40
    max_triples: int = 20000  # box triples tried (crowded frames, e.g. 70+ 3D boxes around a car, need many)
    fov_deg: tuple[float, ...] = (30.0, 45.0, 60.0, 80.0, 100.0)
    fisheye_fov_deg: tuple[float, ...] = ()
    min_altitude_m: float = 0.3  # one frame: thin triangles too (refinement fixes the roll); calibrate uses 0.8
    min_margin: float = 0.3  # one match at the IoU gate
    score_budget: int = 300_000
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.gate <= 1.0:
            raise ValueError(f"ConsensusConfig.gate must be an IoU in (0, 1], got {self.gate}")
        if not (self.min_margin >= 0.0 and self.min_altitude_m >= 0.0):
            raise ValueError("ConsensusConfig.min_margin and min_altitude_m must be >= 0")
        if self.n_refine < 1 or self.keep < 1:
            raise ValueError("ConsensusConfig.n_refine and keep must be >= 1")
        if not self.fov_deg or not all(0.0 < f < 180.0 for f in self.fov_deg):
            raise ValueError(f"ConsensusConfig.fov_deg: fields of view in (0, 180) degrees, got {self.fov_deg}")
        if not all(0.0 < f <= 270.0 for f in self.fisheye_fov_deg):
            raise ValueError(f"ConsensusConfig.fisheye_fov_deg: fields of view in (0, 270] degrees, got "
                             f"{self.fisheye_fov_deg}")


@dataclass
class ConsensusMatches:
    """Matches of one frame by geometric consensus (caller numbering).

    pairs [n,2] int64 (2D index, 3D index), one-to-one; iou [K,M] IoU of every 2D box with every
    3D box projected through the consensus pose (0 for dropped boxes); kept_2d / kept_3d: the
    boxes the geometry could use; T_cam_lidar [4,4] the pose (None when none was found);
    intrinsics (given or searched) and ``intrinsics_source`` ("given" | "searched"); ``score``:
    summed IoU of the matches; ``runner_up``: the same for the best distinct pose; ``margin`` [n]:
    per pair, by how much the best pose beats the best refined pose pairing either box otherwise
    (its confidence, summed IoU); ``ambiguous`` [a,2]: the pairs of the best pose left out because
    their margin is below ``config.min_margin``; ``message``: why there is no pose or what was
    left out, else ""."""

    pairs: np.ndarray
    iou: np.ndarray
    kept_2d: np.ndarray
    kept_3d: np.ndarray
    T_cam_lidar: np.ndarray | None
    intrinsics: CameraIntrinsics | None
    intrinsics_source: str
    score: float = 0.0
    runner_up: float = 0.0
    message: str = ""
    elapsed_s: float = 0.0
    config: ConsensusConfig = field(default_factory=ConsensusConfig)
    margin: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ambiguous: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))

    @property
    def found(self) -> bool:
        return self.T_cam_lidar is not None


def searched_intrinsics(width: int, height: int, fov_deg: float, lens: str = "pinhole"):
    """Intrinsics with the principal point at the image centre and horizontal field of view
    ``fov_deg`` (square pixels): a pinhole ``CameraIntrinsics`` (``lens="pinhole"``, fov < 180)
    or an equidistant ``KannalaBrandt`` with k = 0 (``lens="equidistant"``: r = f theta)."""
    half = np.radians(fov_deg) / 2.0
    if lens == "equidistant":
        f = width / 2.0 / half
        return KannalaBrandt(fx=f, fy=f, cx=width / 2.0, cy=height / 2.0, width=int(width), height=int(height),
                             k=(0.0, 0.0, 0.0, 0.0))
    if lens != "pinhole":
        raise ValueError(f"searched_intrinsics: lens must be 'pinhole' or 'equidistant', got {lens!r}")
    f = width / 2.0 / np.tan(half)
    return CameraIntrinsics(fx=f, fy=f, cx=width / 2.0, cy=height / 2.0, width=int(width), height=int(height))


def pair_margins(pairs: np.ndarray, score: float, others) -> np.ndarray:
    """Per pair (i, j) of the best pose (summed IoU ``score``): ``score`` minus the best score of
    the other poses ``others`` [(score, pairs [n,2])] that pair box i or box j with another box
    (a pose that merely leaves them unmatched is no alternative); ``score`` when none does."""
    out = np.full(len(pairs), float(score))
    for s_k, p_k in others:
        if len(p_k) == 0:
            continue
        row_to = dict(zip(p_k[:, 0].tolist(), p_k[:, 1].tolist()))
        col_to = dict(zip(p_k[:, 1].tolist(), p_k[:, 0].tolist()))
        for n, (i, j) in enumerate(pairs.tolist()):
            if row_to.get(i, j) != j or col_to.get(j, i) != i:
                out[n] = min(out[n], float(score) - float(s_k))
    return out


def _distinct(Ra, ta, Rb, tb, rot_deg: float, trans_m: float) -> bool:
    return rotation_angle(Ra, Rb, degrees=True) > rot_deg or float(np.linalg.norm(ta - tb)) > trans_m


#: how far (deg, m) a batched angle or distance must be from ``_distinct``'s thresholds to decide
#: without ``_distinct`` itself (their rounding differs by some 1e-14; nearer: ``_distinct`` decides)
_SURE = (1e-6, 1e-9)


def _distinct_best(R: np.ndarray, t: np.ndarray, order: np.ndarray, n: int, apart: tuple[float, float]) -> list[int]:
    """The first ``n`` poses in ``order`` that are ``_distinct`` (by ``apart`` = (deg, m)) from every
    pose kept before them: each candidate is compared with all the kept poses in one batch
    (the angle from trace(R_a R_b^T) = sum of R_a * R_b, the distance from the summed squares),
    and ``_distinct`` itself decides the pairs within ``_SURE`` of a threshold: the same poses as
    calling ``_distinct`` on every pair."""
    rot_deg, trans_m = apart
    keep: list[int] = []
    for i in order:
        if keep:
            k = np.asarray(keep)
            c = np.clip(((R[k] * R[i]).sum((1, 2)) - 1.0) / 2.0, -1.0, 1.0)
            ang = np.degrees(np.arccos(c))
            dt = np.sqrt(((t[k] - t[i]) ** 2).sum(1))
            apart_sure = (ang > rot_deg + _SURE[0]) | (dt > trans_m + _SURE[1])
            near_sure = (ang < rot_deg - _SURE[0]) & (dt < trans_m - _SURE[1])
            if near_sure.any():
                continue
            if not all(_distinct(R[i], t[i], R[j], t[j], rot_deg, trans_m) for j in k[~apart_sure].tolist()):
                continue
        keep.append(int(i))
        if len(keep) >= n:
            break
    return keep


def _hypotheses(fr: CalibFrame, intr: CameraIntrinsics, cfg: ConsensusConfig):
    rng = np.random.default_rng(cfg.seed)
    keep = max(cfg.keep, cfg.score_budget // max(8 * fr.n2 * fr.n3, 1))  # frame_hypotheses IoU-scores 8 x keep
    search = TripleSearch(keep=keep, max_triples=cfg.max_triples, min_altitude_m=cfg.min_altitude_m, closed_form=True)
    h = frame_hypotheses(fr, intr, 0, rng=rng, search=replace(search, max_baseline_m=cfg.max_baseline_m))
    if len(h) == 0 and cfg.max_baseline_m is not None:
        h = frame_hypotheses(fr, intr, 0, rng=np.random.default_rng(cfg.seed), search=search)
    return h


def _best_poses(fr: CalibFrame, intr: CameraIntrinsics, h, cfg: ConsensusConfig):
    """Refine the ``n_refine`` best distinct hypotheses; [(summed IoU, RefineResult, IoU [K,M])] best
    first (the pairs and IoU of ``refine.match_frame`` at the pose, at gate ``cfg.gate``)."""
    keep = _distinct_best(h.R, h.t, np.argsort(-h.score, kind="stable"), cfg.n_refine, (3.0, 1.0))
    opts = RefineOptions(gates=((0.1, 1.0), (0.2, 0.5), (cfg.gate, 0.0)), max_nfev=15, max_outer=3)
    fit = refine_poses(fr, intr, h.R[keep], h.t[keep], opts)
    out = [(float(fit.score[i]), RefineResult(fit.R[i], fit.t[i], [fit.pairs[i]], cost=float("nan"), n_iter=opts.max_outer),
            fit.iou[i]) for i in range(len(keep))]
    out.sort(key=lambda x: -x[0])
    return out


def _candidates(frame, intrinsics, cfg: ConsensusConfig):
    """[(CalibFrame, intrinsics, hypotheses)] to refine, source ("given" | "searched"), problem.
    Searched intrinsics: the ``SEARCH_KEEP`` fields of view whose best hypothesis scores highest."""
    if intrinsics is not None:
        cfs, intr, problem = prepare_frames([frame], intrinsics)
        return ([] if problem else [(cfs[0], intr, _hypotheses(cfs[0], intr, cfg))]), "given", problem, cfs[0], intr
    image = frame.image if hasattr(frame, "image") else frame[0]
    H, W = int(image.shape[0]), int(image.shape[1])
    found = []
    lenses = [(fov, "pinhole") for fov in cfg.fov_deg] + [(fov, "equidistant") for fov in cfg.fisheye_fov_deg]
    cfs, _, problem = prepare_frames([frame], searched_intrinsics(W, H, lenses[0][0], lenses[0][1]))
    if problem:
        return [], "searched", problem, cfs[0], as_intrinsics(searched_intrinsics(W, H, *lenses[0]))
    for fov, lens in lenses:  # the frame is prepared once: its outlines do not depend on the lens
        intr = as_intrinsics(searched_intrinsics(W, H, fov, lens))
        intr.check_image_size(*cfs[0].size)
        h = _hypotheses(cfs[0], intr, cfg)
        found.append((float(h.score.max()) if len(h) else -1.0, cfs[0], intr, h))
    found.sort(key=lambda x: -x[0])
    return [(fr, intr, h) for _, fr, intr, h in found[:SEARCH_KEEP]], "searched", "", found[0][1], found[0][2]


def consensus_matches(frame, intrinsics=None, config: ConsensusConfig | None = None) -> ConsensusMatches:
    """Match one frame (a ``Frame`` or an (image, point_cloud, bboxes_2d, bboxes_3d) tuple) by
    geometric consensus; ``intrinsics`` None: searched (see the module docstring). A frame whose
    boxes determine no pose gives no pairs and a ``message`` saying why."""
    cfg = config or ConsensusConfig()
    t0 = time.perf_counter()
    b2 = np.asarray(frame.bboxes_2d if hasattr(frame, "bboxes_2d") else frame[2], dtype=np.float64).reshape(-1, 4)
    b3 = np.asarray(frame.bboxes_3d if hasattr(frame, "bboxes_3d") else frame[3])
    K, M = len(b2), (len(b3) if b3.size else 0)
    cands, source, problem, fr, intr = _candidates(frame, intrinsics, cfg)
    cands = [c for c in cands if len(c[2])]
    if problem or not cands:
        return ConsensusMatches(np.zeros((0, 2), np.int64), np.zeros((K, M)), fr.idx2d.astype(np.int64),
                                fr.idx3d.astype(np.int64), None, intr, source, config=cfg,
                                message=problem or ("no geometric consensus: no 3 detections seen by both sensors form "
                                                    "a consistent, non-collinear triangle"),
                                elapsed_s=time.perf_counter() - t0)
    tried = [(_best_poses(f, k, h, cfg), f, k) for f, k, h in cands]
    poses, fr, intr = max(tried, key=lambda x: x[0][0][0])
    score, best, best_iou = poses[0]
    runner = next((s for s, r, _ in poses[1:] if _distinct(r.R, r.t, best.R, best.t, 1.0, 0.3)), 0.0)
    # the refinement's last matching is ``match_frame`` at the refined pose with the gate: its pairs
    # and IoU (tests/test_matching_consensus.py checks them against ``match_frame``)
    pairs = best.pairs[0]
    margin = pair_margins(pairs, score, [(s, r.pairs[0]) for s, r, _ in poses[1:]])
    sure = margin >= cfg.min_margin
    iou = np.zeros((K, M))
    if fr.n2 and fr.n3:
        iou[np.ix_(fr.idx2d, fr.idx3d)] = best_iou
    caller = (np.column_stack([fr.idx2d[pairs[:, 0]], fr.idx3d[pairs[:, 1]]]).astype(np.int64) if len(pairs)
              else np.zeros((0, 2), np.int64))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = best.R, best.t
    n_unsure = int(np.count_nonzero(~sure))
    msg = (f"{n_unsure} of {len(pairs)} match(es) left out: another pose that pairs those boxes differently explains "
           f"the frame within {cfg.min_margin} summed IoU of the best" if n_unsure else "")
    return ConsensusMatches(caller[sure], iou, fr.idx2d.astype(np.int64), fr.idx3d.astype(np.int64), T, intr, source,
                            score=score, runner_up=float(runner), message=msg, margin=margin[sure],
                            ambiguous=caller[~sure], elapsed_s=time.perf_counter() - t0, config=cfg)
