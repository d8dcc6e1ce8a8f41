"""How a detector's 2D box relates to the 3D box's outline (issue 25): measurements, not a benchmark.

``a9``: A9 sample (``$XCALIB_SHARED_DATA/a9_sample`` and ``real_detections``): calibrates with the
labelled 2D boxes (the reference pose) and with the detector's boxes (YOLOX-Nano 1280, traffic
classes, ``--score``), then, for every matched pair and at the labelled-box pose, the inset of each
2D box edge (left, top, right, bottom; share of the projected rectangle's width / height, positive:
the 2D box lies inside) against the rectangle of the yaw-fitted box's 8 corners and against the
rectangle of the LiDAR point hull, in bins of the viewing angle (0 deg: the ray along the box's
length, head-on; 90: side-on; boxes with a footprint over 3 m^2) and of the distance. Edges on the
image border are left out.

``synth CONDITION SEEDS``: realism sites (``xcalib.data.synth.realism``) with their true matches, the
pose refitted from the truth with the box model (a) plain, (b) one set of outline offsets for all
objects (``boxmodel.outline_edge_term``) and (c) one set per size kind of object
(``boxmodel.fit_kind_outline``); prints each fit's error against the truth.

    XCALIB_SHARED_DATA=../shared/data PYTHONPATH=src python scripts/outline_bias.py a9 [--score 0.5]
    PYTHONPATH=src python scripts/outline_bias.py synth detector_outline 0,16,18
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("XCALIB_SHARED_DATA", REPO.parent / "shared" / "data"))
ANGLE_BINS = ((0, 20), (20, 45), (45, 70), (70, 91))
DIST_BINS = ((0, 30), (30, 50), (50, 80), (80, 1000))


def _detector_frames(frames, score: float):
    root = SHARED / "a9_sample"
    man = json.loads((root / "manifest.json").read_text())
    folder = {str(e["frame_key"]): Path(e["detections"]).parent.name for e in man["frames"]}
    from detector_gap import detector_frames  # scripts/ (this script's folder): one reader of the detections

    return detector_frames(frames, folder, "1280", score)


def edge_insets(frames, intr, pairs, R, t) -> list[dict]:
    """Per matched pair: insets of the 2D box against the corner and point-hull rectangles at (R, t)."""
    from xcalib.calib.boxproj import project_rects
    from xcalib.calib.inputs import prepare_frames

    cf, intr2, _ = prepare_frames(frames, intr)
    campos = -R.T @ t
    rows = []
    for f, p in zip(cf, pairs):
        if not len(p):
            continue
        W, H = f.size
        i2m = {int(v): k for k, v in enumerate(f.idx2d)}
        i3m = {int(v): k for k, v in enumerate(f.idx3d)}
        rc, _ = project_rects(f.box_corners if f.box_corners is not None else f.corners, R, t, intr2, (W, H))
        rh, _ = project_rects(f.corners, R, t, intr2, (W, H))
        for a2, a3 in p:
            i2, i3 = i2m[int(a2)], i3m[int(a3)]
            b = np.asarray(f.boxes2d[i2], dtype=np.float64)
            rec = {}
            for key, c in (("corners", rc[i3]), ("hull", rh[i3])):
                w, h = c[2] - c[0], c[3] - c[1]
                rec[key] = np.array([(b[0] - c[0]) / w, (b[1] - c[1]) / h, (c[2] - b[2]) / w, (c[3] - b[3]) / h])
            c = rc[i3]
            border = np.array([min(c[0], b[0]) <= 1, min(c[1], b[1]) <= 1, max(c[2], b[2]) >= W - 1,
                               max(c[3], b[3]) >= H - 1])
            for key in ("corners", "hull"):
                rec[key][border] = np.nan
            box = f.boxes3d[i3]
            ray = box[:3] - campos
            axis = np.array([np.cos(box[6]), np.sin(box[6])])
            rec["angle"] = float(np.degrees(np.arccos(min(1.0, abs(axis @ ray[:2]) / np.linalg.norm(ray[:2])))))
            rec["dist"] = float(np.linalg.norm(ray))
            rec["area"] = float(box[3] * box[4])
            rows.append(rec)
    return rows


def _table(rows: list[dict], title: str) -> None:
    print(f"\n{title} (n={len(rows)}): median inset, share of the projected rectangle (L T R B)")
    for key in ("corners", "hull"):
        ins = np.array([r[key] for r in rows])
        print(f"  vs {key:7s} all            : " + " ".join(f"{v:+.3f}" for v in np.nanmedian(ins, 0)))
        ang, dist = np.array([r["angle"] for r in rows]), np.array([r["dist"] for r in rows])
        big = np.array([r["area"] > 3.0 for r in rows])
        for lo, hi in ANGLE_BINS:
            m = big & (ang >= lo) & (ang < hi)
            if m.sum():
                print(f"     view {lo:2d}-{hi:2d} deg n={m.sum():3d}: " + " ".join(f"{v:+.3f}" for v in np.nanmedian(ins[m], 0)))
        for lo, hi in DIST_BINS:
            m = (dist >= lo) & (dist < hi)
            if m.sum():
                print(f"     dist {lo:3d}-{hi:3d} m n={m.sum():3d}: " + " ".join(f"{v:+.3f}" for v in np.nanmedian(ins[m], 0)))


def run_a9(score: float) -> None:
    from xcalib.calib.api import calibrate
    from xcalib.calib.pose import Pose
    from xcalib.io.frames import read_frames

    seq = read_frames(SHARED / "a9_sample")
    frames, intr = [seq[i] for i in range(len(seq))], seq.intrinsics
    lab = calibrate(frames, intr)
    ref = Pose.parse(np.asarray(lab.extrinsics if lab.success else lab.diagnostics.refused_T))
    det_frames = _detector_frames(frames, score)
    det = calibrate(det_frames, intr)
    pose = Pose.parse(np.asarray(det.extrinsics if det.success else det.diagnostics.refused_T))
    print(f"A9 labelled: {lab.success} {lab.n_pairs} pairs; detector >= {score}: {det.success} {det.n_pairs} pairs, "
          f"{pose.error(ref)[0]:.3f} deg / {pose.error(ref)[1]:.3f} m from the labelled pose")
    _table(edge_insets(frames, intr, lab.pairs, ref.R, ref.t), "A9 labelled boxes at the labelled pose")
    _table(edge_insets(det_frames, intr, det.pairs, ref.R, ref.t), f"A9 detector boxes (>= {score}) at the labelled pose")


def run_synth(condition: str, seeds: list[int]) -> None:
    from xcalib.calib.boxmodel import fit_kind_outline, outline_edge_term
    from xcalib.calib.cost import Occlusion
    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.pose import Pose
    from xcalib.calib.refine import build_cost
    from xcalib.calib.uncertainty import object_groups
    from xcalib.data.synth.realism import REALISM_CONDITIONS, make_realism_case

    print(f"{condition}: pose error (deg / m) of the refit from the truth with the true matches")
    for seed in seeds:
        case = make_realism_case(REALISM_CONDITIONS[condition], seed, 20)
        truth = Pose.parse(case.T_cam_lidar)
        cf, intr, _ = prepare_frames(list(case.frames), case.intrinsics_given)
        pairs, tracks = [], []
        for f, fin in zip(cf, case.frames):
            ids2 = np.asarray(fin.meta["ids_2d"])[f.idx2d]
            ids3 = np.asarray(fin.track_ids_3d)[f.idx3d]
            p = [(i, j) for i in range(len(ids2)) for j in range(len(ids3)) if ids2[i] >= 0 and ids2[i] == ids3[j]]
            pairs.append(np.array(p, dtype=np.int64).reshape(-1, 2))
            tracks.append(ids3)
        groups = object_groups(cf, pairs, track_ids=tracks)
        plain = build_cost(cf, pairs, intr, truth, None, Occlusion()).fit(f_scale=2.0, max_nfev=80).pose
        common = build_cost(cf, pairs, intr, truth, None, Occlusion(), edge=outline_edge_term).fit(f_scale=2.0, max_nfev=80).pose
        kinds = fit_kind_outline(cf, pairs, intr, truth, None, 2.0, Occlusion(), groups)
        errs = [plain.error(truth), common.error(truth), kinds["pose"].error(truth)]
        offs = "; ".join(f"{k} " + " ".join(f"{v:+.3f}" for v in o.values()) for k, o in kinds["offsets"].items())
        print(f"  site {seed:2d}: {sum(len(p) for p in pairs):3d} pairs  plain {errs[0][0]:.3f}/{errs[0][1]:.3f}  "
              f"common {errs[1][0]:.3f}/{errs[1][1]:.3f}  per kind {errs[2][0]:.3f}/{errs[2][1]:.3f}  "
              f"(offsets sides height: {offs})", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("a9")
    a.add_argument("--score", type=float, default=0.5)
    s = sub.add_parser("synth")
    s.add_argument("condition")
    s.add_argument("seeds")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    if args.cmd == "a9":
        run_a9(args.score)
    else:
        run_synth(args.condition, [int(v) for v in args.seeds.split(",")])
    return 0


if __name__ == "__main__":
    sys.exit(main())
