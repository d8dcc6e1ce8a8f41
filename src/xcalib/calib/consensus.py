"""Geometric consensus matching: a frame's 2D and 3D boxes matched through the one rigid pose
that explains most of them, found from that frame alone (no site weights, no labels).

This is the calibration bring-up (:mod:`xcalib.calib.hypotheses`: box triples -> P3P ->
Kabsch, scored by how well every projected 3D box explains the 2D boxes), run on one frame,
followed by a short refinement of the best few distinct poses (:func:`xcalib.calib.refine.refine_pose`)
and one-to-one matching by projection (Hungarian on IoU >= ``gate``). It transfers between
sites because it learns nothing: what it needs is 3+ objects seen by both sensors, not on one
line.

Intrinsics: given (a ``CameraIntrinsics`` / 3x3 K), or, when unknown, searched: a pinhole
camera with the principal point at the image centre and the horizontal field of view in
``ConsensusConfig.fov_deg``; the field of view whose best pose hypothesis explains the boxes
best is kept (the matches need a pose that projects boxes onto their partners, not the exact
lens). On the 16 real A9 frames (judged against the matches of the all-frame calibration):
recall 0.98 / precision 0.97 with the intrinsics, 0.96 / 0.94 with the searched ones
(``benchmarks/bench_matching_sites.py``).

The pose found here is *not* a calibration: one frame rarely determines it to the accuracy
``calibrate`` demands (it refuses such poses); it only has to put each 3D box on its 2D box.
``Matcher.match`` reaches this module through a lazy delegation (``source="geometry"``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..geometry.camera import CameraIntrinsics
from ..geometry.rotations import rotation_angle
from .boxproj import iou_batched
from .hypotheses import frame_hypotheses
from .inputs import CalibFrame, prepare_frames
from .refine import match_frame, pair_metrics, refine_pose

__all__ = ["ConsensusConfig", "ConsensusMatches", "consensus_matches", "searched_intrinsics"]

SEARCH_KEEP = 2  # searched intrinsics: fields of view whose poses are refined (the best is kept)


@dataclass(frozen=True)
class ConsensusConfig:
    """``gate``: IoU gate of a match; ``max_baseline_m``: first search with the camera within this
    distance of the LiDAR-frame origin (then without); ``n_refine``: distinct poses refined;
    ``fov_deg``: horizontal fields of view tried when the intrinsics are unknown; ``seed``."""

    gate: float = 0.3
    max_baseline_m: float | None = 8.0
    n_refine: int = 6
    keep: int = 40
    max_triples: int = 20000  # box triples tried (crowded frames, e.g. 70+ 3D boxes around a car, need many)
    fov_deg: tuple[float, ...] = (30.0, 45.0, 60.0, 80.0, 100.0)
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.gate <= 1.0:
            raise ValueError(f"ConsensusConfig.gate must be an IoU in (0, 1], got {self.gate}")
        if self.n_refine < 1 or self.keep < 1:
            raise ValueError("ConsensusConfig.n_refine and keep must be >= 1")
        if not self.fov_deg or not all(0.0 < f < 180.0 for f in self.fov_deg):
            raise ValueError(f"ConsensusConfig.fov_deg: fields of view in (0, 180) degrees, got {self.fov_deg}")


@dataclass
class ConsensusMatches:
    """Matches of one frame by geometric consensus (caller numbering).

    pairs [n,2] int64 (2D index, 3D index), one-to-one; iou [K,M] IoU of every 2D box with every
    3D box projected through the consensus pose (0 for dropped boxes); kept_2d / kept_3d: the
    boxes the geometry could use; T_cam_lidar [4,4] the pose (None when none was found);
    intrinsics (given or searched) and ``intrinsics_source`` ("given" | "searched"); ``score``:
    summed IoU of the matches; ``runner_up``: the same for the best distinct pose (ambiguity);
    ``message``: why there is no pose, else ""."""

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

    @property
    def found(self) -> bool:
        return self.T_cam_lidar is not None


def searched_intrinsics(width: int, height: int, fov_deg: float) -> CameraIntrinsics:
    """Pinhole intrinsics with the principal point at the image centre and horizontal field of view
    ``fov_deg`` (square pixels)."""
    f = width / 2.0 / np.tan(np.radians(fov_deg) / 2.0)
    return CameraIntrinsics(fx=f, fy=f, cx=width / 2.0, cy=height / 2.0, width=int(width), height=int(height))


def _distinct(Ra, ta, Rb, tb, rot_deg: float, trans_m: float) -> bool:
    return rotation_angle(Ra, Rb, degrees=True) > rot_deg or float(np.linalg.norm(ta - tb)) > trans_m


def _hypotheses(fr: CalibFrame, intr: CameraIntrinsics, cfg: ConsensusConfig):
    rng = np.random.default_rng(cfg.seed)
    h = frame_hypotheses(fr, intr, 0, rng=rng, max_baseline_m=cfg.max_baseline_m, keep=cfg.keep,
                         max_triples=cfg.max_triples)
    if len(h) == 0 and cfg.max_baseline_m is not None:
        h = frame_hypotheses(fr, intr, 0, rng=np.random.default_rng(cfg.seed), keep=cfg.keep, max_triples=cfg.max_triples)
    return h


def _best_poses(fr: CalibFrame, intr: CameraIntrinsics, h, cfg: ConsensusConfig):
    """Refine the ``n_refine`` best distinct hypotheses; [(summed IoU, RefineResult)] best first."""
    keep: list[int] = []
    for i in np.argsort(-h.score, kind="stable"):
        if all(_distinct(h.R[i], h.t[i], h.R[k], h.t[k], 3.0, 1.0) for k in keep):
            keep.append(int(i))
        if len(keep) >= cfg.n_refine:
            break
    out = []
    for k in keep:
        rr = refine_pose([fr], intr, h.R[k], h.t[k], gates=((0.1, 1.0), (0.2, 0.5), (cfg.gate, 0.0)),
                         max_nfev=15, max_outer=3)
        _, ious = pair_metrics([fr], intr, rr.R, rr.t, rr.pairs)
        out.append((float(np.sum(ious)), rr))
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
    for fov in cfg.fov_deg:
        cfs, intr, problem = prepare_frames([frame], searched_intrinsics(W, H, fov))
        if problem:
            return [], "searched", problem, cfs[0], intr
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
    score, best = poses[0]
    runner = next((s for s, r in poses[1:] if _distinct(r.R, r.t, best.R, best.t, 1.0, 0.3)), 0.0)
    pairs, _, rects = match_frame(fr, intr, best.R, best.t, gate_iou=cfg.gate)
    iou = np.zeros((K, M))
    if fr.n2 and fr.n3:
        iou[np.ix_(fr.idx2d, fr.idx3d)] = iou_batched(rects[None], fr.boxes2d)[0]
    caller = (np.column_stack([fr.idx2d[pairs[:, 0]], fr.idx3d[pairs[:, 1]]]).astype(np.int64) if len(pairs)
              else np.zeros((0, 2), np.int64))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = best.R, best.t
    return ConsensusMatches(caller, iou, fr.idx2d.astype(np.int64), fr.idx3d.astype(np.int64), T, intr, source,
                            score=score, runner_up=float(runner), elapsed_s=time.perf_counter() - t0, config=cfg)
