"""Where the error of a box-edge pose comes from: what each group of edges pulls (issue 25, session 15).

A calibration's pose error against the truth is split over groups of its box-edge residuals. The
calibration's own final cost is rebuilt -- pairs matched at its pose (delivered, or
``diagnostics.refused_T``), its noise model, its outline kind and intrinsics -- at the TRUE pose. The
soft-L1 Gauss-Newton step from the truth, ``dx = -H^-1 J^T W r`` (W the robust loss's weights at the
truth), is what the residuals there pull the pose by. Over a partition of the residuals it is the sum of
the groups' pulls ``dx_g = -H^-1 J_g^T W_g r_g``, and each group's share of the error is
``dx_g^T H dx / dx^T H dx`` (the Fisher metric, so the shares of a partition sum to 1; a negative share
pulls back towards the truth). It is a linearisation: ``fit`` (the robust refit from the truth, matches
held) says how far the step is from the full fit. Not replayed: a time offset estimated with the pose (the 3D
boxes moved along their motion) and the objects' own outline fit (``boxmodel.fit_object_outline``) where
``calibrate`` moved the pose to it; there ``fit`` and ``error`` differ.

Groups: edge kind (``border``: the 2D edge on the image border; ``censored``: hidden behind a nearer box;
``shaped``: inward beyond the occlusion shaping's tau at the truth; ``free``: the rest -- a partition
chosen by the residuals at the truth, so ``free`` leans outward), side (left / top / right / bottom),
2D box size (sqrt of its area, px), detector score, and object (``uncertainty.object_groups``).

Usage::

    PYTHONPATH=src python scripts/edge_attribution.py realism detector_all 8 9 [--json]
    PYTHONPATH=src python scripts/edge_attribution.py a9 0.5 0.3 [--json]
    PYTHONPATH=src python scripts/edge_attribution.py pandaset [--json]

``a9 SCORE...``: the A9 sample (``../shared/data/a9_sample``) with the shared detector's boxes (1280, traffic
classes, score >= SCORE; ``benchmarks/bench_calibration_detections.py``), against the pose its labelled
boxes give (the reference there; not a truth). ``pandaset``: PandaSet 002 frames 00-29 with the shared detector's
boxes (1280, score >= 0.3), against the first frame's ground-truth pose (the per-frame truths agree to
``truth_spread`` deg / m, printed).
"""

from __future__ import annotations

import json
import sys
import warnings

import numpy as np

EDGE_SIDES = ("left", "top", "right", "bottom")
SIZE_BANDS_PX = (40.0, 80.0, 160.0)
SCORE_BANDS = (0.5, 0.7, 0.85)


def split_pull(r: np.ndarray, J: np.ndarray, masks: dict, f_scale: float) -> dict:
    """The soft-L1 Gauss-Newton step at the linearisation pose and each group's part of it.

    ``r`` [m] residuals and ``J`` [m,6] their pose Jacobian (rotation vector rad, translation m) at the
    linearisation pose; ``masks``: name -> [m] bool rows. Returns {"step": dx [6], "groups": {name:
    {"pull": dx_g [6], "share": float, "z": |dx_g| in the Jacobian's sigma units, "n": rows}}}."""
    r, J = np.asarray(r, dtype=np.float64), np.asarray(J, dtype=np.float64)
    w = 1.0 / np.sqrt(1.0 + (r / f_scale) ** 2)  # soft-L1: rho'(z) at z = (r / f)^2
    H = J.T @ (w[:, None] * J)
    Hi = np.linalg.pinv(H)
    g = J * (w * r)[:, None]
    dx = -Hi @ g.sum(0)
    sig = np.sqrt(np.clip(np.diag(Hi), 1e-30, None))
    norm = float(dx @ H @ dx)
    out = {"step": dx, "groups": {}}
    for name, m in masks.items():
        m = np.asarray(m, dtype=bool).ravel()
        dg = -Hi @ g[m].sum(0)
        out["groups"][name] = {"pull": dg, "share": float(dg @ H @ dx) / norm if norm > 0 else 0.0,
                               "z": float(np.linalg.norm(dg / sig)), "n": int(m.sum())}
    return out


def edge_masks(obs: np.ndarray, size: tuple, shaped_r: np.ndarray, censored, tau: float,
               scores=None, objects=None) -> dict:
    """name -> [n,4] bool masks of the box edges (see the module docstring). ``obs`` [n,4] the 2D boxes,
    ``size`` (W, H), ``shaped_r`` [n,4] the weighted edge residuals (pred - obs) at the truth, ``censored``
    [n,4] or None, ``tau`` the occlusion shaping's knee (sigma units), ``scores`` [n] or None, ``objects``
    [n] object id per pair or None."""
    n = len(obs)
    W, H = size
    border = np.column_stack([obs[:, 0] <= 1, obs[:, 1] <= 1, obs[:, 2] >= W - 1, obs[:, 3] >= H - 1])
    cens = np.zeros((n, 4), bool) if censored is None else np.asarray(censored, dtype=bool)
    inward = np.nan_to_num(shaped_r) * np.array([-1.0, -1.0, 1.0, 1.0]) > tau
    shaped = inward & ~border & ~cens
    masks = {"border": border, "censored": cens & ~border, "shaped": shaped, "free": ~border & ~cens & ~shaped}
    for j, e in enumerate(EDGE_SIDES):
        m = np.zeros((n, 4), bool)
        m[:, j] = True
        masks["side " + e] = m
    s = np.sqrt(np.clip((obs[:, 2] - obs[:, 0]) * (obs[:, 3] - obs[:, 1]), 0, None))
    edges = (0.0, *SIZE_BANDS_PX, np.inf)
    for lo, hi in zip(edges[:-1], edges[1:]):
        masks[f"size {lo:.0f}-{hi:.0f} px"] = np.repeat(((s >= lo) & (s < hi))[:, None], 4, 1)
    if scores is not None:
        q = np.asarray(scores, dtype=np.float64)
        edges = (0.0, *SCORE_BANDS, np.inf)
        for lo, hi in zip(edges[:-1], edges[1:]):
            masks[f"score {lo:.2f}-{hi:.2f}"] = np.repeat(((q >= lo) & (q < hi))[:, None], 4, 1)
    if objects is not None:
        ids = np.asarray(objects)
        for i in np.unique(ids):
            masks[f"object {int(i)}"] = np.repeat((ids == i)[:, None], 4, 1)
    return masks


def _outline_kind(cframes) -> str:  # as ``calib.api`` names the outlines in use
    n_pts = sum(int(f.from_points.sum()) for f in cframes if f.from_points is not None)
    n_all = sum(f.n3 for f in cframes)
    return "corners" if n_pts == 0 else "points" if n_pts == n_all else "corners+points"


def attribute(frames, intr_given, truth, config=None) -> dict:
    """Calibrate ``frames`` (default config), rebuild its final edge cost at ``truth`` (a ``Pose``) and
    split the step from the truth over the groups (:func:`split_pull`, :func:`edge_masks`)."""
    from xcalib.calib.api import calibrate
    from xcalib.calib.boxproj import project_rects
    from xcalib.calib.config import CalibConfig
    from xcalib.calib.inputs import prepare_frames, with_corner_outlines, with_point_outlines
    from xcalib.calib.pose import Pose
    from xcalib.calib.refine import build_cost, match_all, pair_scores
    from xcalib.calib.terms import CostSpec
    from xcalib.calib.uncertainty import object_groups

    cfg = config or CalibConfig()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(frames, intr_given, cfg)
    d = res.diagnostics
    est = Pose.parse(res) if res.rotation is not None else Pose.parse(np.asarray(d.refused_T))
    cframes, intr, _ = prepare_frames(frames, intr_given, reestimate_yaw=cfg.reestimate_yaw, box_model=cfg.box_model,
                                      workers=1, scores=cfg.detector_scores)
    if d.box_model and d.box_model != _outline_kind(cframes):  # the run switched its outlines
        alt = with_corner_outlines(cframes)
        if alt is None:
            alt = with_point_outlines(cframes, [project_rects(f.corners, est.R, est.t, intr, f.size)[1] if f.n3
                                                else np.zeros(0, bool) for f in cframes])
        cframes = alt
    intr = res.intrinsics if res.intrinsics is not None else intr
    pairs = match_all(cframes, intr, est.R, est.t, gate_iou=cfg.gate_iou)
    spec = CostSpec.from_config(cfg)
    r_est = build_cost(cframes, pairs, intr, est, d.noise_model, spec).residuals(np.zeros(6))
    f_scale = max(0.5, 1.5 * float(np.median(np.abs(r_est)))) if len(r_est) else 2.0
    model = build_cost(cframes, pairs, intr, truth, d.noise_model, spec)
    term = model.terms[0]
    r, J = model.jacobian()
    n = len(term.obs)
    st = model.state(np.zeros(model.n_params))
    occ = term.occlusion
    masks = edge_masks(term.obs, term.size, term.edges(st) * term.w, term.censored,
                       np.inf if occ is None else occ.tau, pair_scores(cframes, pairs), object_groups(cframes, pairs))
    split = split_pull(r[:4 * n], J[:4 * n, :6], {k: v.ravel() for k, v in masks.items()}, f_scale)
    fit = model.fit(f_scale=f_scale, max_nfev=100)

    def deg_m(x):
        return [round(float(v), 3) for v in np.concatenate([np.degrees(x[:3]), x[3:]])]

    return {"success": bool(res.success), "refusal": d.refusal, "n_pairs": n, "box_model": d.box_model,
            "error": [round(float(v), 3) for v in est.delta(truth)],
            "fit": [round(float(v), 3) for v in fit.pose.delta(truth)], "step": deg_m(split["step"]),
            "groups": {k: {"share": round(v["share"], 3), "z": round(v["z"], 2), "n": v["n"], "pull": deg_m(v["pull"])}
                       for k, v in split["groups"].items()}}


def _print(name: str, rec: dict) -> None:
    print(f"{name}: {'success' if rec['success'] else rec['refusal']}, {rec['n_pairs']} pairs, outline "
          f"{rec['box_model']}\n  error (deg, m) {rec['error']}\n  refit from the truth {rec['fit']}\n"
          f"  step from the truth {rec['step']}")
    objs = sorted((k for k in rec["groups"] if k.startswith("object")), key=lambda k: -abs(rec["groups"][k]["share"]))
    for k, v in rec["groups"].items():
        if v["n"] and (not k.startswith("object") or k in objs[:5]):
            print(f"  {k:24s} edges {v['n']:5d}  share {v['share']:+.2f}  z {v['z']:.2f}")


def _a9(scores: list, as_json: bool) -> int:
    from pathlib import Path

    from xcalib.calib.api import calibrate
    from xcalib.calib.pose import Pose
    from xcalib.io.frames import read_frames

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_calibration_detections import DETS, SHARED, a9_folders, with_detections

    root = SHARED / "a9_sample"
    if not root.exists() or not DETS.exists():
        print(f"data not found: {root} / {DETS}")
        return 1
    seq = read_frames(root)
    frames = [seq[i] for i in range(len(seq))]
    ref = calibrate(frames, seq.intrinsics)
    if ref.rotation is None:
        print("the labelled boxes give no pose")
        return 1
    folder = a9_folders(root)
    for smin in scores:
        det = [with_detections(f, DETS / "yolox_nano_1280" / "a9" / f"{folder[f.frame_key]}.json", float(smin))
               for f in frames]
        rec = attribute(det, seq.intrinsics, Pose.parse(ref))
        if as_json:
            print(json.dumps({"case": f"a9 1280 >= {smin}", **rec}))
        else:
            _print(f"A9 detector 1280 score >= {smin} (against the labelled-box pose)", rec)
    return 0


def _pandaset(as_json: bool) -> int:
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_calibration_detections import DETS, SHARED, pandaset_frames

    root = SHARED / "pandaset_002"
    if not root.exists() or not DETS.exists():
        print(f"data not found: {root} / {DETS}")
        return 1
    seq, truths, det, _ = pandaset_frames(root)
    rec = attribute(det, seq.intrinsics, truths[0])
    rec["truth_spread"] = [round(float(v), 3) for v in np.max([t.error(truths[0]) for t in truths], axis=0)]
    if as_json:
        print(json.dumps({"case": "pandaset 002 detector 1280 >= 0.3", **rec}))
    else:
        _print("PandaSet 002 detector 1280 score >= 0.3 (against frame 00's truth)", rec)
        print(f"  the per-frame truths lie within {rec['truth_spread']} (deg, m) of frame 00's")
    return 0


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    as_json = "--json" in argv
    argv = [a for a in argv if a != "--json"]
    if argv[:1] == ["pandaset"]:
        return _pandaset(as_json)
    if len(argv) < 2 or argv[0] not in ("realism", "a9") or (argv[0] == "realism" and len(argv) < 3):
        print(__doc__)
        return 2
    from xcalib.calib.pose import Pose

    if argv[0] == "a9":
        return _a9(argv[1:], as_json)
    from xcalib.data.synth.realism import make_realism_case

    for seed in argv[2:]:
        case = make_realism_case(argv[1], int(seed))
        rec = attribute(list(case.frames), case.intrinsics_given, Pose.parse(case.T_cam_lidar))
        if as_json:
            print(json.dumps({"condition": argv[1], "seed": int(seed), **rec}))
        else:
            _print(f"{argv[1]} site {seed}", rec)
    return 0


if __name__ == "__main__":
    sys.exit(main())
