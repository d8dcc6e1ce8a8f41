"""Model-misfit checks: does the camera model the pose was fitted with explain the detections?

A pose can be well constrained and still wrong when the model is wrong: the given focal length
is off, the image is mirrored, or the 2D boxes come from two cameras. Each check refits an
alternative model and compares it with the one used; it flags a misfit only when the
alternative is clearly better, by margins measured on real frames (A9 sample: the fitted focal
scale of good intrinsics stays within 2 % over subsets of 4-16 frames, while fx x1.05 gives 0.952
and x1.1 gives 0.910).

* ``focal_scale``: refit with one extra parameter, a common scale of fx and fy
  (``cost.FocalScaleTerm``); flagged when it differs from 1 by more than ``FOCAL_TOL`` and by
  ``FOCAL_SIGMAS`` (2) jackknife sigmas (frames left out, :class:`FocalFit`).
  Before the focal length is blamed the box model is tested (:func:`focal_box_model`): a
  detector's visible outline makes every 2D box a few per cent smaller, which a shorter focal
  length mimics; with the outline offsets free the flag must still stand.
* ``focal_checkable``: the same fit must rule out a focal length ``FOCAL_MAX_UNCHECKED`` (5 %)
  off by ``FOCAL_SIGMAS`` sigmas; if not, a pose that nothing else refuses is refused as not
  verifiable (code ``focal_unverifiable``).
* ``mirrored``: the whole search (bring-up + refinement, on a few frames) run on the 2D boxes
  flipped left-right; flagged when the flipped boxes are explained clearly better.
* ``unexplained_frames``: frames with several 2D boxes that the pose leaves (nearly) unexplained
  while it explains the others well -- frames of another camera mixed in.
* ``second_pose``: the search run again on the 2D boxes the pose leaves unmatched (all 3D boxes
  kept); flagged when a clearly different pose explains a comparable share of them -- the boxes
  of a second camera mixed into the frames (which camera is the one meant cannot be told).
  Realism suite: a second camera's boxes score 0.28-0.91 x the best pose, clean sites <= 0.05.
* ``time_offset``: fitted camera-LiDAR offset (multi-start), flagged when significant and it
  moves the moving objects by more than ``TIME_MIN_SHIFT_M``.
* ``lens``: a pinhole camera (``CameraIntrinsics``) refitted as Mei's unified model with one more
  parameter ``xi`` (``cost.WideLensTerm``: 0 is the given pinhole; an equidistant fisheye is
  ~1.75) and the focal length free, against the same fit with ``xi`` held at 0 (matches fixed);
  flagged when the widened lens fits ``xi >= LENS_MIN_XI`` and lowers the robust cost by more than
  ``LENS_MIN_GAIN`` per object: the frames of a fisheye or wide-angle camera given with pinhole
  intrinsics. Runs first among the intrinsics checks: such frames also bend the focal-length
  and principal-point fits, but the lens is the cause to name. When the focal-length or
  principal-point check fires and this one did not, the same fit is judged as their alternative
  (``LENS_ALT_GAIN``): the lens is named when it explains the boxes better than the rescaled pinhole.
* ``box_frame``: the 3D boxes (pooled over the frames) spread along a direction far out of the
  LiDAR's x-y plane -- boxes given in a camera frame (x right, y down, z forward) or another
  frame whose z axis is not up. Runs on the inputs alone, before the search. Real rigs: the
  plane of the boxes is tilted 1.2-3.2 deg (A9, KITTI, nuScenes, PandaSet, SUSTech); realism
  boxes in the camera frame 49-80 deg.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..geometry.camera import CameraIntrinsics
from .cost import FocalScaleTerm, Occlusion, PrincipalPointTerm, TimeOffsetTerm, WideLensTerm
from .diagnostics import MisfitCheck, NoiseModel
from .inputs import CalibFrame
from .pose import Pose
from .boxmodel import kind_outline_edge_term, outline_edge_term
from .context import FitContext
from .parallel import parallel_map, shared
from .refine import build_cost, lsq, match_all
from .uncertainty import jackknife_sd, leave_frames_out, object_groups, principal_point_information

__all__ = ["MisfitVerdict", "lens_check", "lens_checks", "lens_box_model", "pp_resolution_applies", "LENS_ALT_GAIN", "LensFit", "lens_fit", "LENS_MIN_XI", "LENS_MIN_GAIN", "FocalFit", "focal_fit", "focal_width_check", "focal_box_model", "FOCAL_MIN_GAIN", "FOCAL_BOX_ALT_GAIN", "box_frame_check", "BOX_FRAME_MAX_TILT_DEG", "focal_scale_check", "second_pose_check", "second_pose_screen", "second_pose_support", "mirror_screen", "match_bound", "leftover_frames", "SECOND_POSE_SHARE", "principal_point_check", "principal_point_check_all", "pp_unresolved", "PP_UNRESOLVED", "inner_pairs", "time_offset_check", "TIME_BOX_ALT_GAIN", "time_shifted_frames", "pair_velocities", "unexplained_frames_check", "flipped_frames", "FOCAL_TOL",
           "FOCAL_MAX_UNCHECKED"]

FOCAL_TOL = 0.03          # |fitted focal scale - 1| beyond this (and 2 sigma) is a misfit
FOCAL_SIGMAS = 2.0        # clean sites fit within 1 % (1-4 px 2D noise, 3D noise, A9 subsets: 2 %), so the
# tolerance guards the clean; with 4 px 2D noise a 5 % error fit at 2.2-3.8 sigmas (6-draw bootstrap,
# before the jackknife)
# (4 sigmas let 4 of 40 realism sites through, 0.6-0.9 deg / 0.55-1.7 m off)
FOCAL_MAX_UNCHECKED = 0.05  # ... and the fit must rule out a focal this far off by FOCAL_SIGMAS sigmas:
# realism with 8 px 2D noise, site 16 (5 objects, ~35 m): focal +-5 % fit x0.980 +- 1.8 % / x1.053
# +- 3.1 % (jackknife) and were successes 1.5-1.8 m off (1-sigma 0.5 m); the exact focal there fits
# x0.997 +- 3.2 % (refused too); A9 subsets fit x0.985-0.997 within 1 %
PP_SIGMAS = 4.0           # the principal point's shift (norm) must exceed this many bootstrap sigmas
MIRROR_GAIN = 1.25        # the flipped boxes' score must exceed the best score by this factor
UNEXPLAINED_SHARE = 0.25  # share of the frames with 4+ 2D boxes left unexplained
SECOND_POSE_SHARE = 0.2   # a second pose scoring this share of the best on the leftover 2D boxes
SECOND_POSE_MIN_PAIRS = 10  # ... with at least this many matches
SECOND_POSE_MIN_IOU = 0.6  # ... of this mean IoU (a coherent camera, not boxes aligned by chance)
BOX_FRAME_MAX_TILT_DEG = 30.0  # a direction the 3D boxes spread along may leave the x-y plane by this
BOX_FRAME_MIN_SPREAD_M = 2.0   # ... counting directions with at least this 1-sigma spread (m)
LENS_MIN_XI = 0.25        # the widened lens must bend this much (xi; 0.25 compresses 45 deg off axis by ~5 %)
LENS_MIN_GAIN = 10.0      # ... and lower the robust cost by this per object (~4.5 sigmas for 1 parameter)
LENS_ALT_GAIN = 2.0       # ... per object, when a focal-length / principal-point check has fired (~2 sigmas)
LENS_START_XI = 1.0       # the widened fit starts from the pinhole and from this xi (a fisheye's range)


@dataclass
class MisfitVerdict:
    """The checks run and, when one flagged, the refusal message."""

    checks: list[MisfitCheck]
    message: str | None = None
    code: str = ""


def _focal_fit(frames, pairs, intr, pose: Pose, noise, f_scale, occlusion) -> float:
    *_, fit = lsq(FitContext(frames, pairs, intr, pose, noise, f_scale, occlusion), 40, extra=(FocalScaleTerm(),))
    return float(np.exp(fit.params[FocalScaleTerm.name][0]))


@dataclass(frozen=True)
class FocalFit:
    """The focal scale the matches fit best (pose refitted, matches fixed) and its 1-sigma (log
    scale) from a leave-out jackknife: frames left out in ``FOCAL_JACK_GROUPS`` interleaved groups
    (pairs with fewer than 4 frames with matches); deterministic, unlike a bootstrap."""

    scale: float
    log_sd: float


FOCAL_JACK_GROUPS = 10


def focal_fit(frames: list[CalibFrame], pairs: list[np.ndarray], intr: CameraIntrinsics, pose: Pose,
              noise: NoiseModel, f_scale: float, occlusion: Occlusion) -> FocalFit | None:
    """:class:`FocalFit` of the matches; None with fewer than 12 matches."""
    where = [(k, i) for k, p in enumerate(pairs) for i in range(len(p))]
    if len(where) < 12:
        return None
    s = _focal_fit(frames, pairs, intr, pose, noise, f_scale, occlusion)
    subsets = list(leave_frames_out(pairs, FOCAL_JACK_GROUPS))
    if not subsets:  # fewer than 4 frames with matches: pairs left out
        for g in np.array_split(np.arange(len(where)), FOCAL_JACK_GROUPS):
            drop = {where[i] for i in g}
            subsets.append([p[[i for i in range(len(p)) if (k, i) not in drop]] for k, p in enumerate(pairs)])
    sd = float(jackknife_sd([np.log(_focal_fit(frames, sub, intr, pose, noise, f_scale, occlusion)) for sub in subsets]))
    return FocalFit(s, sd if np.isfinite(sd) and np.isfinite(s) else float("inf"))


def focal_scale_check(fit: FocalFit | None, intr: CameraIntrinsics, *, n_matches: int = 0,
                      places: int | None = None) -> tuple[MisfitCheck, str | None]:
    """Flag a fitted focal scale beyond ``FOCAL_TOL`` and ``FOCAL_SIGMAS`` sigmas. ``places``:
    distinct places of the matched 3D boxes; when the ``n_matches`` repeat a few objects (4+ per
    place) the message says that the pose may be ambiguous too."""
    if fit is None:
        return MisfitCheck("focal_scale", 1.0, FOCAL_TOL, False, "too few matches to fit the focal length"), None
    s, sd = fit.scale, fit.log_sd
    detail = f"fitted focal scale {s:.3f} (jackknife sigma {sd:.3f})"
    if not _focal_flagged(s, sd):
        return MisfitCheck("focal_scale", s, FOCAL_TOL, False, detail), None
    msg = (f"model misfit: the boxes fit best with a focal length about {s:.2f}x the given one (fx ~{intr.fx * s:.0f} "
           f"px instead of {intr.fx:.0f}, fy ~{intr.fy * s:.0f} instead of {intr.fy:.0f}); the pose found with the "
           "given intrinsics is biased. Check the intrinsics (and the image size they belong to), or let xcalib "
           "estimate the focal length")
    if places is not None and n_matches >= 4 * max(places, 1):
        msg += (f" -- but the {n_matches} matches lie at only {places} distinct places (queued or parked objects "
                "repeated over the frames), where the focal length and the pose are hard to separate: add frames "
                "with other objects before changing the intrinsics")
    return MisfitCheck("focal_scale", s, FOCAL_TOL, True, detail), msg


#: with the detector-outline offsets free (box model), the focal scale must still lower the robust
#: cost by more than this per object to stay a misfit (1 parameter: ~4.5 sigmas, as ``LENS_MIN_GAIN``)
FOCAL_MIN_GAIN = 10.0
#: ... and the outline offsets alone must fit the boxes better than the focal scale alone by more than
#: this per object (~2 sigmas, as ``LENS_ALT_GAIN``): realism focal -5 % given as it is, site 9
#: (exact boxes; fitted x1.045): the two fit alike (robust cost 30.1 vs 30.2), the outline fit said
#: x0.982, and only the checkability test (1.97 sigmas against 2) kept a pose 2 deg / 1 m off refused
FOCAL_BOX_ALT_GAIN = 2.0


def _focal_outline_fit(ctx: FitContext, pairs: list[np.ndarray], with_focal: bool = True) -> tuple[float, float]:
    """(focal scale, robust cost) of the fit with the detector-outline offsets
    (``boxmodel.outline_edge_term``) free, the focal scale free too (``with_focal``) or held."""
    model = build_cost(ctx.frames, pairs, ctx.intr, ctx.pose, ctx.noise, ctx.occlusion,
                       (FocalScaleTerm(),) if with_focal else (), edge=outline_edge_term)
    fit = model.fit(f_scale=ctx.f_scale, max_nfev=60)
    return (float(np.exp(fit.params[FocalScaleTerm.name][0])) if with_focal else 1.0), float(fit.cost)


def _focal_flagged(s: float, sd: float) -> bool:
    return bool(abs(np.log(s)) > np.log1p(FOCAL_TOL) and abs(np.log(s)) > FOCAL_SIGMAS * sd)


def focal_box_model(ctx: FitContext, places: int | None = None) -> tuple[FocalFit | None, str]:
    """The box model before the focal length is blamed (run when ``focal_scale_check`` flags).

    A camera detector draws the visible outline of a vehicle, narrower and lower than the
    rectangle around its 3D box: every 2D box a few per cent smaller, which a focal length a few
    per cent shorter mimics (realism ``detector_outline`` / ``detector_all``: fitted x0.95-0.97 of
    an exact focal length). A focal error scales the boxes' positions about the principal point
    as well as their sizes; the outline offsets (sides, top, bottom as shares of the box size)
    change sizes only. So the focal scale is fitted again with the outline offsets free (pose
    refitted, matches fixed), its jackknife over frames as :func:`focal_fit`, and the box model
    explains the flag when (1) the outline offsets alone fit the boxes better than the focal scale
    alone by more than ``FOCAL_BOX_ALT_GAIN`` per object (where the two fit alike the data cannot
    tell a focal error from the outline: the flag stands), (2) the focal scale added to them lowers the robust cost by at most ``FOCAL_MIN_GAIN``
    per object (an object's boxes share its outline error) and (3) that fit flags no focal misfit.
    Returns (that fit, a note) when the box model explains the flag, else (None, ""). The caller
    judges the focal length's checkability (``focal_width_check``) on the returned fit: with the
    outline free the positions alone tell the focal length, and where they cannot rule out a
    focal length 5 % off the pose is refused as not verifiable rather than delivered."""
    pairs = ctx.pairs
    n = int(sum(len(p) for p in pairs))
    if n < 12:
        return None, ""
    s2, c_both = _focal_outline_fit(ctx, pairs)
    _, c_box = _focal_outline_fit(ctx, pairs, with_focal=False)
    *_, focal_only = lsq(ctx, 40, extra=(FocalScaleTerm(),))
    per_obj = max(n / max(places or n / 4.0, 1.0), 1.0)
    gain = (c_box - c_both) / per_obj
    better = (focal_only.cost - c_box) / per_obj
    if not (np.isfinite(s2) and better > FOCAL_BOX_ALT_GAIN and gain <= FOCAL_MIN_GAIN):
        return None, ""
    subsets = list(leave_frames_out(pairs, FOCAL_JACK_GROUPS))
    if not subsets:  # fewer than 4 frames with matches: nothing the caller can rely on
        return None, ""
    sd = float(jackknife_sd([np.log(_focal_outline_fit(ctx, sub)[0]) for sub in subsets]))
    sd = sd if np.isfinite(sd) else float("inf")
    if _focal_flagged(s2, sd):
        return None, ""
    note = (f"; with the 2D outline offsets fitted (box model) it is {s2:.3f} (jackknife sigma {sd:.3f}) and lowers "
            f"the cost by {gain:.1f} per object (limit {FOCAL_MIN_GAIN:g}); cost with the outline offsets alone "
            f"{c_box:.1f}, with the focal scale alone {focal_only.cost:.1f} ({better:.1f} per object better, "
            f"limit {FOCAL_BOX_ALT_GAIN:g}): the box model explains it")
    return FocalFit(s2, sd), note


def focal_width_check(fit: FocalFit | None, frames: list[CalibFrame], pairs: list[np.ndarray],
                      pose: Pose) -> tuple[MisfitCheck, str | None]:
    """Can the matches rule out a given focal length ``FOCAL_MAX_UNCHECKED`` (5 %) off? Flagged
    when the fitted scale lies within ``FOCAL_SIGMAS`` sigmas of x0.95 or x1.05 (statistic: that
    distance in sigmas). The message says how far such an error would move the pose: a focal
    error scales the depth of every object, so about error x depth along the view."""
    if fit is None:
        return MisfitCheck("focal_checkable", float("inf"), FOCAL_SIGMAS, False, "too few matches to fit the focal length"), None
    off = np.log1p(np.array([-FOCAL_MAX_UNCHECKED, FOCAL_MAX_UNCHECKED]))
    z = float(np.min(np.abs(np.log(fit.scale) - off)) / fit.log_sd) if fit.log_sd > 0 else float("inf")
    detail = (f"a focal length {100 * FOCAL_MAX_UNCHECKED:g} % off lies {z:.1f} jackknife sigmas from the fitted "
              f"x{fit.scale:.3f} (1-sigma {100 * fit.log_sd:.1f} %; ruled out beyond {FOCAL_SIGMAS:g})")
    if z > FOCAL_SIGMAS:  # nan (failed refits) is not > 2: not checkable
        return MisfitCheck("focal_checkable", z, FOCAL_SIGMAS, False, detail), None
    X = np.concatenate([f.boxes3d[p[:, 1], :3] for f, p in zip(frames, pairs) if len(p)])
    depth_m = float(np.median((X @ pose.R.T + pose.t)[:, 2]))
    spread = (f"with a jackknife 1-sigma of {100 * fit.log_sd:.1f} %" if np.isfinite(fit.log_sd)
              else "but the leave-out refits failed")
    msg = (f"not verifiable: these detections cannot check the given focal length (they fit x{fit.scale:.3f} of it "
           f"{spread}), so a focal length {100 * FOCAL_MAX_UNCHECKED:g} % off would go unnoticed and move the pose by "
           f"about {FOCAL_MAX_UNCHECKED * depth_m:.1f} m along the view (the matched objects are ~{depth_m:.0f} m "
           "away). Make sure the intrinsics belong to this camera and image size, and add frames with objects at "
           "other depths and across the whole image")
    return MisfitCheck("focal_checkable", z, FOCAL_SIGMAS, True, detail), msg


def box_frame_check(frames: list[CalibFrame]) -> tuple[MisfitCheck, str | None]:
    """Flag 3D boxes that do not lie along the LiDAR's x-y plane (z up). The box centres of all
    frames spread along principal directions; with two of ``BOX_FRAME_MIN_SPREAD_M``+ (1-sigma)
    the statistic is the tilt of the plane they span (its normal from z, deg), with one the
    elevation of that line. Traffic on the ground spreads horizontally; the same boxes in a
    camera frame spread along its x-z plane (y down)."""
    X = [f.boxes3d[:, :3] for f in frames if f.n3]
    X = np.concatenate(X) if X else np.zeros((0, 3))
    if len(X) < 4:
        return MisfitCheck("box_frame", 0.0, BOX_FRAME_MAX_TILT_DEG, False, "too few 3D boxes"), None
    _, s, Vt = np.linalg.svd(X - np.median(X, axis=0), full_matrices=False)
    spread = s / np.sqrt(len(X))
    n_wide = int(np.sum(spread >= BOX_FRAME_MIN_SPREAD_M))
    if n_wide == 0:
        return MisfitCheck("box_frame", 0.0, BOX_FRAME_MAX_TILT_DEG, False, "the 3D boxes spread too little"), None
    if n_wide >= 2:
        n = Vt[2]
        tilt = float(np.degrees(np.arccos(min(1.0, abs(n[2])))))
        detail = (f"they spread {spread[0]:.1f} x {spread[1]:.1f} m (1-sigma) over a plane whose normal "
                  f"({n[0]:+.2f}, {n[1]:+.2f}, {n[2]:+.2f}) is {tilt:.1f} deg from z")
    else:
        d = Vt[0]
        tilt = float(np.degrees(np.arcsin(min(1.0, abs(d[2])))))
        detail = (f"they spread {spread[0]:.1f} m (1-sigma) along ({d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f}), "
                  f"{tilt:.1f} deg out of the x-y plane")
    flagged = tilt > BOX_FRAME_MAX_TILT_DEG
    msg = None
    if flagged:
        msg = (f"model misfit: the 3D boxes do not lie along the ground of a z-up frame ({detail}); they seem to be "
               "given in a camera frame (x right, y down, z forward) or another frame whose z axis is not up. The "
               "calibration's 3D boxes stand on the x-y plane and turn about z (yaw): give the 3D detections in the "
               "LiDAR frame (z up) or another gravity-aligned frame")
    return MisfitCheck("box_frame", tilt, BOX_FRAME_MAX_TILT_DEG, bool(flagged), detail), msg


def unexplained_frames_check(frames: list[CalibFrame], pairs: list[np.ndarray]) -> tuple[MisfitCheck, str | None]:
    """Frames with 4+ 2D boxes of which the pose matches at most 1 in 5, while it matches half or
    more in the other frames: frames from another camera (or another sensor pairing) mixed in."""
    rich = [(fr.key, len(p) / fr.n2) for fr, p in zip(frames, pairs) if fr.n2 >= 4]
    if len(rich) < 4:
        return MisfitCheck("unexplained_frames", 0.0, UNEXPLAINED_SHARE, False, "too few frames with 4+ 2D boxes"), None
    frac = np.array([f for _, f in rich])
    bad = frac <= 0.2
    share = float(bad.mean())
    good = frac[~bad]
    flagged = bool(share >= UNEXPLAINED_SHARE and len(good) and np.median(good) >= 0.5)
    detail = f"{int(bad.sum())} of {len(rich)} frames with 4+ 2D boxes have at most 1 in 5 of them matched"
    msg = None
    if flagged:
        keys = ", ".join(k for (k, _), b in zip(rich, bad) if b)
        msg = (f"model misfit: the pose explains most 2D boxes in some frames and almost none in {int(bad.sum())} others "
               f"({keys[:120]}); frames from a second camera (or with another camera's boxes) seem to be mixed in. "
               "Calibrate one camera at a time")
    return MisfitCheck("unexplained_frames", share, UNEXPLAINED_SHARE, flagged, detail), msg


def leftover_frames(frames: list[CalibFrame], pairs: list[np.ndarray]) -> list[CalibFrame]:
    """The frames with only the 2D boxes that ``pairs`` leave unmatched (all 3D boxes kept)."""
    out = []
    for fr, p in zip(frames, pairs):
        keep = np.setdiff1d(np.arange(fr.n2), p[:, 0]) if len(p) else np.arange(fr.n2)
        out.append(replace(fr, boxes2d=fr.boxes2d[keep], idx2d=fr.idx2d[keep]))
    return out


def match_bound(frames: list[CalibFrame]) -> int:
    """The most matches any pose can make on ``frames``: one-to-one per frame, so at most
    min(2D boxes, 3D boxes) each. A search's score (a sum of IoUs <= 1 over its matches) is bounded
    by it too."""
    return int(sum(min(fr.n2, fr.n3) for fr in frames))


def second_pose_screen(best_score: float, left: list[CalibFrame]) -> str | None:
    """Why no second pose can be flagged on the leftover frames ``left`` whatever the search
    finds (its score and matches cannot reach ``SECOND_POSE_SHARE`` of ``best_score`` or
    ``SECOND_POSE_MIN_PAIRS``), or None when the search must run. Exact: the bound is
    :func:`match_bound`, so skipping the search leaves the verdict unchanged."""
    bound = match_bound(left)
    if bound >= SECOND_POSE_MIN_PAIRS and bound + 1e-9 >= SECOND_POSE_SHARE * best_score:
        return None
    return (f"not searched: the unmatched 2D boxes allow at most {bound} matches (a second pose needs "
            f"{SECOND_POSE_MIN_PAIRS}+ scoring {SECOND_POSE_SHARE:g} x {best_score:.1f})")


def second_pose_support(best_score: float | None) -> int:
    """The fewest matches of a second pose that :func:`second_pose_check` can flag: at least
    ``SECOND_POSE_MIN_PAIRS``, and its score (a sum of IoUs <= 1 over its matches, see
    :func:`match_bound`) must reach ``SECOND_POSE_SHARE`` of ``best_score`` (None: unknown). The
    second-pose search need find no pose with fewer (``bringup.pose_hypotheses``' ``support``)."""
    need = SECOND_POSE_MIN_PAIRS
    if best_score is not None and np.isfinite(best_score):
        need = max(need, int(np.ceil(SECOND_POSE_SHARE * float(best_score) - 1e-9)))
    return int(need)


def second_pose_check(best_score: float, n_best: int, second_score: float, n_second: int,
                      distance: tuple[float, float] | None, admissible: bool = True,
                      screened: str | None = None) -> tuple[MisfitCheck, str | None]:
    """Flag when a pose ``distance`` (deg, m) away from the best explains the 2D boxes the best
    leaves unmatched with ``n_second`` coherent matches scoring ``SECOND_POSE_SHARE``+ of the best.
    ``admissible``: the second pose is a camera the search's assumptions allow (within the
    baseline; a pose tens of metres away aligning leftover boxes by chance is none). ``screened``:
    the reason the search was not run (``second_pose_screen``; ``second_score`` is then its bound)."""
    share = second_score / max(best_score, 1e-9)
    if screened is not None:
        return MisfitCheck("second_pose", share, SECOND_POSE_SHARE, False, screened), None
    mean_iou = second_score / max(n_second, 1)
    far = distance is not None and (distance[0] > 3.0 or distance[1] > 1.0)
    flagged = bool(far and admissible and share >= SECOND_POSE_SHARE and n_second >= SECOND_POSE_MIN_PAIRS
                   and mean_iou >= SECOND_POSE_MIN_IOU)
    where = "" if distance is None else f", {distance[0]:.1f} deg / {distance[1]:.2f} m from the best" + \
        ("" if admissible else " (outside the baseline, not counted)")
    detail = (f"a second pose{where} explains {n_second} of the 2D boxes the best pose leaves unmatched (score "
              f"{second_score:.1f} vs {best_score:.1f}, {n_best} matches)")
    msg = None
    if flagged:
        msg = (f"model misfit: the 2D boxes seem to come from more than one camera -- the best pose explains {n_best} "
               f"of them and a second pose {distance[0]:.0f} deg / {distance[1]:.1f} m away explains {n_second} others "
               "(which camera is meant cannot be told from the boxes). Calibrate one camera at a time: give only the "
               "2D detections of one camera's images")
    return MisfitCheck("second_pose", share, SECOND_POSE_SHARE, flagged, detail), msg


def flipped_frames(frames: list[CalibFrame]) -> list[CalibFrame]:
    """The frames with every 2D box mirrored left-right (u -> W - u)."""
    out = []
    for fr in frames:
        W = fr.size[0]
        b = fr.boxes2d
        out.append(replace(fr, boxes2d=np.column_stack([W - b[:, 2], b[:, 1], W - b[:, 0], b[:, 3]])))
    return out


def mirror_screen(best_score: float, frames: list[CalibFrame], pose: Pose, need: int) -> str | None:
    """Why the flipped boxes cannot be flagged whatever their search finds (:func:`mirror_check`
    with the flipped score and matches at their bound, :func:`match_bound`), or None when the
    search must run. Exact: skipping the search leaves the verdict unchanged."""
    bound = match_bound(frames)
    ratio = (bound + 1e-9) / max(best_score, 1e-9)
    upside_down = bool(pose.R[1, 2] > 0.5)
    if bound >= need and (ratio > MIRROR_GAIN or (ratio > 1.0 and upside_down)):
        return None
    return (f"not searched: the flipped boxes allow at most {bound} matches, a score of at most {ratio:.3f} x "
            f"{best_score:.1f} (a mirror needs > {MIRROR_GAIN:g} x and {need}+ matches)")


def mirror_check(best_score: float, flipped_score: float, pose: Pose,
                 explained: tuple[int, int] | None = None, screened: str | None = None) -> tuple[MisfitCheck, str | None]:
    """Flag when the left-right flipped boxes are explained clearly better than the boxes as given
    (by ``MIRROR_GAIN``), or better at all while the pose for the boxes as given is upside down
    (the LiDAR's up axis, z, pointing down the image: a mirrored image is fitted best by a camera
    rolled 180 deg). ``explained`` = (2D boxes the flipped boxes' pose matches, the matches a pose
    needs to explain the 2D boxes): a mirror is named only when the flipped boxes are explained --
    among many unmatched boxes (distractors, crowded frames) both scores are chance alignments,
    and the one of the flipped boxes may come out ahead (issue 31: 32 + 270 boxes per frame).
    ``screened``: the reason the search was not run (``mirror_screen``; ``flipped_score`` is then its bound)."""
    ratio = flipped_score / max(best_score, 1e-9)
    if screened is not None:
        return MisfitCheck("mirrored", ratio, MIRROR_GAIN, False, screened), None
    upside_down = bool(pose.R[1, 2] > 0.5)
    flagged = bool(ratio > MIRROR_GAIN or (ratio > 1.0 and upside_down))
    unexplained = explained is not None and explained[0] < explained[1]
    detail = (f"score of the flipped boxes {flipped_score:.1f} vs {best_score:.1f} as given"
              f"{'; the pose for the boxes as given is upside down' if upside_down else ''}"
              + (f"; the flipped boxes' pose matches {explained[0]} 2D boxes (a pose that explains them: "
                 f"{explained[1]}+)" if explained is not None else ""))
    if flagged and unexplained:  # no pose explains the flipped boxes either: not a mirror
        flagged = False
        detail += "; not a mirror: the flipped boxes are not explained either"
    msg = None
    if flagged:
        msg = (f"model misfit: the 2D boxes fit a left-right mirrored image much better ({detail}); the image (or the "
               "2D detections) seems to be flipped horizontally. Un-mirror the image or the boxes (u -> width - u)")
    return MisfitCheck("mirrored", ratio, MIRROR_GAIN, flagged, detail), msg


TIME_SIGMAS = 4.0
TIME_MIN_SHIFT_M = 0.15   # the offset must move the matched objects by this much (median over moving ones);
# realism suite: 0.05 s at 5-15 m/s moves them 0.18-0.28 m and biases the pose by 0.3-0.6 m, while
# clean sites fit |dt| <= 1 ms (< 0.01 m)
TIME_START_S = 0.05       # the fit also starts at +-this offset (s; 0.5 frame without timestamps)


def pair_velocities(frames: list[CalibFrame], pairs: list[np.ndarray], times: np.ndarray,
                    max_speed: float = 30.0) -> np.ndarray:
    """Velocity [n,3] (LiDAR frame, m per time unit) of each matched 3D box, from the nearest 3D
    box of the previous and the next frame (central difference; one side at the ends); zero
    where no neighbour lies within ``max_speed`` x the time step."""
    out = []
    for k, (fr, p) in enumerate(zip(frames, pairs)):
        v = np.zeros((len(p), 3))
        X = fr.boxes3d[p[:, 1], :3] if len(p) else np.zeros((0, 3))
        ends = []
        for j in (k - 1, k + 1):
            if 0 <= j < len(frames) and frames[j].n3 and len(X):
                dt = float(times[j] - times[k])
                Y = frames[j].boxes3d[:, :3]
                d = np.linalg.norm(X[:, None] - Y[None], axis=2)
                near = d.argmin(1)
                ok = d[np.arange(len(X)), near] <= max_speed * abs(dt)
                ends.append((np.where(ok[:, None], Y[near], X), ok, dt))
        if len(ends) == 2:
            (a, oka, dta), (b, okb, dtb) = ends
            both = oka & okb
            v[both] = (b[both] - a[both]) / (dtb - dta)
            v[oka & ~okb] = (X[oka & ~okb] - a[oka & ~okb]) / (-dta)
            v[okb & ~oka] = (b[okb & ~oka] - X[okb & ~oka]) / dtb
        elif len(ends) == 1:
            (a, oka, dta), = ends
            v[oka] = (a[oka] - X[oka]) / dta
        out.append(v)
    return np.concatenate(out) if out else np.zeros((0, 3))


def _time_fit(ctx: FitContext, vel, starts: tuple[float, ...] = (0.0,), edge=None) -> tuple[float, Pose, float]:
    """Fitted offset, pose and robust cost from each start offset; the lowest cost wins. Several
    starts: a fit started at exactly 0 can stay there (a stationary point of the robust cost; a
    0.05 s offset left undetected on one realism site until started at -0.05 s). ``edge``: the
    box-edge term's variant (``boxmodel.outline_edge_term``: the detector-outline offsets free)."""
    best = None
    for dt0 in starts:
        model = build_cost(ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise, ctx.occlusion,
                           (TimeOffsetTerm(vel, dt0=dt0),), edge=edge)
        fit = model.fit(f_scale=ctx.f_scale, max_nfev=40)
        if best is None or fit.cost < best[0]:
            best = (fit.cost, dt0 + float(fit.params[TimeOffsetTerm.name][0]), fit.pose)
    return best[1], best[2], float(best[0])


def _time_boot(ctx: FitContext, vel: np.ndarray, dt: float, draws: int, seed: int, edge=None) -> float:
    """Bootstrap 1-sigma of the fitted offset: frames resampled with replacement (each with its
    matches and their velocities), the offset refitted from ``dt``."""
    pairs = ctx.pairs
    rng = np.random.default_rng(seed)
    offs = np.cumsum([0] + [len(p) for p in pairs])
    nz = [k for k, p in enumerate(pairs) if len(p)]
    boot = []
    for _ in range(draws):
        w = np.bincount(rng.integers(0, len(nz), len(nz)), minlength=len(nz))
        sub = [p[:0] for p in pairs]
        for k, c in zip(nz, w):
            sub[k] = np.repeat(pairs[k], c, axis=0)
        weight = dict(zip(nz, w))
        vs = np.concatenate([np.repeat(vel[offs[k]:offs[k + 1]], weight.get(k, 0), axis=0) for k in range(len(pairs))])
        boot.append(_time_fit(ctx.with_pairs(sub), vs, (dt,), edge)[0])
    return float(np.std(boot, ddof=1))


#: a flagged offset is judged against the box model (``_time_box_model``): the detector-outline
#: offsets alone must fit the boxes better than the time offset alone by more than this per object
#: (as ``FOCAL_BOX_ALT_GAIN``: where both fit alike the data cannot tell an offset from the outline
#: and the flag stands)
TIME_BOX_ALT_GAIN = 2.0


def _time_flag(dt: float, sd: float, shift: float) -> bool:
    return bool(abs(dt) / max(sd, 1e-9) > TIME_SIGMAS and shift > TIME_MIN_SHIFT_M)


def _time_box_models():
    """The box models a flagged time offset is tested against, in turn (``_time_box_model``): one
    set of detector-outline offsets for all objects (``boxmodel.outline_edge_term``), then a width
    and a height share per size kind of object (``boxmodel.kind_outline_edge_term``: a person's box
    grows while a car's shrinks, which one set cannot represent; realism ``detector_outline`` site 18,
    no offset: the common outline fits worse than a -0.07 s offset by 2.6 per object, the kinds
    better by 8.8, and the offset refitted with them is 2.2 bootstrap sigmas)."""
    return (("one outline", outline_edge_term), ("outline per kind of object", kind_outline_edge_term()))


def _time_box_model(ctx: FitContext, vel: np.ndarray, fitted: tuple[float, float], speed: np.ndarray,
                    places: int | None, boot: tuple[int, int]) -> tuple[bool, str]:
    """The box model before the sensors' timing is blamed (run when the offset is flagged).

    A camera detector draws the visible outline of a vehicle, narrower and lower than the
    rectangle around its 3D box (a share of each box's size). On frames without any offset such
    outlines fit as one: realism ``detector_all`` site 10 +0.033 s (0.29 m, 4.1 bootstrap
    sigmas), ``detector_truncation`` site 16 +0.048 s, ``detector_outline`` site 13 +0.030 s --
    the pose fitted to the outlines leaves size errors that grow with each object's depth and
    position, and the objects' motion along the view turns part of them into an apparent offset.
    So the offset is fitted again with the outline offsets free (each box model of
    ``_time_box_models`` in turn; pose refitted, matches fixed), and a box model explains the flag
    when (1) its outline offsets alone fit the boxes better than the offset alone by more than
    ``TIME_BOX_ALT_GAIN`` per object (where the two fit alike the data cannot tell them apart and
    the flag stands) and (2) the offset fitted with its outline free flags nothing
    (``TIME_MIN_SHIFT_M``, ``TIME_SIGMAS`` bootstrap sigmas). A real offset moves each object along
    its own motion, across the image too, which no outline can: its flag stands (realism 0.05 s
    offsets, PandaSet's -49.85 ms). ``fitted``: (offset, robust cost) of the flagged fit; ``boot``:
    (draws, seed) of the bootstrap. Returns (whether a box model explains the flag, a note for the
    detail)."""
    notes = []
    for name, edge in _time_box_models():
        cleared, note = _time_box_model_one(ctx, vel, fitted, speed, places, boot, edge)
        notes.append(f"{name}: {note}")
        if cleared:
            return True, "; box model (" + "; ".join(notes) + ")"
    return False, "; box model (" + "; ".join(notes) + ")"


def _time_box_model_one(ctx: FitContext, vel: np.ndarray, fitted: tuple[float, float], speed: np.ndarray,
                        places: int | None, boot: tuple[int, int], edge) -> tuple[bool, str]:
    """``_time_box_model``'s two rules for one box model (``edge``: a ``build_cost`` edge factory)."""
    dt, c_time = fitted
    n = int(sum(len(p) for p in ctx.pairs))
    per_obj = max(n / max(places or n / 4.0, 1.0), 1.0)
    c_box = float(build_cost(ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise, ctx.occlusion, (),
                             edge=edge).fit(f_scale=ctx.f_scale, max_nfev=60).cost)
    better = (c_time - c_box) / per_obj
    costs = (f"cost with the outline offsets alone {c_box:.1f}, with the time offset alone {c_time:.1f} ({better:.1f} per "
             f"object better, limit {TIME_BOX_ALT_GAIN:g})")
    if not (np.isfinite(better) and better > TIME_BOX_ALT_GAIN):
        why = ("the time offset explains the boxes better" if better < -TIME_BOX_ALT_GAIN
               else "the data cannot tell the offset from a detector's outline")
        return False, f"{costs}: {why}"
    dt2, *_ = _time_fit(ctx, vel, (0.0, dt), edge)
    moving = speed > 0
    shift2 = float(np.median(speed[moving]) * abs(dt2)) if moving.any() else 0.0
    sd2 = _time_boot(ctx, vel, dt2, *boot, edge) if shift2 > TIME_MIN_SHIFT_M else float("nan")
    sig = "" if not np.isfinite(sd2) else f", bootstrap sigma {sd2:.3f}"
    fit2 = f"with the 2D outline offsets fitted it is {dt2:+.3f} (moves them {shift2:.2f} m{sig})"
    if shift2 > TIME_MIN_SHIFT_M and not (np.isfinite(sd2) and not _time_flag(dt2, sd2, shift2)):
        return False, f"{fit2}, still a misfit; {costs}"
    return True, f"{fit2}: not a misfit; {costs}: the box model explains it"


def time_offset_check(ctx: FitContext, times: np.ndarray, unit: str, *, draws: int = 6,
                      seed: int = 0, places: int | None = None) -> tuple[MisfitCheck, str | None]:
    """Fitted camera-LiDAR time offset (objects moved along their velocity from adjacent frames).
    A flag is judged against the detector-outline box model first (``_time_box_model``);
    ``places``: distinct places of the matched 3D boxes (the objects, for per-object gains)."""
    frames, pairs = ctx.frames, ctx.pairs
    vel = pair_velocities(frames, pairs, times)
    speed = np.linalg.norm(vel, axis=1)
    moving = speed > 0.5 * (1.0 if unit == "s" else 0.1)
    if moving.sum() < 6:
        return MisfitCheck("time_offset", 0.0, TIME_SIGMAS, False, "too few moving matched objects"), None
    step = TIME_START_S if unit == "s" else TIME_START_S * 10.0
    dt, _, cost = _time_fit(ctx, vel, (0.0, -step, step))
    shift = float(np.median(speed[moving]) * abs(dt))
    if shift <= TIME_MIN_SHIFT_M:  # cannot flag whatever its sigma: the bootstrap refits are not run
        return MisfitCheck("time_offset", 0.0, TIME_SIGMAS, False,
                           f"fitted time offset {dt:+.3f} {unit} moves the moving objects {shift:.2f} m (a misfit needs "
                           f"> {TIME_MIN_SHIFT_M:g} m; its bootstrap sigma not computed, statistic 0)"), None
    sd = _time_boot(ctx, vel, dt, draws, seed)
    z = abs(dt) / max(sd, 1e-9)
    flagged = _time_flag(dt, sd, shift)
    detail = f"fitted time offset {dt:+.3f} {unit} (bootstrap sigma {sd:.3f}; moves the moving objects {shift:.2f} m)"
    if flagged:  # the box model first: a detector's outline on objects moving along the view mimics an offset
        cleared, note = _time_box_model(ctx, vel, (dt, cost), np.where(moving, speed, 0.0), places, (draws, seed))
        detail += note
        if cleared:
            return MisfitCheck("time_offset", z, TIME_SIGMAS, False, detail), None
    msg = None
    if flagged:
        msg = (f"model misfit: the sensors seem out of time -- the boxes fit best with the 3D boxes moved {dt:+.2f} {unit} "
               f"along their motion (about {shift:.1f} m); the pose from unsynchronised frames is biased. Check the "
               "camera/LiDAR timestamps, use frames without moving objects, or let xcalib estimate the offset "
               "(time_offset='auto')")
    return MisfitCheck("time_offset", z, TIME_SIGMAS, flagged, detail), msg


def time_shifted_frames(ctx: FitContext, times: np.ndarray, unit: str) -> list[CalibFrame] | None:
    """The frames with each matched 3D outline moved along its motion by the fitted time offset
    (as ``time_offset_check`` fits it): the model in which a time offset is the cause, for testing
    the other checks against (a 0.05 s offset on PandaSet's projected cuboids also fits as a
    principal point 81 px off). None when too few matched objects move."""
    frames, pairs, intr, pose, noise, f_scale, occlusion = (ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise,
                                                            ctx.f_scale, ctx.occlusion)
    vel = pair_velocities(frames, pairs, times)
    moving = np.linalg.norm(vel, axis=1) > 0.5 * (1.0 if unit == "s" else 0.1)
    if moving.sum() < 6:
        return None
    step = TIME_START_S if unit == "s" else TIME_START_S * 10.0
    dt, *_ = _time_fit(ctx, vel, (0.0, -step, step))
    out, k = [], 0
    for f, p in zip(frames, pairs):
        if not len(p):
            out.append(f)
            continue
        c = f.corners.copy()
        c[p[:, 1]] += (vel[k:k + len(p)] * dt)[:, None, :]
        k += len(p)
        out.append(replace(f, corners=c))
    return out


PP_TOL_FRAC = 0.015       # principal point shift beyond this share of the image width (and 4 sigma)
PP_X_SIGMAS = 4.0         # ... or its horizontal part beyond that share and this many sigmas of its own:
# spurious shifts from box-shape biases (tops and bottoms of real boxes) lie along y, a cropped
# image's along x; realism principal point +3 % W with 4 px 2D noise: the norm test alone let 6 of
# 20 sites through (1.2-2.3 deg off), this test (with the focal check) leaves 2; at 3 sigmas it left
# none but refused the demo's clean synthetic site (x shift 38 px at 3.7 sigmas of 5 draws)


PP_X_UNVERIFIED_SIGMAS = 3.0  # an unflagged shift whose x part is beyond the tolerance and this many
# of its sigmas (but below PP_X_SIGMAS) and that turns the camera beyond PP_CHECK_DEG is not
# verifiable: realism principal point +3 % W, 4 px, sites 7 / 18 (x at 3.9 / 3.3 sigmas) were
# delivered 1.6 deg off; the norm alone refused a clean site (y -128 px, x 2.3 sigmas; pose right)


#: the principal point misfit suggests estimating it (refine_intrinsics='focal+center') only when its
#: bootstrap 1-sigma is within this share of the width: the limit ``selfcal`` asks for, so that the
#: advice, followed, is not refused in turn
PP_ESTIMABLE_FRAC = 0.01
#: with the outline offsets free, a principal-point shift must lower the robust cost (half a chi^2 of
#: 2 parameters) by more than this per object (an object's pairs share one outline error): about
#: 4.5 sigmas for 2 degrees of freedom
PP_MIN_GAIN = 12.0


def _pp_fit(frames, pairs, intr, pose: Pose, noise, f_scale, occlusion, outline: bool = False) -> np.ndarray:
    """Fitted principal-point shift (px); with ``outline`` the detector-outline offsets
    (``boxmodel.outline_edge_term``) are fitted with it as nuisance parameters."""
    if not outline:
        *_, fit = lsq(FitContext(frames, pairs, intr, pose, noise, f_scale, occlusion), 40, extra=(PrincipalPointTerm(),))
        return np.asarray(fit.params[PrincipalPointTerm.name], dtype=np.float64)
    return _pp_outline_fits(frames, pairs, intr, pose, noise, f_scale, occlusion, with_pp=True)[0]


def _pp_outline_fits(frames, pairs, intr, pose: Pose, noise, f_scale, occlusion, with_pp: bool):
    """(principal-point shift [2] px or None, robust cost) of the fit with the outline offsets free."""
    model = build_cost(frames, pairs, intr, pose, noise, occlusion, (PrincipalPointTerm(),) if with_pp else (),
                       edge=outline_edge_term)
    fit = model.fit(f_scale=f_scale, max_nfev=60)
    d = np.asarray(fit.params[PrincipalPointTerm.name], dtype=np.float64) if with_pp else None
    return d, float(fit.cost)


def _pp_boot(ctx: FitContext, draws: int, seed: int, outline: bool, d: np.ndarray | None = None):
    """(shift [2] px, bootstrap sd [2] px over frames) of the principal-point fit (``d``: the shift
    when already fitted)."""
    frames, pairs, intr, pose, noise, f_scale, occlusion = (ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise,
                                                            ctx.f_scale, ctx.occlusion)
    if d is None:
        d = _pp_fit(frames, pairs, intr, pose, noise, f_scale, occlusion, outline)
    rng = np.random.default_rng(seed)
    nz = [k for k, p in enumerate(pairs) if len(p)]
    boot = []
    for _ in range(draws):
        sub = [p[:0] for p in pairs]
        if len(nz) >= 4:
            for k, c in zip(nz, np.bincount(rng.integers(0, len(nz), len(nz)), minlength=len(nz))):
                sub[k] = np.repeat(pairs[k], c, axis=0)
        else:
            sub = [p[rng.integers(0, len(p), len(p))] if len(p) else p for p in pairs]
        boot.append(_pp_fit(frames, sub, intr, pose, noise, f_scale, occlusion, outline))
    return d, np.std(np.asarray(boot), axis=0, ddof=1)


#: objects left out in at most this many interleaved groups by the principal point's object jackknife
PP_OBJECT_GROUPS = 12
#: a principal-point shift the objects must rule out (at ``PP_CHECK_SIGMAS`` of their own sigma) when
#: the frames flagged one that the objects do not support: the shift that turns the camera by this
#: much (deg; fx tan of it, ~35 px at fx 2000), the benchmarks' wrong-pose line
PP_CHECK_DEG = 1.0
PP_CHECK_SIGMAS = 2.0


def _pp_object_sd(ctx: FitContext, outline: bool = False) -> tuple[np.ndarray, int]:
    """(leave-objects-out jackknife 1-sigma [2] px of the principal-point shift, distinct objects).
    The matched pairs are grouped into physical objects (``uncertainty.object_groups``: a parked car
    or a track seen over the frames is one object) and each of ``min(objects, PP_OBJECT_GROUPS)``
    interleaved groups of objects is left out in turn (matches fixed, pose refitted). Zeros with
    fewer than 4 objects (nothing to leave out; the ``few_objects`` rule refuses such poses anyway).

    The bootstrap over frames treats the frames as independent samples; the same objects seen again
    in every frame are not: an object's own error (its outline, its occlusion, its 3D box) repeats in
    each of its boxes and a bootstrap over frames cannot see it. Realism clean site 9 (5 parked
    objects, 66 matches): the shift (+34, -72) px had a frame-bootstrap sigma of (8, 16) px, a false
    misfit; leaving one object out moves it to (+262, -272) px (object jackknife sigma ~180 px)."""
    groups = object_groups(ctx.frames, ctx.pairs)
    n_obj = int(groups.max()) + 1 if len(groups) else 0
    if n_obj < 4:
        return np.zeros(2), n_obj
    G = min(n_obj, PP_OBJECT_GROUPS)
    offs = np.cumsum([0] + [len(p) for p in ctx.pairs])
    est = []
    for g in range(G):
        out = np.arange(g, n_obj, G)
        sub = [p[~np.isin(groups[offs[k]:offs[k + 1]], out)] for k, p in enumerate(ctx.pairs)]
        est.append(_pp_fit(ctx.frames, sub, ctx.intr, ctx.pose, ctx.noise, ctx.f_scale, ctx.occlusion, outline))
    sd = jackknife_sd(np.asarray(est))
    return np.where(np.isfinite(sd), sd, np.inf), n_obj


def _pp_jacobian_sd(ctx: FitContext) -> np.ndarray | None:
    """1-sigma [2] px of the principal-point shift from the cost's Jacobian at the given intrinsics
    and the pose in use, the pose free (its six parameters profiled out of the information, as
    ``uncertainty.pose_covariance`` does for the pose): the larger per parameter of the classic
    inverse information x the inlier residuals' variance and the sandwich clustered per matched
    pair (its 4 edges share one 3D box error). None when the information is singular.

    The frame bootstrap (``_pp_boot``) and the object jackknife measure how the fitted shift moves
    when frames or objects are left out; where the shift trades off against the camera's rotation
    (a wide-angle lens: on the horizon line of an equidistant image a turn of the camera moves every
    point by the same pixels, as a shift of cx does) the fitted shift is a poorly determined,
    heavy-tailed quantity that those resamplings of one draw understate. Double sphere 150 deg,
    site 4 of the camera-model bench, right intrinsics: the boxes fit a shift of (+31, +15) px at
    (5, 2) px of frame-bootstrap sigma, a 6-sigma misfit, while 10 fresh noise draws of the same
    site fit +3 to +18 px in x and freeing cx, cy turned the pose by 4 deg for a robust-cost gain of
    2.4; this Jacobian gives (13, 6) px there, and (3-5, 1) px on the same lens's sites where a
    wrong cx (3 % of the width) is fitted back."""
    info = principal_point_information(ctx)  # (the pose's move per px is the route-b part's, uncertainty)
    return None if info is None else info[0]


def _pp_need(intr: CameraIntrinsics) -> float:
    """The principal-point shift (px) that turns the camera by ``PP_CHECK_DEG``: fx tan of it on a pinhole;
    on a wide-angle model the image's move at the principal point when a ray turns by that much, where
    that is smaller (the model's own focal length there: fx / (1 + xi) on the unified model, whose fx tan
    1 deg is twice the 1-degree shift at xi 1.1). Session 15 review: unified 150 deg, bench site 9, cx
    given 1 % of the width off: the check fitted -11.3 px, "within" the 16.1 px it took for 1 deg, while
    7.7 px turn that camera 1 deg; delivered 1.35 deg off. Never larger than fx tan of it (a model whose
    centre is stretched, double sphere at xi < 0, keeps the stricter fx tan)."""
    need = float(min(intr.fx, intr.fy) * np.tan(np.radians(PP_CHECK_DEG)))
    if isinstance(intr, CameraIntrinsics) or not pp_resolution_applies(intr):  # (a pinhole: fx tan of it)
        return need
    t = float(np.tan(np.radians(PP_CHECK_DEG)))
    uv, ok = intr.project(np.array([[t, 0.0, 1.0], [0.0, t, 1.0]]))
    moved = np.array([abs(uv[0, 0] - intr.cx), abs(uv[1, 1] - intr.cy)], dtype=np.float64)
    if not (np.all(ok) and np.all(np.isfinite(moved)) and np.all(moved > 0)):
        return need
    return float(min(need, float(moved.min())))


def _pp_unverifiable(ctx: FitContext, chk: MisfitCheck, d: np.ndarray, sd_obj: np.ndarray,
                     n_obj: int) -> tuple[MisfitCheck, str]:
    """The ``principal_point_unverifiable`` check and message: the objects' jackknife sigma
    ``sd_obj`` [2] px does not rule out a shift that turns the pose by ``PP_CHECK_DEG``.

    Checked against a second statistic in session 10 (issue 25): the robust cost at this fit's
    context with cx or cy moved by that shift, counted once per object. Wherever this fired on the
    realism suite (right poses at clean site 9, detector sites 4, 13, 18; the principal point +3 % W
    poses 1.2-2.3 deg off at sites 4, 7, 8, 13, 18) no such shift raised it by more than 1.4 per
    object (a 2-sigma difference needs ~2), and the right poses under detector boxes asked for the
    same shift as the wrong principal point (-0.24 to -0.70 per object against -0.26 to -0.90): the
    data, not the jackknife, are what cannot tell them apart."""
    need = _pp_need(ctx.intr)
    detail = chk.detail + (f"; not verifiable: a shift of {need:.0f} px (the camera turned {PP_CHECK_DEG:g} deg) is "
                           f"not ruled out at {PP_CHECK_SIGMAS:g} object sigmas ({n_obj} objects, sigma "
                           f"({sd_obj[0]:.1f}, {sd_obj[1]:.1f}) px)")
    msg = (f"not verifiable: the {sum(len(p) for p in ctx.pairs)} matches come from {n_obj} distinct objects, too few "
           f"to check the principal point: the boxes fit it moved by ({d[0]:+.0f}, {d[1]:+.0f}) px, but leaving one "
           f"object out moves that fit by up to {float(np.max(sd_obj)):.0f} px (1-sigma), so a wrong cx, cy that turns "
           f"the pose by {PP_CHECK_DEG:g} deg would go unnoticed. Add frames in which other objects pass, at other "
           "places in the image (the intrinsics are not blamed: the shift is within the objects' scatter)")
    return replace(chk, flagged=True, detail=detail), msg


def _pp_flagged(d: np.ndarray, sd_xy: np.ndarray, W: int) -> bool:
    sd, shift = float(np.linalg.norm(sd_xy)), float(np.linalg.norm(d))
    return bool((shift > PP_TOL_FRAC * W and shift > PP_SIGMAS * sd)
                or (abs(d[0]) > PP_TOL_FRAC * W and abs(d[0]) > PP_X_SIGMAS * sd_xy[0]))


def _pp_x_unresolved(d: np.ndarray, sd_xy: np.ndarray, W: int, need: float) -> bool:
    """Whether an unflagged shift ``d`` [2] px has an x part that turns the camera beyond ``PP_CHECK_DEG``
    (``need`` px) and the tolerance (``PP_TOL_FRAC`` of the width ``W``) while its x sigma cannot rule out
    a shift of ``need`` at ``PP_CHECK_SIGMAS`` (the objects' rule, ``_pp_unverifiable``, applied where the
    frames flagged nothing): the boxes' best fit says the pose is off beyond the wrong-pose line, and the
    check's resolution is too coarse to say that the given cx is right instead (a flag needs
    ``PP_X_SIGMAS`` sigmas, the gray zone ``PP_X_UNVERIFIED_SIGMAS``; both lie beyond twice the shift it
    would have to see). Session 14 review, cx given 3 % of the width off with detector-outline boxes,
    site 0: the check fitted (-57, +24) px, the true shift, at 2.2 x-sigmas (25.5 px) against a 1-degree
    shift of 41 px, and the pose was delivered 1.15 deg / 0.81 m off."""
    return bool(abs(d[0]) > max(need, PP_TOL_FRAC * W) and PP_CHECK_SIGMAS * float(sd_xy[0]) > need)


#: the principal-point message's words where the frames and the objects flag a shift that the cost's
#: Jacobian, with the camera's rotation free, does not resolve (``principal_point_check_all``)
_PP_TRADES = "trades off against the camera's rotation"
#: the principal-point detail's words for an unflagged shift that turns the camera beyond ``PP_CHECK_DEG``
_PP_ASKED = "neither confirmed nor ruled out"
#: the principal-point detail's words for an unflagged shift whose x part alone turns the camera beyond
#: ``PP_CHECK_DEG`` (``principal_point_resolution`` puts it in the bound on wide-angle models)
_PP_X_BEYOND = "beyond the 1-degree shift, unflagged"
#: the principal-point detail's words for a shift that the box model (outline offsets) explains
_PP_BOX_EXPLAINS = "the box model explains it"
#: a 2D box edge within this many pixels of the image border is the border's, not the object's
PP_BORDER_PX = 1.0


def inner_pairs(frames: list[CalibFrame], pairs: list[np.ndarray]) -> list[np.ndarray]:
    """The matches whose 2D box touches no image border (within ``PP_BORDER_PX``): a box cut by the
    border (a truncated object) carries its object's outline on one side only, which a shift of the
    principal point can mimic."""
    out = []
    for f, p in zip(frames, pairs):
        if not len(p):
            out.append(p)
            continue
        W, H = f.size
        b = f.boxes2d[p[:, 0]]
        keep = ((b[:, 0] > PP_BORDER_PX) & (b[:, 1] > PP_BORDER_PX) & (b[:, 2] < W - PP_BORDER_PX)
                & (b[:, 3] < H - PP_BORDER_PX))
        out.append(p[keep])
    return out


#: the joint principal-point / focal-length fit that re-centres an estimated focal length (``pp_focal_centred``):
#: at most this many cost evaluations (the pose, cx, cy and the focal scale; ~10 needed on the bench's sites)
PP_FOCAL_NFEV = 100


def pp_focal_centred(ctx: FitContext) -> tuple[FitContext, str]:
    """(``ctx`` at the focal length fitted jointly with the principal point and the pose, a note for
    the check's detail): the context :func:`principal_point_check` judges when the calibration
    estimated the focal length from these boxes.

    The check refits the principal point with the pose free because the pose was fitted from the
    same boxes: held at its estimate it would have absorbed part of any shift. An estimated focal
    length is such a fitted parameter too: fitted with the given (possibly wrong) cx, cy, it takes
    up part of their error (with the pose), and the check, holding it, then finds only the rest.
    The joint fit's focal length is where the principal point's profile is judged (at it, the
    shift fitted with the focal held is the joint fit's shift); a right calibration's estimated
    focal length is already that fit's (the shift is ~0) and the context hardly moves. Unified
    150 deg, site 3 of ``bench_camera_models.py``, cx given 38 px (3 % of the width) off: "auto"
    estimated fx 905.7 (true 921.6), the pose 4.8 deg off; with that focal held the check fitted
    (-16.6, +5.7) px, below the tolerance; with the focal free (-41.4, +1.0) px and fx 921.7."""
    *_, fit = lsq(ctx, PP_FOCAL_NFEV, extra=(PrincipalPointTerm(), FocalScaleTerm()))
    s = float(np.exp(float(np.asarray(fit.params[FocalScaleTerm.name])[0])))
    if not np.isfinite(s) or s <= 0:
        return ctx, ""
    intr = replace(ctx.intr, fx=ctx.intr.fx * s, fy=ctx.intr.fy * s)
    note = (f"; the focal length was estimated from these boxes: judged at the focal length fitted with the "
            f"principal point (fx {ctx.intr.fx:.1f} -> {intr.fx:.1f} px)")
    return replace(ctx, intr=intr), note


def principal_point_check(ctx: FitContext, *, draws: int = 5, seed: int = 0, places: int | None = None,
                          focal_free: bool = False) -> tuple[MisfitCheck, str | None]:
    """:func:`principal_point_check_looks`; with ``focal_free`` (the calibration estimated the focal
    length, ``selfcal``) a check that passes at the estimated focal length is judged again at
    :func:`pp_focal_centred`'s, and a flag there stands (the note added to the detail): this only
    ever adds a refusal. Both, not the centred one alone: each refit starts from the calibration's
    pose and the robust cost is not convex; realism principal point +3 % W, site 19 (pinhole, fx
    estimated x1.010): at the estimated focal length the boxes fit (-54, -17) px, a misfit; at the
    jointly fitted one (x0.992 of it) the refit from that pose stops at (0, 0) px (cost 79 against 43),
    and the pose would have been delivered 1.8 deg / 0.61 m off. The second look adds only a "model
    misfit" (see the code)."""
    chk, msg = principal_point_check_looks(ctx, draws=draws, seed=seed, places=places)
    if not focal_free or (msg is not None and not pp_unresolved(chk)):
        return chk, msg
    # (a check "not verifiable" only by the resolution rule may be delivered with its sigma part: it is
    # judged at the jointly fitted focal length too, as a pass)
    centred, note = pp_focal_centred(ctx)
    chk2, msg2 = principal_point_check_looks(centred, draws=draws, seed=seed, places=places)
    traded = _PP_TRADES in (msg2 or "") and pp_resolution_applies(ctx.intr)
    if (msg2 or "").startswith("model misfit") or traded:
        first = chk.detail.replace(f" ({PP_UNRESOLVED})", "")  # (the misfit decides: not the rule's verdict)
        return replace(chk2, detail=chk2.detail + note + f"; at the estimated focal length: {first}"), msg2
    # a second look at another value of a nuisance parameter: only its decisive verdicts add a refusal: a
    # misfit (a shift beyond the tolerance, the objects' scatter, the pose-free sigma and the box model),
    # or a shift that the frames and the objects both flag and only the camera's rotation, traded off
    # against it, leaves unconfirmed (unified 150 deg bench site 2, cx given 3 % of the width low, fx
    # estimated 956.8 for 921.6: the first look fitted (+15, -1) px within its tolerance, the second
    # (+38.8, +0.7) px, the true shift, at 7 x-sigmas of the frames and past the objects' 5.3 px, and
    # the pose was delivered 4.7 deg / 0.60 m off), on a wide-angle model (``pp_resolution_applies``:
    # on a pinhole the trade-off verdict came from a shift along y, realism focal +-5/10 % site 0,
    # (-11, -47) px, and refused a right pose 0.007 deg off); its other gray verdict, the objects' scatter, would
    # refuse right poses the first look passed (realism detector_outline sites 0, 3, 11, pinhole, fx
    # estimated x0.98-1.00: 0.15-0.33 deg off)
    said = "not flagged either" if msg2 is None else f"not verifiable there ({chk2.detail[:160]}), not a misfit"
    if msg is not None:  # the resolution rule's verdict stands (its words end the detail)
        return replace(chk, detail=note[2:] + f": {said}; " + chk.detail), msg
    return replace(chk, detail=chk.detail + note + f": {said}"), None


def principal_point_check_looks(ctx: FitContext, *, draws: int = 5, seed: int = 0,
                                places: int | None = None) -> tuple[MisfitCheck, str | None]:
    """:func:`principal_point_check_all`, and when it names a misfit (or a shift it cannot check)
    while some matched 2D boxes touch the image border, the same check without them (truncated
    boxes do not vote): a shift those boxes alone asked for is no misfit (the second look only
    ever clears or turns a misfit into "not verifiable"; a cropped image moves every box). An
    unflagged shift that turns the camera beyond ``PP_CHECK_DEG`` (not verifiable,
    ``PP_X_UNVERIFIED_SIGMAS``) is cleared only when the boxes inside the image do not ask for such
    a shift either (the border boxes made it); otherwise it stays not verifiable: fewer boxes
    cannot verify what all of them could not. A shift not verifiable because the objects scatter
    (``_pp_object_sd``) is kept alike unless the inner boxes' box-model test explains their shift
    (session 13: it had been judged again as a flag, and a wide-angle camera's wrong cx cleared). Realism
    ``detector_truncation`` (objects cut by the border, their visible outline): shifts of 70-170 px
    in x that the boxes inside the image do not ask for."""
    chk, msg = principal_point_check_all(ctx, draws=draws, seed=seed, places=places)
    if msg is None:  # nothing flagged: nothing to clear; but can these boxes check the principal point at all?
        return principal_point_resolution(ctx, chk)
    inner = inner_pairs(ctx.frames, ctx.pairs)
    n_in, n = sum(len(p) for p in inner), sum(len(p) for p in ctx.pairs)
    if n_in == n:
        return chk, msg
    chk2, msg2 = principal_point_check_all(ctx.with_pairs(inner), draws=draws, seed=seed, places=places)
    if chk2.detail == "too few matches or frames" or (msg2 or "").startswith("model misfit") \
            or (msg2 is not None and not msg.startswith("model misfit")):
        return chk, msg
    explained = _PP_BOX_EXPLAINS in chk2.detail  # the outline offsets, not the principal point, ask for it
    if chk2.statistic > _pp_need(ctx.intr) and (_PP_ASKED in chk.detail
                                               or (msg.startswith("not verifiable") and not explained)):
        # all boxes could not verify the principal point (an unflagged shift that turns the camera
        # beyond PP_CHECK_DEG, or one the objects' scatter does not rule out) and the inner boxes
        # still ask for a shift that turns it beyond PP_CHECK_DEG: the border boxes did not make it,
        # and fewer boxes cannot verify what all of them could not (realism principal point +3 % W,
        # 4 px, site 18: all boxes fit (-35, -44) px, x at 3.3 sigmas; without its 4 border boxes
        # (-41, -56) px at 2.7 sigmas cleared it, and the pose was delivered 1.55 deg / 0.49 m off;
        # unified 150 deg bench site 2, cx 3 % of the width off: the objects' scatter left all boxes'
        # (-19, +5) px not verifiable, the inner boxes' (-18, +2) px (16 px turn the camera 1 deg)
        # below the tolerance cleared it, and the pose was delivered 5.2 deg / 0.55 m off). A shift
        # the inner boxes' box-model test explains (the outline offsets ask for it) still clears the
        # objects' verdict, as before
        return chk, msg
    note = f"without the {n - n_in} matched 2D boxes at the image border (of {n}): "
    cleared = replace(chk2, detail=note + chk2.detail + f"; with them: {chk.detail}")
    return (cleared, msg2) if msg2 is not None else principal_point_resolution(ctx, cleared)


#: the principal point is verifiable by the boxes only when, with the camera's rotation free, the
#: 1-sigma of cx (``_pp_jacobian_sd``) is within the shift that turns the camera by ``PP_CHECK_DEG``
#: times this: beyond it a given cx that is off by a typical (1-sigma) error already turns the pose
#: past the wrong-pose line, and the check (a flag needs ``PP_SIGMAS`` sigmas) lets through errors
#: that turn it several times as far. cx only: a road scene's objects spread along the horizon
#: band, where a turn about the vertical (yaw) moves a wide-angle image almost as a shift of cx does
#: (the degeneracy), while their spread in azimuth separates a pitch from a shift of cy; the
#: vertical sigma is instead widened by the boxes' own shape biases (tops and bottoms, as for
#: ``PP_X_SIGMAS``): realism detector_all, pinhole, right poses: cy 1.0-1.4 x the 1-degree shift,
#: cx 0.36-0.38 x; double sphere 150 site 4: cx 1.4-1.8 x, cy 0.6-0.8 x
PP_RESOLUTION_SIGMAS = 1.0


def pp_resolution_applies(intr) -> bool:
    """Whether :func:`principal_point_resolution` judges this camera: a wide-angle camera model, where
    the lens maps angles nearly linearly to pixels and a turn moves the boxes as a shift of cx does
    (every wrong success it stops: double sphere / unified 150 deg). Not a pinhole (``CameraIntrinsics``):
    there a turn stretches the image towards its edges while a shift does not, the flagged check finds
    a wrong cx (realism principal_point+3%W), and the rule refused right poses of few-frame recordings
    (session 13 review: the docs' 8-frame synthetic site, cx 1-sigma 18 px against 16 px)."""
    return not (isinstance(intr, CameraIntrinsics) or bool(getattr(intr, "is_pinhole", False)))


def principal_point_resolution(ctx: FitContext, chk: MisfitCheck) -> tuple[MisfitCheck, str | None]:
    """The unflagged principal-point check ``chk`` judged for what it can see: (``chk`` with the
    pose-free sigma noted, None) when the boxes fix the principal point to within the shift that
    turns the camera by ``PP_CHECK_DEG`` (at ``PP_RESOLUTION_SIGMAS``), else (flagged, a "not
    verifiable" message): the pose is refused as ``principal_point_unverifiable`` when nothing
    else refused it (``api._misfit_checks``). Never clears a flag; poses are not touched.

    A camera turn and a shift of cx, cy move the boxes alike where the lens maps angles nearly
    linearly to pixels (a wide-angle lens: along the horizon line of an equidistant image a turn
    moves every point by the same pixels); the calibration's pose then absorbs a wrong principal
    point, and the check, refitting from that pose, finds a small shift: what it can detect is
    bounded by how well the boxes fix the principal point with the rotation free, which the
    frame bootstrap of the fitted shift does not measure (it resamples one draw). Double sphere
    150 deg, site 4 of ``bench_camera_models.py``, cx given 38 px (3 % of the width) off: pose
    delivered 4.4 deg off with the shift refitted as (-7, +15) px; the Jacobian sigma there is
    (12.8, 5.4) px against a 1-degree shift of 7.0 px."""
    if chk.flagged or chk.detail == "too few matches or frames" or not pp_resolution_applies(ctx.intr):
        return chk, None
    sd = _pp_jacobian_sd(ctx)
    if sd is None:
        return chk, None
    need = _pp_need(ctx.intr)
    ratio = float(sd[0]) / need
    note = (f"; with the camera's rotation free the boxes fix it to 1-sigma ({sd[0]:.1f}, {sd[1]:.1f}) px, cx at "
            f"{ratio:.2f} x the {need:.1f} px shift that turns the camera {PP_CHECK_DEG:g} deg")
    if ratio <= PP_RESOLUTION_SIGMAS and _PP_X_BEYOND not in chk.detail:
        return replace(chk, detail=chk.detail + note), None
    if ratio <= PP_RESOLUTION_SIGMAS:
        # resolved, but the boxes' best fit turns the camera beyond the wrong-pose line while the check, whose
        # tolerance is in pixels (PP_TOL_FRAC of the width: 1.2-2.7 deg of turn on a 150-degree lens), cannot flag
        # it: a given cx off by that much is what the pose absorbed, and the bound must cover it (route b with the
        # rms of that shift and its sigma). Kannala-Brandt 150 deg, bench site 9, cx given 1.5 % of the width off:
        # the check fitted (-13.1, -0.9) px (8.2 px turn the camera 1 deg; x sigma 6.0 px with the rotation free)
        # and the pose was delivered 2.21 deg off with a 0.30 deg bound; with the part: 2.53 deg, refused
        msg = (f"not verifiable: the boxes fit best with cx moved by more than the {need:.0f} px that turn the camera "
               f"{PP_CHECK_DEG:g} deg, below the check's tolerance ({PP_TOL_FRAC * 100:g} % of the width, which on a "
               "wide-angle lens is a larger turn); a given cx that is off by that much would be absorbed by the pose. "
               "Give cx, cy from a calibration you trust and add frames in which objects pass nearer the image's left "
               "and right edges and at other depths")
        return replace(chk, flagged=True, detail=chk.detail + note + f": not verifiable, {_PP_ASKED} ({PP_UNRESOLVED})"), msg
    turn = float(np.degrees(np.arctan(float(sd[0]) / min(ctx.intr.fx, ctx.intr.fy))))
    msg = (f"not verifiable: these detections cannot check the principal point: with the camera's rotation free they "
           f"fix cx only to 1-sigma {float(sd[0]):.0f} px, a camera turn of {turn:.1f} deg (the check needs it within "
           f"{need:.0f} px, {PP_CHECK_DEG:g} deg), because a turn of the camera moves the boxes almost as a shift of cx "
           f"does (common with wide-angle lenses); a given cx that is off would be absorbed by the pose unseen. Give "
           f"cx, cy from a calibration you trust and add frames in which objects pass at other places in the image, "
           f"nearer its left and right edges and at other depths")
    return replace(chk, flagged=True, detail=chk.detail + note + f": not verifiable, {_PP_ASKED} ({PP_UNRESOLVED})"), msg


#: the principal-point detail's words where :func:`principal_point_resolution` alone makes the check "not
#: verifiable" (the boxes fix cx, with the rotation free, only beyond the 1-degree shift; nothing flagged)
PP_UNRESOLVED = "cx not resolved with the rotation free"


def pp_unresolved(chk: MisfitCheck | None) -> bool:
    """Whether the principal-point check ``chk`` is "not verifiable" only by :func:`principal_point_resolution`
    (an unflagged shift on a wide-angle camera whose cx the boxes do not resolve with the rotation free):
    the calibration then puts the pose's move for that resolution into the reported sigma
    (``uncertainty.principal_point_part``) and lets the 95 % bound decide, instead of refusing (issue 26,
    route b). Any other "not verifiable" verdict (the objects' scatter, the Jacobian trade-off of a flagged
    shift, an unflagged shift that turns the camera beyond ``PP_CHECK_DEG``) keeps its refusal."""
    return chk is not None and chk.flagged and chk.detail.endswith(f"({PP_UNRESOLVED})")


def principal_point_check_all(ctx: FitContext, *, draws: int = 5, seed: int = 0,
                              places: int | None = None) -> tuple[MisfitCheck, str | None]:
    """Fitted shift of the principal point (px; pose refitted, matches fixed) and its bootstrap
    spread over frames; flagged beyond ``PP_TOL_FRAC`` of the width and 4 sigma, or when its x part
    alone is beyond that share and ``PP_X_SIGMAS`` sigmas of x. ``places``:
    distinct places of the matched 3D boxes; when the matches repeat a few objects (4+ matches
    per place) the message says that the shift may be the pose's ambiguity instead (realism queue
    site 9: exact intrinsics fit a shift of 80 px, a 3 % W error one of 76 px).

    The box model is tested before the intrinsics are blamed: a flagged shift is fitted again with
    the detector-outline offsets (``boxmodel.outline_edge_term``: sides, top, bottom as shares of
    the box size) free; when the shift is then no longer flagged, the 2D boxes' outline, not the
    principal point, explains it (PandaSet 002 with detector boxes: +108 px vertical, the tops and
    bottoms of vehicles' visible outlines against their point hulls) and nothing is flagged."""
    frames, pairs, intr, pose, noise, f_scale, occlusion = (ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise,
                                                            ctx.f_scale, ctx.occlusion)
    W = frames[0].size[0]
    if sum(len(p) for p in pairs) < 12 or sum(len(p) > 0 for p in pairs) < 4:
        # a principal-point shift trades off against a small rotation; with fewer than 4 frames the
        # bootstrap over pairs understates that (one nuScenes frame, 47 pairs: a false 78 px)
        return MisfitCheck("principal_point", 0.0, PP_TOL_FRAC * W, False, "too few matches or frames"), None
    d = _pp_fit(frames, pairs, intr, pose, noise, f_scale, occlusion)
    need = _pp_need(intr)
    if float(np.linalg.norm(d)) <= min(PP_TOL_FRAC * W, need):  # cannot flag nor turn the pose: no bootstrap refits
        return MisfitCheck("principal_point", float(np.linalg.norm(d)), PP_TOL_FRAC * W, False,
                           f"fitted principal point shift ({d[0]:+.1f}, {d[1]:+.1f}) px, within the tolerance (its "
                           "bootstrap sigma not computed)"), None
    d, sd_xy = _pp_boot(ctx, draws, seed, False, d)
    box_memo: list = []

    def box_model_clears() -> str:
        """The box model first: with the outline offsets free, is the shift still asked for? Its x
        part by its own sigma (the symmetric side offset cannot mimic it); the whole shift by how
        much it lowers the robust cost, counted once per object (a vertical shift and a pitch of the
        pose nearly trade off, so its size and a bootstrap over frames that share one box bias say
        little: PandaSet's detector boxes fit +108 px alone and +196 px with the offsets). The note
        when the box model explains the shift, else "" (fitted once)."""
        if box_memo:
            return box_memo[0]
        d2, sd2 = _pp_boot(ctx, draws, seed, True)
        _, c_pp = _pp_outline_fits(frames, pairs, intr, pose, noise, f_scale, occlusion, True)
        _, c_box = _pp_outline_fits(frames, pairs, intr, pose, noise, f_scale, occlusion, False)
        *_, pp_only = lsq(ctx, 60, extra=(PrincipalPointTerm(),))
        n = sum(len(p) for p in pairs)
        per_obj = max(n / max(places or n / 4.0, 1.0), 1.0)
        gain = (c_box - c_pp) / per_obj
        x_flag = abs(d2[0]) > PP_TOL_FRAC * W and abs(d2[0]) > PP_X_SIGMAS * sd2[0]
        # the outline must explain the boxes better than the principal point does (alternative
        # models, each alone), and the shift must add little to it
        note = ""
        if not x_flag and c_box < pp_only.cost and gain <= PP_MIN_GAIN:
            note = (f"; with the 2D outline offsets fitted (box model) it is ({d2[0]:+.1f}, {d2[1]:+.1f}) px, "
                    f"x sigma {sd2[0]:.1f} px, and lowers the cost by {gain:.1f} per object (limit "
                    f"{PP_MIN_GAIN:g}); cost with the outline offsets alone {c_box:.1f}, with the principal "
                    f"point alone {pp_only.cost:.1f}: {_PP_BOX_EXPLAINS}")
        box_memo.append(note)
        return note

    def judge(sd_xy: np.ndarray) -> tuple[bool, str]:
        flagged = _pp_flagged(d, sd_xy, W)
        x_alone = bool(abs(d[0]) > PP_TOL_FRAC * W and abs(d[0]) > PP_X_SIGMAS * sd_xy[0])
        if flagged and not x_alone:  # a horizontal shift no outline offset can mimic stays flagged
            note = box_model_clears()
            if note:
                return False, note
        return flagged, ""

    flagged, box_note = judge(sd_xy)
    obj_note, unverifiable = "", None
    if flagged:  # the objects' own errors too: only ever widens the sigma (exact to skip otherwise)
        sd_obj, n_obj = _pp_object_sd(ctx)
        if np.any(sd_obj > sd_xy):
            obj_note = (f"; leaving objects out ({n_obj} objects) gives a sigma of ({sd_obj[0]:.1f}, {sd_obj[1]:.1f}) px, "
                        f"against ({sd_xy[0]:.1f}, {sd_xy[1]:.1f}) px over frames")
            sd_xy = np.maximum(sd_xy, sd_obj)
            flagged, box_note = judge(sd_xy)
            if not flagged and PP_CHECK_SIGMAS * float(np.max(sd_obj)) > need:
                # the frames' flag was the objects' own errors, but these objects cannot check the
                # principal point either: a shift that turns the pose by PP_CHECK_DEG would pass unseen
                unverifiable = (need, n_obj)
    jac_note = ""
    if flagged:  # the model's own Jacobian, the pose free: is the shift beyond its sigma there too?
        sd_jac = _pp_jacobian_sd(ctx)
        if sd_jac is not None and np.any(sd_jac > sd_xy) and not judge(np.maximum(sd_xy, sd_jac))[0]:
            # the resamplings of these boxes flag a shift that the information in them does not
            # support: it trades off against the pose, and the boxes neither confirm a wrong cx, cy
            # nor rule one out (never a success: refused as not verifiable instead of blaming the
            # intrinsics)
            z = float(np.linalg.norm(d) / max(float(np.linalg.norm(np.maximum(sd_xy, sd_jac))), 1e-9))
            turn = float(np.degrees(np.arctan(float(np.linalg.norm(d)) / min(intr.fx, intr.fy))))
            jac_note = (f"; with the camera's rotation free its sigma from the cost's Jacobian is ({sd_jac[0]:.1f}, "
                        f"{sd_jac[1]:.1f}) px ({z:.1f} sigmas): not verifiable, the shift turns the camera by {turn:.2f} "
                        f"deg, {_PP_ASKED}")
            detail = (f"fitted principal point shift ({d[0]:+.1f}, {d[1]:+.1f}) px (bootstrap sigma "
                      f"{float(np.linalg.norm(sd_xy)):.1f} px; x alone {sd_xy[0]:.1f} px){obj_note}{box_note}{jac_note}")
            msg = (f"not verifiable: the boxes fit best with the principal point moved by ({d[0]:+.0f}, {d[1]:+.0f}) px "
                   f"(cx ~{intr.cx + d[0]:.0f} instead of {intr.cx:.0f}, cy ~{intr.cy + d[1]:.0f} instead of {intr.cy:.0f}), "
                   f"which would turn the camera by {turn:.1f} deg; but that shift {_PP_TRADES} "
                   f"here (1-sigma ({sd_jac[0]:.0f}, {sd_jac[1]:.0f}) px with the rotation free, {z:.1f} sigmas), "
                   "so these detections can neither confirm it nor rule out a wrong cx, cy that turns the pose by as "
                   "much (common with wide-angle lenses). Add frames in which objects pass at other places in the "
                   "image, nearer its left and right edges and at other heights (the intrinsics are not blamed)")
            return MisfitCheck("principal_point", float(np.linalg.norm(d)), PP_TOL_FRAC * W, True, detail), msg
    sd, shift = float(np.linalg.norm(sd_xy)), float(np.linalg.norm(d))
    detail = (f"fitted principal point shift ({d[0]:+.1f}, {d[1]:+.1f}) px (bootstrap sigma {sd:.1f} px; "
              f"x alone {sd_xy[0]:.1f} px){obj_note}{box_note}")
    msg = None
    if unverifiable is not None:
        need, n_obj = unverifiable
        return _pp_unverifiable(ctx, MisfitCheck("principal_point", shift, PP_TOL_FRAC * W, True, detail), d,
                                sd_obj, n_obj)
    x_gray = bool(abs(d[0]) > PP_TOL_FRAC * W and abs(d[0]) > PP_X_UNVERIFIED_SIGMAS * sd_xy[0])
    if not flagged and shift > need and (x_gray or _pp_x_unresolved(d, sd_xy, W, need)) \
            and not (box_note or box_model_clears()):
        # not flagged, yet the boxes ask for a shift that turns the camera beyond PP_CHECK_DEG, with a
        # horizontal part beyond the tolerance and PP_X_UNVERIFIED_SIGMAS of its sigma (box-shape biases
        # shift along y, a cropped image along x), and the box model does not explain it: the pose with
        # the given cx, cy and the one with the fitted shift differ beyond the wrong-pose line, and the
        # data cannot choose between them
        detail += (f"; not verifiable: the shift turns the camera by {np.degrees(np.arctan(shift / min(intr.fx, intr.fy))):.2f}"
                   f" deg (limit {PP_CHECK_DEG:g} deg, {need:.0f} px), not flagged"
                   + ("" if x_gray else f", and {PP_CHECK_SIGMAS:g} x its x sigma ({sd_xy[0]:.1f} px) exceeds that shift")
                   + f": {_PP_ASKED}")
        msg = (f"not verifiable: the boxes fit best with the principal point moved by ({d[0]:+.0f}, {d[1]:+.0f}) px "
               f"(cx ~{intr.cx + d[0]:.0f} instead of {intr.cx:.0f}, cy ~{intr.cy + d[1]:.0f} instead of {intr.cy:.0f}), "
               f"which would turn the camera by {np.degrees(np.arctan(shift / min(intr.fx, intr.fy))):.1f} deg; these "
               f"detections can neither confirm that shift (1-sigma {sd:.0f} px) nor rule it out, so the pose found "
               "with the given intrinsics may be off by as much. Check cx, cy (cropped or resized image?) and add "
               "frames in which other objects pass, at other places and depths in the image")
        return MisfitCheck("principal_point", shift, PP_TOL_FRAC * W, True, detail), msg
    if flagged:
        msg = (f"model misfit: the boxes fit best with the principal point moved by ({d[0]:+.0f}, {d[1]:+.0f}) px "
               f"(cx ~{intr.cx + d[0]:.0f} instead of {intr.cx:.0f}, cy ~{intr.cy + d[1]:.0f} instead of {intr.cy:.0f}); "
               "the pose found with the given intrinsics is biased. Check the intrinsics (cropped or resized image?)")
        if float(np.max(sd_xy)) <= PP_ESTIMABLE_FRAC * W:
            msg += ", or let xcalib estimate them (refine_intrinsics='focal+center')"
        else:  # advice that would only be refused in turn ("principal point ... not constrained")
            msg += (f"; these detections cannot estimate the principal point (1-sigma {float(np.max(sd_xy)):.0f} px, "
                    f"more than {100 * PP_ESTIMABLE_FRAC:.0f} % of the width): give the right cx, cy")
        n = sum(len(p) for p in pairs)
        if places is not None and n >= 4 * max(places, 1):
            msg += (f" -- but the {n} matches lie at only {places} distinct places (queued or parked objects "
                    "repeated over the frames), where the principal point and the pose are hard to separate: add "
                    "frames with other objects before changing the intrinsics")
    if not flagged and abs(float(d[0])) > need:  # (judged by ``principal_point_resolution`` on wide-angle models)
        detail += (f"; its x part turns the camera by {np.degrees(np.arctan(abs(float(d[0])) / min(intr.fx, intr.fy))):.2f}"
                   f" deg ({_PP_X_BEYOND})")
    return MisfitCheck("principal_point", shift, PP_TOL_FRAC * W, flagged, detail), msg


@dataclass(frozen=True)
class LensFit:
    """The wide-lens refit of :func:`lens_fit`: the unified model's ``xi`` and focal scale, the
    robust costs with ``xi`` held at 0 and free (focal length free in both), the gain per object."""

    xi: float
    focal_scale: float
    cost_pinhole: float
    cost_wide: float
    gain_per_object: float
    # the fits' matches and the wide fit's pose (for :func:`lens_box_model`; not compared)
    pairs: list | None = field(default=None, repr=False, compare=False)
    pose: Pose | None = field(default=None, repr=False, compare=False)


def _wide_fit(frames, pairs, intr, pose: Pose, noise, f_scale, occlusion, lens: tuple):
    """(xi, focal scale, robust cost, pose) of the unified-lens fit. ``lens``: (xi held at this
    value, or None: free; the (xi, focal scale) starts, the lowest cost wins; with xi held, the
    first start's focal scale[; n: the starts after the first n run only while the lens question is
    open, :func:`_lens_open`]). The residuals are weighted as at ``intr`` whatever the lens, so
    costs compare. Several starts and the pinhole fit's focal length as the start: from xi 0 and
    the given focal alone, a 185-degree fisheye given as pinhole that fit the pinhole with the focal
    x1.41 ended at xi 0 and a cost above the pinhole's (22.5 -> 25.2). A start at the focal scale
    divided by 1 + xi reads the given focal length as the unified model's own f (1 + xi) (Mei's,
    Kalibr's omni convention): a unified 120-degree lens (xi 1.1) given as pinhole fit nothing
    from the given focal (xi 1.00, cost 16950) and xi 1.14 (cost 137) from there."""
    fixed, starts = lens[:2]
    n_always = lens[2] if len(lens) > 2 else len(starts)
    best, ended = None, []
    todo = starts[:1] if fixed is not None else starts
    shared_frames = shared(frames, "pool")
    items = [(shared_frames, pairs, intr, pose, noise, f_scale, occlusion, (fixed, x0, s0)) for x0, s0 in todo]
    # the starts that always run are independent: on the open pool's processes where there is one
    first = parallel_map(_lens_start, items[:n_always], "pool")
    for k, (x0, s0) in enumerate(todo):
        if k >= n_always and not _lens_open(ended):
            break
        fit = first[k] if k < len(first) else parallel_map(_lens_start, items[k:k + 1], "pool")[0]
        ended.append(float(fit.params[WideLensTerm.name][0]))
        if best is None or fit.cost < best[2]:
            best = (ended[-1], s0 * float(np.exp(fit.params[FocalScaleTerm.name][0])), float(fit.cost), fit.pose)
    return best


def _lens_start(item):
    """One start of :func:`_wide_fit`: the fitted cost model (a task of ``parallel_map``)."""
    frames, pairs, intr, pose, noise, f_scale, occlusion, (fixed, x0, s0) = item
    lens_base = replace(intr, fx=intr.fx * s0, fy=intr.fy * s0)
    return build_cost(frames, pairs, intr, pose, noise, occlusion,
                      extra=(WideLensTerm(lens_base, fixed, 0.0 if fixed is not None else x0),
                             FocalScaleTerm())).fit(f_scale=f_scale, max_nfev=60)


def _lens_open(ended_xi: list[float]) -> bool:
    """Whether the free lens fits so far (``ended_xi``: the xi each start ended at) leave the lens
    question open: some start ended bent (xi >= ``LENS_MIN_XI``). When the start from the pinhole
    and the start from ``LENS_START_XI`` both came back below it, the boxes pull the lens to the
    pinhole from either side, and the start that reads the focal length as the unified model's
    f (1 + xi) is not run (~1/3 of the lens check's CPU on a pinhole site). It exists for the lens
    that does bend: from the given focal length a unified 120-degree lens stayed at xi 1.00 with a
    cost 120x the one that start found."""
    return any(x >= LENS_MIN_XI for x in ended_xi)


def lens_fit(frames: list[CalibFrame], pairs: list[np.ndarray], intr: CameraIntrinsics, pose: Pose,
             noise: NoiseModel, f_scale: float, occlusion: Occlusion, places: int | None = None) -> LensFit:
    """Refit the matches (fixed) with the pinhole widened into Mei's unified model (one parameter
    ``xi``, ``cost.WideLensTerm``) and the focal length free, against ``xi`` held at 0. The cost
    drop is counted per object (``places``: distinct places of the matched 3D boxes; the pairs of
    one object share its outline error), as the principal-point check does. The widened fit
    starts where the pinhole fit ended (pose, focal length), from xi 0 and ``LENS_START_XI`` (there
    also with the focal length read as the unified model's f (1 + xi), when one of the first two
    ended bent: ``_lens_open``).

    When the lens bends (``xi >= LENS_MIN_XI``) the boxes are matched once more through the fitted
    lens at its pose and both fits are repeated on those matches; the larger gain counts. A pose
    found with the wrong lens matches the boxes it can explain (the image centre), which hides
    the lens: a fisheye site at 185 degrees fit xi 0.40 (gain 12.9 per object) on the pinhole's
    matches. A pinhole site fits xi ~0 and is never rematched."""
    n = sum(len(p) for p in pairs)
    per_obj = max(n / max(places or n / 4.0, 1.0), 1.0)
    _, s0, c0, pose0 = _wide_fit(frames, pairs, intr, pose, noise, f_scale, occlusion, (0.0, ((0.0, 1.0),)))
    xi, scale, c1, pose1 = _wide_fit(frames, pairs, intr, pose0, noise, f_scale, occlusion,
                                     (None, ((0.0, s0), (LENS_START_XI, s0), (LENS_START_XI, s0 / (1 + LENS_START_XI))), 2))
    best = LensFit(xi, scale, c0, c1, (c0 - c1) / per_obj, pairs, pose1)
    if xi >= LENS_MIN_XI:
        cam = WideLensTerm(intr).camera(xi)
        cam = replace(cam, fx=cam.fx * scale, fy=cam.fy * scale)
        pairs2 = match_all(frames, cam, pose1.R, pose1.t)
        n2 = sum(len(p) for p in pairs2)
        if n2 >= 12:
            _, _, c0b, _ = _wide_fit(frames, pairs2, intr, pose, noise, f_scale, occlusion, (0.0, ((0.0, 1.0),)))
            xib, scaleb, c1b, pose1b = _wide_fit(frames, pairs2, intr, pose1, noise, f_scale, occlusion, (None, ((xi, scale),)))
            gain = (c0b - c1b) / max(n2 / max(places or n2 / 4.0, 1.0), 1.0)
            if gain > best.gain_per_object:
                best = LensFit(xib, scaleb, c0b, c1b, gain, pairs2, pose1b)
    return best


def lens_check(frames: list[CalibFrame], pairs: list[np.ndarray], intr, pose: Pose, noise: NoiseModel,
               f_scale: float, occlusion: Occlusion, *, places: int | None = None) -> tuple[MisfitCheck, str | None]:
    """Flag pinhole intrinsics that a wider-angle lens explains much better (:func:`lens_fit`):
    fitted ``xi >= LENS_MIN_XI`` and a robust-cost drop above ``LENS_MIN_GAIN`` per object. The
    frames of a fisheye camera given as pinhole fit xi 1.4-1.6 (equidistant ~1.75) at their true
    pose; good pinhole frames fit xi ~0 with no gain. Statistic: the gain per object. Only for a
    pinhole camera (a given wide-angle model is the user's statement of the lens)."""
    return lens_checks(frames, pairs, intr, pose, noise, f_scale, occlusion, places=places)[0]


def lens_checks(frames: list[CalibFrame], pairs: list[np.ndarray], intr, pose: Pose, noise: NoiseModel,
                f_scale: float, occlusion: Occlusion, *,
                places: int | None = None) -> tuple[tuple[MisfitCheck, str | None], tuple[MisfitCheck, str | None]]:
    """(:func:`lens_check`, the lens as the alternative cause): one :func:`lens_fit`, judged twice.
    The second verdict is the one to use when another intrinsics check (focal length, principal
    point) has fired: the data then already refuse the given pinhole, and the question is only which
    cause they support. The lens fit frees the focal length too, so its gain is what the wider lens
    explains beyond a rescaled pinhole; ``xi >= LENS_MIN_XI`` and a gain above ``LENS_ALT_GAIN`` per
    object name the lens. Unified 120/150-degree sites given as pinhole fit xi 0.44 / 4.0 with
    gains 4.3 / 8.5 per object at the (wrong) pinhole pose and were refused as focal-length misfits;
    wrong focal lengths on pinhole sites (realism +-5..20 %) fit xi <= 0.13."""
    if not WideLensTerm.applies(intr):
        what = "a pinhole with k3+ distortion" if isinstance(intr, CameraIntrinsics) else f"a {getattr(intr, 'name', '')} model"
        chk = MisfitCheck("lens", 0.0, LENS_MIN_GAIN, False, f"not checked: the camera is {what}"), None
        return chk, chk
    if sum(len(p) for p in pairs) < 12:
        chk = MisfitCheck("lens", 0.0, LENS_MIN_GAIN, False, "too few matches to fit a lens"), None
        return chk, chk
    fit = lens_fit(frames, pairs, intr, pose, noise, f_scale, occlusion, places)
    alt = _lens_verdict(fit, LENS_ALT_GAIN, True)
    chk, msg = _lens_verdict(fit, LENS_MIN_GAIN, False)
    if msg is not None:  # the box model first, as for the focal length (focal_box_model); where it does not
        boxed = lens_box_model(frames, intr, pose, noise, f_scale, occlusion, fit, places)  # explain it: as before
        chk_box, msg_box = _lens_verdict(boxed, LENS_MIN_GAIN, False)
        if msg_box is None:
            chk, msg = replace(chk_box, detail=chk_box.detail + f"; with the 2D outline offsets free in both fits (box "
                               f"model); without them {fit.gain_per_object:.1f} per object: the box model explains it"), None
    return (chk, msg), alt


def lens_box_model(frames: list[CalibFrame], intr: CameraIntrinsics, pose: Pose, noise: NoiseModel, f_scale: float,
                   occlusion: Occlusion, fit: LensFit, places: int | None = None) -> LensFit:
    """``fit`` (:func:`lens_fit`) with both of its fits repeated with the detector-outline offsets
    (``boxmodel.outline_edge_term``) free, on the same matches: the wide lens's gain over the
    pinhole beyond what the box model explains. A camera detector's visible outline makes every 2D
    box a few per cent smaller than the rectangle around its 3D box, and unevenly (its sides, top
    and bottom), which a unified lens with a small ``xi`` partly takes up: realism
    ``detector_outline`` 0, a pinhole with its exact focal length, fit xi 0.29 with a gain of 11.1
    per object (limit 10) at its right pose (0.10 deg / 0.09 m; its exact focal length kept by
    ``CalibConfig.focal_keep_box_model``) and was refused as a lens misfit;
    ``detector_truncation`` 13 alike. The offsets change the boxes' sizes only, as shares of each box,
    whatever its place in the image; a wider lens moves the boxes toward the centre the more the
    farther out they lie, which no offset takes up, so a fisheye given as pinhole keeps its gain.
    Each cost is at most the one without the offsets (the offsets at 0 are a point of the fit), so
    a refit that stops short never clears a flag by itself."""
    pairs = fit.pairs if fit.pairs is not None else []
    n = sum(len(p) for p in pairs)
    if n < 12:
        return fit
    per_obj = max(n / max(places or n / 4.0, 1.0), 1.0)

    def cost(fixed, xi0: float, s0: float, start: Pose) -> float:
        lens_base = replace(intr, fx=intr.fx * s0, fy=intr.fy * s0)
        model = build_cost(frames, pairs, intr, start, noise, occlusion,
                           (WideLensTerm(lens_base, fixed, 0.0 if fixed is not None else xi0), FocalScaleTerm()),
                           edge=outline_edge_term)
        return float(model.fit(f_scale=f_scale, max_nfev=60).cost)

    c0 = min(cost(0.0, 0.0, 1.0, pose), fit.cost_pinhole)
    c1 = min(cost(None, fit.xi, fit.focal_scale, fit.pose if fit.pose is not None else pose), fit.cost_wide)
    return replace(fit, cost_pinhole=c0, cost_wide=c1, gain_per_object=(c0 - c1) / per_obj)


def _lens_verdict(fit: LensFit, min_gain: float, alternative: bool) -> tuple[MisfitCheck, str | None]:
    """The lens check's verdict on ``fit`` at ``min_gain`` per object (``alternative``: judged because
    another intrinsics check fired)."""
    flagged = bool(fit.xi >= LENS_MIN_XI and fit.gain_per_object > min_gain)
    detail = (f"widened into a unified lens the boxes fit xi {fit.xi:.2f} (0: the given pinhole; limit {LENS_MIN_XI:g}) "
              f"with the focal length x{fit.focal_scale:.3f}; robust cost {fit.cost_wide:.1f} against {fit.cost_pinhole:.1f} "
              f"as pinhole: {fit.gain_per_object:.1f} per object (limit {min_gain:g}"
              + ("; judged as the alternative to a fired focal-length / principal-point check)" if alternative else ")"))
    msg = None
    if flagged:
        why = ("the boxes fit a wider-angle lens than the given pinhole intrinsics" if not alternative else
               "the given pinhole intrinsics do not fit the boxes, and a wider-angle lens explains them better than "
               "a changed focal length or principal point alone")
        msg = (f"model misfit: {why} -- a fisheye or wide-angle "
               f"camera given as pinhole? (refitted as a unified/Mei lens with xi ~{fit.xi:.1f}, the boxes are explained "
               f"with a robust cost of {fit.cost_wide:.0f} instead of {fit.cost_pinhole:.0f}"
               + (" with the focal length free in both" if alternative else "")
               + "; a pinhole has xi 0, an "
               "equidistant fisheye ~1.75). The pose found with pinhole intrinsics is biased. Give the camera's own "
               "model: an intrinsics JSON with a \"model\" field (kannala_brandt, unified, ucm, eucm, double_sphere; "
               "--intrinsics FILE, see docs/camera-models.md), a CameraInfo with distortion_model equidistant, or a "
               "Kalibr camchain (pinhole-equi, omni-radtan, ds-none, eucm-none); for a bag's equidistant camera, "
               "calibrate --fisheye keep")
    return MisfitCheck("lens", fit.gain_per_object, min_gain, flagged, detail), msg
