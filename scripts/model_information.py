"""Can the data tell a wrong camera model from the right one? The robust-cost profile (issue 25).

A refusal "not verifiable" (``few_objects``, ``principal_point_unverifiable``,
``focal_unverifiable``) claims that the detections cannot tell a camera-model error that would move
the pose beyond the wrong-pose line from the right model. This measures that claim directly on a
realism site: its true matches at the true pose are refitted (pose free, matches held, the
calibration's soft-L1 cost) once with the true camera and once with each wrong camera, and the
robust cost's increase is counted once per object (divided by the matched pairs per distinct
object, the convention of ``calib.misfit``'s gains; the cost is half a chi-square in sigma units,
so a 2-sigma difference of one parameter needs about 2 per object). Next to it, how far the wrong
camera moves the refitted pose. A small increase with a large move: truly unverifiable; a large
increase where a check still refuses: a weak check.

    PYTHONPATH=src python scripts/model_information.py --condition clean --sites 9,10,20,0
    PYTHONPATH=src python scripts/model_information.py --condition clean_4px --sites 9,4

Session 10 (clean): a principal point 3 % of the width off costs 0.58 / 0.29 / 0.45 per object at
sites 9 / 10 / 20 (pose 1.4-1.6 deg off) against 9.4 / 121 at sites 0 / 3; at 4 px noise -0.07 at
site 9 (the data prefer the wrong cx).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import numpy as np

#: the wrong cameras tried: name -> (principal-point shift as a share of the width, focal scale)
ERRORS = {"pp+3%W": (0.03, 1.0), "pp-3%W": (-0.03, 1.0), "focal+5%": (0.0, 1.05), "focal-5%": (0.0, 0.95)}


def profile(cframes, intr, truth, errors: dict = ERRORS, max_nfev: int = 60) -> dict:
    """``{"pairs", "objects", "cost_true", name: {"dcost", "per_object", "pose_err"}}`` for the
    true matches of ``cframes`` (``calib.inputs.CalibFrame``) at ``truth`` (a ``calib.pose.Pose``)
    under ``intr`` (the true camera) and under each wrong camera of ``errors``."""
    from xcalib.calib.context import F_SCALE, FitContext
    from xcalib.calib.cost import Occlusion
    from xcalib.calib.pose import Pose
    from xcalib.calib.refine import lsq, match_all
    from xcalib.calib.uncertainty import object_groups

    pairs = match_all(cframes, intr, truth.R, truth.t)
    groups = object_groups(cframes, pairs)
    n, n_obj = int(sum(len(p) for p in pairs)), (int(groups.max()) + 1 if len(groups) else 0)
    per_obj = max(n / max(n_obj, 1), 1.0)
    W = cframes[0].size[0]
    c0 = float(lsq(FitContext(cframes, pairs, intr, truth, None, F_SCALE, Occlusion()), max_nfev)[2])
    out: dict = {"pairs": n, "objects": n_obj, "cost_true": c0}
    for name, (dx, s) in errors.items():
        wrong = dataclasses.replace(intr, cx=intr.cx + dx * W, fx=intr.fx * s, fy=intr.fy * s)
        R, t, c1, *_ = lsq(FitContext(cframes, pairs, wrong, truth, None, F_SCALE, Occlusion()), max_nfev)
        rot, tr = Pose(R, t).error(truth)
        out[name] = {"dcost": float(c1) - c0, "per_object": (float(c1) - c0) / per_obj, "pose_err": [rot, tr]}
    return out


def realism_profile(condition: str, seed: int, n_frames: int = 20) -> dict:
    """:func:`profile` of realism site ``seed`` under ``condition`` (its true camera and pose)."""
    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.pose import Pose
    from xcalib.data.synth.realism import REALISM_CONDITIONS, make_realism_case

    case = make_realism_case(REALISM_CONDITIONS[condition], seed, n_frames)
    T = np.asarray(case.T_cam_lidar)
    cframes, intr, _ = prepare_frames(list(case.frames), case.intrinsics_true)
    return {"condition": condition, "seed": seed, **profile(cframes, intr, Pose(T[:3, :3], T[:3, 3]))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--condition", default="clean")
    ap.add_argument("--sites", default="9,10,20", help="comma-separated realism site seeds")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--json", action="store_true", help="one JSON line per site instead of the table")
    args = ap.parse_args(argv)
    if not args.json:
        print("site objects pairs | " + " | ".join(f"{k}: dcost/object, pose err deg / m" for k in ERRORS))
    for seed in (int(s) for s in args.sites.split(",") if s):
        r = realism_profile(args.condition, seed, args.frames)
        if args.json:
            print(json.dumps(r), flush=True)
            continue
        cells = " | ".join(f"{r[k]['per_object']:+.2f}, {r[k]['pose_err'][0]:.2f} / {r[k]['pose_err'][1]:.2f}" for k in ERRORS)
        print(f"{seed:>4} {r['objects']:>7} {r['pairs']:>5} | {cells}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
