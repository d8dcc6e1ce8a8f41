"""``calibrate``: camera<-LiDAR extrinsics from 2D and 3D detections, with no target and no guess.

One static rig, one pose for all frames. ``calibrate`` is a composition of the stages:

0. frame selection (``selection``): a recording longer than ``CalibConfig.max_frames`` is reduced
   to its informative frames (distinct objects, places, depths, bearings), linear in the frames;
1. inputs (``inputs.prepare_frames``; yaw re-estimated for yaw-less 3D boxes) and
   ``decision.precheck``;
2. bring-up (``bringup.pose_hypotheses``) -- or the ``prior`` pose;
3. refinement of the best distinct hypotheses over all frames (``refine.refine_pose``: the cost
   model of ``cost``, the per-edge error model fitted to the residuals);
4. uncertainty (``uncertainty.estimate``);
5. the verdict (``decision.verdict``) -> ``CalibrationResult`` with its config and diagnostics.

A matcher's similarities (``matcher.match``) and a ``prior`` pose only seed the hypotheses;
every pose is judged by geometry alone. Settings: :class:`~xcalib.calib.config.CalibConfig`.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..geometry.boxes import box2d_centers
from ..geometry.projection import project_points
from ..geometry.transforms import make_transform
from .boxmodel import fit_object_outline, fit_outline
from .bringup import (distinct_best, gated_frames, gated_matches, matcher_similarities, pose_hypotheses,
                      unoccluded_frames)
from .config import CalibConfig
from .cost import Occlusion
from .terms import CostSpec
from .decision import (POOLED_OFF_LINE_M, Evidence, Refusal, crowded_check, data_sd_beyond_noise, matched_places, precheck,
                       verdict)
from .diagnostics import CalibDiagnostics, CandidateSummary, FrameSelectionSummary, FrameSummary
from .hypotheses import Hypotheses
from .inputs import CalibFrame, lean_frames, prepare_frames, with_corner_outlines, with_point_outlines
from .misfit import box_frame_check, flipped_frames, lens_checks, focal_box_model, focal_fit, focal_scale_check, focal_width_check, leftover_frames, match_bound, second_pose_check, second_pose_screen, second_pose_support, mirror_check, mirror_screen, principal_point_check, pp_unresolved, TIME_SIGMAS, time_offset_check, time_shifted_frames, unexplained_frames_check
from .motion import BoxMotion, box_motion, shift_frames
from .parallel import Deferred, WorkerPool, Workers, parallel_map, resolve_workers, shared
from .pose import Pose
from .refine import (FitContext, RefineOptions, RefineResult, RefineRun, match_all, pair_metrics, refine_finish, refine_pose,
                     refine_start, refine_step)
from .result import CalibrationResult
from .selection import FrameSelection, scan_frames, select_frames
from .selfcal import decide as decide_selfcal, wants_selfcal
from .uncertainty import estimate as estimate_uncertainty
from .uncertainty import MIN_OBJECTS, bound95, object_groups, outline_fit, principal_point_part, statistical_sd, with_focal_box_model, with_object_outline, with_principal_point

__all__ = ["calibrate", "calibrate_single", "METHOD"]

METHOD = "xcalib-boxes-v1"
Progress = Callable[[str, int, int], None]


def _result(success: bool, message: str, intr, frames: Sequence[CalibFrame], config: CalibConfig,
            diag: CalibDiagnostics, **fields) -> CalibrationResult:
    return CalibrationResult(success=success, intrinsics=intr, message=message, frame_keys=[f.key for f in frames],
                             method=METHOD, config=config, diagnostics=diag, **fields)


def _refused(refusal: Refusal, intr, frames, config, diag) -> CalibrationResult:
    diag.refusal = refusal.code
    return _result(False, refusal.message, intr, frames, config, diag)


@dataclass
class _Refined:
    best: RefineResult
    best_score: float
    others: list[tuple[float, RefineResult]]


def _score(cframes, intr, rr: RefineResult) -> float:
    return float(np.sum(pair_metrics(cframes, intr, rr.R, rr.t, rr.pairs)[1]))


#: the quick refinement's schedule (``_refine_candidates``): three loose-to-tight matchings, short fits
QUICK = RefineOptions(gates=((0.1, 1.0), (0.2, 0.5), (0.3, 0.0)), max_nfev=15, max_outer=3)
#: two quick refinements that reach the same matches at the same iteration with poses this close
#: (deg, m) go on as one (``_merged``): the rest of each would fit the same matches from the same
#: point, to the same minimum
SAME_RUN = (0.01, 0.01)


def _quick_step(args) -> tuple[RefineRun, tuple[float, RefineResult] | None]:
    """One outer iteration of a candidate's quick refinement (a task of ``_refine_candidates``; the
    run is started first when ``args`` holds a pose): (the run, (score, result) once it is done)."""
    cframes, intr, run, occlusion = args
    if not isinstance(run, RefineRun):
        run = refine_start(cframes, intr, *run, QUICK)
    if not run.done:
        refine_step(cframes, intr, run, QUICK, occlusion)
    if not run.done:
        return run, None
    rr = refine_finish(cframes, intr, run, QUICK)
    return run, (_score(cframes, intr, rr), rr)


def _merged(run: RefineRun, earlier: list[RefineRun]) -> bool:
    """Whether ``run`` goes on as one of the ``earlier`` runs still going: the same iteration, the
    same matches, poses within ``SAME_RUN``. Its next fits would then fit the same matches from
    the same point (to within ``SAME_RUN``; the error model and robust scale each refits from it
    differ as little), so they end at the same pose: its result would be that run's (same score,
    not distinct from it), which takes its place in the ranking."""
    for e in earlier:
        if e.done or e.it != run.it or len(e.pairs) != len(run.pairs):
            continue
        if not all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(e.pairs, run.pairs)):
            continue
        deg, m = Pose(run.R, run.t).error(Pose(e.R, e.t))
        if deg <= SAME_RUN[0] and m <= SAME_RUN[1]:
            return True
    return False


def _quick_refines(qf, intr, cand: Hypotheses, occlusion: Occlusion, workers: Workers) -> list[tuple[float, RefineResult]]:
    """The quick refinement of every candidate, in candidate order, as (score, result); run in
    lockstep, one outer iteration of every candidate still going per round (each round on up to
    ``workers`` processes). A run that reaches another one's matches and pose (``_merged``) ends
    there: its result would be that run's, so it adds nothing to the ranking and is left out.
    The same results whatever the number of workers."""
    sq = shared(qf, workers)  # pickled once for all the tasks
    runs: list = [(cand.R[k], cand.t[k]) for k in range(len(cand))]
    results: list = [None] * len(cand)
    live = list(range(len(cand)))
    while live:
        out = parallel_map(_quick_step, [(sq, intr, runs[k], occlusion) for k in live], workers)
        going = []
        for k, (run, res) in zip(live, out):
            runs[k], results[k] = run, res
            if res is None and not _merged(run, [runs[j] for j in going]):
                going.append(k)
        live = going
    return [r for r in results if r is not None]


def _full_refine(args) -> tuple[float, RefineResult]:
    """One finalist's full refinement and its score (a task of ``_refine_candidates``). On a crowded
    site (``view``: ``bringup.unoccluded_frames``) it is also refined from its fit on the unambiguous
    boxes, and the better-scoring of the two results is kept: both are optima of the same score on
    every box, so the choice can only raise it (junction, 200 boxes a side: 1.96 deg / 0.96 m off,
    score 1248, from the finalist directly; 0.008 deg / 0.013 m, score 1941, through the view)."""
    cframes, intr, R, t, occlusion, view = args
    opts = RefineOptions(gates=((0.2, 0.5), (0.3, 0.0), (0.3, 0.0)))
    rr = refine_pose(cframes, intr, R, t, options=opts, occlusion=occlusion)
    best = (_score(cframes, intr, rr), rr)
    if view is not None:
        r0 = refine_pose(view, intr, R, t, options=opts, occlusion=occlusion)
        rr = refine_pose(cframes, intr, r0.R, r0.t, options=opts, occlusion=occlusion)
        s = _score(cframes, intr, rr)
        if s > best[0]:
            best = (s, rr)
    return best


def _refine_candidates(cframes, intr, cand: Hypotheses, occlusion: Occlusion,
                       progress: Progress | None, workers: Workers = 1, max_candidates: int | None = None) -> _Refined:
    """A quick refinement of every candidate, then a full one of the best and the best distinct
    runner-up (each stage on up to ``workers`` processes; the results, in candidate order, are the
    same whatever the number). ``max_candidates`` (``CalibConfig.max_candidates``): the quick
    refinements see crowded frames through the search's gate (``bringup.gated_frames``), so their
    cost stops growing with the boxes per frame; None: every frame as it is."""
    lean = lean_frames(cframes) if resolve_workers(workers) > 1 else cframes
    gated = None if max_candidates is None else gated_frames(lean, max_candidates)
    qf = lean if gated is None else gated
    quick = _quick_refines(qf, intr, cand, occlusion, workers)
    if progress:
        for k in range(len(cand)):
            progress("refine", k + 1, len(cand) + 1)
    quick.sort(key=lambda x: -x[0])
    best0 = Pose(quick[0][1].R, quick[0][1].t)
    finals = [quick[0]] + [next((x for x in quick[1:] if Pose(x[1].R, x[1].t).distinct(best0, 1.0, 0.3)), None)]
    finals = [f for f in finals if f is not None]
    sl = shared(lean, workers)
    view = None if max_candidates is None else unoccluded_frames(lean, max_candidates)
    sv = None if view is None else shared(view, workers)
    refined = parallel_map(_full_refine, [(sl, intr, r0.R, r0.t, occlusion, sv) for _, r0 in finals], workers)
    if progress:
        for k in range(len(finals)):
            progress("refine", len(cand) + k + 1, len(cand) + len(finals))
    refined.sort(key=lambda x: -x[0])
    return _Refined(refined[0][1], refined[0][0], refined[1:])


def _outline_kind(cframes) -> str:
    n_pts = sum(int(f.from_points.sum()) for f in cframes if f.from_points is not None)
    n_all = sum(f.n3 for f in cframes)
    return "corners" if n_pts == 0 else "points" if n_pts == n_all else "corners+points"


def _in_view(cframes, intr, R, t) -> list[np.ndarray]:
    """Per frame, [M] bool: the 3D boxes the pose projects (at least partly) into the image."""
    from .boxproj import project_rects

    return [project_rects(f.corners, R, t, intr, f.size)[1] if f.n3 else np.zeros(0, dtype=bool) for f in cframes]


#: Point hulls replace the corners of boxes *with* a yaw only when their median edge residual is
#: below this share of the corners' (a clear win, not a tie).
HULL_CLEAR_MARGIN = 0.9


def _choose_box_model(cframes, intr, cand: Hypotheses, ref: _Refined, occlusion: Occlusion, config: CalibConfig,
                      diag: CalibDiagnostics, progress: Progress | None) -> tuple[list, _Refined]:
    """``box_model="auto"``: which outline of a 3D box the 2D boxes follow, decided by the data.

    With point-hull outlines (yaw-less boxes): fit the yaw-fitted boxes' 8 corners too and keep
    the outlines whose edges fit the 2D boxes better (median px). A hull follows a real vehicle
    (rounded, narrower roof: on A9 the corners overshoot the 2D boxes by 8-17 % of their size)
    but misses the parts between scan lines; corners are exact for box-shaped objects and for
    labelled (amodal) or projected-cuboid 2D boxes. With box corners (boxes with a yaw) and a
    cloud: the hulls of the points of the boxes in view are fitted too, the same way (a camera
    detector draws the visible outline: PandaSet's detector boxes are 11-13 % smaller than the
    cuboids' corner rectangles, which pushed the camera 1.2 m back). When the other outline wins,
    every candidate is refined again with it."""
    if config.box_model != "auto":
        diag.box_model = _outline_kind(cframes)
        return cframes, ref
    best = ref.best
    alt, hull_first = with_corner_outlines(cframes), True
    if alt is None and any(f.points is not None and len(f.points) for f in cframes):  # (no cloud: no hulls)
        alt, hull_first = with_point_outlines(cframes, _in_view(cframes, intr, best.R, best.t)), False
    if alt is None:
        diag.box_model = _outline_kind(cframes)
        return cframes, ref
    rr = refine_pose(alt, intr, best.R, best.t, options=RefineOptions(gates=((0.2, 0.5), (0.3, 0.0), (0.3, 0.0))),
                     occlusion=occlusion)
    px_used, _ = pair_metrics(cframes, intr, best.R, best.t, best.pairs)
    px_alt, _ = pair_metrics(alt, intr, rr.R, rr.t, rr.pairs)
    med = [float(np.median(v)) if len(v) else float("inf") for v in (px_used, px_alt)]
    diag.box_model_px = med if hull_first else med[::-1]  # [point hulls, corners]
    # boxes with a yaw: their corners are the model until the hulls fit clearly better (PandaSet's
    # detector boxes: 5.9 vs 10.5 px); a near tie (a synthetic site's amodal boxes: 7.88 vs 7.99 px)
    # keeps the corners -- switching there tripled the rotation error (0.13 -> 0.35 deg)
    margin = 1.0 if hull_first else HULL_CLEAR_MARGIN
    if not med[1] < margin * med[0]:
        diag.box_model = _outline_kind(cframes)
        return cframes, ref
    diag.box_model = _outline_kind(alt)
    return alt, _refine_candidates(alt, intr, cand, occlusion, progress, config.workers, config.max_candidates)


def _runner_up(ref: _Refined, max_baseline_m: float | None, r2: float = 1.0, t2: float = 0.3) -> float:
    """Score of the best distinct runner-up admissible under the search's assumption: with
    ``max_baseline_m`` the camera sits within that distance of the LiDAR origin (|t|); a runner-up
    far outside it is no competing explanation (when the best pose is outside it too, the
    assumption is dropped). Distinct: more than max(1 deg, r2) / max(0.3 m, t2) away."""
    best = Pose(ref.best.R, ref.best.t)
    free = max_baseline_m is None or np.linalg.norm(best.t) > max_baseline_m
    for s, r in ref.others:
        p = Pose(r.R, r.t)
        if p.distinct(best, 1.0, 0.3) and p.distinct(best, r2, t2) and (free or np.linalg.norm(r.t) <= max_baseline_m):
            return s
    return 0.0


def _centre_offsets(frames, intr, R, t, pairs) -> np.ndarray:
    """Pixel distance between each matched 2D box centre and its projected 3D box centre."""
    out = []
    for fr, p in zip(frames, pairs):
        if len(p):
            uv, _ = project_points(fr.boxes3d[p[:, 1], :3], intr, R, t)
            out.append(np.linalg.norm(uv - box2d_centers(fr.boxes2d[p[:, 0]]), axis=1))
    return np.concatenate(out) if out else np.zeros(0)


def _frame_summaries(cframes, intr, R, t, pairs) -> list[FrameSummary]:
    rows = []
    for fr, p in zip(cframes, pairs):
        px, iou = pair_metrics([fr], intr, R, t, [p])
        rows.append(FrameSummary(fr.key, fr.n2, fr.n3, int(len(p)), float(np.median(px)) if len(px) else None,
                                 float(np.median(iou)) if len(iou) else None))
    return rows


def _track_ids(frames_in, cframes) -> list | None:
    """Per CalibFrame, the track id of each kept 3D box (``Frame.track_ids_3d``), or None."""
    out, any_ = [], False
    for item, fr in zip(frames_in, cframes):
        ids = getattr(item, "track_ids_3d", None)
        if ids is None or len(np.asarray(ids)) <= (fr.idx3d.max() if len(fr.idx3d) else -1):
            out.append(None)
            continue
        out.append(np.asarray(ids)[fr.idx3d])
        any_ = True
    return out if any_ else None


def _objects_sd(parts, config: CalibConfig) -> dict:
    """``Evidence``'s object-level statistical sigma (``uncertainty.statistical_sd``), when objects are counted."""
    sd = statistical_sd(parts) if config.uncertainty != "frames" else None
    return {} if sd is None else {"rot_sd_objects": sd[:3], "tr_sd_objects": sd[3:]}


def _beyond_noise_sd(parts, config: CalibConfig) -> dict:
    """``Evidence``'s data sigma with the occlusion shift beyond its noise (``decision.data_sd_beyond_noise``),
    when objects are counted (the reported sigma it is weighed with then counts each object once)."""
    sd = data_sd_beyond_noise(parts) if config.uncertainty != "frames" else None
    return {} if sd is None else {"rot_sd_beyond_noise": sd[:3], "tr_sd_beyond_noise": sd[3:]}


def _search(cframes, frames_in, intr, config: CalibConfig, matcher, prior: Pose | None, diag: CalibDiagnostics,
            progress: Progress | None) -> Hypotheses:
    """Bring-up hypotheses (or the prior), scored on every frame."""
    if prior is not None:
        diag.seed_source = "prior"
        return Hypotheses(prior.R[None], prior.t[None], np.zeros(1), np.zeros(1, dtype=np.int64))
    sims = matcher_similarities(matcher, frames_in, cframes) if matcher is not None else None
    bu = pose_hypotheses(cframes, intr, config, similarities=sims, max_baseline_m=config.max_baseline_m,
                         rng=np.random.default_rng(config.seed), progress=progress)
    diag.seed_source = "matcher" if matcher is not None else "geometry"
    diag.sparse_search, diag.pooled_search, diag.split_searches = bu.sparse_search, bu.pooled_search, bu.split_searches
    return bu.hyps


_MISFIT_CAN_EXPLAIN = ("poorly_constrained", "ambiguous", "few_explained", "uncertain", "too_few_objects")


def _mirror_need(cframes, config: CalibConfig) -> int:
    """The matches a pose needs to explain the 2D boxes (``mirror_check``'s ``explained``)."""
    return max(config.min_pairs, 3, int(np.ceil(config.min_explained * sum(f.n2 for f in cframes))))


def _mirror_score(cframes, intr, config: CalibConfig, occlusion: Occlusion, best_score: float | None = None,
                  pose: Pose | None = None) -> tuple[float, int, str | None]:
    """(best score, 2D boxes its pose matches, None) of the search (a few frames, few candidates) on
    the left-right flipped 2D boxes; with the best pose's ``best_score`` and ``pose``, not searched
    where no result could flag a mirror (``misfit.mirror_screen``): (the bound, the bound, why)."""
    if best_score is not None:
        why = mirror_screen(best_score, cframes, pose, _mirror_need(cframes, config))
        if why is not None:
            return float(match_bound(cframes)), match_bound(cframes), why
    flipped = flipped_frames(cframes)
    small = config.replace(max_hyp_frames=min(config.max_hyp_frames, 4), max_refine=min(config.max_refine, 3))
    bu = pose_hypotheses(flipped, intr, small, max_baseline_m=config.max_baseline_m,
                         rng=np.random.default_rng(config.seed))
    if len(bu.hyps) == 0:
        return 0.0, 0, None
    ref = _refine_candidates(flipped, intr, distinct_best(bu.hyps, small.max_refine), occlusion, None,
                             config.workers, config.max_candidates)
    matched = match_all(flipped, intr, ref.best.R, ref.best.t, gate_iou=config.gate_iou)
    return ref.best_score, int(sum(len(p) for p in matched)), None


def _second_pose(cframes, pairs, intr, pose: Pose, config: CalibConfig, occlusion: Occlusion,
                 best_score: float | None = None):
    """The search (a few frames, few candidates) on the 2D boxes the pose leaves unmatched:
    (score, matches, (deg, m) from ``pose``, admissible under ``config.max_baseline_m``, None) of the
    best pose found there, or (0, 0, None, False, None); with the best pose's ``best_score``, not
    searched where no result could flag (``misfit.second_pose_screen``): (bound, bound, None, False, why)."""
    left = leftover_frames(cframes, pairs)
    if sum(f.n2 for f in left) < 6:
        return 0.0, 0, None, False, None
    why = None if best_score is None else second_pose_screen(best_score, left)
    if why is not None:
        return float(match_bound(left)), match_bound(left), None, False, why
    small = config.replace(max_hyp_frames=min(config.max_hyp_frames, 4), max_refine=min(config.max_refine, 3))
    # a pose with fewer matches than a flag needs is not looked for (the pooled groups are skipped where
    # the search over every leftover frame finds one with that many with probability >= 99 %)
    bu = pose_hypotheses(left, intr, small, max_baseline_m=config.max_baseline_m, rng=np.random.default_rng(config.seed),
                         support=second_pose_support(best_score))
    if len(bu.hyps) == 0:
        return 0.0, 0, None, False, None
    ref = _refine_candidates(left, intr, distinct_best(bu.hyps, small.max_refine), occlusion, None,
                             config.workers, config.max_candidates)
    p2, cap = Pose(ref.best.R, ref.best.t), config.max_baseline_m
    n2 = int(sum(len(p) for p in match_all(left, intr, p2.R, p2.t, gate_iou=config.gate_iou)))
    admissible = cap is None or np.linalg.norm(pose.t) > cap or np.linalg.norm(p2.t) <= cap
    return ref.best_score, n2, tuple(float(v) for v in p2.error(pose)), bool(admissible), None


def _frame_times(frames_in) -> tuple[np.ndarray, str]:
    """LiDAR time of each frame (s) when every frame has one, else the frame index ("frames")."""
    t = [getattr(f, "lidar_time_s", None) for f in frames_in]
    if all(v is not None for v in t) and len(set(t)) == len(t):
        return np.asarray(t, dtype=np.float64), "s"
    return np.arange(len(frames_in), dtype=np.float64), "frames"


def _misfit_searches(ctx: FitContext, config: CalibConfig, best_score: float | None = None,
                     refits: tuple | None = None) -> Deferred:
    """The misfit checks' searches and refits that need no other check (second pose, lens, mirror;
    with ``refits``: the focal-length, time-offset and principal-point refits too), started now on up
    to ``config.workers`` processes, the longest first (the second-pose search on a few frames; the
    lens refit, numeric derivatives, on long recordings: ~4.5 s of a 200-frame selection's 5.5 s of
    checks). With one worker each runs here when its result is first asked for, so the serial order
    of work is unchanged. Close it (or use it as a context manager). ``best_score``: the best pose's
    score; the second-pose and mirror searches that could not flag whatever they found are then not
    run (exact screens, ``misfit.second_pose_screen`` / ``mirror_screen``). ``refits``: (frame
    times, their unit, whether the focal length was estimated) -- calls 3, 4, 5 are then
    ``focal_fit``, ``time_offset_check`` and ``principal_point_check`` on every frame (None where the
    check does not apply), as ``_misfit_checks`` would call them."""
    cframes, pairs, intr, pose, noise, f_scale, occlusion = (ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise,
                                                             ctx.f_scale, ctx.occlusion)
    lean = lean_frames(cframes)
    refit_calls = [] if refits is None else _refit_calls(ctx, config, refits, lean)
    view = _search_view(ctx.with_frames(lean), config)
    if view is not None:  # crowded frames: the searches and the lens refits on the gate's view
        lean, pairs, best_score = view.frames, view.pairs, None if best_score is None else view.score
    # the two searches and the lens refit run on threads here, their own searches, refinements and fits on the
    # pool's processes (as one task each, the second-pose search on A9 and the lens refit on 200 frames alone
    # outlasted everything else); the other refits are tasks, queued behind the searches' own (``later``: they
    # are independent and wanted last, the searches are chains of tasks one after another)
    return Deferred([(_second_pose, (lean, pairs, intr, pose, config, occlusion, best_score)),
                     (_lens_check, (dataclasses.replace(ctx, frames=lean, pairs=pairs), None)),
                     (_mirror_score, (lean, intr, config, occlusion, best_score, pose))] + refit_calls,
                    config.workers, threads=(0, 1, 2), later=(3, 4, 5))


def _refit_calls(ctx: FitContext, config: CalibConfig, refits: tuple, lean: list) -> list:
    """``_misfit_searches``' calls 3-5 (see there): the checks' refits on every frame, with the
    frames' point clouds and images left out where they run on other processes."""
    times, unit, focal_estimated = refits
    # several workers: the refits are tasks on other processes, their frames one ``Shared`` (pickled once
    # for the three, unpickled once per worker; a task receives the frames themselves)
    full = ctx if resolve_workers(config.workers) == 1 else ctx.with_frames(shared(lean, config.workers))
    focal = None if focal_estimated else (focal_fit, (full.frames, full.pairs, full.intr, full.pose, full.noise,
                                                      full.f_scale, full.occlusion))
    time_chk = (_time_check, (full, times, unit, config.seed, None)) if config.time_offset is None else None
    pp = (_pp_check, (full, config.seed, None, focal_estimated)) if config.refine_intrinsics != "focal+center" else None
    return [focal, time_chk, pp]


def _time_check(ctx: FitContext, times: np.ndarray, unit: str, seed: int, places: int | None = None):
    """``misfit.time_offset_check`` (a task of ``_misfit_searches``; ``places``: the matched places,
    None: counted here, in the task)."""
    places = len(matched_places(ctx.frames, ctx.pairs)[0]) if places is None else places
    return time_offset_check(ctx, times, unit, seed=seed, places=places)


def _pp_check(ctx: FitContext, seed: int, places: int | None, focal_free: bool = False):
    """``misfit.principal_point_check`` (a task of ``_misfit_searches``; ``places``: the matched
    places, None: counted here, in the task, rather than before the tasks start; ``focal_free``:
    the focal length was estimated, judged with it refitted)."""
    places = len(matched_places(ctx.frames, ctx.pairs)[0]) if places is None else places
    return principal_point_check(ctx, seed=seed, places=places, focal_free=focal_free)


def _early_searches(frames_in, state: tuple, occlusion: Occlusion, config: CalibConfig,
                    diag: CalibDiagnostics) -> tuple:
    """``_misfit_searches`` started on ``state`` = (frames, intrinsics, refined candidates) before the
    box-model choice and the self-calibration: (state, the refits' inputs, the searches), for ``_kept``."""
    cframes, intr, ref = state
    best, pose = ref.best, Pose(ref.best.R, ref.best.t)
    pairs = match_all(cframes, intr, pose.R, pose.t, gate_iou=config.gate_iou)
    f_scale = max(0.5, 1.5 * float(np.median(np.abs(best.residuals)))) if len(best.residuals) else 2.0
    refits = (*_frame_times(frames_in), diag.selfcal.focal_estimated)
    fit = FitContext(cframes, pairs, intr, pose, best.noise, f_scale, occlusion)
    return state, refits, _misfit_searches(fit, config, ref.best_score, refits)


def _kept(early: tuple | None, state: tuple | None, refits: tuple) -> Deferred | None:
    """The searches of ``_early_searches`` when they were started on this ``state`` (the same frames,
    intrinsics and candidates: the same pose, matches and noise) and these refits' inputs; else
    None, the early ones given up."""
    if early is None:
        return None
    (frames0, intr0, ref0), refits0, searches = early
    same = state is not None and state[0] is frames0 and state[1] is intr0 and state[2] is ref0 and \
        len(refits) == len(refits0) and all(np.array_equal(a, b) for a, b in zip(refits, refits0))
    if same:
        return searches
    searches.cancel()
    return None


@dataclass
class _View:
    """The misfit searches' view of a crowded site: the frames through the search's gate, the
    matches on them (renumbered) and the best pose's score there (summed IoU of those matches)."""

    frames: list
    pairs: list
    score: float


def _search_view(ctx: FitContext, config: CalibConfig) -> _View | None:
    """On a crowded site (``bringup.gated_matches``), the view the second-pose and mirror searches
    and the lens refits run on: each crowded frame's ``GATE_2D`` most informative 2D boxes, every
    3D box, the pose's matches among them. Their flags compare the alternative's score with the
    best pose's *on the same boxes* (shares and per-object gains), so the thresholds mean what they
    mean on a site of that many boxes, and their cost no longer grows with the boxes per frame
    (at 200 boxes a side the searches on every box took ~40 % of the calibration). None: no frame
    is crowded, every check on every box as before."""
    gated = gated_matches(ctx.frames, ctx.pairs, config.max_candidates)
    if gated is None:
        return None
    frames, pairs = gated
    _, iou = pair_metrics(frames, ctx.intr, ctx.pose.R, ctx.pose.t, pairs)
    return _View(frames, pairs, float(np.sum(iou)))


def _misfit(ctx: FitContext, best_score: float, config: CalibConfig, diag: CalibDiagnostics, frames_in,
            refusal: Refusal | None = None, searches: Deferred | None = None) -> Refusal | None:
    """Run the model-misfit checks (``misfit``); the first that flags becomes the refusal. A given
    focal length the matches cannot check refuses only a pose that ``refusal`` (the verdict's)
    and every misfit check let through. ``searches``: ``_misfit_searches`` of these inputs, started
    earlier by the caller (None: started here, while the other checks run)."""
    if searches is not None:
        return _misfit_checks(ctx, best_score, config, diag, frames_in, refusal, searches)
    with _misfit_searches(ctx, config, best_score) as searches:
        return _misfit_checks(ctx, best_score, config, diag, frames_in, refusal, searches)


def _lens_check(ctx: FitContext, places: int | None):
    """``misfit.lens_checks`` (a task of ``_misfit``'s deferred calls): (the lens check, the lens as
    the alternative cause when the focal-length / principal-point check fires). ``places``: the
    matched places, None: counted here (on the call's thread, not before the calls start)."""
    places = len(matched_places(ctx.frames, ctx.pairs)[0]) if places is None else places
    return lens_checks(ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise, ctx.f_scale, ctx.occlusion, places=places)


def _started(searches, k: int, fn, *args):
    """The refit started as ``searches``' call ``k`` (``_misfit_searches`` with ``refits``), or
    ``fn(*args)`` run here where the searches hold no such call."""
    return searches.result(k) if getattr(searches, "has", lambda _: False)(k) else fn(*args)


def _misfit_checks(ctx: FitContext, best_score: float, config: CalibConfig, diag: CalibDiagnostics, frames_in,
                   refusal: Refusal | None, searches: Deferred) -> Refusal | None:
    cframes, pairs, intr, pose, noise, f_scale, occlusion = (ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise,
                                                             ctx.f_scale, ctx.occlusion)
    found = []
    view = _search_view(ctx, config)  # crowded: the searches ran on this view, their flags compare on it
    s_score, s_frames, s_pairs = (best_score, cframes, pairs) if view is None else (view.score, view.frames, view.pairs)
    # a mirrored image first: it also bends the focal / principal-point fits, but is the cause to name
    flipped_score, flipped_matched, screened = searches.result(2)
    need = _mirror_need(s_frames, config)
    chk, msg = mirror_check(s_score, flipped_score, pose, (flipped_matched, need), screened)
    found.append((chk, msg, "misfit_mirrored"))
    chk, msg = unexplained_frames_check(cframes, pairs)
    found.append((chk, msg, "misfit_mixed_cameras"))
    places = len(matched_places(cframes, pairs)[0])
    # a fisheye given as pinhole bends the focal / principal-point fits too: the lens is the cause to name
    (chk_lens, msg), lens_alt = searches.result(1)
    found.append((chk_lens, msg, "misfit_lens"))
    width = None
    if not diag.selfcal.focal_estimated:  # an estimated focal length needs no check against the given one
        fit = _started(searches, 3, focal_fit, cframes, pairs, intr, pose, noise, f_scale, occlusion)
        chk, msg = focal_scale_check(fit, intr, n_matches=int(sum(len(p) for p in pairs)), places=places)
        if msg:  # the box model first: a detector's tight outline mimics a shorter focal length
            alt, note = focal_box_model(ctx, places)
            if alt is not None:  # checkability is then judged on the fit with the outline free
                chk, msg, fit = dataclasses.replace(chk, flagged=False, detail=chk.detail + note), None, alt
        found.append((chk, msg, "misfit_focal_length"))
        width = focal_width_check(fit, cframes, pairs, pose)
    time_chk, pp_unverifiable, pp_chk = None, None, None
    if config.time_offset is None:  # a fixed or estimated offset is already in the model
        times, unit = _frame_times(frames_in)
        time_chk = _started(searches, 4, _time_check, ctx, times, unit, config.seed, places)
    if config.refine_intrinsics != "focal+center":
        chk, msg = _started(searches, 5, _pp_check, ctx, config.seed, places, diag.selfcal.focal_estimated)
        if msg and time_chk is not None and time_chk[1]:
            # both fit: a shift that the fitted time offset, applied, leaves unflagged is the time
            # offset's doing (PandaSet's projected cuboids carry a real -0.05 s: 81 px otherwise). Only
            # ever clears the principal point -- the time-offset refusal stands
            shifted = time_shifted_frames(ctx, times, unit)
            if shifted is not None and principal_point_check(ctx.with_frames(shifted), seed=config.seed, places=places,
                                                             focal_free=diag.selfcal.focal_estimated)[1] is None:
                chk, msg = dataclasses.replace(chk, flagged=False, detail=chk.detail + "; explained by the fitted "
                                               "time offset (not flagged with it applied)"), None
        if (msg or "").startswith("not verifiable"):  # like an unverifiable focal: refuses only what nothing else did
            pp_unverifiable, msg, pp_chk = msg, None, chk
        found.append((chk, msg, "misfit_principal_point"))
    if time_chk is not None:
        found.append((*time_chk, "misfit_time_offset"))
    score2, n2, dist2, admissible2, screened = searches.result(0)
    chk, msg = second_pose_check(s_score, int(sum(len(p) for p in s_pairs)), score2, n2, dist2, admissible2, screened)
    found.append((chk, msg, "misfit_mixed_cameras"))
    diag.misfit = diag.misfit + [c for c, _, _ in found] + ([] if width is None else [width[0]])
    named = next((Refusal(code, m) for _, m, code in found if m), None)  # a misfit names the cause first
    if named is not None and named.code in ("misfit_focal_length", "misfit_principal_point") and lens_alt[1]:
        # the given pinhole is refused either way: name the lens when it explains the boxes better
        diag.misfit = [lens_alt[0] if c is chk_lens else c for c in diag.misfit]
        named = Refusal("misfit_lens", lens_alt[1])
    if named is None and pp_unverifiable and lens_alt[1]:
        # a principal-point shift the boxes cannot check, and a widened lens explains them better: a fisheye
        # given as pinhole or a pinhole's principal point off -- the boxes do not say which, so both are named
        diag.misfit = [lens_alt[0] if c is chk_lens else c for c in diag.misfit]
        named = Refusal("misfit_lens", _lens_or_principal_point(lens_alt[1], pp_unverifiable))
    if named is None and refusal is None and width is not None and width[1]:
        return Refusal("focal_unverifiable", width[1])  # only a pose nothing else refused
    if named is None and refusal is None and pp_unverifiable:
        part = _pp_unresolved_part(ctx, pp_chk, diag)
        if part is not None:  # route b: the bound decides (``_with_pp_part``)
            diag.uncertainty = dataclasses.replace(diag.uncertainty, principal_point=[float(v) for v in part])
            return None
        return Refusal("principal_point_unverifiable", pp_unverifiable)
    return named


def _pp_unresolved_part(ctx: FitContext, chk, diag: CalibDiagnostics):
    """The reported sigma's part for a given cx that the boxes do not resolve (``uncertainty.principal_point_part``)
    where the principal-point check is "not verifiable" only by its resolution rule (``misfit.pp_unresolved``)
    and the objects are counted (``MIN_OBJECTS``+: with fewer, the part's Jacobian rests on one or two objects
    and means nothing; the refusal stands); None otherwise."""
    if not pp_unresolved(chk) or diag.uncertainty.n_objects < MIN_OBJECTS:
        return None
    return principal_point_part(ctx)


def _with_pp_part(unc, ev: Evidence, config: CalibConfig, diag: CalibDiagnostics):
    """(``unc`` with the unresolved principal point's part, the verdict on it) where ``_misfit_checks`` put that
    part in ``diag.uncertainty`` (issue 26, route b): the pose is judged again with the part in its reported
    sigma (the 95 % bound decides: ``uncertain`` beyond the limits), the message naming the part."""
    part = diag.uncertainty.principal_point
    unc = with_principal_point(unc, part)
    diag.uncertainty = unc.parts
    refusal = verdict(dataclasses.replace(ev, rot_sd_total=unc.rot_sd, tr_sd_total=unc.tr_sd,
                                         parts=unc.parts), config)
    why = (f"a given cx that these detections cannot check moves the pose by {float(np.linalg.norm(part[:3])):.2f} deg / "
           f"{float(np.linalg.norm(part[3:])):.2f} m at 1-sigma (with the camera's rotation free they fix cx, or ask for a "
           "shift of it, only beyond the shift that turns the camera 1 deg: a turn moves the boxes almost as a shift of cx "
           "does, common with wide-angle lenses)")
    advice = ("give cx, cy from a calibration you trust and add frames in which objects pass nearer the image's left "
              "and right edges and at other depths")
    if refusal is not None and refusal.code == "uncertain":
        refusal = Refusal("uncertain", f"too uncertain: the frames agree on the pose at the given principal point, but "
                          f"{why}; with that in its sigma the pose's 95 % bound is {bound95(unc.rot_sd):.2f} deg / "
                          f"{bound95(unc.tr_sd):.2f} m (limit {config.max_rot_bound_deg:g} deg / "
                          f"{config.max_trans_bound_m:g} m); {advice}")
    elif refusal is not None:
        refusal = Refusal(refusal.code, refusal.message + f" (the sigma includes the principal point's part: {why})")
    return unc, refusal


def _lens_or_principal_point(lens_msg: str, pp_msg: str) -> str:
    """The refusal message where the lens alternative fired beside a principal-point check that could
    only say "not verifiable" (no flagged shift): two causes the boxes do not tell apart. A pinhole
    whose principal point is off but unresolved also lets a widened lens fit better (session 14, G: the
    review's cx +3 % W detector-outline site, a pinhole, was refused with only the lens message, "a
    fisheye or wide-angle camera given as pinhole?"), so the message names the principal point first
    and the lens as the other cause; the refusal code stays ``misfit_lens``."""
    return (f"model misfit: the given principal point cannot be checked, and a wider-angle lens explains the boxes "
            f"better than the given pinhole -- either the principal point (cx, cy) is off or the camera is a "
            f"fisheye / wide-angle lens given as pinhole. Principal point: {pp_msg.rstrip('.')}. Lens: {lens_msg}")


def _motion(frames_in, cframes, config: CalibConfig, diag: CalibDiagnostics) -> tuple[list, BoxMotion | None, str]:
    """Object motion when a time offset is asked for; a fixed offset moves the 3D boxes now.
    Returns (frames, motion or None, refusal message or "")."""
    if config.time_offset is None:
        return cframes, None, ""
    motion = box_motion(frames_in, cframes)
    sc = diag.selfcal
    sc.time_offset_mode, sc.stamp_offset_s = str(config.time_offset), motion.stamp_offset_s
    sc.velocity_source, sc.ego_motion = motion.source, motion.ego_motion
    if not isinstance(config.time_offset, float):
        return cframes, motion, ""
    if motion.problem:
        return cframes, motion, f"time_offset={config.time_offset:g} s cannot be applied: {motion.problem}"
    sc.time_offset_s, sc.time_offset_source = config.time_offset, "fixed"
    return shift_frames(cframes, motion.velocity, config.time_offset), motion, ""


def _selfcal_note(diag: CalibDiagnostics) -> str:
    """What was estimated with the pose (appended to a refusal: it widens the pose's uncertainty)."""
    sc, bits = diag.selfcal, []
    if sc.focal_estimated:
        bits.append(f"focal length x{sc.focal_scale:.4f} of the given (1-sigma {100 * (sc.focal_scale_std or 0):.1f} %)")
    if sc.time_offset_source == "estimated":
        bits.append(f"time offset {1e3 * sc.time_offset_s:+.1f} ms (1-sigma {1e3 * (sc.time_offset_std_s or 0):.1f} ms)")
    return f" [estimated with the pose: {'; '.join(bits)}; with exact values given the pose may be determined]" \
        if bits else ""


def _calibrate(frames_in: list, intr_in, config: CalibConfig, matcher, prior: Pose | None,
               progress: Progress | None) -> CalibrationResult:
    t0 = time.perf_counter()
    cframes, intr, problem = prepare_frames(frames_in, intr_in, reestimate_yaw=config.reestimate_yaw,
                                            box_model=config.box_model, workers=config.workers,
                                            scores=config.detector_scores)
    diag = CalibDiagnostics(n_2d=sum(f.n2 for f in cframes), n_3d=sum(f.n3 for f in cframes),
                            max_baseline_m=config.max_baseline_m)
    diag.selfcal.intrinsics_mode, diag.selfcal.intrinsics_given = config.refine_intrinsics, intr.to_dict()
    if problem:
        return _refused(Refusal("mixed_cameras", problem), intr, cframes, config, diag)
    cframes, motion, why = _motion(frames_in, cframes, config, diag)
    if why:
        return _refused(Refusal("time_offset", why), intr, cframes, config, diag)
    pre = precheck(cframes)
    if pre is None and config.misfit_check:  # boxes in a wrong frame: named before any search
        chk, msg = box_frame_check(cframes)
        diag.misfit = [chk]
        pre = Refusal("misfit_box_frame", msg) if msg else None
    if pre is not None:
        return _refused(pre, intr, cframes, config, diag)
    hyps = _search(cframes, frames_in, intr, config, matcher, prior, diag, progress)
    if len(hyps) == 0:
        return _refused(Refusal("no_hypothesis", "not identifiable: no 3 detections seen by both sensors form a "
                                "consistent, non-collinear triangle (objects on one line, or too few objects)"),
                        intr, cframes, config, diag)
    diag.n_hypotheses = int(len(hyps))
    cand = distinct_best(hyps, config.max_refine * 2 if diag.sparse_search else config.max_refine)
    diag.bringup_T = Pose(cand.R[0], cand.t[0]).T.tolist()
    occlusion = CostSpec.from_config(config)  # the box-edge shaping and the config's cost terms, for every fit
    ref = _refine_candidates(cframes, intr, cand, occlusion, progress, config.workers, config.max_candidates)
    # several workers: the misfit checks' searches start now, before the box-model choice and the
    # self-calibration, at the pose they start from; kept when neither changes the frames, the intrinsics
    # or the candidates (the pose is then this one), else given up (``_kept``)
    early = _early_searches(frames_in, (cframes, intr, ref), occlusion, config, diag) \
        if config.misfit_check and resolve_workers(config.workers) > 1 else None
    cframes, ref = _choose_box_model(cframes, intr, cand, ref, occlusion, config, diag, progress)
    inflation, focal_box = None, None
    if wants_selfcal(config):
        choice = decide_selfcal(cframes, intr, Pose(ref.best.R, ref.best.t), config, motion, occlusion, diag.selfcal)
        diag.selfcal = choice.diag
        if choice.refusal:
            _kept(early, None, ())
            return _refused(Refusal("selfcal", choice.refusal), intr, cframes, config, diag)
        focal_box = choice.box_model  # (also where "auto" kept the given focal length by the box model)
        if choice.intr is not intr or choice.frames is not cframes:
            # every candidate again with the estimated intrinsics / moved 3D boxes (a fair runner-up)
            cframes, intr, inflation = choice.frames, choice.intr, choice.inflation
            joint = Hypotheses(choice.pose.R[None], choice.pose.t[None], np.zeros(1), np.zeros(1, dtype=np.int64))
            ref = _refine_candidates(cframes, intr, Hypotheses.concat([joint, cand]), occlusion, progress,
                                     config.workers, config.max_candidates)
    best, pose = ref.best, Pose(ref.best.R, ref.best.t)
    diag.score, diag.runner_up_score = ref.best_score, _runner_up(ref, config.max_baseline_m)
    diag.refine_history, diag.noise_model = list(best.history), best.noise
    diag.candidates = [CandidateSummary(s, *Pose(r.R, r.t).error(pose), float(np.linalg.norm(r.t)))
                       for s, r in [(ref.best_score, best)] + ref.others]
    diag.bringup_error_vs_final = list(Pose.parse(np.asarray(diag.bringup_T)).error(pose))

    pairs = match_all(cframes, intr, pose.R, pose.t, gate_iou=config.gate_iou)
    f_scale = max(0.5, 1.5 * float(np.median(np.abs(best.residuals)))) if len(best.residuals) else 2.0
    track_ids = _track_ids(frames_in, cframes)
    fit = FitContext(cframes, pairs, intr, pose, best.noise, f_scale, occlusion)
    # the misfit checks' searches start now on the other cores (workers > 1), beside the uncertainty and
    # the verdict (one worker: they run only when the checks ask for them); closed before returning
    refits = (*_frame_times(frames_in), diag.selfcal.focal_estimated)  # the checks' refits start with the searches
    searches = _kept(early, (cframes, intr, ref), refits) or \
        (_misfit_searches(fit, config, ref.best_score, refits) if config.misfit_check else None)
    unc = estimate_uncertainty(fit,
                               mode=config.uncertainty, track_ids=track_ids, seed=config.seed,
                               floor=inflation)
    # each object's own outline (a detector's box of this car vs that one): random effects, fitted
    # where the objects differ beyond the edge noise; the pose moves to that fit (matches held)
    obj_fit = fit_object_outline(cframes, pairs, intr, pose, best.noise, f_scale, occlusion,
                                 object_groups(cframes, pairs, track_ids=track_ids))
    pose_plain = pose
    if obj_fit is not None and not obj_fit.shift_significant(pose_plain) and obj_fit.sd_plain is not None:
        # the plain pose kept: its sigma counts the objects' outline errors its edges share
        unc = with_object_outline(unc, obj_fit.sd_plain)
    elif obj_fit is not None and obj_fit.shift_significant(pose_plain):  # the plain pose is biased beyond its noise
        unc = with_object_outline(unc, obj_fit.sd)
        pose = obj_fit.pose
        fit = fit.with_pose(pose)
        if searches is not None:  # searched from the plain pose: again from the moved one (those given up)
            searches.cancel()
            searches = _misfit_searches(fit, config, ref.best_score, refits)
    unc = with_focal_box_model(unc, focal_box)  # the focal choice's box-model part: the reported sigma only
    px, ious = pair_metrics(cframes, intr, pose.R, pose.t, pairs)
    diag.uncertainty = unc.parts  # its selfcal part: the pose spread the estimated intrinsics / offset add
    # a runner-up within 2 sigma of the best is the same solution (the decision then bounds the
    # error by 2 sigma); only one beyond that is a competing explanation
    runner = _runner_up(ref, config.max_baseline_m, 2 * float(np.linalg.norm(unc.rot_sd_data)),
                        2 * float(np.linalg.norm(unc.tr_sd_data)))
    diag.ambiguity_runner_up_score = runner
    n_pairs = int(sum(len(p) for p in pairs))
    diag.max_pairs_per_frame = int(max((len(p) for p in pairs), default=0))
    places, off = (np.zeros((0, 3)), np.zeros(0))
    if diag.max_pairs_per_frame < 3:
        places, off = matched_places(cframes, pairs)
        diag.matched_places, diag.matched_places_off_line = int(len(places)), int(np.sum(off > POOLED_OFF_LINE_M))
    diag.box_fit = {"outline": diag.box_model or "corners", "px_hulls_corners": diag.box_model_px,
                    **fit_outline(cframes, pairs, intr, pose, best.noise, f_scale, occlusion,
                                  outline_fit(fit) if occlusion is not None else None)}
    if obj_fit is not None:
        diag.box_fit["objects"] = obj_fit.summary(pose_plain)
    centre_off = _centre_offsets(cframes, intr, pose.R, pose.t, pairs)
    diag.centre_offset_px_median = float(np.median(centre_off)) if len(centre_off) else None
    diag.frames = _frame_summaries(cframes, intr, pose.R, pose.t, pairs)
    ev = Evidence(n_pairs=n_pairs, n_2d=diag.n_2d, most_per_frame=diag.max_pairs_per_frame,
                               places=len(places), places_off_line=int(np.sum(off > POOLED_OFF_LINE_M)),
                               halves_available=unc.halves_available, best_score=ref.best_score,
                               runner_up_score=runner, rot_sd=unc.rot_sd_data, tr_sd=unc.tr_sd_data,
                               rot_sd_total=unc.rot_sd, tr_sd_total=unc.tr_sd,
                               n_objects=unc.parts.n_objects if config.uncertainty != "frames" else None,
                               **_objects_sd(unc.parts, config), **_beyond_noise_sd(unc.parts, config),
                               parts=unc.parts)
    refusal = verdict(ev, config)
    if refusal is None and prior is None:
        refusal = crowded_check(cframes, config, n_pairs / max(diag.n_2d, 1))
    if config.misfit_check and (refusal is None or refusal.code in _MISFIT_CAN_EXPLAIN):
        # a refusal that a model misfit explains is replaced by the misfit's message (it names the cause)
        refusal = _misfit(fit, ref.best_score, config, diag, frames_in, refusal, searches) or refusal
        if refusal is None and diag.uncertainty.principal_point is not None:
            unc, refusal = _with_pp_part(unc, ev, config, diag)
    if searches is not None:
        searches.cancel()  # (what was not asked for is given up: not started, or ended at its next parallel stage)
    if refusal is not None and inflation is not None:
        refusal = Refusal(refusal.code, refusal.message + _selfcal_note(diag))
    diag.refusal = "" if refusal is None else refusal.code
    if refusal is not None:  # kept for diagnostics only: a failed result has no pose (as the reference)
        diag.refused_T = make_transform(pose.R, pose.t).tolist()
    diag.elapsed_s = time.perf_counter() - t0
    caller_pairs = [np.column_stack([f.idx2d[p[:, 0]], f.idx3d[p[:, 1]]]) if len(p) else np.zeros((0, 2), np.int64)
                    for f, p in zip(cframes, pairs)]
    return _result(
        refusal is None, "" if refusal is None else refusal.message, intr, cframes, config, diag,
        accepted=refusal is None, rotation=pose.R if refusal is None else None,
        translation=pose.t if refusal is None else None, n_correspondences=n_pairs,
        n_inliers=int(np.sum(ious >= 0.5)), reproj_error_px=float(np.mean(px)) if len(px) else float("inf"),
        residual_px_median=float(np.median(px)) if len(px) else float("nan"),
        iou_median=float(np.median(ious)) if len(ious) else float("nan"),
        iou_mean=float(np.mean(ious)) if len(ious) else float("nan"),
        rotation_std_deg=unc.rot_sd, translation_std_m=unc.tr_sd, pairs=caller_pairs,
        camera_name=next((f.camera for f in cframes if f.camera), ""), image_size=cframes[0].size)


def calibrate(frames, intrinsics=None, config: CalibConfig | None = None, *args, matcher=None, prior=None,
              progress: Progress | None = None, **legacy_kwargs) -> CalibrationResult:
    """Estimate ``T_cam_lidar`` from detections over one or many frames of one static rig.

    Args:
        frames: ``xcalib.types.Frame``s or (image, point_cloud, bboxes_2d, bboxes_3d) tuples
            (LiDAR frame, metres; pixels): a list, an iterable, or an indexable sequence read
            lazily (only the frames used are kept). More than ``config.max_frames`` frames: the
            informative ones are used (``selection``; ``diagnostics.selection`` says which and
            how many objects; ``pairs`` still has one entry per given frame). The reference's single-frame form
            ``calibrate(image, point_cloud, bboxes_2d, bboxes_3d, intrinsics)`` is accepted too.
        intrinsics: ``CameraIntrinsics`` / 3x3 K (None: taken from the frames).
        config: :class:`CalibConfig` (None: the defaults). The older keyword arguments
            (``gate=``, ``max_rot_std_deg=``, ...) are mapped onto it; unknown ones raise TypeError.
        matcher: optional object with ``match(image, pc, b2, b3) -> MatchResult``; its
            similarities only rank candidate pairs (geometry decides).
        prior: optional initial pose (``CalibrationResult``, (R, t) or 4x4): skips the bring-up.
        progress: optional callback(stage, done, total).
    Returns:
        ``CalibrationResult`` (with ``config`` and ``diagnostics``); ``success=False`` with a
        ``message`` when the inputs do not determine the pose or the model does not fit them.
        Raises ValueError for impossible intrinsics or malformed inputs.
    """
    if isinstance(frames, np.ndarray) and frames.ndim == 3 and config is not None and len(args) >= 1:
        # reference form: calibrate(image, point_cloud, bboxes_2d, bboxes_3d[, intrinsics])
        intr_arg = args[1] if len(args) > 1 else legacy_kwargs.pop("K", None)
        return calibrate_single(frames, intrinsics, config, args[0], intr_arg, matcher=matcher, prior=prior,
                                **legacy_kwargs)
    if args:
        raise TypeError("calibrate(frames, intrinsics, config=None, *, ...): unexpected positional arguments")
    if config is not None and not isinstance(config, CalibConfig):
        raise TypeError(f"calibrate: config must be a CalibConfig, got {type(config).__name__}")
    config = CalibConfig.from_kwargs(config, **legacy_kwargs) if legacy_kwargs else (config or CalibConfig())
    prior_pose = None if prior is None else Pose.parse(prior, "prior")
    frames_in, selection = _selected_frames(frames, intrinsics, config, progress)
    with WorkerPool(config.workers):  # one pool of processes for every parallel stage of this call (and its retries)
        res = _calibrate_retry(frames_in, intrinsics, config, matcher, prior_pose, progress)
        res = _deliver_time_offset(res, frames_in, intrinsics, config, (matcher, prior_pose, progress))
    return _with_selection(res, selection)


def _indexable(frames) -> bool:
    return hasattr(frames, "__len__") and hasattr(frames, "__getitem__") and not isinstance(frames, (dict, str))


def _selected_frames(frames, intrinsics, config: CalibConfig, progress: Progress | None) -> tuple[list, FrameSelection]:
    """The frames the calibration uses (``selection``: up to ``config.max_frames`` informative ones)
    and the selection. An indexable sequence (a recording read lazily) is read one frame at a time
    and only the chosen frames are kept; anything else is listed first."""
    seq = frames if _indexable(frames) else list(frames)
    if not isinstance(seq, list) and (config.max_frames is None or len(seq) <= config.max_frames):
        seq = [seq[i] for i in range(len(seq))]  # every frame is used: read each once
    if len(seq) == 0:
        raise ValueError("frames: expected at least one frame, got an empty sequence")
    size = (getattr(intrinsics, "width", None), getattr(intrinsics, "height", None))
    boxes = scan_frames(seq, size if None not in size else None,
                        progress if progress is not None and len(seq) > (config.max_frames or len(seq)) else None)
    budget = config.max_frames
    if budget is not None and config.time_offset is not None and len(seq) > budget:
        budget = max(1, budget // 2)  # each chosen frame with its successor: object velocities from tracks
    sel = select_frames(boxes, budget)
    if budget != config.max_frames and not sel.all_used:
        idx = np.unique(np.r_[sel.indices, np.minimum(sel.indices + 1, len(seq) - 1)])
        sel = dataclasses.replace(sel, indices=idx, max_frames=config.max_frames)
    if sel.all_used:
        return (seq if isinstance(seq, list) else [seq[i] for i in range(len(seq))]), sel
    return [seq[int(i)] for i in sel.indices], sel  # a lazy sequence: only the chosen frames read again


def _with_selection(res: CalibrationResult, sel: FrameSelection) -> CalibrationResult:
    """The selection in the result: ``diagnostics.selection``, and ``pairs`` one entry per *given*
    frame (frames not used: none), so they line up with the caller's frames."""
    if res.diagnostics is not None:
        res.diagnostics.selection = FrameSelectionSummary(
            n_frames_given=sel.n_given, n_frames_used=sel.n_used, n_objects=sel.n_objects,
            n_objects_used=sel.n_objects_used, object_identity=sel.identity, max_frames=sel.max_frames,
            used_indices=[int(i) for i in sel.indices] if not sel.all_used else [], elapsed_s=sel.elapsed_s)
    if not sel.all_used and len(res.pairs) == sel.n_used:
        full = [np.zeros((0, 2), np.int64) for _ in range(sel.n_given)]
        for j, i in enumerate(sel.indices):
            full[int(i)] = res.pairs[j]
        res.pairs = full
    return res


def _calibrate_retry(frames_in: list, intrinsics, config: CalibConfig, matcher, prior_pose: Pose | None,
                     progress: Progress | None) -> CalibrationResult:
    """``_calibrate``, and once more without ``max_baseline_m`` when that assumption may be what failed."""
    res = _calibrate(frames_in, intrinsics, config, matcher, prior_pose, progress)
    if not res.success and config.max_baseline_m is not None and prior_pose is None \
            and res.diagnostics.refusal not in ("mixed_cameras", "too_few_detections", "collinear_3d", "collinear_2d") \
            and not res.diagnostics.refusal.startswith("misfit") and res.diagnostics.refusal not in ("crowded", "few_objects", "focal_unverifiable",
                                                                             "principal_point_unverifiable") \
            and res.diagnostics.uncertainty.principal_point is None:
        # (a bound that fails by the unresolved principal point's part is no co-location question either)
        # the co-located-rig assumption may be wrong (e.g. boxes in a global frame): search again
        retry = _calibrate(frames_in, intrinsics, config.replace(max_baseline_m=None), matcher, None, progress)
        if retry.success or res.diagnostics.refusal == "no_hypothesis":
            return retry
    return res


#: refusals after which a default run is retried with the time offset estimated: the time-offset misfit,
#: and a focal-length / principal-point misfit found together with a flagged time-offset check (an
#: offset bends those fits too: realism time-offset sites refused as such, the time check at 9-30 sigmas)
TIME_TRIGGERS = ("misfit_time_offset", "misfit_focal_length", "misfit_principal_point")
_MISFIT_NAMES = {"misfit_focal_length": "focal-length", "misfit_principal_point": "principal-point"}


def _deliver_time_offset(res: CalibrationResult, frames_in: list, intrinsics, config: CalibConfig,
                         rest: tuple) -> CalibrationResult:
    """Deliver when the data allow: a default run (no ``time_offset`` asked for) refused because the
    sensors are out of time (``misfit_time_offset``: a significant fitted offset that moves the
    moving objects), on frames that carry LiDAR timestamps, is calibrated once more with the offset
    estimated with the pose (``time_offset="auto"``: used only when object motion determines it
    within ``config.time_offset_max_std_s``). That run's success is delivered when the offset it used
    is itself significant (beyond ``TIME_SIGMAS`` of its 1-sigma). A refusal as a focal-length or
    principal-point misfit is retried the same way when the default run's time-offset check flagged
    too (``TIME_TRIGGERS``): the retry runs every misfit check again with the offset in the model,
    so it succeeds only when the offset explains what those checks found. The result names the
    offset, its 1-sigma, why it was estimated and which other check it explained (``message``,
    ``summary()``, ``selfcal.time_offset_trigger``).
    Otherwise the refusal stands, saying what the estimate gave. The run with the offset estimated
    is the one the refusal's advice asks for, with every check it has: nothing is accepted here that
    following the advice would not accept. ``rest``: (matcher, prior pose, progress)."""
    d = res.diagnostics
    if res.success or d is None or config.time_offset is not None or _frame_times(frames_in)[1] != "s":
        return res
    check = next((c for c in d.misfit if c.name == "time_offset" and c.flagged), None)
    if d.refusal not in TIME_TRIGGERS or (d.refusal != "misfit_time_offset" and check is None):
        return res
    est = _calibrate_retry(frames_in, intrinsics, config.replace(time_offset="auto"), *rest)
    sc = None if est.diagnostics is None else est.diagnostics.selfcal
    used = sc is not None and sc.time_offset_source == "estimated" and sc.time_offset_s is not None
    significant = used and abs(sc.time_offset_s) > TIME_SIGMAS * (sc.time_offset_std_s or np.inf)
    if est.success and significant:
        also = "" if d.refusal == "misfit_time_offset" else f" (with {d.refusal}: explained by the offset)"
        sc.time_offset_trigger = "misfit_time_offset" + also + (f": {check.detail}" if check is not None else "")
        est.message = (f"the sensors are out of time: the camera-LiDAR time offset was estimated with the pose, "
                       f"{1e3 * sc.time_offset_s:+.1f} ms (1-sigma {1e3 * sc.time_offset_std_s:.1f} ms; the default "
                       "run's time-offset check found the 3D boxes fit best moved along their motion"
                       + ("" if not also else f", and the {_MISFIT_NAMES[d.refusal]} misfit it also found passes with "
                          "the offset applied") + "). Check the sensors' timestamps; give the offset "
                       "(time_offset=seconds) once it is known")
        return est
    why = est.message if not est.success else (
        "the offset was not used (too few moving objects to determine it)" if not used else
        f"the offset estimated with the pose ({1e3 * sc.time_offset_s:+.1f} ms, 1-sigma "
        f"{1e3 * (sc.time_offset_std_s or 0):.1f} ms) is not significant")
    res.message = f"{res.message}. Estimating the offset with the pose was tried and did not deliver: {why}"
    return res


_REFERENCE_ONLY = ("match_threshold", "ransac_reproj_px", "validate")


def calibrate_single(image, point_cloud, bboxes_2d, bboxes_3d, intrinsics, config: CalibConfig | None = None, *,
                     matcher=None, prior=None, **kwargs) -> CalibrationResult:
    """The reference's one-frame form: ``calibrate_single(image, pc, b2, b3, K)`` -> CalibrationResult.

    Same pipeline as :func:`calibrate` on a single frame (best-effort: one frame often leaves the
    pose ambiguous, which is then reported as a failure, not guessed). The reference's
    ``match_threshold``, ``ransac_reproj_px`` and ``validate`` keywords are accepted and ignored
    (matcher scores only rank candidates here; geometry decides).
    """
    for k in _REFERENCE_ONLY:
        kwargs.pop(k, None)
    return calibrate([(image, point_cloud, bboxes_2d, bboxes_3d)], intrinsics, config, matcher=matcher, prior=prior,
                     **kwargs)
