"""``calibrate``: camera<-LiDAR extrinsics from 2D and 3D detections, with no target and no guess.

Pipeline (one static rig, one pose for all frames):

1. normalise the inputs (``inputs.prepare_frames``; yaw re-estimated for yaw-less 3D boxes);
2. bring-up: pose hypotheses from box triples per frame (``hypotheses``), pooled over frames
   and re-scored on all frames by how well every projected 3D box explains the 2D boxes; with
   too few rich frames, triples also mix frames spread over the recording (``_pooled_groups``:
   one static rig, so pairs of different frames are rigidly consistent too);
3. refinement of the best distinct hypotheses over all frames (``refine.refine_pose``); the
   per-edge error model (2D noise, 3D centre error seen at depth Z, 3D size error) is fitted to
   the residuals, so noisy 3D detections are weighted by their actual error;
4. uncertainty (per axis, 1-sigma): the larger of the Jacobian sandwich and the two frame-halves
   spread (with too few matches for the halves, fewer than 12: the leave-one-pair-out jackknife
   spread, ``refine.pose_jackknife``), plus the pose shift without the occlusion model
   (``_honest_std``);
5. decision: the best pose must match 3+ objects in some frame (or, with 1-2 per frame, match
   boxes at 4+ places over the recording, 2+ of them off one line, and 12+ matches so that each
   half of the frames is checked on its own), explain enough of the 2D boxes,
   be clearly better than any admissible runner-up beyond 2 sigma and be well constrained (norm of the
   1-sigma vector <= ``max_rot_std_deg`` / ``max_trans_std_m``, i.e. 2 sigma within 1 deg / 0.5 m),
   otherwise ``success=False`` with a message saying why.

A matcher's similarities (``matcher.match``) and a ``prior`` pose only seed the hypotheses;
every pose is judged by geometry alone.
"""

from __future__ import annotations

import inspect
import logging
import time
from typing import Any, Callable, Sequence

import numpy as np

from ..geometry.boxes import box2d_centers
from ..geometry.rotations import rotation_angle
from .hypotheses import Hypotheses, frame_hypotheses, score_poses
from .inputs import CalibFrame, prepare_frames
from .refine import HALF_MIN_MATCHES, match_all, pair_metrics, pose_covariance, pose_jackknife, pose_spread, refine_pose
from .result import CalibrationResult

__all__ = ["calibrate", "calibrate_single", "METHOD"]

log = logging.getLogger("xcalib.calib")
METHOD = "xcalib-boxes-v1"


def _fail(message: str, intr=None, frames: Sequence[CalibFrame] = (), **meta) -> CalibrationResult:
    return CalibrationResult(success=False, intrinsics=intr, message=message,
                             frame_keys=[f.key for f in frames], method=METHOD, meta=meta)


def _prior_pose(prior):
    if prior is None:
        return None
    if hasattr(prior, "rotation") and hasattr(prior, "translation"):
        return np.asarray(prior.rotation, float), np.asarray(prior.translation, float)
    if isinstance(prior, (tuple, list)) and len(prior) == 2:
        return np.asarray(prior[0], float).reshape(3, 3), np.asarray(prior[1], float).reshape(3)
    T = np.asarray(prior, dtype=np.float64)
    if T.shape not in ((4, 4), (3, 4)):
        raise ValueError(f"prior: expected a CalibrationResult, (R, t) or a 4x4 T_cam_lidar, got shape {T.shape}")
    return T[:3, :3].copy(), T[:3, 3].copy()


def _matcher_priors(matcher, frames_in, cframes: list[CalibFrame]) -> list[np.ndarray | None]:
    """Per-frame similarity [K,M] (rows/cols of the CalibFrame) from ``matcher.match``; None if unavailable."""
    out: list[np.ndarray | None] = []
    for item, fr in zip(frames_in, cframes):
        try:
            args = item.inputs() if hasattr(item, "inputs") else tuple(item)
            kw = {"geometry": "off"} if "geometry" in inspect.signature(matcher.match).parameters else {}  # model priors
            mr = matcher.match_frame(item, **kw) if hasattr(item, "inputs") and hasattr(matcher, "match_frame") \
                else matcher.match(*args, **kw)
            full = mr.full_similarity(len(np.asarray(args[2]).reshape(-1, 4)), len(np.asarray(args[3]).reshape(len(args[3]), -1)))
            out.append(np.asarray(full, dtype=np.float64)[np.ix_(fr.idx2d, fr.idx3d)])
        except Exception as exc:  # noqa: BLE001 - a matcher failure must not stop geometry
            log.warning("matcher.match failed on frame %s (%s); using geometry only", fr.key, exc)
            out.append(None)
    return out


def _distinct(Ra, ta, Rb, tb, rot_deg: float, trans_m: float) -> bool:
    return rotation_angle(Ra, Rb, degrees=True) > rot_deg or np.linalg.norm(ta - tb) > trans_m


def _nms(h: Hypotheses, n: int, rot_deg: float = 3.0, trans_m: float = 1.0) -> Hypotheses:
    order = np.argsort(-h.score, kind="stable")
    keep: list[int] = []
    for i in order:
        if all(_distinct(h.R[i], h.t[i], h.R[k], h.t[k], rot_deg, trans_m) for k in keep):
            keep.append(int(i))
        if len(keep) >= n:
            break
    return h.take(np.array(keep, dtype=np.int64))


def _pose_err(T, R, t):
    return rotation_angle(T[:3, :3], R, degrees=True), float(np.linalg.norm(T[:3, 3] - t))


# pooled identifiability (frames with only 1-2 matched objects each): the matched 3D boxes over
# all frames must sit at POOLED_MIN_PLACES+ places at least POOLED_SEP_M apart, two of which lie
# more than POOLED_OFF_LINE_M off the line through all of them (else the roll about it is free)
POOLED_MIN_PLACES = 4
POOLED_SEP_M = 1.0
POOLED_OFF_LINE_M = 1.0


def _matched_places(frames: Sequence[CalibFrame], pairs: list[np.ndarray],
                    max_centres: int = 1000) -> tuple[np.ndarray, np.ndarray]:
    """Distinct places [D,3] (LiDAR frame, m) of the matched 3D boxes over all frames and their
    distances [D] (m) from the principal line through them. Places are a maximal set of box
    centres at least ``POOLED_SEP_M`` apart (every matched centre lies within that of one);
    beyond ``max_centres`` matches an even subsample is used (fewer places, never more)."""
    X = [f.boxes3d[p[:, 1], :3] for f, p in zip(frames, pairs) if len(p)]
    if not X:
        return np.zeros((0, 3)), np.zeros(0)
    X = np.concatenate(X)
    if len(X) > max_centres:
        X = X[np.linspace(0, len(X) - 1, max_centres).round().astype(np.int64)]
    # random priorities (fixed seed): a slow track is a chain of near centres, which in time order
    # would take one round per link; random order takes a few rounds (Luby's independent set)
    X = X[np.random.default_rng(0).permutation(len(X))]
    near = np.linalg.norm(X[:, None] - X[None], axis=2) < POOLED_SEP_M
    kept = np.zeros(len(X), dtype=bool)
    open_ = np.ones(len(X), dtype=bool)
    while np.any(open_):  # each round keeps every open centre with no lower-index open neighbour
        first = open_ & ~np.any(np.tril(near & open_[None, :], -1), axis=1)
        kept |= first
        open_ &= ~np.any(near[first], axis=0)
    P = X[kept]
    if len(P) < 2:
        return P, np.zeros(len(P))
    c = P - P.mean(0)
    axis = np.linalg.svd(c, full_matrices=False)[2][0]
    return P, np.linalg.norm(c - np.outer(c @ axis, axis), axis=1)


def _pooled_groups(frames: Sequence[CalibFrame], n_groups: int = 3, per_group: int = 24,
                   every_max: int = 80) -> list[list[int]]:
    """Frame groups for hypotheses pooled across a sparse recording (1-2 objects per frame).

    One static rig: the LiDAR -> camera transform is the same in every frame, so a box pair of
    one frame and a box pair of another keep their distance (rigid) exactly like two pairs of
    one frame, and triples may mix frames. ``n_groups`` groups of about ``per_group`` 2D boxes
    each take every n-th frame, so that each spans the whole recording (objects far apart
    give well-conditioned triangles); with ``every_max`` > 0, one more group of frames spread
    over the recording holds up to that many 2D boxes. Returns lists of frame indices.
    """
    have = np.array([i for i, f in enumerate(frames) if f.n2 and f.n3], dtype=np.int64)
    if len(have) < 2:
        return []
    n2 = np.array([frames[i].n2 for i in have])
    per = max(2, int(per_group // max(1, np.median(n2))))
    G = int(min(n_groups, max(1, len(have) // per)))
    pick = have[np.unique(np.linspace(0, len(have) - 1, min(len(have), G * per)).round().astype(np.int64))]
    groups = [pick[g::G].tolist() for g in range(G)]
    if every_max > 0 and n2.sum() > every_max:
        m = max(2, int(len(have) * every_max / n2.sum()))
        groups.append(have[np.unique(np.linspace(0, len(have) - 1, m).round().astype(np.int64))].tolist())
    return [g for g in groups if len(g) >= 2]


def _collinear(P: np.ndarray, tol: float) -> bool:
    if len(P) < 3:
        return True
    s = np.linalg.svd(P - P.mean(0), compute_uv=False)
    return s[1] / np.sqrt(len(P)) < tol


def calibrate(frames, intrinsics=None, *args, matcher=None, prior=None, gate: float = 0.3,
              max_hyp_frames: int = 10, max_refine: int = 6, min_pairs: int = 4,
              ambiguity_ratio: float = 0.85, max_rot_std_deg: float = 0.5, max_trans_std_m: float = 0.25,
              reestimate_yaw: str | bool = "auto", box_model: str = "auto", max_baseline_m: float | None = 8.0,
              min_explained: float = 0.3, seed: int = 0,
              progress: Callable[[str, int, int], None] | None = None) -> CalibrationResult:
    """Estimate ``T_cam_lidar`` from detections over one or many frames of one static rig.

    Args:
        frames: ``xcalib.types.Frame``s or (image, point_cloud, bboxes_2d, bboxes_3d) tuples
            (LiDAR frame, metres; pixels). The reference's single-frame form
            ``calibrate(image, point_cloud, bboxes_2d, bboxes_3d, intrinsics)`` is accepted too.
        intrinsics: ``CameraIntrinsics`` / 3x3 K (None: taken from the frames).
        matcher: optional object with ``match(image, pc, b2, b3) -> MatchResult``; its
            similarities only rank candidate pairs (geometry decides).
        prior: optional initial pose (``CalibrationResult``, (R, t) or 4x4): skips the bring-up.
        gate: IoU gate of the final one-to-one matches.
        box_model: "auto" | "corners" | "points" (see ``inputs.prepare_frames``).
        max_baseline_m: bring-up assumes the camera within this distance of the LiDAR-frame origin
            (a co-located rig in the sensor's own frame); when that search fails it is repeated
            without the assumption. None: never assume it.
        min_explained: fail when the pose explains fewer than this fraction of the 2D boxes.
        ambiguity_ratio: fail when a distinct runner-up pose scores at least this fraction of the best.
        progress: optional callback(stage, done, total).
    Returns:
        ``CalibrationResult``; ``success=False`` with a ``message`` when the inputs do not
        determine the pose. Raises ValueError for impossible intrinsics or malformed inputs.
    """
    if isinstance(frames, np.ndarray) and frames.ndim == 3 and len(args) >= 2:
        # reference form: calibrate(image, point_cloud, bboxes_2d, bboxes_3d, intrinsics)
        image, pc = frames, intrinsics
        b2, b3 = args[0], args[1]
        intr_arg = args[2] if len(args) > 2 else None
        return calibrate_single(image, pc, b2, b3, intr_arg, matcher=matcher, prior=prior, gate=gate,
                                min_pairs=min_pairs, seed=seed)
    if args:
        raise TypeError("calibrate(frames, intrinsics, *, ...): unexpected positional arguments")
    _kw = dict(matcher=matcher, prior=prior, gate=gate, max_hyp_frames=max_hyp_frames, max_refine=max_refine,
               min_pairs=min_pairs, ambiguity_ratio=ambiguity_ratio, max_rot_std_deg=max_rot_std_deg,
               max_trans_std_m=max_trans_std_m, reestimate_yaw=reestimate_yaw, box_model=box_model,
               max_baseline_m=max_baseline_m, min_explained=min_explained, seed=seed, progress=progress)
    t0 = time.perf_counter()
    frames_in = list(frames) if not isinstance(frames, (list, tuple)) else frames
    cframes, intr, problem = prepare_frames(frames_in, intrinsics, reestimate_yaw=reestimate_yaw,
                                            box_model=box_model)
    camera = next((f.camera for f in cframes if f.camera), "")
    if problem:
        return _fail(problem, intr, cframes)
    n2, n3 = sum(f.n2 for f in cframes), sum(f.n3 for f in cframes)
    if n2 < 3 or n3 < 3:
        return _fail(f"too few detections: {n2} valid 2D and {n3} 3D boxes over {len(cframes)} frame(s); "
                     "need at least 3 of each (better 6+ spread over several frames)", intr, cframes)
    all3 = np.concatenate([f.boxes3d[:, :3] for f in cframes if f.n3])
    all2 = np.concatenate([box2d_centers(f.boxes2d) for f in cframes if f.n2])
    if _collinear(all3, 0.3):
        return _fail("not identifiable: all 3D boxes lie on one line (the roll about that line is free)", intr, cframes)
    if _collinear(all2, 3.0):
        return _fail("not identifiable: all 2D boxes lie on one image line", intr, cframes)
    rng = np.random.default_rng(seed)
    meta: dict[str, Any] = {}

    # ------------------------------------------------------------------ bring-up
    pp = _prior_pose(prior)
    if pp is not None:
        hyps = Hypotheses(pp[0][None], pp[1][None], np.zeros(1), np.zeros(1, dtype=np.int64))
        meta["seed"] = "prior"
    else:
        sims = _matcher_priors(matcher, frames_in, cframes) if matcher is not None else [None] * len(cframes)
        usable = [i for i, f in enumerate(cframes) if f.n2 >= 3 and f.n3 >= 3]
        if len(usable) > max_hyp_frames:
            richness = np.array([min(cframes[i].n2, cframes[i].n3) for i in usable])
            pick = np.sort(np.argsort(-richness, kind="stable")[:max_hyp_frames])
            usable = [usable[k] for k in pick]
        groups = [[i] for i in usable]
        # sparse scenes: a static rig makes pairs from different frames rigidly consistent too,
        # so pool frames (a few detections each) into groups of about 12 detections
        sparse = [i for i, f in enumerate(cframes) if f.n2 and f.n3 and i not in usable]
        if sparse:
            per = max(1, 12 // max(1, int(np.median([cframes[i].n2 for i in sparse]))))
            step = max(1, len(sparse) // max(1, (max_hyp_frames - len(groups))) // per) if len(sparse) > per else 1
            pool = sparse[::step] if len(sparse) > per * max_hyp_frames else sparse
            groups += [pool[k:k + per] for k in range(0, len(pool), per) if len(pool[k:k + per]) > 0]
            groups = groups[: max(max_hyp_frames, 1)]
        # few detections in all: search exhaustively-ish (cheap here) so that a second pose that
        # explains the boxes as well is found, and reported as an ambiguity, not silently dropped
        sparse_scene = n2 <= 80
        if sparse_scene:
            every = [i for i, f in enumerate(cframes) if f.n2 and f.n3]
            groups.append(every)
        meta["sparse_search"] = bool(sparse_scene)
        # too few rich frames (4+ detections of each kind): extra groups pooled across the whole
        # recording (see _pooled_groups); their hypotheses only add to the per-frame ones
        n_before = len(groups)
        if sum(min(f.n2, f.n3) >= 4 for f in cframes) < max_hyp_frames:
            groups += _pooled_groups(cframes, every_max=0 if sparse_scene else 80)
        meta["pooled_search"] = len(groups) > n_before
        parts = []
        for k, g in enumerate(groups):
            gs = [sims[i] for i in g]
            big = (sparse_scene or k >= n_before) and len(g) > 1
            h = frame_hypotheses([cframes[i] for i in g], intr, g[0], prior_sims=gs, rng=rng,
                                 max_baseline_m=max_baseline_m, max_triples=20000 if big else 3000,
                                 keep=60 if big else 25)
            if any(x is not None for x in gs) and len(h) == 0:
                h = frame_hypotheses([cframes[i] for i in g], intr, g[0], rng=rng, max_baseline_m=max_baseline_m)
            parts.append(h)
            if progress:
                progress("hypotheses", k + 1, len(groups))
        hyps = Hypotheses.concat(parts)
        meta["seed"] = "matcher" if matcher is not None else "geometry"
        if len(hyps) == 0 and max_baseline_m is not None:
            return calibrate(frames_in, intr, **{**_kw, "max_baseline_m": None})
        if len(hyps) == 0:
            return _fail("not identifiable: no 3 detections seen by both sensors form a consistent, "
                         "non-collinear triangle (objects on one line, or too few objects)", intr, cframes, **meta)
        # re-score the pooled hypotheses on every frame (static rig: one pose explains all)
        total = np.zeros(len(hyps))
        for k, fr in enumerate(cframes):
            total += score_poses(fr, intr, hyps.R, hyps.t)
        hyps.score = total
    meta["n_hypotheses"] = int(len(hyps))
    cand = _nms(hyps, max_refine * 2 if meta.get("sparse_search") else max_refine)
    meta["bringup_T"] = np.vstack([np.hstack([cand.R[0], cand.t[0][:, None]]), [0, 0, 0, 1]]).tolist()

    # ---------------------------------------------------------------- refinement
    refined = []
    short = ((0.1, 1.0), (0.2, 0.5), (0.3, 0.0))
    for k in range(len(cand)):  # quick refinement of every candidate ...
        rr = refine_pose(cframes, intr, cand.R[k], cand.t[k], gates=short, max_nfev=15, max_outer=3)
        _, ious = pair_metrics(cframes, intr, rr.R, rr.t, rr.pairs)
        refined.append((float(np.sum(ious)), rr))
        if progress:
            progress("refine", k + 1, len(cand) + 1)
    refined.sort(key=lambda x: -x[0])
    finals = [refined[0]]
    other = next((x for x in refined[1:] if _distinct(x[1].R, x[1].t, refined[0][1].R, refined[0][1].t, 1.0, 0.3)),
                 None)
    if other is not None:
        finals.append(other)
    refined = []
    for k, (_, r0) in enumerate(finals):  # ... then a full one of the best and the best distinct runner-up
        rr = refine_pose(cframes, intr, r0.R, r0.t, gates=((0.2, 0.5), (0.3, 0.0), (0.3, 0.0)))
        _, ious = pair_metrics(cframes, intr, rr.R, rr.t, rr.pairs)
        refined.append((float(np.sum(ious)), rr))
        if progress:
            progress("refine", len(cand) + k + 1, len(cand) + len(finals))
    refined.sort(key=lambda x: -x[0])
    best_score, best = refined[0]
    # a runner-up only makes the result ambiguous when it is admissible under the same assumption
    # as the search: with ``max_baseline_m`` the camera sits within that distance of the LiDAR
    # origin (|t| = |camera centre|); a runner-up far outside it is no competing explanation
    # (when the best pose is outside it too, the assumption is dropped and every runner-up counts)
    in_base = (lambda r: True) if max_baseline_m is None or np.linalg.norm(best.t) > max_baseline_m \
        else (lambda r: np.linalg.norm(r.t) <= max_baseline_m)
    runner = next((s for s, r in refined[1:] if _distinct(r.R, r.t, best.R, best.t, 1.0, 0.3) and in_base(r)), 0.0)
    meta.update(score=best_score, runner_up_score=runner, refine_history=best.history,
                candidates=[{"score": s, "rot_deg_from_best": rotation_angle(r.R, best.R, degrees=True),
                             "baseline_m": float(np.linalg.norm(r.t)),
                             "trans_m_from_best": float(np.linalg.norm(r.t - best.t))} for s, r in refined],
                bringup_error_vs_final=list(_pose_err(np.asarray(meta["bringup_T"]), best.R, best.t)))

    pairs = match_all(cframes, intr, best.R, best.t, gate_iou=gate)
    px, ious = pair_metrics(cframes, intr, best.R, best.t, pairs)
    rot_sd, tr_sd, _ = pose_covariance(cframes, pairs, intr, best.R, best.t, noise=best.noise)
    meta["noise_model"] = dict(zip(("sigma_px", "sigma_3d_m", "sigma_size"), best.noise))
    f_scale = max(0.5, 1.5 * float(np.median(np.abs(best.residuals)))) if len(best.residuals) else 2.0
    halves, occl = pose_spread(cframes, pairs, intr, best.R, best.t, noise=best.noise, f_scale=f_scale)
    meta["jacobian_std"] = {"rotation_deg": np.asarray(rot_sd).tolist(), "translation_m": np.asarray(tr_sd).tolist()}
    meta["halves_delta"] = None if halves is None else halves.tolist()
    meta["occlusion_delta"] = occl.tolist()
    jack = pose_jackknife(cframes, pairs, intr, best.R, best.t, noise=best.noise, f_scale=f_scale) \
        if halves is None else None
    meta["jackknife_std"] = None if jack is None else jack.tolist()
    rot_sd, tr_sd = _honest_std(np.concatenate([rot_sd, tr_sd]), halves, occl, jack)
    # a runner-up within 2 sigma of the best is the same solution (the decision below then bounds
    # the error by 2 sigma <= 1 deg / 0.5 m); only one beyond that is a competing explanation
    r2, t2 = 2 * float(np.linalg.norm(rot_sd)), 2 * float(np.linalg.norm(tr_sd))
    runner = next((s for s, r in refined[1:] if _distinct(r.R, r.t, best.R, best.t, 1.0, 0.3) and in_base(r)
                   and _distinct(r.R, r.t, best.R, best.t, r2, t2)), 0.0)
    meta["ambiguity_runner_up_score"] = runner
    n_pairs = int(sum(len(p) for p in pairs))
    centre_off = _centre_offsets(cframes, intr, best.R, best.t, pairs)
    meta.update(centre_offset_px_median=float(np.median(centre_off)) if len(centre_off) else None,
                n_2d=int(n2), n_3d=int(n3), elapsed_s=time.perf_counter() - t0)
    caller_pairs = [np.column_stack([f.idx2d[p[:, 0]], f.idx3d[p[:, 1]]]) if len(p) else np.zeros((0, 2), np.int64)
                    for f, p in zip(cframes, pairs)]
    res = CalibrationResult(
        success=True, intrinsics=intr, rotation=best.R, translation=best.t, n_correspondences=n_pairs,
        n_inliers=int(np.sum(ious >= 0.5)), reproj_error_px=float(np.mean(px)) if len(px) else float("inf"),
        residual_px_median=float(np.median(px)) if len(px) else float("nan"),
        iou_median=float(np.median(ious)) if len(ious) else float("nan"),
        iou_mean=float(np.mean(ious)) if len(ious) else float("nan"),
        rotation_std_deg=rot_sd, translation_std_m=tr_sd, pairs=caller_pairs,
        frame_keys=[f.key for f in cframes], camera_name=camera, image_size=cframes[0].size, method=METHOD,
        meta=meta,
    )
    # ------------------------------------------------------------------ decision
    need = max(min_pairs, 3)
    why = None
    most = max((len(p) for p in pairs), default=0)
    meta["max_pairs_per_frame"] = int(most)
    if most < 3:
        places, off_line = _matched_places(cframes, pairs)
        meta.update(matched_places=int(len(places)), matched_places_off_line=int(np.sum(off_line > POOLED_OFF_LINE_M)))
    if most < 3 and (len(places) < POOLED_MIN_PLACES or np.sum(off_line > POOLED_OFF_LINE_M) < 2):
        # a static rig: objects at other places in other frames constrain the one pose together,
        # but only when the matched objects cover enough places that are not on one line
        why = (f"not identifiable: no frame has 3 or more objects matched between the sensors (at most {most}) "
               f"and over all frames the matched objects are at {len(places)} distinct place(s), "
               f"{int(np.sum(off_line > POOLED_OFF_LINE_M))} of them off one line (need {POOLED_MIN_PLACES}+, "
               f"2+ off the line by > {POOLED_OFF_LINE_M:g} m); one or two objects on one path leave the pose ambiguous")
    elif most < 3 and halves is None:
        # with 1-2 objects per frame each half of the frames must determine the pose on its own
        # (the frame-halves check of the uncertainty needs 6+ matches per half)
        why = (f"not identifiable: no frame has 3 or more objects matched between the sensors (at most {most}) "
               f"and the {n_pairs} matches over all frames are too few to check the pose on each half of the "
               f"frames (need {HALF_MIN_MATCHES}+ per half); add frames")
    elif n_pairs < need or n_pairs < min_explained * n2:
        why = (f"the best pose explains only {n_pairs} of {n2} 2D boxes (need {max(need, int(np.ceil(min_explained * n2)))}); "
               "too few objects seen by both sensors, or no pose explains the detections")
    elif runner >= ambiguity_ratio * best_score:
        why = (f"ambiguous: two different poses explain the boxes about equally well (scores {best_score:.2f} "
               f"vs {runner:.2f}); add frames with objects spread over the image")
    elif not (np.all(np.isfinite(rot_sd)) and np.all(np.isfinite(tr_sd))) or \
            np.linalg.norm(rot_sd) > max_rot_std_deg or np.linalg.norm(tr_sd) > max_trans_std_m:
        if halves is None:  # few matches: no frame-halves check; the leave-one-pair-out spread judged the pose
            why = _few_pairs_message(n_pairs, rot_sd, tr_sd, max_rot_std_deg, max_trans_std_m)
        else:
            why = (f"not identifiable: the pose is poorly constrained (1-sigma rotation {np.linalg.norm(rot_sd):.2f} "
                   f"deg, translation {np.linalg.norm(tr_sd):.2f} m, over all axes; the frame halves and the "
                   "occlusion model included); add frames or objects at other places/depths")
    if why and max_baseline_m is not None and pp is None:
        # the co-located-rig assumption may be wrong (e.g. boxes in a global frame): search again
        retry = calibrate(frames_in, intr, **{**_kw, "max_baseline_m": None})
        if retry.success:
            return retry
    meta["max_baseline_m"] = max_baseline_m
    if why:
        res.success = False
        res.accepted = False
        res.message = why
    return res


def _honest_std(jac_sd: np.ndarray, halves: np.ndarray | None, occl: np.ndarray,
                jack: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis 1-sigma (rotation deg, translation m) that also covers what the Jacobian misses.

    Statistical part: the larger of the Jacobian (sandwich) sigma and half the difference of the
    two frame-half poses (a one-sample check that frames agree; inflates when a few frames or
    boxes with bad 3D detections drive the pose). Systematic part, added in quadrature: the shift
    of the pose when the occlusion model is switched off (how much the pose leans on it; grows
    with the 3D-box error). On the synthetic benchmark 2 sigma (vector norm) covers >= 90 % of
    the true errors with exact and with noisy 3D boxes.

    With too few matches for the frame halves (fewer than 6 per half), the data-fitted error
    model and the linearised covariance are optimistic (a few pairs whose 3D boxes are off by
    0.1 m fit each other well); the leave-one-pair-out spread ``jack`` takes the halves' place.
    With neither, the pose cannot be checked at all: infinite sigma.
    """
    var = jac_sd ** 2
    if halves is not None:
        var = np.fmax(var, (np.asarray(halves) / 2.0) ** 2)
    elif jack is not None:
        var = np.fmax(var, np.asarray(jack) ** 2)
    else:
        var = np.full_like(var, np.inf)
    sd = np.sqrt(var + np.asarray(occl) ** 2)
    return sd[:3], sd[3:]


HALVES_MIN_MATCHES = 2 * HALF_MIN_MATCHES  # the frame-halves check (pose_spread) needs this many matches


def _few_pairs_message(n_pairs: int, rot_sd, tr_sd, max_rot: float, max_tr: float) -> str:
    """Refusal text when there are too few matched pairs to verify the pose (no frame-halves check)."""
    r, t = float(np.linalg.norm(rot_sd)), float(np.linalg.norm(tr_sd))
    spread = (f"; leaving one pair out moves the pose by 1-sigma {r:.2f} deg / {t:.2f} m (limit {max_rot:g} deg / "
              f"{max_tr:g} m)") if np.isfinite(r) and np.isfinite(t) else ""
    return (f"not identifiable: too few matched pairs to verify the pose ({n_pairs} matched pairs; the frame-halves "
            f"check needs {HALVES_MIN_MATCHES}+, {HALF_MIN_MATCHES}+ per half){spread}; add frames or objects seen by both sensors: "
            f"at least {max(HALVES_MIN_MATCHES - n_pairs, 1)} more matched pairs, at other places")


def _centre_offsets(frames, intr, R, t, pairs) -> np.ndarray:
    """Pixel distance between each matched 2D box centre and its projected 3D box centre."""
    from ..geometry.projection import project_points

    out = []
    for fr, p in zip(frames, pairs):
        if len(p):
            uv, _ = project_points(fr.boxes3d[p[:, 1], :3], intr, R, t)
            out.append(np.linalg.norm(uv - box2d_centers(fr.boxes2d[p[:, 0]]), axis=1))
    return np.concatenate(out) if out else np.zeros(0)


_REFERENCE_ONLY = ("match_threshold", "ransac_reproj_px", "validate")


def calibrate_single(image, point_cloud, bboxes_2d, bboxes_3d, intrinsics, *, matcher=None, prior=None,
                     gate: float = 0.3, min_pairs: int = 4, seed: int = 0, **kwargs) -> CalibrationResult:
    """The reference's one-frame form: ``calibrate_single(image, pc, b2, b3, K)`` -> CalibrationResult.

    Same pipeline as :func:`calibrate` on a single frame (best-effort: one frame often leaves the
    pose ambiguous, which is then reported as a failure, not guessed). The reference's
    ``match_threshold``, ``ransac_reproj_px`` and ``validate`` keywords are accepted and ignored
    (matcher scores only rank candidates here; geometry decides).
    """
    for k in _REFERENCE_ONLY:
        kwargs.pop(k, None)
    return calibrate([(image, point_cloud, bboxes_2d, bboxes_3d)], intrinsics, matcher=matcher, prior=prior,
                     gate=gate, min_pairs=min_pairs, seed=seed, **kwargs)
