"""Is "a subset's pose against the all-frame pose" a yardstick for the sigma? (issue 25, session 10)

``bench_coverage_real.py`` judges the A9 sigma by comparing random frame subsets with the
all-frame labelled pose (A9 has no ground truth), the reference's sigma added in quadrature. On
synthetic roadside sites (static camera, as A9) with a known truth this script calibrates the
realism ``clean`` case with all 20 frames and with random 8-frame subsets, and compares each
subset's per-axis error z = |error| / sigma against the truth (the right yardstick) with the same
against the all-frame pose (with ``hypot(sd_sub, sd_all)`` as the benchmark does, and with the
subset's sigma alone). The subset shares its objects -- and so most of its error -- with the
all-frame pose, so the second yardstick shrinks z and shows a right sigma as too wide.

    PYTHONPATH=src OMP_NUM_THREADS=1 python scripts/subset_yardstick.py --sites 8 [--subsets 3] [--out FILE.jsonl]
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings

import numpy as np


def run(sites: int, subsets: int, out: str | None) -> list[dict]:
    import xcalib
    from xcalib.calib.pose import Pose
    from xcalib.data.synth.realism import identifiable_site_seeds, make_realism_case

    warnings.simplefilter("ignore")
    recs = []
    for seed in identifiable_site_seeds(sites, 20):
        case = make_realism_case("clean", seed)
        frames = list(case.frames)
        full = xcalib.calibrate(frames, case.intrinsics_given)
        if not full.success:
            continue
        p_full, p_true = Pose.parse(np.asarray(full.extrinsics)), Pose.parse(case.T_cam_lidar)
        sd_full = np.concatenate([full.rotation_std_deg, full.translation_std_m])
        rng = np.random.default_rng(seed)
        for k in range(subsets):
            idx = sorted(rng.choice(len(frames), 8, replace=False))
            sub = xcalib.calibrate([frames[i] for i in idx], case.intrinsics_given)
            if not sub.success:
                continue
            p_sub = Pose.parse(np.asarray(sub.extrinsics))
            rec = dict(seed=seed, k=k, e_truth=list(np.abs(p_sub.delta(p_true))), e_full=list(np.abs(p_sub.delta(p_full))),
                       sd_sub=list(np.concatenate([sub.rotation_std_deg, sub.translation_std_m])), sd_full=list(sd_full))
            recs.append(rec)
            if out:
                with open(out, "a") as f:
                    f.write(json.dumps(rec, default=float) + "\n")
    return recs


def summary(recs: list[dict]) -> None:
    et, ef = np.array([r["e_truth"] for r in recs]), np.array([r["e_full"] for r in recs])
    ss, sf = np.array([r["sd_sub"] for r in recs]), np.array([r["sd_full"] for r in recs])
    for name, e, sd in (("subset vs truth, subset sigma", et, ss),
                        ("subset vs all-frame pose, hypot(sub, all) (bench)", ef, np.hypot(ss, sf)),
                        ("subset vs all-frame pose, subset sigma", ef, ss)):
        z = e / sd
        print(f"{name:50s} n={len(e)} axes within 2 sigma {np.mean(z <= 1.959964):.3f}  rms z {np.sqrt(np.mean(z ** 2)):.2f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sites", type=int, default=8)
    ap.add_argument("--subsets", type=int, default=3)
    ap.add_argument("--out", default=None, help="append each subset's record to this .jsonl")
    ap.add_argument("--summary", default=None, help="only summarise the records of this .jsonl")
    args = ap.parse_args(argv)
    if args.summary:
        recs = [json.loads(line) for line in open(args.summary) if line.strip()]
    else:
        recs = run(args.sites, args.subsets, args.out)
    summary(recs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
