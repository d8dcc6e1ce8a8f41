"""Bring-up: pose hypotheses with no initial guess, from the detections alone.

:func:`pose_hypotheses` is the public entry point (also used by geometric matching for
unknown sites): box triples per frame (``hypotheses.frame_hypotheses``), pooled over frames and
re-scored on all frames by how well every projected 3D box explains the 2D boxes; with too few
rich frames, triples also mix frames spread over the recording (``pooled_groups``: one static
rig, so pairs of different frames are rigidly consistent too). :func:`distinct_best` keeps the
best distinct ones for refinement.
"""

from __future__ import annotations

import inspect
import logging
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from ..geometry.camera import CameraIntrinsics
from .config import CalibConfig
from .densegate import front_view, lidar_view
from .hypotheses import (Hypotheses, TripleSearch, draw_triples, frame_hypotheses, informative_view, score_poses,
                         solve_triples, triple_miss_bound)
from .inputs import CalibFrame, lean_frames
from .parallel import Stream, Workers, chunks, parallel_map, resolve_workers
from .pose import Pose

__all__ = ["BringUp", "pose_hypotheses", "distinct_best", "pooled_groups", "matcher_similarities", "gated_frames",
           "gated_matches", "unoccluded_frames"]

log = logging.getLogger("xcalib.calib")

SPARSE_SCENE_MAX_2D = 80  # with at most this many 2D boxes in all, search (nearly) exhaustively
#: with a requested support, the pooled groups are skipped where the search over every frame misses a
#: pose of that support with at most this probability (``hypotheses.triple_miss_bound``)
SEARCH_MISS = 0.01


@dataclass
class BringUp:
    """Pose hypotheses scored on all frames, and how the search went."""

    hyps: Hypotheses
    sparse_search: bool = False
    pooled_search: bool = False
    split_searches: int = 0
    #: pooled groups not searched: the search over every frame already finds a pose of the
    #: requested support with probability >= 1 - ``SEARCH_MISS`` (see ``pose_hypotheses``' ``support``)
    pooled_skipped: int = 0


def matcher_similarities(matcher, frames_in, cframes: list[CalibFrame]) -> list[np.ndarray | None]:
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


def pooled_groups(frames: Sequence[CalibFrame], n_groups: int = 3, per_group: int = 24,
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


def _search_groups(cframes: Sequence[CalibFrame], max_hyp_frames: int) -> tuple[list[list[int]], int, bool]:
    """(frame groups to search, how many of them are per-frame/sparse groups, sparse scene?)."""
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
    sparse_scene = sum(f.n2 for f in cframes) <= SPARSE_SCENE_MAX_2D
    if sparse_scene:
        groups.append([i for i, f in enumerate(cframes) if f.n2 and f.n3])
    n_before = len(groups)
    # too few rich frames (4+ detections of each kind): extra groups pooled across the whole
    # recording; their hypotheses only add to the per-frame ones
    if sum(min(f.n2, f.n3) >= 4 for f in cframes) < max_hyp_frames:
        groups += pooled_groups(cframes, every_max=0 if sparse_scene else 80)
    return groups, n_before, sparse_scene


#: the search's gate on crowded frames (more than twice ``max_candidates`` box pairs): the largest
#: 2D boxes it searches and scores with (``hypotheses.informative_view``)
GATE_2D = 24


def _gated(cframes: Sequence[CalibFrame], sims: list, max_candidates: int):
    """The frames (and matcher similarities) the search sees: each crowded frame (n2 x n3 above
    twice ``max_candidates``) through the gate, the others as they are."""
    out, out_sims = [], []
    for fr, sm in zip(cframes, sims):
        if fr.n2 * fr.n3 > 2 * max_candidates:
            fr, rows = informative_view(fr, GATE_2D)
            sm = None if sm is None else np.asarray(sm)[rows]
        out.append(fr)
        out_sims.append(sm)
    return out, out_sims


def gated_frames(cframes: Sequence[CalibFrame], max_candidates: int) -> list[CalibFrame] | None:
    """The frames with each crowded one (n2 x n3 above twice ``max_candidates``) seen through the
    search's gate (its ``GATE_2D`` most informative 2D boxes, every 3D box), or None when no frame
    is crowded. The candidates' quick refinements use it: their job is to rank the candidates and
    bring them near their optimum, which ~``GATE_2D`` well-separated boxes per frame do as well as
    all of them, at a cost that no longer grows with the boxes (the finalists are refined on every
    box). Frames that are not crowded are the same objects, so nothing changes for them."""
    if not any(fr.n2 * fr.n3 > 2 * max_candidates for fr in cframes):
        return None
    return _gated(cframes, [None] * len(cframes), max_candidates)[0]


def unoccluded_frames(cframes: Sequence[CalibFrame], max_candidates: int) -> list[CalibFrame] | None:
    """The frames with each crowded one (n2 x n3 above twice ``max_candidates``) cut to the boxes
    whose matches are unambiguous at a busy junction: its front 2D boxes (``densegate.front_view``,
    at most ``GATE_2D``) and the 3D boxes the LiDAR sees unoccluded (``densegate.lidar_view``); None
    when no frame is crowded. The finalists' full refinement also starts from a fit on it
    (``api._full_refine``): on all boxes of a dense frame the matching aliases (a pose 1-4 deg / 1-3 m
    off still finds a box near most projections) and the fit can stop in that local minimum, which
    the few unambiguous boxes do not share."""
    if not any(fr.n2 * fr.n3 > 2 * max_candidates for fr in cframes):
        return None
    return [lidar_view(front_view(fr, GATE_2D)[0]) if fr.n2 * fr.n3 > 2 * max_candidates else fr for fr in cframes]


def gated_matches(cframes: Sequence[CalibFrame], pairs: list[np.ndarray],
                  max_candidates: int) -> tuple[list[CalibFrame], list[np.ndarray]] | None:
    """:func:`gated_frames` with the matches ``pairs`` (per frame [n,2] rows) that fall on the
    gate's 2D boxes, renumbered to the view's rows; None when no frame is crowded. The misfit
    refits that cost one fit each over all matches (the lens check) use it on crowded sites: the
    ``GATE_2D`` well-separated boxes of every frame are as many matches as the sites the checks
    were designed on have in all (A9: 16 frames, ~150), and their statistics are per match or per
    object, so their thresholds mean the same on the view."""
    if not any(fr.n2 * fr.n3 > 2 * max_candidates for fr in cframes):
        return None
    frames, out = [], []
    for fr, p in zip(cframes, pairs):
        if fr.n2 * fr.n3 <= 2 * max_candidates:
            frames.append(fr)
            out.append(p)
            continue
        view, rows = informative_view(fr, GATE_2D)
        keep = np.isin(p[:, 0], rows)
        q = p[keep].copy()
        q[:, 0] = np.searchsorted(rows, q[:, 0])
        frames.append(view)
        out.append(q)
    return frames, out


def search_cost(n_windows: int, crowded: bool) -> int:
    """What one frame's search (drawn in ``n_windows`` azimuth windows) spends of the bring-up's
    budget of ``max_hyp_frames`` searches: a
    search of at most ``max_candidates`` candidate pairs costs one, and a crowded frame (through the
    gate, still above ``max_candidates`` pairs: a 360-degree LiDAR's boxes all around) is split
    into azimuth windows, each a search of its own (``hypotheses.frame_hypotheses``), so it costs
    its windows. The per-frame searches stop once the budget is spent (at least one frame is
    searched): the bring-up's cost is that of ``max_hyp_frames`` plain searches however many boxes
    a frame holds, where ten crowded frames of six windows each cost six times the budget. Frames
    that are not crowded cost one each, so their search is the same as before."""
    return max(1, int(n_windows)) if crowded else 1


def pose_hypotheses(cframes: Sequence[CalibFrame], intr: CameraIntrinsics, config: CalibConfig = CalibConfig(), *,
                    similarities: list | None = None, max_baseline_m: float | None = None,
                    rng: np.random.Generator | None = None,
                    progress: Callable[[str, int, int], None] | None = None, support: int | None = None) -> BringUp:
    """Pose hypotheses (LiDAR -> camera) from the detections of ``cframes``, scored on every frame.

    ``similarities``: optional per-frame [K,M] matcher scores (rows/cols of the CalibFrames) that
    rank candidate pairs; ``max_baseline_m`` overrides ``config.max_baseline_m`` (None in the
    config means never assume a co-located rig). Memory is bounded by ``config.max_candidates``.
    ``support``: only poses that at least this many box pairs agree with are wanted (a caller that
    ignores the others, e.g. the second-pose search: ``misfit.second_pose_support``). In a sparse
    scene the pooled groups (subsets of the frames of the search over every frame, drawn after it)
    are then drawn only while that search's miss bound for such a pose (``hypotheses.triple_miss_bound``, one
    azimuth window, no matcher priors) is above ``SEARCH_MISS``: where it is not, they would add
    hypotheses for a pose that the search over every frame finds with probability >= 99 % already.
    """
    rng = np.random.default_rng(config.seed) if rng is None else rng
    sims = [None] * len(cframes) if similarities is None else list(similarities)
    crowded = [fr.n2 * fr.n3 > 2 * config.max_candidates for fr in cframes]
    cframes, sims = _gated(cframes, sims, config.max_candidates)
    groups, n_before, sparse_scene = _search_groups(cframes, config.max_hyp_frames)
    workers = resolve_workers(config.workers)
    lean = lean_frames(cframes) if workers > 1 else cframes
    jobs, budget, covered, skipped = [], config.max_hyp_frames, False, 0
    # each search's triples are drawn here (every random number, in order) and solved as a task that
    # starts as soon as it is drawn (several workers: while the next one is drawn; one: all after the
    # draws, in order) -- the same hypotheses whatever the number
    with Stream(_solve_job, workers) as stream:
        for k, g in enumerate(groups):
            if k < n_before and len(g) == 1 and crowded[g[0]] and budget <= 0:
                continue  # the per-frame searches' budget is spent (see ``search_cost``)
            if k >= n_before and covered:
                skipped += 1  # the search over every frame already finds a pose of the support wanted
                continue
            gs = [sims[i] for i in g]
            big = (sparse_scene or k >= n_before) and len(g) > 1
            # closed_form: each triple's Kabsch fit without an SVD (``hypotheses.kabsch_triangles``, the same
            # poses to ~1e-12, 2.5x faster; the search's largest cost on sparse leftovers)
            everywhere = support is not None and sparse_scene and k == n_before - 1  # (the search over every frame)
            search = TripleSearch(max_baseline_m=max_baseline_m, max_candidates=config.max_candidates,
                                  closed_form=True, miss_stats=everywhere)
            wide = replace(search, max_triples=20000 if big else 3000, keep=60 if big else 25)
            frs = [lean[i] for i in g]
            draw = draw_triples(frs, intr, prior_sims=gs, rng=rng, search=wide)
            if k < n_before and len(g) == 1:
                budget -= search_cost(draw.n_windows, crowded[g[0]])
            if everywhere:
                covered = _covers(draw, support)
            if any(x is not None for x in gs):  # matcher priors: solved now (a search without them may follow)
                h = solve_triples(frs, intr, g[0], draw, wide)
                if len(h) == 0:
                    h = frame_hypotheses(frs, intr, g[0], rng=rng, search=search)
                jobs.append(h)
            else:
                stream.put((frs, intr, g[0], draw, wide))
                jobs.append(None)  # (the stream's next result)
        solved = iter(stream.results())
        found = [next(solved) if h is None else h for h in jobs]
    splits = sum(int(getattr(h, "n_searches", 1) > 1) for h in found)
    if progress:  # (the searches are solved together: reported once they are)
        for k in range(len(groups)):
            progress("hypotheses", k + 1, len(groups))
    hyps = Hypotheses.concat(found)
    if len(hyps):  # re-scored on every frame (static rig: one pose explains all), summed frame by frame
        hyps.score = sum(frame_scores(lean, intr, hyps.R, hyps.t, workers))
    return BringUp(hyps, sparse_search=bool(sparse_scene), pooled_search=len(groups) > n_before + skipped,
                   split_searches=splits, pooled_skipped=skipped)


def _covers(draw, support: int) -> bool:
    """Whether a drawn search (one azimuth window, no matcher priors) misses a pose that ``support``
    of its candidate pairs agree with with probability <= ``SEARCH_MISS`` (``triple_miss_bound``)."""
    if draw.have_prior or draw.n_windows != 1 or not draw.pair_stats:
        return False
    return triple_miss_bound(support, draw.pair_stats[0]) <= SEARCH_MISS


def frame_scores(frames: Sequence[CalibFrame], intr, R: np.ndarray, t: np.ndarray, workers: Workers = 1) -> list[np.ndarray]:
    """``score_poses`` of the poses (R [H,3,3], t [H,3]) on each of ``frames``, in frame order: the
    frames in ranges (``parallel.chunks``) on up to ``workers`` processes. Each frame's scores are
    one call on all the poses either way, so the values are those of one loop over the frames."""
    spans = chunks(len(frames), workers)
    if len(spans) <= 1:
        return [score_poses(fr, intr, R, t) for fr in frames]
    parts = parallel_map(_score_span, [(list(frames[lo:hi]), intr, R, t) for lo, hi in spans], workers)
    return [s for part in parts for s in part]


def _score_span(job) -> list[np.ndarray]:
    """``score_poses`` on each frame of a range (a task of ``frame_scores``)."""
    frames, intr, R, t = job
    return [score_poses(fr, intr, R, t) for fr in frames]


def _solve_job(job) -> Hypotheses:
    """One drawn search solved (a task of ``pose_hypotheses``' stream)."""
    return solve_triples(*job)


def distinct_best(h: Hypotheses, n: int, rot_deg: float = 3.0, trans_m: float = 1.0) -> Hypotheses:
    """The ``n`` best hypotheses that are pairwise more than ``rot_deg`` / ``trans_m`` apart."""
    order = np.argsort(-h.score, kind="stable")
    keep: list[int] = []
    for i in order:
        p = Pose(h.R[i], h.t[i])
        if all(p.distinct(Pose(h.R[k], h.t[k]), rot_deg, trans_m) for k in keep):
            keep.append(int(i))
        if len(keep) >= n:
            break
    return h.take(np.array(keep, dtype=np.int64))
